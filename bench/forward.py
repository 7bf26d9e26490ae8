"""Forward-rendering throughput: path samples per second on the Cornell box, and memory at high spp.

    python bench/forward.py [--resolution 128] [--spp 64] [--max-depth 8] [--repeats 5]
    python bench/forward.py --mesh                  # also an 82k-triangle scene
    python bench/forward.py --memory-spp 65536      # peak RSS of a 64x64 render at that spp
    python bench/forward.py --breakdown             # one worker's time: ray queries, compiled kernels, torch
    python bench/forward.py --rays                  # one render's ray queries: Embree's packets against embreex
    ATEN_CPU_CAPABILITY=avx2 python bench/forward.py --llvm-target znver3:8   # AVX2 code on an AVX-512 CPU

invrender with each intersection backend (``--backends``; default embree and warp on the CPU) and
(when installed) Mitsuba 3 ``llvm_ad_rgb`` ``path`` render the same scene at the same settings in
the same process, alternating, after one warm-up each; the median time of each gives the
throughput and the ratio. Two more rows render with the first backend without the fused bounce
(``INVRENDER_KERNELS=steps``: the compiled single steps on) and as eager torch throughout
(``INVRENDER_KERNELS=torch`` with ``INVRENDER_BOUNCE=torch``): what each gains; with ``embree``, one more with
embreex's single rays instead of Embree's packets (``INVRENDER_EMBREE=embreex``). ``--scenes`` times other
scenes the same way (e.g. ``cornell_specular``, ``forward/textured_floor.toml``: the torch bounce). With a GPU present the same follows on CUDA (invrender's warp and torch
backends, Mitsuba's ``cuda_ad_rgb``). Figures are printed, never asserted.

``--llvm-target CPU:WIDTH`` has Dr.Jit's LLVM backend, which compiles both Mitsuba's kernels and
invrender's, generate code for another CPU and vector width (``znver3:8``: AVX2, 8 lanes, as a
Zen 3 runs it), a stand-in for an AVX2 machine on an AVX-512 one (with ``ATEN_CPU_CAPABILITY=avx2``
for torch's kernels). Where that CPU has no AVX-512, both renderers' Embree run the kernels of its
instruction set too: invrender's through ``INVRENDER_EMBREE_CONFIG=isa=avx2``, Mitsuba's, which
takes no such setting, through ``bench/embree_isa.c`` (compiled here, loaded before Mitsuba: the
settings are appended to those Mitsuba gives its Embree device). Still a stand-in, not a real AVX2
machine (the same cores, caches and clocks), and labelled so.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from _measure import Results, add_json_option, peak_rss_mib  # noqa: E402

import invrender as ir  # noqa: E402
from invrender.backends import embree_native  # noqa: E402
from invrender.backends.embree_native import ENV as EMBREE_ENV  # noqa: E402
from invrender.backends.kernels import ENV as KERNELS_ENV  # noqa: E402
from invrender.backends.arrays import ENV as BOUNCE_ENV, stacked  # noqa: E402


def sphere_in_box(n: int):
    """The Cornell box with an 81,920-triangle sphere in the middle (a mesh heavy enough that
    brute force is out of the question and the BVHs differ)."""
    import trimesh

    from invrender.scene.scene import build_scene
    from invrender.scene.shapes import Mesh

    box = ir.load_scene("cornell_box", resolution=(n, n))
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=0.35)
    t = box.triangles
    corners = t.corners().numpy()
    meshes = [Mesh(corners[i], [[0, 1, 2]], None, box.materials[int(t.material[i])], box.emitters[int(t.emitter[i])] if t.emitter[i] >= 0 else None) for i in range(t.count)]
    meshes.append(Mesh(sphere.vertices + [0.0, -0.2, 0.2], sphere.faces, None, "white"))
    materials = {m: box.params[f"{m}.reflectance"] for m in box.materials}
    return build_scene(meshes, materials, {e: box.params[f"{e}.emission"] for e in box.emitters}, box.camera, (n, n), name="sphere_in_box")


def throughput(args, results: Results) -> None:
    n, spp, depth = args.resolution, args.spp, args.max_depth
    samples = n * n * spp
    device = torch.device(args.device)
    backends = args.backends.split(",") if args.backends else (["embree", "warp"] if device.type == "cpu" else ["warp", "torch"])
    if not args.no_torch_steps:
        backends.append(f"{backends[0]}/steps")  # the same without the fused bounce (the kernels of single steps on)
        backends.append(f"{backends[0]}/torch")  # the same, as eager torch throughout (the reference)
    if "embree" in backends and embree_native.library()[0] is not None and not args.target:  # (embreex's own Embree takes no instruction set from a stand-in)
        backends.append("embree/embreex")  # Embree's single rays through embreex instead of its packets
    with_mitsuba = mitsuba_ref.available() and not args.no_mitsuba and device.type == "cpu"
    scenes = [ir.load_scene(name, resolution=(n, n)) for name in args.scenes.split(",")]
    if args.mesh:
        scenes.append(sphere_in_box(n))
    bounce = os.environ.get(BOUNCE_ENV, "drjit")
    for scene in scenes:
        mi_scene = None
        if with_mitsuba:
            mi_scene = mitsuba_ref.cornell_scene(n, n, spp, depth) if scene.name == "cornell_box" else mitsuba_ref.load_scene(scene, spp, depth)

        def ours(seed, variant):
            backend, kernels = variant.split("/") if "/" in variant else (variant, "warp")
            os.environ[EMBREE_ENV] = "embreex" if kernels == "embreex" else "packets"
            os.environ[KERNELS_ENV] = "warp" if kernels == "embreex" else kernels
            os.environ[BOUNCE_ENV] = "torch" if kernels == "torch" else bounce  # eager torch throughout
            if device.type == "cuda":
                torch.cuda.synchronize()
            start = time.perf_counter()
            ir.render(scene, spp=spp, max_depth=depth, seed=seed, progress=False, backend=backend, device=device)
            if device.type == "cuda":
                torch.cuda.synchronize()
            return time.perf_counter() - start

        for b in backends:
            ours(0, b)  # warm-up: builds the BVH, compiles the kernels once
        if mi_scene is not None:
            mitsuba_ref.time_render(mi_scene, spp)  # warm-up: compiles the kernels
        times, mi_times = {b: [] for b in backends}, []
        for i in range(args.repeats):  # alternating, so that a change of load falls on all alike
            for b in backends:
                times[b].append(ours(i + 1, b))
            if mi_scene is not None:
                mi_times.append(mitsuba_ref.time_render(mi_scene, spp, seed=i + 1))
        heading = f"{scene.name} ({scene.triangles.count} triangles) {n}x{n}, {spp} spp, max_depth {depth}, {device}, {args.repeats} repeats (median)" + (f"; {args.target}" if args.target else "")
        print(heading)
        rows = results.table(heading, ["renderer", "time s (median)", "min-max s", "M path samples/s", "x Mitsuba"])
        for b in backends:
            t = statistics.median(times[b])
            ratio = f"  {statistics.median(mi_times) / t:.3f}x Mitsuba" if mi_times else ""
            label = {"torch": f"{b.split('/')[0]}, torch steps", "steps": f"{b.split('/')[0]}, unfused bounce", "embreex": "embree, single rays (embreex)"}[b.split("/")[1]] if "/" in b else b
            print(f"  {'invrender path (' + label + '):':42s} {t:7.3f} s  {samples / t / 1e6:.3f} M path samples/s{ratio}")
            rows.append([f"invrender path ({label})", round(t, 3), f"{min(times[b]):.3f}-{max(times[b]):.3f}", round(samples / t / 1e6, 3),
                         round(statistics.median(mi_times) / t, 3) if mi_times else "n/a"])
        if mi_times:
            tm = statistics.median(mi_times)
            print(f"  {mitsuba_ref.label() + ' path:':42s} {tm:7.3f} s  {samples / tm / 1e6:.3f} M path samples/s")
            rows.append([f"{mitsuba_ref.label()} path", round(tm, 3), f"{min(mi_times):.3f}-{max(mi_times):.3f}", round(samples / tm / 1e6, 3), 1.0])
        elif device.type == "cpu":
            print("  (Mitsuba 3 not installed: no ratio; see bench/README.md)")
    if device.type == "cpu" and torch.cuda.is_available() and not args.no_cuda:
        cuda = argparse.Namespace(**{**vars(args), "device": "cuda", "backends": "warp,torch" if not args.backends else args.backends})
        os.environ[KERNELS_ENV] = "warp"
        throughput(cuda, results)
        if mitsuba_ref.available() and not args.no_mitsuba:
            line = mitsuba_ref.cuda_forward(n, spp, depth, args.repeats)
            print(line)
            results.note(str(line))


def breakdown(args, results: Results) -> None:
    """Where a render's time goes: the Cornell box rendered by one worker thread with Embree on one
    thread, the time inside the ray queries and inside the compiled steps (the bounce written once:
    :func:`invrender.core.compiled.run`) measured, the
    rest being torch's operations and Python; with the fused bounce and without it."""
    from invrender.backends import accel
    from invrender.core import compiled, context

    torch.set_num_threads(1)  # one worker
    spent = {"rays": 0.0, "kernels": 0.0}

    inside = {"rays": 0, "kernels": 0}

    def timed(key, call):
        def run(*a, **k):  # (a query made inside another of the same key is counted once)
            inside[key] += 1
            start = time.perf_counter()
            try:
                return call(*a, **k)
            finally:
                inside[key] -= 1
                if not inside[key]:
                    spent[key] += time.perf_counter() - start

        return run

    for kind in ("intersect", "closest_hits", "occluded"):
        setattr(accel.EmbreeIntersector, kind, timed("rays", getattr(accel.EmbreeIntersector, kind)))
    compiled.run = timed("kernels", compiled.run)  # the bounce written once (Dr.Jit, or eager torch)
    build = context.TransportContext.build
    context.TransportContext.build = staticmethod(lambda scene, device, backend=None, threads=None, *a, **k: build(scene, device, backend, 1, *a, **k))
    n, spp = args.resolution, args.spp
    scene = ir.load_scene("cornell_box", resolution=(n, n))
    heading = f"cornell_box {n}x{n}, {spp} spp, max_depth {args.max_depth}: one worker thread, Embree on one thread, medians of {args.repeats}"
    print(heading)
    rows = results.table(heading, ["bounce", "total s", "ray queries s", "kernels s (Dr.Jit)", "torch and Python s", "share left to torch and Python"])
    for choice, label in (("warp", "fused"), ("steps", "unfused (kernels of single steps)")):
        os.environ[KERNELS_ENV] = choice
        ir.render(scene, spp=4, max_depth=args.max_depth, progress=False)
        figures = []
        for i in range(args.repeats):
            spent.update(rays=0.0, kernels=0.0)
            start = time.perf_counter()
            ir.render(scene, spp=spp, max_depth=args.max_depth, seed=i, progress=False)
            figures.append((time.perf_counter() - start, spent["rays"], spent["kernels"]))
        total, rays, warp = (statistics.median(f[j] for f in figures) for j in range(3))
        rest = total - rays - warp
        print(f"  {label:36s} {total:6.3f} s: ray queries {rays:.3f} s ({rays / total:.0%}), kernels {warp:.3f} s ({warp / total:.0%}), torch and Python {rest:.3f} s ({rest / total:.0%})")
        rows.append([label, round(total, 3), round(rays, 3), round(warp, 3), round(rest, 3), f"{rest / total:.0%}"])
    os.environ[KERNELS_ENV] = "warp"


