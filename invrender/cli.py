"""The ``invrender`` command line: a thin front end over the public API.

Bad input ends with one line ``invrender: error: ...`` on stderr and exit status 2; outputs are
written atomically, so a failed or interrupted run leaves no half-written file.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

from invrender.errors import ImageError, InvRenderError

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130

DESCRIPTION = """\
invrender renders Kajiya's rendering equation I = g(eps + M I) by Monte Carlo on torch tensors
(a path tracer estimating the Neumann series g eps + gMg eps + g(Mg)^2 eps + ...).

commands:
  render    render a built-in scene (cornell_box, furnace) or a scene file (.toml, .gltf, .glb, .obj)
            to EXR (linear float32) and/or PNG (sRGB)

Run 'invrender COMMAND --help' for a command's options.
"""

RENDER_EPILOG = """\
examples:
  invrender render                                         # Cornell box, 256x256, 64 spp -> out.exr
  invrender render cornell_box --spp 256 --resolution 128x128 --out cbox.exr cbox.png
  invrender render forward/mesh_in_box.toml --max-depth -1 --out mesh.png
  invrender render furnace --integrator random_walk --max-depth 4 --terms --out furnace.exr

max_depth counts Neumann terms as Mitsuba 3 does: 1 = emitters seen directly, 2 = + direct
illumination, ...; -1 = unbounded (paths end by Russian roulette only). With --terms, term k
(the light reflected k times, g(Mg)^k eps) is also written to OUT_STEM.termK.SUFFIX.
"""


def parse_resolution(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (width, height)."""
    try:
        w, h = (int(p) for p in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 64x64, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"resolution must be positive, got {text!r}")
    return w, h


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``invrender: error: ...``) and exit status 2."""

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"invrender: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="invrender", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    from invrender import __version__

    parser.add_argument("--version", action="version", version=f"invrender {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)

    r = sub.add_parser(
        "render",
        help="render a scene to EXR/PNG",
        description="Render a scene by Monte Carlo path tracing and write the image(s).",
        epilog=RENDER_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("scene", nargs="?", default="cornell_box", help="built-in name (cornell_box, furnace) or a .toml/.gltf/.glb/.obj file (default: cornell_box)")
    r.add_argument("--out", nargs="+", default=["out.exr"], metavar="PATH", help="output image(s): .exr (linear float32) and/or .png (sRGB, clipped) (default: out.exr)")
    r.add_argument("--spp", type=int, default=64, help="samples per pixel (default: 64)")
    r.add_argument("--max-depth", type=int, default=8, help="Neumann terms kept, Mitsuba's count; -1 = unbounded (default: 8)")
    r.add_argument("--resolution", type=parse_resolution, default=None, metavar="WxH", help="image size in pixels (default: the scene's)")
    r.add_argument("--integrator", default="path", help="path (NEE + MIS, default) or random_walk (BSDF sampling only)")
    r.add_argument("--seed", type=int, default=0, help="random seed; the image is a pure function of it (default: 0)")
    r.add_argument("--rr-depth", type=int, default=5, help="Russian roulette starts after this many terms (default: 5)")
    r.add_argument("--terms", action="store_true", help="also write one image per Neumann term (OUT_STEM.termK.SUFFIX)")
    r.add_argument("--device", default="cpu", help="torch device: cpu or cuda (default: cpu)")
    r.add_argument("--backend", default=None, help="intersection backend: embree (CPU) or torch (any device); default by device")
    r.add_argument("--memory-mb", type=float, default=512.0, help="memory budget of one chunk of paths, MiB (default: 512)")
    r.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    r.set_defaults(run=run_render)
    return parser


def check_outputs(paths: list[str]) -> list[Path]:
    """Fail early (before a long render) on output paths that cannot be written."""
    from invrender.io.images import SUFFIXES

    out = []
    for p in paths:
        path = Path(p)
        if path.suffix.lower() not in SUFFIXES:
            raise ImageError(f"cannot write {p}: unknown image suffix {path.suffix or '(none)'!r} (use {', '.join(SUFFIXES)})")
        parent = path.parent if str(path.parent) else Path(".")
        existing = next((a for a in [parent, *parent.parents] if a.exists()), Path("."))
        if not existing.is_dir() or not os.access(existing, os.W_OK):
            raise ImageError(f"cannot write {p}: {existing} is not a writable directory")
        if path.is_dir():
            raise ImageError(f"cannot write {p}: it is a directory")
        out.append(path)
    return out


def run_render(args) -> int:
    import invrender as ir

    outputs = check_outputs(args.out)
    scene = ir.load_scene(args.scene, resolution=args.resolution)
    start = time.perf_counter()
    image = ir.render(
        scene, integrator=args.integrator, spp=args.spp, max_depth=args.max_depth, seed=args.seed, terms=args.terms,
        rr_depth=args.rr_depth, backend=args.backend, device=args.device, memory_mb=args.memory_mb, progress=not args.quiet,
    )  # fmt: skip
    seconds = time.perf_counter() - start
    full = image.sum(0) if args.terms else image
    for path in outputs:
        ir.write_image(path, full)
        if args.terms:
            for k in range(image.shape[0]):
                ir.write_image(path.with_name(f"{path.stem}.term{k}{path.suffix}"), image[k])
    if not args.quiet:
        paths = scene.width * scene.height * args.spp
        mean = ", ".join(f"{v:.4g}" for v in full.mean(dim=(0, 1)).tolist())
        print(f"{scene.name}: {scene.width}x{scene.height}, {args.spp} spp, {seconds:.2f} s ({paths / seconds / 1e6:.3g} M paths/s); mean RGB {mean}", file=sys.stderr)
        print("wrote " + ", ".join(str(p) for p in outputs) + (f" (+ {image.shape[0]} term images each)" if args.terms else ""), file=sys.stderr)
    return 0


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f"invrender: warning: {message}", file=sys.stderr)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    warnings.showwarning = _one_line_warning
    try:
        return args.run(args)
    except InvRenderError as e:
        print(f"invrender: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("invrender: interrupted; nothing was written", file=sys.stderr)
        return EXIT_INTERRUPTED


def entry() -> None:
    """Console-script entry point."""
    sys.exit(main())


if __name__ == "__main__":
    entry()
