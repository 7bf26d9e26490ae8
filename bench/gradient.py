"""Gradient cost: time and peak memory of one gradient of an L2 loss on the Cornell box.

    python bench/gradient.py [--resolution 128] [--spp 64] [--max-depth 8] [--repeats 5]
    python bench/gradient.py --quick                    # small smoke run (32x32, few spp)
    python bench/gradient.py --tables 2 --max-autodiff-spp 64

The problem: ``mse_loss(render(scene), target)`` differentiated w.r.t. all four Cornell-box
parameters (``white``, ``red``, ``green`` reflectance and ``light`` emission, 12 scalars). The
target is the ground-truth scene rendered at ``--spp`` with seed 1000 and the same max_depth; the
parameters are then halved (Mitsuba's ``perturb=0.5``), so the gradient is far from zero. One
gradient is forward + backward (for invrender: ``render`` + ``mse_loss(...).backward()``).

Every configuration runs in its own fresh subprocess (``--child``), which reports as JSON its peak
RSS (``VmHWM``; see ``_measure.peak_rss_mib``) and its RSS after the imports, the scene load (for
invrender with its Embree scene built and its compiled bounce's Dr.Jit LLVM backend started, as
Mitsuba's child has loaded its plugins, built its scene and started the same backend) and the target
load, but before the first gradient. The *increment* (peak minus that baseline) is the
gradient's own memory; the absolute peak also counts torch/Dr.Jit and their libraries. Tables:

1. the main problem for invrender ``autodiff`` and ``replay`` and, when installed, Mitsuba 3
   ``prb`` (path replay) and ``path`` (plain AD): one warm-up gradient, then the median time of
   ``--repeats``; the ratios invrender replay / Mitsuba prb;
2. memory vs spp (16, 64, 256) for replay and autodiff: replay's increment should be flat;
3. memory vs max_depth (2, 4, 8, 16) at ``--spp``: replay's increment should not depend on it.

Tables 2 and 3 take one gradient per child, no warm-up, and show the child of median increment
among ``--memory-repeats`` (3) of them: the allocator makes a single child's increment vary by
about +-20% from run to run. A child that fails or runs longer than ``--timeout`` seconds is
printed as "failed". Figures are printed, never asserted.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from _measure import ChildError, Results, add_json_option, peak_rss_mib, print_json, rss_mib, run_json_child  # noqa: E402

PARAMS = ("white.reflectance", "red.reflectance", "green.reflectance", "light.emission")
MI_PARAMS = ("white", "red", "green", "light")  # the same four, as named in mitsuba_ref.PARAM_KEYS
PERTURB = 0.5  # differentiated values = ground truth * PERTURB (target: ground truth)
TARGET_SEED = 1000  # Mitsuba's target seed (seed + 1000 with seed 0)


# --------------------------------------------------------------------------------------- children


def child(args) -> dict:
    """One configuration (``args.child``) in this (fresh) process; the figures as a dict."""
    if args.child in ("prb", "path"):
        return _child_mitsuba(args)
    import torch

    import invrender as ir

    n = args.resolution
    scene = ir.load_scene("cornell_box", resolution=(n, n))
    target = torch.load(args.target)
    with torch.no_grad():
        for name in PARAMS:
            scene.params[name].mul_(PERTURB)
    for name in PARAMS:
        scene.params[name].requires_grad_(True)
    # what the Mitsuba child has done before its baseline (its plugins loaded, its scene's BVH built,
    # its Dr.Jit LLVM backend started): the Embree scene built and the compiled bounce's backend
    # started (libLLVM loaded: about 60 MiB), one-time costs of a process
    from invrender.backends import arrays
    from invrender.backends.accel import intersector_for

    intersector_for(scene.triangles)
    before_backend = rss_mib()
    arrays.drjit_arrays(torch.device("cpu"))
    baseline = rss_mib()

    def once(seed: int):
        for name in PARAMS:
            scene.params[name].grad = None
        start = time.perf_counter()
        img = ir.render(scene, spp=args.spp, max_depth=args.max_depth, seed=seed, estimator=args.child, progress=False)
        loss = torch.nn.functional.mse_loss(img, target)
        loss.backward()
        seconds = time.perf_counter() - start
        return seconds, float(loss.detach()), {name: scene.params[name].grad.tolist() for name in PARAMS}

    warmup = [once(0)[0] for _ in range(args.warmup)]
    runs = [once(i + 1) for i in range(args.repeats)]
    times = [r[0] for r in runs]
    return {
        "kind": args.child,
        "seconds": statistics.median(times),
        "all_seconds": times,
        "warmup_seconds": warmup,
        "baseline_rss_mib": baseline,
        "backend_rss_mib": baseline - before_backend,
        "peak_rss_mib": peak_rss_mib(),
        "loss": runs[-1][1],
        "grads": runs[-1][2],
    }


def _child_mitsuba(args) -> dict:
    """Mitsuba 3 through ``mitsuba_ref``'s in-process gradient, with a baseline RSS taken after
    importing Mitsuba and loading the scene once (its target render happens inside the helper)."""
    if not mitsuba_ref.available():
        raise RuntimeError("Mitsuba 3 is not available")
    n = args.resolution
    mitsuba_ref.cornell_scene(n, n, args.spp, args.max_depth, integrator=args.child)  # loads the plugins
    baseline = rss_mib()
    res = mitsuba_ref.gradient_in_process(n, n, args.spp, args.max_depth, args.child, MI_PARAMS, args.repeats, 0, PERTURB)
    out = {
        "kind": args.child,
        "seconds": res["seconds"],
        "all_seconds": res["all_seconds"],
        "warmup_seconds": [res["warmup_seconds"]],
        "baseline_rss_mib": baseline,
        "peak_rss_mib": res["peak_rss_mib"],  # this process's VmHWM, like the invrender children's
        "loss": res["loss"],
        "grads": {name: res["grads"][mi] for name, mi in zip(PARAMS, MI_PARAMS)},
        "mitsuba": res["mitsuba"],
    }
    if args.warmup == 0:
        out["note"] = "mitsuba_ref always takes one warm-up gradient"
    return out


def run_child(kind: str, resolution: int, spp: int, max_depth: int, repeats: int, warmup: int, target: str | None, timeout: float) -> dict:
    """Run one configuration in a fresh subprocess; its JSON, or ``{"failed": reason}``."""
    cmd = [
        sys.executable, os.path.abspath(__file__), "--child", kind, "--resolution", str(resolution), "--spp", str(spp),
        "--max-depth", str(max_depth), "--repeats", str(repeats), "--warmup", str(warmup), "--target", target or "",
    ]  # fmt: skip
    start = time.perf_counter()
    try:
        res = run_json_child(cmd, timeout)
    except ChildError as e:
        return {"failed": str(e)}
    res["child_seconds"] = time.perf_counter() - start
    return res


# --------------------------------------------------------------------------------------- parent


def machine_info() -> str:
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    mi = mitsuba_ref.label() if mitsuba_ref.available() else "Mitsuba 3 not installed"
    return f"{cpu}, {len(os.sched_getaffinity(0))} cores, {mem:.1f} GiB; torch {torch.__version__}; {mi}; load average {load}"


class Targets:
    """Target images (ground-truth scene, seed ``TARGET_SEED``), rendered once in the parent and
    written where the children load them, so that no child pays for them in its peak memory."""

    def __init__(self, folder: str, spp: int):
        self.folder, self.spp, self.paths = folder, spp, {}

    def __call__(self, resolution: int, max_depth: int) -> str:
        key = (resolution, max_depth)
        if key not in self.paths:
            import torch

            import invrender as ir

            scene = ir.load_scene("cornell_box", resolution=(resolution, resolution))
            with torch.no_grad():
                img = ir.render(scene, spp=self.spp, max_depth=max_depth, seed=TARGET_SEED, progress=False)
            path = os.path.join(self.folder, f"target_{resolution}_{max_depth}.pt")
            torch.save(img, path)
            self.paths[key] = path
        return self.paths[key]


def increment(res: dict) -> float | None:
    """Peak RSS minus the RSS before the first gradient, MiB (None for a failed child)."""
    return None if "failed" in res else res["peak_rss_mib"] - res["baseline_rss_mib"]


def _fmt(res: dict) -> tuple[str, str, str, str]:
    """(time, peak, increment, note) columns of a child's result, 7 characters wide."""
    if "failed" in res:
        word = "skipped" if res["failed"].startswith("skipped") else "failed"
        return (f"{word:>7}", f"{'-':>7}", f"{'-':>7}", res["failed"])
    return (f"{res['seconds']:7.3f}", f"{res['peak_rss_mib']:7.0f}", f"{increment(res):7.0f}", "")


