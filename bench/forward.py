"""Forward-rendering throughput: path samples per second on the Cornell box, and memory at high spp.

    python bench/forward.py [--resolution 128] [--spp 64] [--max-depth 8] [--repeats 5]
    python bench/forward.py --memory-spp 65536      # peak RSS of a 64x64 render at that spp

invrender and (when installed) Mitsuba 3 ``llvm_ad_rgb`` ``path`` render the same scene at the same
settings in the same process, alternating, after one warm-up each; the median time of each gives
the throughput and the ratio. Figures are printed, never asserted.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from _measure import peak_rss_mib  # noqa: E402

import invrender as ir  # noqa: E402


def throughput(args) -> None:
    n, spp, depth = args.resolution, args.spp, args.max_depth
    samples = n * n * spp
    scene = ir.load_scene("cornell_box", resolution=(n, n))
    with_mitsuba = mitsuba_ref.available() and not args.no_mitsuba
    mi_scene = mitsuba_ref.cornell_scene(n, n, spp, depth) if with_mitsuba else None

    def ours(seed):
        start = time.perf_counter()
        ir.render(scene, spp=spp, max_depth=depth, seed=seed, progress=False)
        return time.perf_counter() - start

    ours(0)  # warm-up
    if with_mitsuba:
        mitsuba_ref.time_render(mi_scene, spp)  # warm-up: compiles the kernels
    times, mi_times = [], []
    for i in range(args.repeats):
        times.append(ours(i + 1))
        if with_mitsuba:
            mi_times.append(mitsuba_ref.time_render(mi_scene, spp, seed=i + 1))
    t = statistics.median(times)
    print(f"Cornell box {n}x{n}, {spp} spp, max_depth {depth}, {args.repeats} repeats (median)")
    print(f"  invrender path (embree):             {t:.3f} s  {samples / t / 1e6:.3f} M path samples/s")
    if with_mitsuba:
        tm = statistics.median(mi_times)
        print(f"  {mitsuba_ref.label()} path:     {tm:.3f} s  {samples / tm / 1e6:.3f} M path samples/s")
        print(f"  ratio invrender / Mitsuba throughput: {tm / t:.3f}x")
    else:
        print("  (Mitsuba 3 not installed: no ratio; see bench/README.md)")


def memory(args) -> None:
    scene = ir.load_scene("cornell_box", resolution=(64, 64))
    start = time.perf_counter()
    img = ir.render(scene, spp=args.memory_spp, max_depth=args.max_depth, seed=0, progress=True)
    seconds = time.perf_counter() - start
    print(f"Cornell box 64x64, {args.memory_spp} spp, max_depth {args.max_depth}: {seconds:.1f} s, peak RSS {peak_rss_mib():.0f} MiB, mean RGB {img.mean(dim=(0, 1)).tolist()}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-mitsuba", action="store_true", help="skip Mitsuba even when installed")
    parser.add_argument("--memory-spp", type=int, default=0, help="instead: peak memory of a 64x64 render at this spp")
    args = parser.parse_args()
    memory(args) if args.memory_spp else throughput(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
