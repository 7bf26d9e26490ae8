"""``invrender fit``: fit parameters to target images (a front over
:func:`invrender.inverse.fit_output.fit_into` and :func:`invrender.study.recipe_fits.fit_recipe`)."""

from __future__ import annotations

import argparse
import sys

from invrender.cli import catalog
from invrender.cli.common import (
    EXIT_INTERRUPTED, add_integrator_arguments, check_out_dir, fmt, integrator_spec, integrators_epilog, one_or_three_numbers, parse_bool, parse_init, parse_resolution,
)  # fmt: skip
from invrender.errors import InvRenderError, ParameterError

EPILOG = """\
examples:
  invrender render cornell_box --resolution 64x64 --spp 1024 --out target.exr
  invrender fit --scene cornell_box --target target.exr --init reflectance=0.5 --init emission=5 \\
      --params red.reflectance,green.reflectance,white.reflectance,light.emission --out runs/cbox
  invrender fit --scene cornell_box --target target.exr --params light.emission \\
      --integrator path --set rr_depth=3 --set strategy=emitter --out runs/nee
  invrender fit --scene scene.xml --cameras capture/transforms.json --params white.reflectance --out runs/capture
                                                # every view of a dataset; its images the targets
  invrender fit --scene sky_spheres --cameras views/transforms.json --held-out 3 --params sky.emission \\
      --init sky.emission=1 --integrator path --set hide_emitters=true --truth sky.emission=true_sky.exr --out runs/sky
                                                # an environment map: the relighting product, view 3 held out
  invrender fit optimize/cornell_random.toml --out runs/cornell_random
  invrender fit optimize/cornell_random.toml --out runs/cornell_random --resume     # after Ctrl-C
  invrender fit optimize/utah_bias.toml --out runs/utah_bias    # a model study: path vs utah
  torchrun --standalone --nproc-per-node 2 -m invrender fit optimize/cornell_views.toml --out runs/views
                                                # renders and gradients split across 2 processes

Defaults: --solver auto, which picks the solver from the parameters and says which and why: the
transport-matrix solve for one environment map alone, lm on path records (albedos, k_s, emissions,
the sensor) or on re-traced renders (a roughness), else Adam; settings only Adam has (--steps,
--lr, --loss other than relative_l2, --control-variate, ...) choose Adam. Adam: up to 200 steps on
rho = sigmoid(x), eps = exp(x) (step 0.15, cosine decay), 16 then 64 spp, stopping on the loss's
plateau; lm: up to 5 rounds from 16 spp, 4x more each. The path tracer at max_depth 8, relative L2
loss. A fit that did not converge says so (a warning, and "converged": false in report.json). --integrator and --set choose the model every render of the fit uses (any setting of
any integrator, listed below); with a recipe they change the recipe's integrator (a variant that
names an integrator of its own keeps it).

Writes OUT/report.json (initial, recovered and, when a recipe knows it, true values with errors),
OUT/loss.png (loss and parameter error per step), OUT/final.exr (the recovered scene rendered),
OUT/NAME.exr and OUT/NAME.png for every recovered map (a texture or a normal map: its values, and a
picture; a normal map's PNG holds its codes as a normal-map file does) and OUT/checkpoint.pt
(every few steps and on Ctrl-C; --resume continues to the same result).
A fit of one environment map's texels alone also writes the relighting product: OUT/map.exr (the
recovered map), OUT/stderr.exr (its standard errors), OUT/resolution.png (its identifiability: 1
set by the images, 0 by the prior), OUT/heldout*.exr/png (the --held-out views relit) and
OUT/relighting.png (true map with --truth, recovered map, standard errors, identifiability, and
each training and held-out view's target beside its relit render, labelled); each view's errors
are in report.json under "relighting".
A recipe with [[variants]] runs one fit per variant into OUT/<label>/ and writes OUT/study.md and
OUT/study.json: each parameter channel's relative error under each variant.

"""


