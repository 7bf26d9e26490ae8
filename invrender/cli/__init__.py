"""The ``invrender`` command line: one thin module per command over the public API.

Bad input ends with one line ``invrender: error: ...`` on stderr and exit status 2; outputs are
written atomically, so a failed or interrupted run leaves no half-written file. Each command module
(:mod:`invrender.cli.render`, ``fit``, ``gradcheck``, ``dataset``, ``baseline``, ``compare``,
``variance``, ``ablation``, ``hdr``, ``plugins``) has ``add_parser(sub)`` and ``run(args)``; what they share is in
:mod:`invrender.cli.common`.

The parser, the help texts and the checks of names import no torch (the command modules import
the standard library at module level, the library inside ``run``; what the help texts list of the
library comes from :mod:`invrender.cli.catalog`), so ``--help`` and a mistyped name answer at once.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

from invrender.cli import ablation, baseline, compare, dataset, fit, gradcheck, hdr, plugins, render, variance
from invrender.cli.common import EXIT_BAD_INPUT, EXIT_INTERNAL, EXIT_INTERRUPTED, OneLineParser, check_names, join_process_group, leave_process_group, one_line_warning
from invrender.cli.fit import FIT_OPTIONS
from invrender.errors import InvRenderError

#: the commands, in the order of ``--help``
COMMANDS = (render, fit, gradcheck, dataset, baseline, compare, variance, ablation, hdr, plugins)

DESCRIPTION = """\
invrender renders Kajiya's rendering equation I = g(eps + M I) by Monte Carlo on torch tensors
(a path tracer estimating the Neumann series g eps + gMg eps + g(Mg)^2 eps + ...).

commands:
  render     render a built-in scene (cornell_box, cornell_specular, furnace) or a scene file (.toml,
             Mitsuba .xml, .gltf, .glb, .obj) to EXR (linear float32) and/or PNG (sRGB), with the
             path tracer or another integrator (--integrator NAME, --set KEY=VALUE: 'invrender render
             --help' lists each integrator with its settings)
  fit        recover reflectances rho, specular reflectances k_s and emissions eps from target images
             by differentiating the path tracer (from --scene/--target/--params, or an optimize/*.toml recipe)
  gradcheck  compare each gradient estimator with central finite differences (common random numbers)
  dataset    render a datasets_synthetic/*.toml recipe: target EXRs, ground truth, manifest
  baseline   rasterize a scene with pyrender (the Utah approximation's independent baseline)
  compare    pyrender, utah, path at max_depth 2 and the full path side by side: what ignoring
             interreflection costs (a PNG figure and a table of channel means)
  variance   gradient-variance study: variance, bias, cost and per-pixel noise of gradient
             estimators over independent trials (CSV, JSON, PNG figures); 'variance furnace'
             checks them against closed forms
  ablation   sampling strategies (pixel samples, hemisphere sampling, MIS / BSDF / emitter
             sampling, Russian roulette, adaptive sampling) compared by RMSE against a high-spp
             reference at equal samples and equal time (a table, CSV and a log-log figure)
  hdr        merge an exposure bracket of 8-bit photographs into a linear EXR, with the camera
             response recovered from it (Debevec; a CSV and its plot)
  plugins    the registered materials, emitters and integrators with their parameters and
             settings (Markdown tables, as docs/plugins.md shows them)

Run 'invrender COMMAND --help' for a command's options.
"""



def build_parser() -> argparse.ArgumentParser:
    from invrender import __version__

    parser = OneLineParser(prog="invrender", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"invrender {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=OneLineParser)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    warnings.showwarning = one_line_warning
    prefix = "invrender: error: "
    started = False
    try:
        check_names(args)  # before torch is imported
        started = True
        if getattr(args, "group", False):  # commands that split their work across a torchrun group
            prefix = join_process_group(args) or prefix
        return args.run(args)
    except InvRenderError as e:
        print(f"{prefix}{e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("invrender: interrupted; nothing was written", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:  # a bug, not bad input: still one line, unless asked for the traceback
        if os.environ.get("INVRENDER_TRACEBACK") == "1":
            raise
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        print(f"invrender: internal error: {type(e).__name__}: {first} (a bug in invrender, please report it; "
              "INVRENDER_TRACEBACK=1 shows where)", file=sys.stderr)  # fmt: skip
        return EXIT_INTERNAL
    finally:
        if started:
            leave_process_group()


def entry() -> None:
    """Console-script entry point."""
    sys.exit(main())


__all__ = ["FIT_OPTIONS", "build_parser", "entry", "main"]
