"""``invrender gradcheck``: each gradient estimator against central finite differences (a front
over :func:`invrender.inverse.gradcheck.gradcheck`)."""

from __future__ import annotations

import argparse

from invrender.cli.common import add_integrator_arguments, add_scene_argument, integrator_spec, integrators_epilog, parse_resolution, parse_rgb

DOC = """\
Compare each gradient estimator (autodiff, replay) with central finite differences of a fixed random
pixel weighting sum(W * I), re-rendered with the same seed (common random numbers). Prints one row
per parameter component with the relative errors: |gradient - difference| over the component's
difference, or over a thousandth of its parameter's largest where that is larger (a component the
image does not depend on, such as a unit normal moved along itself, has a difference of 0).
"""

#: Neumann terms the checked renders keep unless --max-depth (or --set max_depth) says otherwise
DEFAULT_DEPTH = 4


def add_parser(sub) -> None:
    g = sub.add_parser("gradcheck", help="check gradients against finite differences", description=DOC, epilog=integrators_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(g)
    g.add_argument("--params", default="red.reflectance,white.reflectance,light.emission", help="comma-separated parameter names")
    g.add_argument("--estimators", default="autodiff,replay", help="comma-separated: autodiff, replay")
    g.add_argument("--resolution", type=parse_resolution, default=(32, 32), metavar="WxH", help="(default: 32x32)")
    g.add_argument("--spp", type=int, default=32, help="(default: 32)")
    g.add_argument("--max-depth", type=int, default=None, help=f"keep below the integrator's rr_depth so the estimate is smooth (default: {DEFAULT_DEPTH})")
    g.add_argument("--seed", type=int, default=0)
    add_integrator_arguments(g, what="the integrator differentiated")
    g.add_argument("--ambient", type=parse_rgb, default=None, metavar="R,G,B", help="ambient radiance eps0 (makes ambient.emission a parameter to check)")
    g.add_argument("--step", type=float, default=1e-2, help="finite-difference step, relative (default: 0.01)")
    g.add_argument("--tolerance", type=float, default=None, help="exit 1 if any relative error exceeds this")
    g.set_defaults(run=run)


def run(args) -> int:
    import invrender as ir
    from invrender.inverse.gradcheck import format_rows, gradcheck

    spec = integrator_spec(args, flags={"max_depth": args.max_depth})
    max_depth = spec.pop("max_depth", DEFAULT_DEPTH)
    scene = ir.load_scene(args.scene, resolution=args.resolution, ambient=args.ambient)
    estimators = [e.strip() for e in args.estimators.split(",") if e.strip()]
    rows = gradcheck(scene, args.params, estimators=estimators, spp=args.spp, max_depth=max_depth, seed=args.seed, h=args.step, integrator=spec)
    print(format_rows(rows))
    worst = max(max(r.rel_errors.values()) for r in rows)
    print(f"largest relative error: {worst:.3e}")
    return 1 if args.tolerance is not None and worst > args.tolerance else 0