def rays(args, results: Results) -> None:
    """The ray queries alone: the batches of one render (Cornell box, closest hits and shadow rays of
    every bounce) traced again on one thread by Embree's packets and by embreex's single
    rays, alternating, 5 times each; nanoseconds per ray (minimum and median)."""
    from invrender.backends import accel

    n, spp = args.resolution, args.spp
    scene = ir.load_scene("cornell_box", resolution=(n, n))
    batches = []
    cls = accel.EmbreeIntersector
    closest_hits, occluded = cls.closest_hits, cls.occluded
    cls.closest_hits = lambda self, o, d, misses=False, alive=None: batches.append(("closest hits", o, d, alive)) or closest_hits(self, o, d, misses, alive)
    cls.occluded = lambda self, o, d, tmax: batches.append(("shadow rays", o, d, tmax)) or occluded(self, o, d, tmax)
    ir.render(scene, spp=spp, max_depth=args.max_depth, seed=0, progress=False)
    cls.closest_hits, cls.occluded = closest_hits, occluded
    engines = {}
    for mode in ("packets", "embreex"):
        os.environ[EMBREE_ENV] = mode
        engines[mode] = accel.make_intersector(scene.triangles, "embree", 1)
    os.environ[EMBREE_ENV] = "packets"
    if not engines["packets"].packets:
        print(f"  Embree's packets do not build here ({embree_native.library()[1]}): nothing to compare")
        return
    heading = f"ray queries of one render: cornell_box {n}x{n}, {spp} spp, max_depth {args.max_depth}, one thread, packets of {engines['packets']._packets.lanes} rays"
    print(heading)
    rows = results.table(heading, ["query", "rays", "packets ns/ray (min, median)", "embreex ns/ray (min, median)", "embreex / packets"])
    for kind in ("closest hits", "shadow rays"):
        mine = [b for b in batches if b[0] == kind]
        # rays traced: a closest-hit batch's live ones (its last argument: the paths that go on)
        count = sum(stacked(b[1]).shape[0] if b[3] is None or kind == "shadow rays" else int(b[3].sum()) for b in mine)
        spent = {mode: [] for mode in engines}
        for _ in range(5):
            for mode, engine in engines.items():
                start = time.perf_counter()
                for _, o, d, last in mine:
                    engine.closest_hits(o, d, alive=last) if kind == "closest hits" else engine.occluded(o, d, last)
                spent[mode].append((time.perf_counter() - start) / count * 1e9)
        p, e = (sorted(spent[m]) for m in ("packets", "embreex"))
        print(f"  {kind:13s} {count:9d} rays: packets {p[0]:6.1f} ns ({p[2]:.1f}), embreex {e[0]:6.1f} ns ({e[2]:.1f}): {e[2] / p[2]:.2f}x")
        rows.append([kind, count, f"{p[0]:.1f}, {p[2]:.1f}", f"{e[0]:.1f}, {e[2]:.1f}", round(e[2] / p[2], 2)])