def _grad_vector(res: dict) -> list[float]:
    return [v for name in PARAMS for v in res["grads"][name]]


def _rel_diff(a: dict, b: dict) -> float:
    x, y = _grad_vector(a), _grad_vector(b)
    return sum((p - q) ** 2 for p, q in zip(x, y)) ** 0.5 / max(sum(q * q for q in y) ** 0.5, 1e-30)


def main_table(args, targets: Targets, with_mitsuba: bool, record: Results) -> None:
    n, spp, depth = args.resolution, args.spp, args.max_depth
    target = targets(n, depth)
    kinds = [("invrender autodiff", "autodiff"), ("invrender replay", "replay")]
    if with_mitsuba:
        kinds += [(f"Mitsuba {mitsuba_ref.version()} prb", "prb"), (f"Mitsuba {mitsuba_ref.version()} path (AD)", "path")]
    print(f"\n1. one gradient, Cornell box {n}x{n}, {spp} spp, max_depth {depth}, 4 parameters (12 scalars), L2 loss;")
    print(f"   one warm-up, then median of {args.repeats}; each estimator in a fresh process")
    print(f"   {'estimator':<28} {'time s':>7} {'min-max s':>11} {'peak RSS MiB':>12} {'increment MiB':>13}   loss")
    results = {}
    rows = record.table(f"one gradient, Cornell box {n}x{n}, {spp} spp, max_depth {depth}, 4 parameters (12 scalars), L2 loss; "
                        f"one warm-up, then the median of {args.repeats}; each estimator in a fresh process",
                        ["estimator", "time s", "min-max s", "peak RSS MiB", "increment MiB"])  # fmt: skip
    for label, kind in kinds:
        res = results[kind] = run_child(kind, n, spp, depth, args.repeats, 1, target, args.main_timeout)
        t, peak, inc, note = _fmt(res)
        loss = f"{res['loss']:.6g}" if "loss" in res else note
        spread = f"{min(res['all_seconds']):.2f}-{max(res['all_seconds']):.2f}" if "all_seconds" in res else "-"
        print(f"   {label:<28} {t:>7} {spread:>11} {peak:>12} {inc:>13}   {loss}", flush=True)
        rows.append([label, t.strip(), spread, peak.strip(), inc.strip()])
    ad, rp = results["autodiff"], results["replay"]
    if "backend_rss_mib" in rp:
        line = f"invrender's compiled backend (Dr.Jit LLVM) started before the baseline: {rp['backend_rss_mib']:.0f} MiB, once per process (Mitsuba's baseline holds its own)"
        print(f"   {line}")
        record.note(line)
    if "failed" not in ad and "failed" not in rp:
        print(f"   gradient |replay - autodiff| / |autodiff| = {_rel_diff(rp, ad):.2e} (same seeds)")
        record.note(f"gradient |replay - autodiff| / |autodiff| = {_rel_diff(rp, ad):.2e} (same seeds)")
    if not with_mitsuba:
        print("   (Mitsuba 3 not installed or --no-mitsuba: no ratios; see bench/README.md)")
        return
    prb = results["prb"]
    if "failed" in rp or "failed" in prb:
        print("   (a run failed: no ratios)")
        return
    lines = [f"gradient |replay - Mitsuba prb| / |Mitsuba prb| = {_rel_diff(rp, prb):.2e} (independent samples: Monte Carlo noise)",
             f"ratio invrender replay / Mitsuba prb: time {rp['seconds'] / prb['seconds']:.2f}x, "
             f"peak RSS {rp['peak_rss_mib'] / prb['peak_rss_mib']:.2f}x, increment {increment(rp) / max(increment(prb), 1e-9):.2f}x"]  # fmt: skip
    for line in lines:
        print(f"   {line}")
        record.note(line)


