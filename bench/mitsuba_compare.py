"""invrender vs Mitsuba 3 on the Cornell box: channel means at high spp (box filter, same max_depth).

    python bench/mitsuba_compare.py [--resolution 64] [--spp 4096] [--max-depth 8 2 1]

Prints both renderers' RGB means and the relative differences; the forward renderer's acceptance is
agreement within 1% per channel. Needs Mitsuba 3 (see bench/README.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402

import invrender as ir  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--spp", type=int, default=4096)
    parser.add_argument("--max-depth", type=int, nargs="+", default=[8, 2, 1])
    args = parser.parse_args()
    if not mitsuba_ref.available():
        print("Mitsuba 3 is not installed (see bench/README.md); nothing to compare.")
        return 0
    n = args.resolution
    scene = ir.load_scene("cornell_box", resolution=(n, n))
    print(f"Cornell box {n}x{n}, {args.spp} spp, box filter; {mitsuba_ref.label()}")
    print(f"{'max_depth':>9}  {'invrender RGB mean':>32}  {'Mitsuba 3 RGB mean':>32}  {'rel. diff (%)':>22}")
    fmt = lambda v: " ".join(f"{x:10.6f}" for x in v)  # noqa: E731
    worst = 0.0
    for depth in args.max_depth:
        ours = ir.render(scene, spp=args.spp, max_depth=depth, seed=0, progress=False).mean(dim=(0, 1)).tolist()
        theirs = mitsuba_ref.render_cornell(n, n, args.spp, depth).mean(axis=(0, 1)).tolist()
        rel = [100 * (a - b) / b for a, b in zip(ours, theirs)]
        worst = max(worst, *map(abs, rel))
        print(f"{depth:>9}  {fmt(ours):>32}  {fmt(theirs):>32}  {' '.join(f'{r:+6.3f}' for r in rel):>22}")
    print(f"largest channel difference: {worst:.3f}% ({'within' if worst < 1 else 'NOT within'} 1%)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
