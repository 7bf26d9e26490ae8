"""``invrender ablation``: sampling strategies compared at equal samples and equal time (a front
over :func:`invrender.ablation.ablation`)."""

from __future__ import annotations

import argparse
import sys

from invrender.cli.common import add_integrator_arguments, add_scene_argument, check_out_dir, int_list, integrator_spec, integrators_epilog, parse_resolution

#: Neumann terms kept unless --max-depth (or --set max_depth) says otherwise
DEFAULT_DEPTH = 8

DOC = """\
Compare the path tracer's sampling strategies. Each variant changes one choice of the defaults
(stratified pixel samples, cosine-weighted hemisphere sampling, MIS of emitter and BSDF samples,
Russian roulette from rr_depth 5, every pixel the same spp): independent or antithetic pixel
samples, uniform hemisphere sampling, BSDF samples only, emitter samples only, no roulette,
adaptive sampling. Each renders the scene at every --spp for --trials seeds; the error is the RMSE
against a --reference-spp render of the defaults, the cost the CPU time of one render (all its
threads: on a shared machine wall-clock time varies with the other processes' load). The table
gives each variant's RMSE per spp, its RMSE at equal time (the CPU time of the defaults' largest
spp) and its efficiency (the defaults' MSE over its MSE at that time: > 1 is better); the figure
plots RMSE against samples and against CPU time, log-log, one line per variant. All variants
estimate the same image, so their differences are variance only.
"""

EPILOG = """\
examples:
  invrender ablation cornell_box --out runs/ablation                    # 1-2 minutes on 2 cores
  invrender ablation forward/cornell_far.toml --strategies adaptive --out runs/adaptive
  invrender ablation cornell_specular --strategies bsdf_only,emitter_only --spp 16,64,256 --out runs/mis
  invrender ablation cornell_box --set rr_depth=3 --strategies no_roulette --out runs/rr3   # other defaults

--integrator and --set change the defaults every variant starts from (any setting of the path
tracer, listed below); each variant then changes one choice of them.

"""


def add_parser(sub) -> None:
    a = sub.add_parser("ablation", help="compare sampling strategies at equal samples and equal time", description=DOC, epilog=EPILOG + integrators_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(a)
    a.add_argument("--out", required=True, help="output folder: ablation.csv, ablation.md, ablation.png")
    a.add_argument("--strategies", default=None, metavar="NAME,NAME", help="variants besides default (default: all): " + ", ".join(ablation_names()))
    a.add_argument("--spp", default="8,16,32,64", metavar="N,N", help="samples per pixel, ascending (default: 8,16,32,64)")
    a.add_argument("--trials", type=int, default=2, help="seeds per strategy and spp (default: 2)")
    a.add_argument("--reference-spp", type=int, default=4096, help="spp of the reference, the defaults with other seeds (default: 4096)")
    a.add_argument("--resolution", type=parse_resolution, default=(64, 64), metavar="WxH", help="(default: 64x64)")
    a.add_argument("--max-depth", type=int, default=None, help=f"the integrator's max_depth: Neumann terms kept (default: {DEFAULT_DEPTH})")
    add_integrator_arguments(a, what="the integrator of the defaults")
    a.add_argument("--seed", type=int, default=0, help="offsets every seed of the study (default: 0)")
    a.add_argument("--quiet", action="store_true", help="no progress bar")
    a.set_defaults(run=run)


def ablation_names() -> list[str]:
    """The variants of :mod:`invrender.ablation.variants` besides the defaults (by way of
    :mod:`invrender.cli.catalog`)."""
    from invrender.cli.catalog import ABLATION_VARIANTS

    return list(ABLATION_VARIANTS)


def run(args) -> int:
    import invrender as ir
    from invrender.ablation import ablation, format_table, write_ablation

    out = check_out_dir(args.out)
    spec = integrator_spec(args, flags={"max_depth": args.max_depth})
    spp = tuple(int_list(args.spp, "--spp"))
    scene = ir.load_scene(args.scene, resolution=args.resolution)
    result = ablation(scene, args.strategies, spp=spp, trials=args.trials, reference_spp=args.reference_spp, max_depth=None if "max_depth" in spec else DEFAULT_DEPTH, seed=args.seed, progress=not args.quiet, integrator=spec)
    written = write_ablation(result, out)
    print(format_table(result), flush=True)
    if not args.quiet:
        print("wrote " + ", ".join(str(p) for p in written), file=sys.stderr)
    return 0