def _spread(label: str, values: list[float | None], within: float | None = None) -> None:
    vals = [v for v in values if v is not None]
    if len(vals) < 2:
        print(f"   {label}: not enough successful runs")
        return
    lo, hi = min(vals), max(vals)
    ratio = hi / max(lo, 1e-9)
    verdict = f" ({'within' if ratio <= 1 + within else 'NOT within'} {within:.0%})" if within is not None else ""
    print(f"   {label} increment max/min: {ratio:.2f}{verdict}")


def median_child(results: list[dict]) -> dict:
    """The run with the median increment among successful ones (its time: the median time)."""
    ok = sorted((r for r in results if "failed" not in r), key=increment)
    if not ok:
        return results[0]
    res = dict(ok[(len(ok) - 1) // 2])
    res["seconds"] = statistics.median(r["seconds"] for r in ok)
    return res


def sweep_table(title: str, column: str, points: list[int], config, skip_autodiff, args, targets: Targets, record: Results) -> None:
    """One row per point: replay and autodiff time / peak / increment (one gradient per child; the
    child of median increment among ``--memory-repeats``)."""
    print(f"\n{title}; the median increment of {args.memory_repeats} process(es) per point")
    print(f"   {column:>9}   {'replay: time s':>14} {'peak MiB':>8} {'incr MiB':>8}   {'autodiff: time s':>16} {'peak MiB':>8} {'incr MiB':>8}")
    rows, notes = {}, []
    table = record.table(f"{title}; the median increment of {args.memory_repeats} process(es) per point",
                         [column, "replay: time s", "peak MiB", "incr MiB", "autodiff: time s", "peak MiB", "incr MiB"])
    for x in points:
        res, spp, depth = {}, *config(x)
        for kind in ("replay", "autodiff"):
            if kind == "autodiff" and skip_autodiff(x):
                res[kind] = {"failed": f"skipped (spp > --max-autodiff-spp {args.max_autodiff_spp})"}
                continue
            target = targets(args.resolution, depth)
            res[kind] = median_child([run_child(kind, args.resolution, spp, depth, 1, 0, target, args.timeout) for _ in range(args.memory_repeats)])
        rows[x] = res
        r, a = _fmt(res["replay"]), _fmt(res["autodiff"])
        print(f"   {x:>9}   {r[0]:>14} {r[1]:>8} {r[2]:>8}   {a[0]:>16} {a[1]:>8} {a[2]:>8}", flush=True)
        table.append([x, *(v.strip() for v in r[:3]), *(v.strip() for v in a[:3])])
        notes += [f"{column} {x} {kind}: {res[kind]['failed']}" for kind in res if "failed" in res[kind]]
    for note in notes:
        print(f"   note: {note}")
    _spread("replay", [increment(rows[x]["replay"]) for x in points], within=0.30)
    _spread("autodiff", [increment(rows[x]["autodiff"]) for x in points])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5, help="timed gradients of table 1 (median)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 32x32, 16 spp, 1 repeat, spp 4 16 64, depth 2 8")
    parser.add_argument("--tables", type=int, nargs="+", default=[1, 2, 3], choices=[1, 2, 3])
    parser.add_argument("--sweep-spp", type=int, nargs="+", help="spp of table 2 (default 16 64 256)")
    parser.add_argument("--sweep-depth", type=int, nargs="+", help="max_depth of table 3 (default 2 4 8 16)")
    parser.add_argument("--max-autodiff-spp", type=int, default=256, help="skip autodiff above this spp in table 2")
    parser.add_argument("--memory-repeats", type=int, help="processes per point of tables 2 and 3 (median increment; default 3)")
    parser.add_argument("--timeout", type=float, default=600, help="seconds per child of tables 2 and 3")
    parser.add_argument("--main-timeout", type=float, default=1800, help="seconds per child of table 1")
    parser.add_argument("--no-mitsuba", action="store_true", help="skip Mitsuba even when installed")
    parser.add_argument("--child", choices=["autodiff", "replay", "prb", "path"], help=argparse.SUPPRESS)
    parser.add_argument("--warmup", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--target", help=argparse.SUPPRESS)
    add_json_option(parser)
    args = parser.parse_args()

    if args.child:
        print_json(child(args))
        return 0

    if args.quick:
        args.resolution, args.spp, args.repeats = 32, 16, 1
    args.memory_repeats = args.memory_repeats or (1 if args.quick else 3)
    args.sweep_spp = args.sweep_spp or ([4, 16, 64] if args.quick else [16, 64, 256])
    args.sweep_depth = args.sweep_depth or ([2, 8] if args.quick else [2, 4, 8, 16])
    with_mitsuba = not args.no_mitsuba and mitsuba_ref.available()
    n = args.resolution
    print(f"gradient benchmark: {machine_info()}")
    print(f"target: ground truth at {args.spp} spp, seed {TARGET_SEED}; differentiated at parameters x {PERTURB}; "
          f"increment = peak RSS - RSS before the first gradient")  # fmt: skip
    start = time.perf_counter()
    record = Results("gradient", "Gradient cost: time and memory of one L2 gradient")
    with tempfile.TemporaryDirectory(prefix="invrender-gradient-bench-") as folder:
        targets = Targets(folder, args.spp)
        if 1 in args.tables:
            main_table(args, targets, with_mitsuba, record)
        if 2 in args.tables:
            sweep_table(
                f"2. memory vs spp: one gradient, {n}x{n}, max_depth {args.max_depth}", "spp", args.sweep_spp,
                lambda s: (s, args.max_depth), lambda s: s > args.max_autodiff_spp, args, targets, record,
            )  # fmt: skip
        if 3 in args.tables:
            sweep_table(
                f"3. memory vs max_depth: one gradient, {n}x{n}, {args.spp} spp", "max_depth", args.sweep_depth,
                lambda d: (args.spp, d), lambda d: False, args, targets, record,
            )  # fmt: skip
    print(f"\n(total {time.perf_counter() - start:.0f} s)")
    record.write(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