def memory(args, results: Results) -> None:
    scene = ir.load_scene("cornell_box", resolution=(64, 64))
    start = time.perf_counter()
    img = ir.render(scene, spp=args.memory_spp, max_depth=args.max_depth, seed=0, progress=True)
    seconds = time.perf_counter() - start
    print(f"Cornell box 64x64, {args.memory_spp} spp, max_depth {args.max_depth}: {seconds:.1f} s, peak RSS {peak_rss_mib():.0f} MiB, mean RGB {img.mean(dim=(0, 1)).tolist()}")
    rows = results.table("peak memory of one render, Cornell box 64x64", ["spp", "max_depth", "seconds", "peak RSS MiB", "mean RGB"])
    rows.append([args.memory_spp, args.max_depth, round(seconds, 1), round(peak_rss_mib()), " ".join(f"{v:.4f}" for v in img.mean(dim=(0, 1)).tolist())])


#: the CPUs ``--llvm-target`` accepts (LLVM's names), each with the instruction set its code needs
LLVM_CPUS = {"x86-64-v2": "sse4_2", "x86-64-v3": "avx2", "x86-64-v4": "avx512f", "haswell": "avx2", "skylake": "avx2", "skylake-avx512": "avx512f",
             "icelake-server": "avx512f", "znver2": "avx2", "znver3": "avx2", "znver4": "avx512f"}  # fmt: skip


