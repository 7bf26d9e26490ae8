"""``invrender compare``: pyrender, utah, path at max_depth 2 and the full path side by side (a
front over :func:`invrender.baseline.compare.compare`)."""

from __future__ import annotations

import argparse
import sys

from invrender.cli.common import add_scene_argument, check_outputs, parse_resolution, parse_rgb
from invrender.errors import ImageError

DOC = """\
Render a scene with pyrender, with the utah integrator, with path at max_depth 2 and with the full
path tracer; write one PNG with the images side by side over their differences to the full path,
and print a table of channel means and relative differences, the share of energy the Utah
approximation drops, and the ambient eps0 that best stands in for interreflection (least squares).
"""


def add_parser(sub) -> None:
    c = sub.add_parser("compare", help="pyrender vs utah vs path: what ignoring interreflection costs", description=DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(c)
    c.add_argument("--out", default="compare.png", help="the figure, a .png (default: compare.png)")
    c.add_argument("--resolution", type=parse_resolution, default=(128, 128), metavar="WxH", help="(default: 128x128)")
    c.add_argument("--spp", type=int, default=64, help="samples per pixel of the Monte Carlo images (default: 64)")
    c.add_argument("--max-depth", type=int, default=-1, help="Neumann terms of the full path image (default: -1, unbounded)")
    c.add_argument("--ambient", type=parse_rgb, default=None, metavar="R,G,B", help="eps0 of utah and pyrender (default: the scene's, else 0)")
    c.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    c.add_argument("--no-pyrender", action="store_true", help="leave out the pyrender image")
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    c.set_defaults(run=run)


def run(args) -> int:
    import invrender as ir
    from invrender.baseline.compare import compare, format_table, plot_comparison

    (out,) = check_outputs([args.out])
    if out.suffix.lower() != ".png":
        raise ImageError(f"cannot write {args.out}: the comparison figure is a .png")
    scene = ir.load_scene(args.scene, resolution=args.resolution, ambient=args.ambient)
    result = compare(scene, spp=args.spp, seed=args.seed, max_depth=args.max_depth, pyrender=not args.no_pyrender, progress=not args.quiet)
    plot_comparison(result, out)
    print(f"{scene.name}: {scene.width}x{scene.height}, {args.spp} spp")
    print(format_table(result), flush=True)
    print(f"wrote {out}", file=sys.stderr)
    return 0
