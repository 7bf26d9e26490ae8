"""The inverse-rendering acceptance fit: the Cornell box's three albedos and light emission.

    python bench/fit_cornell.py [--resolution 64] [--target-spp 4096] [--out runs/fit_cornell]

Renders a target of the classic Cornell box at high spp, resets ``white``, ``red``, ``green`` to grey
0.5 and ``light.emission`` to 5, runs ``ir.fit`` with its defaults (any setting can be overridden,
e.g. ``--set steps=300 --set loss=l2``), and prints the recovered values, every channel's relative
error against the ground truth, the steps and the wall time. With ``--out`` it also writes the fit
report (JSON) and the loss / error plot (PNG).
"""

from __future__ import annotations

import argparse
import time

import torch

import invrender as ir

PARAMS = ["white.reflectance", "red.reflectance", "green.reflectance", "light.emission"]


def setting(text: str) -> tuple[str, object]:
    """``"KEY=VALUE"`` -> (KEY, VALUE as int, float, bool or str: the first that parses)."""
    key, _, value = text.partition("=")
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            pass
    return key, {"true": True, "false": False}.get(value.lower(), value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--target-spp", type=int, default=4096)
    parser.add_argument("--target-seed", type=int, default=12345)
    parser.add_argument("--set", type=setting, action="append", default=[], metavar="KEY=VALUE", help="an ir.fit setting")
    parser.add_argument("--out", default=None, help="folder for report.json and loss.png")
    args = parser.parse_args()

    n = args.resolution
    scene = ir.load_scene("cornell_box", resolution=(n, n))
    truth = {k: scene.params[k].clone() for k in PARAMS}
    start = time.perf_counter()
    target = ir.render(scene, spp=args.target_spp, max_depth=8, seed=args.target_seed)
    target_seconds = time.perf_counter() - start
    with torch.no_grad():
        for k in PARAMS:
            scene.params[k].fill_(5.0 if k.endswith(".emission") else 0.5)

    start = time.perf_counter()
    res = ir.fit(scene, target, PARAMS, truth=truth, **dict(args.set))
    seconds = time.perf_counter() - start

    s = res.settings
    print(f"Cornell box {n}x{n}: target {args.target_spp} spp ({target_seconds:.1f} s); fit from grey 0.5 / emission 5")
    print(f"settings: {s.steps} steps, loss {s.loss}, lr {s.lr}/{s.lr_emission}, spp {s.spp}->{s.spp_final}, "
          f"max_depth {s.max_depth}, estimator {s.estimator}, decorrelate {s.decorrelate}")  # fmt: skip
    print(f"{'parameter':<20} {'recovered':<28} {'truth':<28} rel. error per channel")
    fmt = lambda t: "(" + ", ".join(f"{x:.4f}" for x in t.tolist()) + ")"  # noqa: E731
    for k in PARAMS:
        got, want = res.params[k], truth[k]
        err = ((got - want).abs() / want.abs()).tolist()
        print(f"{k:<20} {fmt(got):<28} {fmt(want):<28} " + ", ".join(f"{100 * e:.2f}%" for e in err))
    worst = max(res.errors.values())  # the largest of the channel errors above (relative_error per parameter)
    print(f"largest relative error {100 * worst:.2f}% ({'within' if worst <= 0.02 else 'OUTSIDE'} 2%); "
          f"{len(res.history)} steps in {seconds:.1f} s ({seconds / len(res.history):.2f} s/step)")  # fmt: skip
    if args.out:
        from pathlib import Path

        from invrender.inverse.report import plot_history, report_dict, write_json

        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "report.json", report_dict(res))
        plot_history(res, out / "loss.png")
        print(f"wrote {out / 'report.json'}, {out / 'loss.png'}")


if __name__ == "__main__":
    main()