def llvm_target(spec: str) -> str:
    """Dr.Jit's LLVM code for CPU ``spec`` = ``CPU:WIDTH`` (e.g. ``znver3:8``), for every kernel
    compiled from here on (Mitsuba's and invrender's share Dr.Jit); returns a label."""
    import ctypes

    import drjit as dr
    from drjit.llvm import Float

    cpu, _, width = spec.partition(":")
    if not cpu or not width.isdigit() or int(width) not in (4, 8, 16):
        raise SystemExit(f"--llvm-target must be CPU:WIDTH with WIDTH 4, 8 or 16 (e.g. znver3:8), got {spec!r}")
    if cpu not in LLVM_CPUS:  # (LLVM aborts the process on a name it does not know)
        raise SystemExit(f"--llvm-target: unknown CPU {cpu!r}; one of {', '.join(LLVM_CPUS)}")
    flags = Path("/proc/cpuinfo").read_text().split() if Path("/proc/cpuinfo").exists() else []
    if LLVM_CPUS[cpu] not in flags:
        raise SystemExit(f"--llvm-target: {cpu} code needs {LLVM_CPUS[cpu]}, which this CPU lacks")
    dr.eval(Float(0.0) + 1.0)  # the LLVM backend initialized
    core = ctypes.CDLL(str(Path(dr.__file__).parent / "libdrjit-core.so"))
    setter = getattr(core, "_Z19jit_llvm_set_targetPKcS0_j", None)  # jit_llvm_set_target(cpu, features, width)
    if setter is None:
        raise SystemExit("--llvm-target: this Dr.Jit does not export jit_llvm_set_target")
    setter.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    setter(cpu.encode(), b"", int(width))
    isa = EMBREE_ISAS[LLVM_CPUS[cpu]]
    if isa:
        embree_isa(isa)
    return (f"Dr.Jit's LLVM code for {cpu}, {width} lanes; torch's kernels {os.environ.get('ATEN_CPU_CAPABILITY', 'as the CPU allows')}; "
            f"Embree's {'kernels for ' + isa if isa else 'as the CPU allows'} in both renderers")  # fmt: skip


