"""``invrender baseline``: rasterize a scene with pyrender (a front over :func:`invrender.baseline.pyrender_render`)."""

from __future__ import annotations

import argparse
import sys

from invrender.cli.common import add_scene_argument, check_outputs, mean_rgb, parse_resolution, parse_rgb

DOC = """\
Rasterize a scene with pyrender (OpenGL, offscreen through EGL or OSMesa): the Utah approximation
as a rasterizer computes it (emitters as lights, one reflection, ambient eps0; no interreflection).
Writes linear radiance in the same convention as 'invrender render'.
"""


def add_parser(sub) -> None:
    b = sub.add_parser("baseline", help="rasterize a scene with pyrender (Utah baseline)", description=DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(b)
    b.add_argument("--out", nargs="+", default=["baseline.exr"], metavar="PATH", help="output image(s): .exr and/or .png (default: baseline.exr)")
    b.add_argument("--resolution", type=parse_resolution, default=None, metavar="WxH", help="image size (default: the scene's)")
    b.add_argument("--ambient", type=parse_rgb, default=None, metavar="R,G,B", help="ambient radiance eps0 (default: the scene's, else 0)")
    b.add_argument("--quiet", action="store_true", help="no summary")
    b.set_defaults(run=run)


def run(args) -> int:
    import invrender as ir
    from invrender.baseline import pyrender_render

    outputs = check_outputs(args.out)
    scene = ir.load_scene(args.scene, resolution=args.resolution, ambient=args.ambient)
    image = pyrender_render(scene)
    for path in outputs:
        ir.write_image(path, image)
    if not args.quiet:
        print(f"{scene.name}: {scene.width}x{scene.height} rasterized by pyrender; mean RGB {mean_rgb(image)}", file=sys.stderr)
        print("wrote " + ", ".join(str(p) for p in outputs), file=sys.stderr)
    return 0
