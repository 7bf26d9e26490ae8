"""Replay gradient beyond the Cornell box: invrender ``replay`` against Mitsuba 3 ``prb``, scene by scene.

    python bench/gradient_scenes.py [--scenes cornell_specular,forward/textured_floor.toml] [--resolution 128] [--spp 64]

For each scene: ``mean((render - target)^2)`` differentiated with respect to every RGB colour
parameter that is a reflectance or an emission (textures are held fixed), at the scene's values
halved; the target is the scene at its own values, rendered once in the child (seed 1000). Each
estimator runs in a fresh process (``--child``): one warm-up gradient, then the median time of
``--repeats``, and its peak RSS minus the RSS before the first gradient (the increment; as in
``bench/gradient.py``, after the scene load, invrender's Embree scene and Dr.Jit backend or
Mitsuba's plugins). Mitsuba gets the same scene through ``mitsuba_ref.load_scene`` (one mesh per
material group, each with its own BSDF: its gradient is per mesh, which changes nothing of its
cost). Figures are printed, never asserted; ratios name the CPU (``machine_info`` line).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from _measure import ChildError, Results, add_json_option, peak_rss_mib, print_json, rss_mib, run_json_child  # noqa: E402
from gradient import machine_info  # noqa: E402

PERTURB = 0.5
TARGET_SEED = 1000
SCENES = "cornell_box,cornell_specular,forward/textured_floor.toml"


def _scene(name: str, n: int):
    import invrender as ir

    path = Path(__file__).resolve().parents[1] / name  # a file of the repository (forward/...)
    return ir.load_scene(str(path) if path.exists() else name, resolution=(n, n))


def _colour_params(scene) -> list[str]:
    """The reflectances and emissions that are RGB colours (3 floats)."""
    return [k for k, v in scene.params.items() if k.endswith((".reflectance", ".emission")) and v.dim() == 1 and v.numel() == 3]


def _timed(once, repeats: int) -> tuple[list[float], float]:
    warmup = once(0)
    return [once(i + 1) for i in range(repeats)], warmup


def child_invrender(args) -> dict:
    import torch

    import invrender as ir
    from invrender.backends import arrays
    from invrender.backends.accel import intersector_for

    scene = _scene(args.scene, args.resolution)
    names = _colour_params(scene)
    with torch.no_grad():
        target = ir.render(scene, spp=args.spp, max_depth=args.max_depth, seed=TARGET_SEED, progress=False)
        for n in names:
            scene.params[n].mul_(PERTURB)
    for n in names:
        scene.params[n].requires_grad_(True)
    intersector_for(scene.triangles)
    arrays.drjit_arrays(torch.device("cpu"))
    baseline = rss_mib()

    def once(seed: int) -> float:
        for n in names:
            scene.params[n].grad = None
        start = time.perf_counter()
        img = ir.render(scene, spp=args.spp, max_depth=args.max_depth, seed=seed, estimator="replay", progress=False)
        torch.nn.functional.mse_loss(img, target).backward()
        return time.perf_counter() - start

    times, warmup = _timed(once, args.repeats)
    return {"seconds": statistics.median(times), "all_seconds": times, "warmup_seconds": warmup, "baseline_rss_mib": baseline,
            "peak_rss_mib": peak_rss_mib(), "parameters": names}  # fmt: skip


def child_mitsuba(args) -> dict:
    mi, dr = mitsuba_ref._require()
    scene = mitsuba_ref.load_scene(_scene(args.scene, args.resolution), args.spp, args.max_depth, integrator="prb")
    target = mitsuba_ref._render_synced(scene, args.spp, TARGET_SEED)
    p = mi.traverse(scene)
    keys = [k for k in p.keys() if k.endswith(("reflectance.value", "radiance.value")) and dr.width(p[k]) == 1 and len(p[k]) == 3]
    for k in keys:
        p[k] = p[k] * PERTURB
        dr.enable_grad(p[k])
    p.update()
    baseline = rss_mib()

    def once(seed: int) -> float:
        for k in keys:
            dr.clear_grad(p[k])
        start = time.perf_counter()
        with mitsuba_ref.whole_pool():
            img = mi.render(scene, p, spp=args.spp, seed=seed)
            loss = dr.mean(dr.square(img - target), axis=None)
            dr.backward(loss)
            dr.eval(loss, *[dr.grad(p[k]) for k in keys])
            dr.sync_thread()
        return time.perf_counter() - start

    times, warmup = _timed(once, args.repeats)
    return {"seconds": statistics.median(times), "all_seconds": times, "warmup_seconds": warmup, "baseline_rss_mib": baseline,
            "peak_rss_mib": peak_rss_mib(), "parameters": keys}  # fmt: skip


def run_child(kind: str, scene: str, args) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", kind, "--scene", scene, "--resolution", str(args.resolution),
           "--spp", str(args.spp), "--max-depth", str(args.max_depth), "--repeats", str(args.repeats)]  # fmt: skip
    try:
        return run_json_child(cmd, args.timeout)
    except ChildError as e:
        return {"failed": str(e)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default=SCENES, help=f"comma-separated scene names or files of the repository (default: {SCENES})")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--timeout", type=float, default=900, help="seconds per child")
    parser.add_argument("--child", choices=["replay", "prb"], help=argparse.SUPPRESS)
    parser.add_argument("--scene", help=argparse.SUPPRESS)
    add_json_option(parser)
    args = parser.parse_args()
    if args.child:
        print_json(child_invrender(args) if args.child == "replay" else child_mitsuba(args))
        return 0
    for name in ("resolution", "spp", "max_depth", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    from invrender.errors import InvRenderError

    for scene in args.scenes.split(","):
        try:
            _scene(scene, 8)
        except InvRenderError as e:
            parser.error(str(e))

    with_mitsuba = mitsuba_ref.available()
    print(f"replay gradient per scene: {machine_info()}")
    record = Results("gradient_scenes", "Replay gradient per scene against Mitsuba 3 prb")
    n = args.resolution
    title = (f"one gradient of an L2 loss in every RGB reflectance and emission, {n}x{n}, {args.spp} spp, max_depth {args.max_depth}; "
             f"one warm-up, then the median of {args.repeats}; each in a fresh process")  # fmt: skip
    print(f"\n{title}")
    print(f"   {'scene':<32} {'replay s':>9} {'incr MiB':>8} {'prb s':>7} {'incr MiB':>8} {'ratio':>6}")
    rows = record.table(title, ["scene", "invrender replay s", "increment MiB", "Mitsuba prb s", "increment MiB", "replay / prb"])
    for scene in args.scenes.split(","):
        ours = run_child("replay", scene, args)
        theirs = run_child("prb", scene, args) if with_mitsuba else {"failed": "Mitsuba 3 not installed"}
        cells = []
        for res in (ours, theirs):
            ok = "failed" not in res
            cells += [f"{res['seconds']:.3f}" if ok else "failed", f"{res['peak_rss_mib'] - res['baseline_rss_mib']:.0f}" if ok else "-"]
        ratio = f"{ours['seconds'] / theirs['seconds']:.2f}x" if "failed" not in ours and "failed" not in theirs else "-"
        print(f"   {scene:<32} {cells[0]:>9} {cells[1]:>8} {cells[2]:>7} {cells[3]:>8} {ratio:>6}", flush=True)
        for res in (ours, theirs):
            if "failed" in res:
                print(f"      ({res['failed']})")
        rows.append([scene, *cells, ratio])
    record.write(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