#: every FitSettings field as a flag: (name, kind: int, float, bool or str, help), from the dataclass
#: and its docstring (:mod:`invrender.cli.catalog`); ``integrator`` is --integrator (and --set)
FIT_OPTIONS = catalog.FIT_OPTIONS


def add_parser(sub) -> None:
    f = sub.add_parser(
        "fit", help="recover rho and eps from target images",
        description="Fit parameters to target images by gradient descent through the Monte Carlo estimate.",
        epilog=EPILOG + integrators_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    f.add_argument("recipe", nargs="?", help="an optimize/*.toml fit recipe (instead of --scene/--target/--params)")
    f.add_argument("--scene", help="built-in name or scene file whose parameters are fitted")
    f.add_argument("--target", nargs="+", metavar="IMAGE", help="target image(s): EXR or HDR (linear), PNG (8/16-bit) or JPEG (photographs: sRGB unless --response); one per view")
    f.add_argument("--cameras", metavar="FILE", help="the views: a NeRF transforms.json, a COLMAP cameras.txt/images.txt or a folder holding them (docs/cameras.md); every view is fitted at once, its image the target unless --target is given")
    f.add_argument("--params", help="comma-separated parameter names, e.g. red.reflectance,light.emission")
    f.add_argument("--init", action="append", default=[], metavar="KEY=VALUE", help="starting value: NAME=v or NAME=r,g,b; NAME is any name --params takes (sensor.exposure, sensor.white_balance too), or a kind (reflectance, specular_reflectance, emission) for all fitted ones of it (repeatable)")
    f.add_argument("--resolution", type=parse_resolution, default=None, metavar="WxH", help="render size (default: the target's)")
    f.add_argument("--out", required=True, help="output folder: report.json, loss.png, final.exr, final.png, checkpoint.pt (correlation.png for lm, pixels.png where pixels were left out)")
    f.add_argument("--truth", action="append", default=[], metavar="KEY=VALUE", help="ground truth of a fitted parameter, where known: NAME=v, NAME=r,g,b or NAME=IMAGE (an EXR/HDR map, e.g. an environment map's): its errors in report.json, its panel in relighting.png (repeatable)")
    f.add_argument("--held-out", nargs="+", type=int, default=None, metavar="N", help="views of --cameras (0-based, in the file's order) left out of the fit and relit under the recovered environment map, each against its image (or its --target: then one per view, the held-out ones too)")
    f.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt with the settings stored in it, except those given anew")
    # photographs (docs/photographs.md): masks, the camera response, the sensor
    f.add_argument("--mask", nargs="+", metavar="IMAGE", help="pixel weights: one mask image for every target or one per target (white counts, black does not; default: a PNG target's alpha)")
    f.add_argument("--response", nargs="+", metavar="NAME", help="camera response of the targets: linear, srgb, gamma:G or a CSV curve; one, or one per target (default: srgb for 8/16-bit files, linear for EXR/HDR)")
    f.add_argument("--shared-sensor", metavar="LIST", help="comma-separated: exposure, white_balance: one value for every view (default: one per view)")
    f.add_argument("--keep-clipped", action="store_true", help="do not exclude the saturated pixels and pixels at 0 of 8/16-bit targets")
    add_integrator_arguments(f, default=None, what="the model fitted")
    for name, kind, doc in FIT_OPTIONS:
        if name != "integrator":
            f.add_argument(f"--{name.replace('_', '-')}", dest=name, type={"int": int, "float": float, "bool": parse_bool, "str": str}[kind], default=None, metavar=name.upper() if kind != "bool" else "true|false", help=doc)
    f.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    f.set_defaults(run=run, group=True)


def run(args) -> int:
    import invrender as ir
    from invrender.inverse.fit_output import fit_into
    from invrender.recipes import apply_init, load_fit_recipe, split_init
    from invrender.study.recipe_fits import fit_recipe

    out = check_out_dir(args.out)
    settings = {name: getattr(args, name) for name, _, _ in FIT_OPTIONS if name != "integrator" and getattr(args, name) is not None}
    recipe = None
    if args.recipe:
        if args.scene or args.target or args.params or args.cameras or args.held_out or args.truth:
            raise ParameterError("give either a recipe or --scene/--target/--params (and --cameras, --held-out, --truth), not both")
        recipe = load_fit_recipe(args.recipe)
        if args.mask or args.response or args.shared_sensor or args.keep_clipped:
            raise ParameterError("--mask, --response, --shared-sensor and --keep-clipped go with --target, not with a recipe")
    elif not (args.scene and (args.target or args.cameras) and args.params):
        raise ParameterError("fit needs a recipe, or all of --scene, --target (or --cameras) and --params")
    if args.integrator or args.set:
        base = recipe.settings.get("integrator") if recipe is not None else None
        settings["integrator"] = integrator_spec(args, base)
    init = parse_init(args.init)
    try:
        if recipe is not None:
            done = fit_recipe(recipe, out, init=init, settings=settings, resume=args.resume, progress=not args.quiet, log=lambda line: _say(args, line), on_fit=lambda label, o: _summary(args, o))
            if done.markdown is not None:
                print(done.markdown)
                print(f"wrote {out}/study.md, study.json and one folder per variant", file=sys.stderr)
            return 0
        cameras, size = _cameras(args)
        targets = list(args.target or [])  # paths: fit reads them, and its errors name the file
        if args.resolution is None and size is None:
            height, width = ir.read_image(targets[0]).shape[:2]
            size = (width, height)
        scene = ir.load_scene(args.scene, resolution=args.resolution or size)
        names = [n.strip() for n in args.params.split(",") if n.strip()]
        if cameras is not None:
            targets = targets or [str(f.image) for f in cameras]
        views = None if cameras is None else [f.camera for f in cameras]
        views, targets, held_out = _held_out(args, views, targets)
        report = {"targets": targets, **({"cameras": str(args.cameras)} if cameras is not None else {})}
        if held_out:
            report["held_out"] = {"views": args.held_out, "targets": [str(t) for _, t in held_out]}
        photo = _photo_options(args, len(targets))
        init, sensor = split_init(init, photo.get("sensor"))  # --init takes every name --params does
        photo |= {"sensor": sensor} if sensor else {}
        apply_init(scene, names, init)
        truth = _truth(args.truth, ir.read_image)
        labels = None
        if held_out:  # the views by their numbers in the --cameras file
            labels = [f"view {i} (fitted)" for i in range(len(cameras)) if i not in args.held_out] + [f"view {i} (held out)" for i in sorted(set(args.held_out))]
        _summary(args, fit_into(out, scene, targets, names, cameras=views, truth=truth, held_out=held_out, labels=labels, resume=args.resume, progress=not args.quiet, report=report, **photo, **settings))
    except KeyboardInterrupt:
        print("invrender: interrupted; checkpoint saved (continue with --resume)", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def _cameras(args):
    """(the --cameras views, their common (width, height)), or (None, None) without --cameras."""
    if not args.cameras:
        return None, None
    from invrender.scene.formats.cameras import common_resolution, load_cameras

    frames = load_cameras(args.cameras, require_images=not args.target)
    return frames, common_resolution(frames, args.cameras)


def _held_out(args, views, targets):
    """(the views fitted, their targets, [(camera, target)] of the --held-out views) from the
    --cameras views and their targets; one-line errors for held-out views that are not there."""
    if not args.held_out:
        return views, targets, None
    if views is None:
        raise ParameterError("--held-out names views of --cameras (0-based, in the file's order): give --cameras")
    if len(targets) != len(views):
        raise ParameterError(f"--target: {len(targets)} image(s) for the {len(views)} views of {args.cameras}: give one per view, the held-out ones too")
    bad = [i for i in args.held_out if not 0 <= i < len(views)]
    if bad:
        raise ParameterError(f"--held-out {bad[0]}: {args.cameras} has {len(views)} views (0 to {len(views) - 1})")
    left = sorted(set(args.held_out))
    if len(left) == len(views):
        raise ParameterError(f"--held-out leaves none of the {len(views)} views of {args.cameras} to fit")
    kept = [i for i in range(len(views)) if i not in left]
    return [views[i] for i in kept], [targets[i] for i in kept], [(views[i], targets[i]) for i in left]


def _truth(items: list[str], read_image) -> dict:
    """``["NAME=v", "NAME=r,g,b", "NAME=map.exr"]`` -> {NAME: value or image}."""
    truth = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip() or not text:
            raise ParameterError(f"--truth expects NAME=VALUE, NAME=R,G,B or NAME=IMAGE, got {item!r}")
        values = one_or_three_numbers(text)
        if values is None:  # an image file: a map
            try:
                truth[key.strip()] = read_image(text)
            except InvRenderError as e:
                raise ParameterError(f"--truth {key.strip()}: {e}") from None
        else:
            truth[key.strip()] = values[0] if len(values) == 1 else values
    return truth


def _photo_options(args, views: int) -> dict:
    """fit's mask, response, sensor and exclude_clipped from the photograph flags."""
    out = {"exclude_clipped": not args.keep_clipped}
    for key in ("mask", "response"):
        given = getattr(args, key)
        if given:
            if len(given) not in (1, views):
                raise ParameterError(f"--{key}: give one for every target or one per target ({views}), got {len(given)}")
            out[key] = given[0] if len(given) == 1 else list(given)
    if args.shared_sensor:
        out["sensor"] = {"shared": [s.strip() for s in args.shared_sensor.split(",") if s.strip()]}
    return out


def _say(args, line: str) -> None:
    if not args.quiet:
        print(line, file=sys.stderr)


def _summary(args, output) -> None:
    """What a fit recovered, on stderr (unless --quiet)."""
    if args.quiet:
        return
    report, result = output.report, output.result
    state = {True: "converged", False: "NOT converged", None: "convergence not checked"}[result.converged]
    print(f"{result.solver}: {report['steps']} {'steps' if result.solver == 'adam' else 'rounds'} in {report['seconds']:.1f} s, final loss {report['final_loss']:.4g}, {state}", file=sys.stderr)
    for name, value in result.params.items():
        err = f"  (rel. error {result.errors[name]:.2%})" if name in result.errors else ""
        print(f"  {name}: {fmt(value)}{err}", file=sys.stderr)
    folder = output.written[0].parent
    names = {p.name for p in output.written}
    figures = ", ".join(n for n in ("loss.png", "correlation.png") if n in names)
    pixels = ", pixels*.png (the pixels that counted)" if any(n.startswith("pixels") for n in names) else ""
    product = ", " + ", ".join(n for n in ("map.exr", "stderr.exr", "resolution.png", "relighting.png") if n in names) if "map.exr" in names else ""
    held = ", held-out views relit (heldout*.exr, .png)" if any(n.startswith("heldout") for n in names) else ""
    maps = sorted(n[: -len(".exr")] for n in names if n.endswith(".exr") and "." in n[: -len(".exr")])  # NAME.kind.exr: a recovered map
    recovered = f", the recovered maps ({', '.join(maps)}: EXR and PNG)" if maps else ""
    print(f"wrote {folder}/report.json, {figures}, final EXR and PNG{pixels}{product}{held}{recovered}, checkpoint.pt", file=sys.stderr)
    for label, error in output.report.get("relighting", {}).items():
        print(f"  {label} relit: channel means {' '.join(f'{100 * m:+.2f}%' for m in error['channel_means'])}, pooled relative RMSE {100 * error['rmse']:.2f}%", file=sys.stderr)