#: Embree's ``isa`` setting for the instruction set an ``--llvm-target`` CPU needs (None: AVX-512, Embree's own choice here)
EMBREE_ISAS = {"sse4_2": "sse4.2", "avx2": "avx2", "avx512f": None}


def embree_isa(isa: str) -> None:
    """Both renderers' Embree on the kernels of ``isa`` from here on: invrender's by its device
    setting (``INVRENDER_EMBREE_CONFIG``), Mitsuba's by ``embree_isa.c`` (compiled with the system's C
    compiler and loaded before Mitsuba is)."""
    import ctypes
    import shutil
    import subprocess
    import tempfile

    if "mitsuba" in sys.modules:
        raise SystemExit("--llvm-target: Mitsuba was loaded before its Embree could be told the instruction set")
    os.environ[embree_native.CONFIG_ENV] = f"isa={isa}"
    os.environ["IR_BENCH_EMBREE_CONFIG"] = f"isa={isa}"
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise SystemExit("--llvm-target: a C compiler is needed to set Mitsuba's Embree instruction set (bench/embree_isa.c)")
    with tempfile.TemporaryDirectory(prefix="embree_isa") as folder:  # (a loaded library outlives its file)
        built = Path(folder) / "embree_isa.so"
        run = subprocess.run([compiler, "-O2", "-shared", "-fPIC", str(Path(__file__).with_name("embree_isa.c")), "-o", str(built), "-ldl"], capture_output=True, text=True)
        if run.returncode:
            raise SystemExit(f"--llvm-target: bench/embree_isa.c does not compile: {run.stderr.strip().splitlines()[0]}")
        ctypes.CDLL(str(built), mode=ctypes.RTLD_GLOBAL)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-mitsuba", action="store_true", help="skip Mitsuba even when installed")
    parser.add_argument("--backends", default=None, help="comma-separated intersection backends (default: embree,warp on the CPU; warp,torch on CUDA)")
    parser.add_argument("--scenes", default="cornell_box", help="comma-separated scenes (names or files; default: cornell_box), e.g. cornell_box,cornell_specular,forward/textured_floor.toml")
    parser.add_argument("--mesh", action="store_true", help="also the Cornell box with an 81,920-triangle sphere")
    parser.add_argument("--no-torch-steps", action="store_true", help="skip the rows without the fused bounce (INVRENDER_KERNELS=steps) and without any kernel (INVRENDER_KERNELS=torch)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (default: cpu; with a GPU present the CUDA figures follow the CPU ones)")
    parser.add_argument("--no-cuda", action="store_true", help="skip the CUDA figures even when a GPU is present")
    parser.add_argument("--memory-spp", type=int, default=0, help="instead: peak memory of a 64x64 render at this spp")
    parser.add_argument("--breakdown", action="store_true", help="instead: where one worker's render time goes (ray queries, compiled kernels, torch), with and without the fused bounce")
    parser.add_argument("--rays", action="store_true", help="instead: one render's ray queries traced by Embree's packets and by embreex's single rays, ns per ray")
    parser.add_argument("--llvm-target", default=None, metavar="CPU:WIDTH", help="Dr.Jit's LLVM code (Mitsuba's and invrender's kernels) for another CPU and vector width, e.g. znver3:8 (AVX2) on an AVX-512 CPU")
    add_json_option(parser)
    args = parser.parse_args()
    args.target = llvm_target(args.llvm_target) if args.llvm_target else ""
    if args.target:
        print(args.target)
    title = "Forward rendering: memory" if args.memory_spp else "Forward rendering: where the time goes" if args.breakdown else "Forward rendering: ray queries" if args.rays else "Forward rendering throughput"
    results = Results("forward_avx2_standin" if args.target else "forward", title + (" (an AVX2 stand-in)" if args.target else ""))
    memory(args, results) if args.memory_spp else breakdown(args, results) if args.breakdown else rays(args, results) if args.rays else throughput(args, results)
    results.write(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
