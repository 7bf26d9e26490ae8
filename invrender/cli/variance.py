"""``invrender variance``: gradient-variance studies, the furnace check against closed forms, and
fit studies (a front over :func:`invrender.gradient_study`, :func:`invrender.study.furnace.furnace_check`
and :func:`invrender.study.fits.fit_study`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from invrender.cli.common import add_scene_argument, check_out_dir, int_list, parse_init, parse_resolution
from invrender.errors import ParameterError

DOC = """\
Measure gradient estimators: for each configuration (integrator, estimator autodiff|replay,
pairing of dl/dI correlated|decorrelated|control_variate, and render options such as
sampler=antithetic or rr_depth) and each spp, draw
--trials gradients of the loss from independent seeds; report per parameter and component the mean,
variance (with its standard error), bias against a high-spp reference (with both standard errors),
seconds per gradient and efficiency 1/(variance x seconds); plot variance and bias against spp and
the per-pixel variance of one parameter's gradient. With SCENE 'furnace', compare measured bias and
variance with the closed forms (docs/closed_forms.md#gradient-statistics-in-the-furnace). With
--fits, run a fit (ir.fit) with each configuration instead, from the same start against the same
target, and plot the largest relative parameter error against wall time (time to 2% and 1%).
"""

EPILOG = """\
examples:
  invrender variance cornell_box --params red.reflectance,light.emission --out runs/variance
  invrender variance cornell_box --params white.reflectance --configs path/replay/correlated,random_walk/replay/correlated/rr_depth=1 --spp 4,16,64 --out runs/rw
  invrender variance cornell_box --params red.reflectance --configs path/replay/decorrelated,path/replay/decorrelated/sampler=antithetic,path/replay/control_variate --at 0.95 --out runs/vr
  invrender variance furnace                                 # -> runs/variance/furnace; add --tolerance 4 to exit 1 on a miss
  invrender variance cornell_box --fits --params red.reflectance,green.reflectance,white.reflectance,light.emission --repeats 3 --out runs/fits

A configuration spec names its parts with '/', in any order: an integrator (path, random_walk, ...),
an estimator (replay, autodiff), a pairing (correlated: dl/dI from the differentiated render itself;
decorrelated: from an independent one, as fit does; control_variate: at a recursive control variate
carried along cv_steps=8 steps of cv_step=0.01 toward the point, as fit --control-variate does) and
KEY=VALUE render options (sampler=independent|stratified|antithetic, rr_depth=1, max_depth=-1, ...).
KEY may be any setting of the integrator (listed by 'invrender render --help').
Left out: path, replay, decorrelated. With --fits a configuration becomes fit settings: the
integrator with its settings (rr_depth, strategy, ...; the fit's integrator spec), estimator,
pairing (correlated: decorrelate false; control_variate: control_variate true), max_depth and
sampler; the other render settings and the pairing's own options are refused.
"""


def add_parser(sub) -> None:
    v = sub.add_parser("variance", help="gradient-variance study of gradient estimators", description=DOC, epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(v)
    v.add_argument("--params", default=None, help="comma-separated parameter names (required, except for furnace: glow.emission,wall.reflectance)")
    v.add_argument("--out", default=None, help="output folder (default: runs/variance/SCENE, SCENE the scene's name or file stem): results.csv, results.json, samples.pt, variance.png, bias.png, pixel_variance.png (with --fits: fits.csv, fits_summary.csv, fits.json, fits.png)")
    v.add_argument("--configs", default=None, metavar="SPEC,SPEC", help="configurations INTEGRATOR/ESTIMATOR/PAIRING[/KEY=VALUE...], comma-separated (default: " + ",".join(study_defaults()[0]) + "; --fits: " + ",".join(study_defaults()[2]) + "; furnace: the closed-form checks)")
    v.add_argument("--spp", default=None, metavar="N,N", help="comma-separated samples per pixel (default: " + ",".join(map(str, study_defaults()[1])) + "; furnace: 1,4,16)")
    v.add_argument("--trials", type=int, default=None, help="independent gradients per configuration and spp, >= 2 (default: 200, ~10%% error on a variance)")
    v.add_argument("--loss", default=None, help="relative_l2, l2 or l1 (default: relative_l2, fit's; furnace: l2)")
    v.add_argument("--resolution", type=parse_resolution, default=None, metavar="WxH", help="(default: 16x16; --fits: 32x32)")
    v.add_argument("--target", default=None, metavar="IMAGE", help="target image (default: the scene rendered at --target-spp with its own values)")
    v.add_argument("--target-spp", type=int, default=None, help="spp of the rendered target (default: 1024; --fits: 4096)")
    v.add_argument("--at", type=float, default=None, metavar="FACTOR", help="take the gradient (--fits: start the fits) at the studied parameters' values times FACTOR (default: 0.5; 1 = at the target's values)")
    v.add_argument("--init", action="append", default=[], metavar="KEY=VALUE", help="take the gradient (--fits: start) at these values instead: NAME=v or NAME=r,g,b, NAME may be a kind (repeatable)")
    v.add_argument("--reference-spp", type=int, default=None, help="spp of each reference gradient; 0 = no reference, no bias (default: 128)")
    v.add_argument("--reference-repeats", type=int, default=None, help="decorrelated gradients averaged into the reference (default: 16)")
    v.add_argument("--workers", type=int, default=None, help="trials drawn at once, each on one core (default: one per core)")
    v.add_argument("--fits", action="store_true", help="run fits (ir.fit, Adam) with each configuration from the start (--at/--init) against the target and plot the largest parameter error against wall time")
    v.add_argument("--repeats", type=int, default=None, help="--fits: fits per configuration, seeds SEED..SEED+N-1; medians reported (default: 1)")
    v.add_argument("--steps", type=int, default=None, help="--fits: Adam steps of each fit (default: 200, fit's)")
    v.add_argument("--fit-spp", default=None, metavar="N[,N]", help="--fits: spp of the first half of the steps and of the second (default: 16,64, fit's)")
    v.add_argument("--pixel-param", default=None, metavar="NAME", help="parameter of the per-pixel variance image (default: the first of --params)")
    v.add_argument("--pixel-spp", type=int, default=None, help="spp of the per-pixel variance image (default: the smallest --spp)")
    v.add_argument("--no-pixel-maps", action="store_true", help="skip the per-pixel variance image")
    v.add_argument("--rho", type=float, default=0.5, help="furnace: grey albedo, 0 < rho < 1 (default: 0.5)")
    v.add_argument("--eps", type=float, default=1.0, help="furnace: emission (default: 1)")
    v.add_argument("--tolerance", type=float, default=None, metavar="Z", help="furnace: exit 1 if a measured bias or variance is more than Z standard errors from its closed form")
    v.add_argument("--seed", type=int, default=0, help="the study's seed (default: 0)")
    v.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    v.set_defaults(run=run)


def study_defaults() -> tuple:
    """(a study's default configurations, its spp, a fit study's configurations): the defaults of
    :mod:`invrender.study`, by way of :mod:`invrender.cli.catalog`."""
    from invrender.cli.catalog import FIT_STUDY_CONFIGS, STUDY_CONFIGS, STUDY_SPP

    return STUDY_CONFIGS, STUDY_SPP, FIT_STUDY_CONFIGS


def run(args) -> int:
    import invrender as ir
    from invrender.io.reports import write_json, write_text
    from invrender.study.furnace import FURNACE_CONFIGS, FURNACE_PARAMS, FURNACE_SPP, furnace_check
    from invrender.study.output import summary_text, write_study
    from invrender.study.plots import plot_study

    out = check_out_dir(args.out if args.out is not None else str(Path("runs", "variance", Path(args.scene).stem)))
    fit_flags = (("--repeats", args.repeats), ("--steps", args.steps), ("--fit-spp", args.fit_spp))
    study_flags = (("--spp", args.spp), ("--trials", args.trials), ("--reference-spp", args.reference_spp), ("--reference-repeats", args.reference_repeats),
                   ("--pixel-param", args.pixel_param), ("--pixel-spp", args.pixel_spp), ("--no-pixel-maps", args.no_pixel_maps), ("--workers", args.workers))  # fmt: skip
    if args.fits:
        return run_fit_study(args, out, study_flags)
    given = [flag for flag, value in fit_flags if value is not None]
    if given:
        raise ParameterError(f"{given[0]} applies to fits only (add --fits)")
    spp = None if args.spp is None else int_list(args.spp, "--spp")
    trials = 200 if args.trials is None else args.trials
    resolution = (16, 16) if args.resolution is None else args.resolution
    if args.scene == "furnace":
        given = [flag for flag, value in (("--target", args.target), ("--target-spp", args.target_spp), ("--at", args.at), ("--init", args.init), ("--pixel-param", args.pixel_param), ("--pixel-spp", args.pixel_spp)) if value]
        if given:
            raise ParameterError(f"{given[0]} does not apply to the furnace check (its target is the exact radiance, its gradient taken at the scene's values)")
        check = furnace_check(
            FURNACE_CONFIGS if args.configs is None else args.configs, FURNACE_SPP if spp is None else spp, trials, rho=args.rho, eps=args.eps, resolution=resolution,
            loss="l2" if args.loss is None else args.loss, params=args.params.split(",") if args.params else FURNACE_PARAMS, seed=args.seed, workers=args.workers,
            progress=not args.quiet,
        )  # fmt: skip
        study = check.study
        written = write_study(study, out) + plot_study(study, out, check.predictions())
        write_text(out / "check.md", check.table())
        write_json(out / "check.json", check.to_dict())
        written += [out / "check.md", out / "check.json"]
        print(check.table(), flush=True)
    else:
        scene = variance_scene(args, resolution)
        study = ir.gradient_study(
            scene, args.params, study_defaults()[0] if args.configs is None else args.configs, study_defaults()[1] if spp is None else spp, trials,
            loss="relative_l2" if args.loss is None else args.loss, target=args.target, target_spp=1024 if args.target_spp is None else args.target_spp,
            at=parse_init(args.init) if args.init else (0.5 if args.at is None else args.at),
            reference_spp=128 if args.reference_spp is None else args.reference_spp, reference_repeats=16 if args.reference_repeats is None else args.reference_repeats,
            pixel_maps=not args.no_pixel_maps, pixel_param=args.pixel_param, pixel_spp=args.pixel_spp, seed=args.seed, workers=args.workers, progress=not args.quiet,
        )  # fmt: skip
        written = write_study(study, out) + plot_study(study, out)
        check = None
    if not args.quiet:
        print(summary_text(study), flush=True)
        print("wrote " + ", ".join(str(p) for p in written), file=sys.stderr)
    if check is not None and args.tolerance is not None and check.worst_z() > args.tolerance:
        print(f"invrender: a closed form is missed by {check.worst_z():.1f} standard errors (tolerance {args.tolerance:g})", file=sys.stderr)
        return 1
    return 0


def variance_scene(args, resolution):
    """The scene of a study or fit study, after the checks of --params, --at and --init."""
    import invrender as ir

    if not args.params:
        scene = ir.load_scene(args.scene, resolution=resolution)
        raise ParameterError(f"variance needs --params NAME,NAME (the scene's: {', '.join(scene.params)})")
    if args.at is not None and args.init:
        raise ParameterError("give --at or --init, not both")
    return ir.load_scene(args.scene, resolution=resolution)


def run_fit_study(args, out: Path, study_flags) -> int:
    """``invrender variance SCENE --fits``: a fit per configuration and repeat."""
    from invrender.study.fits import DEFAULT_FIT_CONFIGS, fit_study, fit_summary_text
    from invrender.study.output import write_fit_study

    if args.scene == "furnace":
        raise ParameterError("--fits does not apply to the furnace check (its gradients are checked against closed forms, not fitted)")
    given = [flag for flag, value in study_flags if value not in (None, False)]
    if given:
        raise ParameterError(f"{given[0]} applies to gradient studies, not to --fits (fits take --steps, --fit-spp, --repeats)")
    fit_spp = [16, 64] if args.fit_spp is None else int_list(args.fit_spp, "--fit-spp")
    if len(fit_spp) not in (1, 2):
        raise ParameterError(f"--fit-spp takes one or two values (first half, second half of the steps), got {args.fit_spp!r}")
    scene = variance_scene(args, (32, 32) if args.resolution is None else args.resolution)
    study = fit_study(
        scene, args.params, DEFAULT_FIT_CONFIGS if args.configs is None else args.configs, repeats=1 if args.repeats is None else args.repeats,
        steps=200 if args.steps is None else args.steps, spp=fit_spp[0], spp_final=fit_spp[-1], loss="relative_l2" if args.loss is None else args.loss,
        target=args.target, target_spp=4096 if args.target_spp is None else args.target_spp, at=parse_init(args.init) if args.init else (0.5 if args.at is None else args.at),
        seed=args.seed, progress=not args.quiet,
    )  # fmt: skip
    written = write_fit_study(study, out)
    print(fit_summary_text(study), flush=True)
    if not args.quiet:
        print("wrote " + ", ".join(str(p) for p in written), file=sys.stderr)
    return 0
