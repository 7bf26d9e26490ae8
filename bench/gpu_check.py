"""Every CUDA path of invrender, each against the CPU result of the same seed, in one short run.

    python bench/gpu_check.py --out DIR [--device cuda|cpu] [--quick]

Runs on ``--device`` (default ``cuda``) and again on the CPU, with the same scene, settings and
seed, and compares the two:

- ``render_torch``, ``render_warp``: the Cornell box with the ``torch`` and ``warp`` intersection
  backends (images: largest pixel difference at most 1e-4 of the image's mean);
- ``kernels``: the compiled bounce (Dr.Jit's CUDA backend on a GPU: the lane functions of
  ``invrender.core.lanes`` and the plugins, the camera samples among them) against their eager torch
  evaluation on the device (uniforms, camera samples and the sampler ``"stratified_direct"``'s
  first-vertex numbers bit for bit; images with the ``"stratified"`` and ``"stratified_direct"``
  samplers as above), and their images against the CPU's;
- ``grad_replay``, ``grad_autodiff``: the L2 gradient of four parameters by path replay and by
  autodiff (largest difference at most 1e-3 of the largest component);
- ``records``: path records (:func:`invrender.record_paths`): their image and Jacobian;
- ``fit_lm``, ``fit_adam``: a short Levenberg-Marquardt fit on records and a few Adam steps on
  re-traced renders, from the same start (fitted values within 1e-3 relative);
- ``process_group``: a 1-rank process group (NCCL on CUDA, gloo on the CPU): an all-reduce and a
  render inside the group, against the render outside;
- ``throughput``: the forward render (Cornell 128x128, 64 spp, depth 8) on the device with each
  backend present, in M path samples/s, beside Mitsuba 3 ``cuda_ad_rgb`` when it imports.

Renders compared across devices stop at ``max_depth`` 4, below Russian roulette's ``rr_depth`` 5, so
that float rounding of a throughput cannot end one device's path and not the other's; renders and
gradients name their backend (the same on both devices), records and fits use each device's
default (``warp`` on CUDA, ``embree`` on the CPU, ``torch`` where their package is missing). A check
whose package or device is missing (warp-lang, NCCL, Mitsuba) is listed as skipped with the reason.
``--device cpu`` runs the CPU against itself: a smoke test of this script, in seconds with
``--quick`` (smaller images and fits; the CI runs it, tests/scale/test_gpu_check.py).

Writes ``DIR/gpu_check.json`` (machine, settings, every check's status, errors, tolerances and
seconds, the throughput) and prints one line per check. Exit status 0 when no check failed, 1 when
one did, 2 on bad arguments (``--device cuda`` where torch sees no GPU).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

import torch

import invrender as ir
from invrender.backends import accel, arrays, kernels, packages

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _measure import machine  # noqa: E402

CPU = torch.device("cpu")
#: the Cornell box's four parameters, differentiated and fitted
NAMES = ["white.reflectance", "red.reflectance", "green.reflectance", "light.emission"]
IMAGE_TOL = 1e-4  # largest pixel difference / image mean
GRAD_TOL = 1e-3  # largest difference / largest component
PARAM_TOL = 1e-3  # largest relative difference of fitted values


@dataclasses.dataclass(frozen=True)
class Sizes:
    """Image sizes, samples and fit lengths of one run (``--quick``: the CI's smoke test)."""

    resolution: int = 64
    spp: int = 16
    fit_resolution: int = 32
    adam_steps: int = 10
    lm_rounds: int = 2
    throughput_resolution: int = 128
    throughput_spp: int = 64
    repeats: int = 3


QUICK = Sizes(resolution=16, spp=4, fit_resolution=12, adam_steps=3, lm_rounds=1, throughput_resolution=32, throughput_spp=8, repeats=1)
DEPTH = 4  # below rr_depth 5: no roulette in compared renders


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def cornell(n: int, device: torch.device, scale: float = 1.0):
    """The Cornell box at n x n on ``device``, its four parameters times ``scale``."""
    scene = ir.load_scene("cornell_box", resolution=(n, n), device=device)
    if scale != 1.0:
        with torch.no_grad():
            for name in NAMES:
                scene.params[name].mul_(scale)
    return scene


@dataclasses.dataclass
class Kernels:
    """Set INVRENDER_KERNELS for a block (None: leave it), and with it INVRENDER_BOUNCE: ``torch``
    runs everything as eager torch, another value compiles the bounce (Dr.Jit, where it loads)."""

    value: str | None

    def __enter__(self):
        self.saved = {name: os.environ.get(name) for name in (kernels.ENV, arrays.ENV)}
        if self.value is not None:
            os.environ[kernels.ENV] = self.value
            os.environ[arrays.ENV] = "torch" if self.value == "torch" else "drjit"

    def __exit__(self, *exc):
        for name, value in self.saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


# --- what each check computes on one device: name -> (kind, tensor) ------------------------------


def render_with(backend: str, kernel_choice: str | None):
    def run(sizes: Sizes, device: torch.device) -> dict:
        with Kernels(kernel_choice):
            img = ir.render(cornell(sizes.resolution, device), spp=sizes.spp, max_depth=DEPTH, seed=3, backend=backend, progress=False)
        return {"image": ("image", img)}

    return run


def check_kernels(sizes: Sizes, device: torch.device) -> dict:
    """The compiled bounce (Dr.Jit) against eager torch on ``device``; its image for the CPU's."""
    from invrender.core.sampler import mirrored, path_keys, uniform

    pixel = torch.arange(200_000, device=device)
    keys = mirrored(path_keys(7, pixel, pixel % 13), pixel % 3 == 0)
    with Kernels("warp"):
        fused = uniform(keys, 3, 7)
    with Kernels("torch"):
        expected = uniform(keys, 3, 7)
    out = {"uniforms": ("exact", fused), "uniforms_vs_torch": ("self", (fused, expected, "exact"))}
    scene = cornell(sizes.resolution, device)
    from invrender.core import driver
    from invrender.core.driver import RenderSettings

    ids = torch.arange(5, sizes.resolution**2 * sizes.spp, 3, device=device)
    with Kernels("warp"):
        camera = driver._camera_samples(scene, RenderSettings(spp=sizes.spp, seed=3), ids)
    with Kernels("torch"):
        expected_camera = driver._camera_samples(scene, RenderSettings(spp=sizes.spp, seed=3), ids)
    out["camera_samples"] = ("exact", camera[2])
    out["camera_samples_vs_torch"] = ("self", (camera[2], expected_camera[2], "exact"))
    strata = {}  # the first vertex's stratified numbers of "stratified_direct" (the camera samples' last output)
    for choice in ("warp", "torch"):
        with Kernels(choice):
            strata[choice] = driver._camera_samples(scene, RenderSettings(spp=sizes.spp, seed=3, sampler="stratified_direct"), ids)[-1]
    out["direct_strata"] = ("exact", strata["warp"])
    out["direct_strata_vs_torch"] = ("self", (strata["warp"], strata["torch"], "exact"))
    images = {}
    for choice in ("warp", "torch"):
        for sampler in ("stratified", "stratified_direct"):
            with Kernels(choice):
                images[choice, sampler] = ir.render(scene, spp=sizes.spp, max_depth=DEPTH, seed=3, backend="torch", sampler=sampler, progress=False)
    for sampler, suffix in (("stratified", ""), ("stratified_direct", "_stratified_direct")):
        out["image" + suffix] = ("image", images["warp", sampler])
        out[f"image{suffix}_vs_torch"] = ("self", (images["warp", sampler], images["torch", sampler], "image"))
    return out


def gradient(estimator: str, kernel_choice: str | None = None):
    """The L2 gradient; ``kernel_choice`` "torch": with the torch bounce (replay's adjoint pass,
    where the fused bounce would otherwise carry the derivatives forward)."""

    def run(sizes: Sizes, device: torch.device) -> dict:
        with Kernels(kernel_choice):
            return _gradient(sizes, device, estimator)

    return run


def _gradient(sizes: Sizes, device: torch.device, estimator: str) -> dict:
    target = ir.render(cornell(sizes.resolution, CPU), spp=sizes.spp, max_depth=DEPTH, seed=99, backend="torch", progress=False).to(device)
    scene = cornell(sizes.resolution, device, scale=0.8)
    for name in NAMES:
        scene.params[name].requires_grad_(True)
    img = ir.render(scene, spp=sizes.spp, max_depth=DEPTH, seed=1, estimator=estimator, backend="torch", progress=False)
    ((img - target) ** 2).mean().backward()
    out = {"image": ("image", img.detach())}
    out.update({f"grad {n}": ("grad", scene.params[n].grad) for n in NAMES})
    return out


def check_records(sizes: Sizes, device: torch.device) -> dict:
    scene = cornell(sizes.fit_resolution, device, scale=0.8)
    rec = ir.record_paths(scene, NAMES, spp=sizes.spp, max_depth=3, seed=5, device=device, progress=False)
    out = {"image": ("image", rec.image().float())}
    out.update({f"jacobian {n}": ("grad", j) for n, j in rec.jacobian().items()})
    return out


def fit_target(sizes: Sizes) -> torch.Tensor:
    return ir.render(cornell(sizes.fit_resolution, CPU), spp=64 if sizes is QUICK else 256, max_depth=3, seed=77, progress=False)


def fit(solver: str):
    def run(sizes: Sizes, device: torch.device) -> dict:
        scene = cornell(sizes.fit_resolution, device)
        truth = {n: scene.params[n].detach().cpu().clone() for n in NAMES}
        with torch.no_grad():
            for n in NAMES[:3]:
                scene.params[n].fill_(0.5)
            scene.params["light.emission"].fill_(5.0)
        if solver == "lm":
            res = ir.fit(scene, fit_target(sizes), NAMES, solver="lm", max_depth=3, spp=16, rounds=sizes.lm_rounds, progress=False)
        else:
            res = ir.fit(scene, fit_target(sizes), NAMES, max_depth=3, steps=sizes.adam_steps, spp=4, spp_final=4, progress=False)
        out = {f"{n}": ("param", res.params[n]) for n in NAMES}
        out["error vs truth"] = ("info", max(float(((res.params[n].cpu() - truth[n]).abs() / truth[n]).max()) for n in NAMES))
        return out

    return run


def check_process_group(sizes: Sizes, device: torch.device) -> dict:
    """A 1-rank group of the device's backend: an all-reduce, and a render inside the group."""
    dist = torch.distributed
    backend = "nccl" if device.type == "cuda" else "gloo"
    outside = ir.render(cornell(sizes.resolution, device), spp=sizes.spp, max_depth=DEPTH, seed=4, backend="torch", progress=False)
    with tempfile.TemporaryDirectory() as tmp:
        bound = {"device_id": torch.device("cuda", torch.cuda.current_device())} if backend == "nccl" else {}  # NCCL: this GPU
        dist.init_process_group(backend, init_method=f"file://{tmp}/store", rank=0, world_size=1, **bound)
        try:
            x = torch.arange(4, dtype=torch.float32, device=device)
            dist.all_reduce(x)
            dist.barrier()
            inside = ir.render(cornell(sizes.resolution, device), spp=sizes.spp, max_depth=DEPTH, seed=4, backend="torch", progress=False)
        finally:
            dist.destroy_process_group()
    return {
        "all_reduce": ("self", (x, torch.arange(4, dtype=torch.float32, device=device), "exact")),
        "image": ("image", inside),
        "image_vs_outside": ("self", (inside, outside, "image")),
    }


@dataclasses.dataclass(frozen=True)
class Check:
    name: str
    what: str
    run: object
    needs: tuple[str, ...] = ()


CHECKS = [
    Check("render_torch", "render, torch backend", render_with("torch", None)),
    Check("render_warp", "render, warp backend (Warp's BVH)", render_with("warp", None), ("warp",)),
    Check("kernels", "compiled bounce (Dr.Jit) against eager torch", check_kernels, ()),
    Check("grad_replay", "L2 gradient of 4 parameters, path replay (the fused bounce's forward-mode derivatives)", gradient("replay")),
    Check("grad_replay_torch", "L2 gradient of 4 parameters, path replay with the torch bounce (adjoint pass)", gradient("replay", "torch")),
    Check("grad_autodiff", "L2 gradient of 4 parameters, autodiff", gradient("autodiff")),
    Check("records", "path records: image and Jacobian", check_records),
    Check("fit_lm", "lm fit on records", fit("lm")),
    Check("fit_adam", "Adam steps on re-traced renders", fit("adam")),
    Check("process_group", "1-rank process group (NCCL on CUDA, gloo on the CPU)", check_process_group, ("group",)),
]


def missing(needs: tuple[str, ...], device: torch.device) -> str | None:
    """Why a check cannot run here (None: it can)."""
    for need in needs:
        if need == "warp" and packages.find("warp") is None:
            return f"warp-lang is not installed ({packages.install_hint('warp')})"
        if need == "group":
            if not torch.distributed.is_available():
                return "this torch has no torch.distributed"
            if device.type == "cuda" and not torch.distributed.is_nccl_available():
                return "this torch has no NCCL"
    return None


def compare(kind: str, a: torch.Tensor, b: torch.Tensor) -> tuple[float, float]:
    """(error, tolerance) of ``a`` against the reference ``b`` for a kind of result."""
    a, b = a.detach().double().cpu(), b.detach().double().cpu()
    if a.shape != b.shape:
        return float("inf"), 0.0
    if kind == "exact":
        return float((a != b).sum()), 0.0
    diff = float((a - b).abs().max()) if a.numel() else 0.0
    if kind == "image":
        return diff / max(float(b.abs().mean()), 1e-12), IMAGE_TOL
    if kind == "grad":
        return diff / max(float(b.abs().max()), 1e-30), GRAD_TOL
    return float(((a - b).abs() / b.abs().clamp_min(1e-12)).max()), PARAM_TOL  # param


def run_check(check: Check, sizes: Sizes, device: torch.device) -> dict:
    """One check on ``device`` and on the CPU; its status, errors and seconds."""
    entry = {"name": check.name, "what": check.what}
    reason = missing(check.needs, device)
    if reason:
        return {**entry, "status": "skipped", "reason": reason}
    try:
        sync(device)
        start = time.perf_counter()
        ours = check.run(sizes, device)
        sync(device)
        entry["seconds"] = round(time.perf_counter() - start, 3)
        start = time.perf_counter()
        ref = check.run(sizes, CPU)
        entry["cpu_seconds"] = round(time.perf_counter() - start, 3)
    except Exception as e:  # a failed check is reported, the others still run
        return {**entry, "status": "failed", "reason": f"{type(e).__name__}: {e}".splitlines()[0], "traceback": traceback.format_exc()}
    results, ok = {}, True
    for key, (kind, value) in ours.items():
        if kind == "info":
            results[key] = {"device": value, "cpu": ref[key][1]}
            continue
        if kind == "self":  # two results on the device compared with each other
            a, b, kind = value
            label = f"{key} (on {device})"
        else:
            a, b, label = value, ref[key][1], f"{key} (vs cpu)"
        err, tol = compare(kind, a, b)
        good = err <= tol
        ok &= good
        results[label] = {"kind": kind, "error": err, "tolerance": tol, "ok": good}
    return {**entry, "status": "passed" if ok else "failed", "results": results}


def throughput(sizes: Sizes, device: torch.device) -> dict:
    """Forward renders (Cornell box, max_depth 8) on ``device`` per backend present, and Mitsuba's
    ``cuda_ad_rgb`` beside them on CUDA when it imports."""
    n, spp, depth = sizes.throughput_resolution, sizes.throughput_spp, 8
    scene = cornell(n, device)
    rows, skipped = [], []
    backends = ["torch", "warp"] if device.type == "cuda" else ["torch", "warp", "embree"]
    for backend in backends:
        why = accel.missing(backend)
        if why is not None:
            skipped.append({"name": f"throughput {backend}", "reason": why})
            continue
        times = []
        for seed in range(sizes.repeats + 1):  # the first: a warm-up (BVH, kernels, caches)
            sync(device)
            start = time.perf_counter()
            ir.render(scene, spp=spp, max_depth=depth, seed=seed, backend=backend, progress=False)
            sync(device)
            times.append(time.perf_counter() - start)
        t = sorted(times[1:])[len(times[1:]) // 2]
        rows.append({"renderer": f"invrender path ({backend})", "seconds": round(t, 4), "mpaths_per_s": round(n * n * spp / t / 1e6, 3)})
    mitsuba = None
    if device.type != "cuda":
        skipped.append({"name": "throughput Mitsuba cuda_ad_rgb", "reason": f"needs --device cuda (this run: {device})"})
    else:
        import mitsuba_ref

        if not mitsuba_ref.available():
            skipped.append({"name": "throughput Mitsuba cuda_ad_rgb", "reason": "Mitsuba 3 is not importable (pip install mitsuba)"})
        else:
            mitsuba = mitsuba_ref.cuda_forward(n, spp, depth, max(1, sizes.repeats)).strip()
    return {"scene": f"cornell_box {n}x{n}, {spp} spp, max_depth {depth}, {device}", "rows": rows, "mitsuba": mitsuba, "skipped": skipped}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="folder for gpu_check.json (made if missing)")
    parser.add_argument("--device", default="cuda", choices=["cuda", "cpu"], help="the device checked against the CPU (default cuda)")
    parser.add_argument("--quick", action="store_true", help="small images and fits (the CI's smoke test)")
    parser.add_argument("--only", default=None, metavar="NAMES", help="comma-separated check names to run (default: all, and the throughput)")
    args = parser.parse_args(argv)
    if args.device == "cuda" and not torch.cuda.is_available():
        print("gpu_check: error: --device cuda, but torch sees no CUDA device here (use --device cpu for the smoke test)", file=sys.stderr)
        return 2
    known = [c.name for c in CHECKS] + ["throughput"]
    only = args.only.split(",") if args.only else known
    unknown = [name for name in only if name not in known]
    if unknown:
        print(f"gpu_check: error: unknown check(s) {', '.join(unknown)} (known: {', '.join(known)})", file=sys.stderr)
        return 2
    device = torch.device(args.device)
    sizes = QUICK if args.quick else Sizes()
    begin = time.perf_counter()
    info = machine()
    print(f"gpu_check: {device} against cpu; torch {torch.__version__}; {info.get('cuda') or info['cpu']}{' (quick)' if args.quick else ''}")
    checks = []
    for check in CHECKS:
        if check.name not in only:
            continue
        entry = run_check(check, sizes, device)
        checks.append(entry)
        worst = ""
        if entry.get("results"):
            bad = [(k, r) for k, r in entry["results"].items() if "ok" in r]
            k, r = max(bad, key=lambda kr: kr[1]["error"] / kr[1]["tolerance"] if kr[1]["tolerance"] else (0.0 if kr[1]["error"] == 0 else float("inf")))
            worst = f"; worst {k}: {r['error']:.2e} (tolerance {r['tolerance']:.0e})"
        seconds = f" {entry['seconds']:.2f} s (cpu {entry['cpu_seconds']:.2f} s)" if "seconds" in entry else ""
        print(f"  {entry['status']:8s} {check.name:14s}{seconds}{worst}{'; ' + entry['reason'] if entry.get('reason') else ''}")
    perf = None
    if "throughput" in only:
        perf = throughput(sizes, device)
        print(f"  throughput: {perf['scene']}")
        for row in perf["rows"]:
            print(f"    {row['renderer']:30s} {row['seconds']:8.3f} s  {row['mpaths_per_s']:.3f} M path samples/s")
        if perf["mitsuba"]:
            print(f"    {perf['mitsuba']}")
    skipped = [{"name": c["name"], "reason": c["reason"]} for c in checks if c["status"] == "skipped"] + (perf["skipped"] if perf else [])
    for s in skipped:
        print(f"  skipped {s['name']}: {s['reason']}")
    failed = [c["name"] for c in checks if c["status"] == "failed"]
    total = time.perf_counter() - begin
    summary = {
        "device": str(device),
        "machine": info,
        "sizes": dataclasses.asdict(sizes),
        "tolerances": {"image": IMAGE_TOL, "gradient": GRAD_TOL, "param": PARAM_TOL},
        "checks": checks,
        "throughput": perf,
        "skipped": skipped,
        "failed": failed,
        "seconds": round(total, 1),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = args.out / "gpu_check.json.tmp"
    tmp.write_text(json.dumps(summary, indent=1, default=float) + "\n")
    os.replace(tmp, args.out / "gpu_check.json")
    print(f"gpu_check: {len(checks) - len(failed) - sum(c['status'] == 'skipped' for c in checks)} passed, {len(failed)} failed, {len(skipped)} skipped in {total:.1f} s; wrote {args.out / 'gpu_check.json'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
