"""The ``invrender`` command line: a thin front end over the public API.

Bad input ends with one line ``invrender: error: ...`` on stderr and exit status 2; outputs are
written atomically, so a failed or interrupted run leaves no half-written file.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings
from pathlib import Path

from invrender.errors import ImageError, InvRenderError, ParameterError
from invrender.scene.builtin import BUILTIN_SCENES

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130

DESCRIPTION = """\
invrender renders Kajiya's rendering equation I = g(eps + M I) by Monte Carlo on torch tensors
(a path tracer estimating the Neumann series g eps + gMg eps + g(Mg)^2 eps + ...).

commands:
  render     render a built-in scene (cornell_box, cornell_specular, furnace) or a scene file (.toml,
             Mitsuba .xml, .gltf, .glb, .obj) to EXR (linear float32) and/or PNG (sRGB), with the
             path tracer or an older method of the ladder (random_walk, utah, whitted, distributed)
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

Run 'invrender COMMAND --help' for a command's options.
"""

RENDER_EPILOG = """\
examples:
  invrender render                                         # Cornell box, 256x256, 64 spp -> out.exr
  invrender render cornell_box --spp 256 --resolution 128x128 --out cbox.exr cbox.png
  invrender render forward/mesh_in_box.toml --max-depth -1 --out mesh.png
  invrender render furnace --integrator random_walk --max-depth 4 --terms --out furnace.exr
  invrender render cornell_box --integrator utah --ambient 0.05 --out utah.exr
  invrender render cornell_specular --spp 256 --out spec.png            # mirror, glass, glossy
  invrender render cornell_specular --integrator whitted --ambient 0.02 --out whitted.png
  invrender render cornell_specular --integrator distributed --out cook.png
  invrender render cornell_box --strategy emitter --hemisphere uniform --rr-depth -1 --out nee.png
  invrender render forward/cornell_far.toml --spp 64 --adaptive --out far.png   # + far.spp.png
  invrender render cornell_box --device cuda --backend warp --spp 4096 --out gpu.exr
  torchrun --standalone --nproc-per-node 4 -m invrender render cornell_box --spp 4096 --out big.exr
                                                # split across 4 processes; rank 0 writes (docs/scale.md)

max_depth counts Neumann terms as Mitsuba 3 does: 1 = emitters seen directly, 2 = + direct
illumination, ...; -1 = unbounded (paths end by Russian roulette only). With --terms, term k
(the light reflected k times, g(Mg)^k eps) is also written to OUT_STEM.termK.SUFFIX.

Sampling strategies (docs/sampling.md): --sampler (pixel samples), --hemisphere (diffuse BSDF
sampling), --strategy (direct light by MIS, BSDF samples or emitter samples), --rr-depth -1 (no
Russian roulette); all estimate the same image. With --adaptive, --spp is the average number of
samples per pixel: a pilot pass estimates each pixel's variance, then --rounds passes spend the
samples where the estimated relative error is high (the image stays unbiased), and the samples
each pixel got are written to OUT_STEM.spp.png (and OUT_STEM.spp.exr for an .exr output).
"""


def _integrator_names() -> list[str]:
    from invrender.transport.integrators import INTEGRATORS

    return list(INTEGRATORS)


def integrator_help() -> str:
    """One clause per registered integrator, for ``--integrator``'s help."""
    from invrender.transport.integrators import INTEGRATORS

    return "; ".join(f"{name}: {cls.summary}" for name, cls in INTEGRATORS.items()) + " (default: path)"


def parse_bool(text: str) -> bool:
    """``true``/``false`` (also yes/no, 1/0)."""
    value = {"true": True, "yes": True, "1": True, "false": False, "no": False, "0": False}.get(text.strip().lower())
    if value is None:
        raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
    return value


def parse_resolution(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (width, height)."""
    try:
        w, h = (int(p) for p in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 64x64, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"resolution must be positive, got {text!r}")
    return w, h


def parse_rgb(text: str) -> list[float]:
    """``"v"`` or ``"r,g,b"`` -> [r, g, b] (finite, >= 0)."""
    values = _one_or_three_numbers(text)
    if values is None or not all(math.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected one number or R,G,B, finite and >= 0, got {text!r}")
    return values * 3 if len(values) == 1 else values


def _one_or_three_numbers(text: str) -> list[float] | None:
    """``"v"`` -> [v], ``"r,g,b"`` -> [r, g, b]; None for anything else."""
    try:
        values = [float(p) for p in text.split(",")]
    except ValueError:
        return None
    return values if len(values) in (1, 3) else None


def add_scene_argument(parser: argparse.ArgumentParser) -> None:
    """The optional positional SCENE every rendering command takes."""
    parser.add_argument(
        "scene", nargs="?", default="cornell_box",
        help=f"built-in name ({', '.join(BUILTIN_SCENES)}) or a scene file: .toml, Mitsuba 3 .xml (a subset), .gltf/.glb/.obj (default: cornell_box)",
    )  # fmt: skip


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
    add_scene_argument(r)
    r.add_argument("--out", nargs="+", default=["out.exr"], metavar="PATH", help="output image(s): .exr (linear float32) and/or .png (sRGB, clipped) (default: out.exr)")
    r.add_argument("--spp", type=int, default=None, help="samples per pixel (default: the scene file's, e.g. a Mitsuba sampler's sample_count, else 64)")
    r.add_argument("--max-depth", type=int, default=None, help="Neumann terms kept, Mitsuba's count; -1 = unbounded (default: 8; utah: 2)")
    r.add_argument("--resolution", type=parse_resolution, default=None, metavar="WxH", help="image size in pixels (default: the scene's)")
    r.add_argument("--integrator", default="path", help=integrator_help())
    r.add_argument("--ambient", type=parse_rgb, default=None, metavar="R,G,B", help="ambient radiance eps0 for --integrator utah, whitted or distributed (one number or R,G,B; default: the scene's, else 0)")
    r.add_argument("--seed", type=int, default=0, help="random seed; the image is a pure function of it (default: 0)")
    r.add_argument("--rr-depth", type=int, default=None, help="Russian roulette starts after this many terms; -1 = no roulette (path, random_walk, distributed; default: 5)")
    r.add_argument("--sampler", default="stratified", help="pixel samples: stratified (jittered on a grid, default), independent, or antithetic (pairs whose second path draws 1 - u for every number of the first)")
    r.add_argument("--strategy", default=None, help="direct light of the path tracer: mis (emitter and BSDF samples by multiple importance sampling, default), bsdf (BSDF samples only) or emitter (emitter samples only)")
    r.add_argument("--hemisphere", default=None, help="diffuse BSDF sampling: cosine (default) or uniform over the hemisphere (path, random_walk)")
    r.add_argument("--adaptive", action="store_true", help="adaptive sampling: --spp samples per pixel on average, spent where the estimated error is high; writes OUT_STEM.spp.png")
    for name, kind, doc in ADAPTIVE_OPTIONS:
        r.add_argument(f"--{name.replace('_', '-')}", dest=name, type=kind, default=None, metavar=name.upper(), help=doc)
    r.add_argument("--terms", action="store_true", help="also write one image per Neumann term (OUT_STEM.termK.SUFFIX)")
    r.add_argument("--device", default="cpu", help="torch device: cpu or cuda (default: cpu)")
    r.add_argument("--backend", default=None, help="intersection backend: embree (CPU only; its default), warp (NVIDIA Warp BVH, CUDA or CPU; the default on CUDA) or torch (brute force, any device: the reference)")
    r.add_argument("--memory-mb", type=float, default=512.0, help="memory budget of one chunk of paths, MiB (default: 512)")
    r.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    r.set_defaults(run=run_render)

    f = sub.add_parser(
        "fit",
        help="recover rho and eps from target images",
        description="Fit parameters to target images by gradient descent through the Monte Carlo estimate.",
        epilog=FIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    f.add_argument("recipe", nargs="?", help="an optimize/*.toml fit recipe (instead of --scene/--target/--params)")
    f.add_argument("--scene", help="built-in name or scene file whose parameters are fitted")
    f.add_argument("--target", nargs="+", metavar="IMAGE", help="target image(s): EXR (linear) or PNG; one per view")
    f.add_argument("--params", help="comma-separated parameter names, e.g. red.reflectance,light.emission")
    f.add_argument("--init", action="append", default=[], metavar="KEY=VALUE", help="starting value: NAME=v or NAME=r,g,b; NAME may be a kind (reflectance, specular_reflectance, emission) for all fitted ones of it (repeatable)")
    f.add_argument("--resolution", type=parse_resolution, default=None, metavar="WxH", help="render size (default: the target's)")
    f.add_argument("--out", required=True, help="output folder: report.json, loss.png, final.exr, final.png, checkpoint.pt")
    f.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt with the settings stored in it, except those given anew")
    for name, kind, doc in FIT_OPTIONS:
        f.add_argument(f"--{name.replace('_', '-')}", dest=name, type=parse_bool if kind == "bool" else kind, default=None, metavar=name.upper() if kind != "bool" else "true|false", help=doc)
    f.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    f.set_defaults(run=run_fit)

    g = sub.add_parser("gradcheck", help="check gradients against finite differences", description=GRADCHECK_DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(g)
    g.add_argument("--params", default="red.reflectance,white.reflectance,light.emission", help="comma-separated parameter names")
    g.add_argument("--estimators", default="autodiff,replay", help="comma-separated: autodiff, replay")
    g.add_argument("--resolution", type=parse_resolution, default=(32, 32), metavar="WxH", help="(default: 32x32)")
    g.add_argument("--spp", type=int, default=32, help="(default: 32)")
    g.add_argument("--max-depth", type=int, default=4, help="keep below --rr-depth so the estimate is smooth (default: 4)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--integrator", default="path", help="the integrator differentiated (default: path): " + ", ".join(_integrator_names()))
    g.add_argument("--ambient", type=parse_rgb, default=None, metavar="R,G,B", help="ambient radiance eps0 (makes ambient.emission a parameter to check)")
    g.add_argument("--step", type=float, default=1e-2, help="finite-difference step, relative (default: 0.01)")
    g.add_argument("--tolerance", type=float, default=None, help="exit 1 if any relative error exceeds this")
    g.set_defaults(run=run_gradcheck)

    d = sub.add_parser("dataset", help="render a synthetic dataset recipe", description="Render a datasets_synthetic/*.toml recipe: view_NN.exr/png, truth.json, manifest.json.")
    d.add_argument("recipe", help="a dataset recipe (.toml)")
    d.add_argument("--out", required=True, help="output folder")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(run=run_dataset)

    b = sub.add_parser("baseline", help="rasterize a scene with pyrender (Utah baseline)", description=BASELINE_DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(b)
    b.add_argument("--out", nargs="+", default=["baseline.exr"], metavar="PATH", help="output image(s): .exr and/or .png (default: baseline.exr)")
    b.add_argument("--resolution", type=parse_resolution, default=None, metavar="WxH", help="image size (default: the scene's)")
    b.add_argument("--ambient", type=parse_rgb, default=None, metavar="R,G,B", help="ambient radiance eps0 (default: the scene's, else 0)")
    b.add_argument("--quiet", action="store_true", help="no summary")
    b.set_defaults(run=run_baseline)

    c = sub.add_parser("compare", help="pyrender vs utah vs path: what ignoring interreflection costs", description=COMPARE_DOC, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(c)
    c.add_argument("--out", default="compare.png", help="the figure, a .png (default: compare.png)")
    c.add_argument("--resolution", type=parse_resolution, default=(128, 128), metavar="WxH", help="(default: 128x128)")
    c.add_argument("--spp", type=int, default=64, help="samples per pixel of the Monte Carlo images (default: 64)")
    c.add_argument("--max-depth", type=int, default=-1, help="Neumann terms of the full path image (default: -1, unbounded)")
    c.add_argument("--ambient", type=parse_rgb, default=None, metavar="R,G,B", help="eps0 of utah and pyrender (default: the scene's, else 0)")
    c.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    c.add_argument("--no-pyrender", action="store_true", help="leave out the pyrender image")
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    c.set_defaults(run=run_compare)

    v = sub.add_parser("variance", help="gradient-variance study of gradient estimators", description=VARIANCE_DOC, epilog=VARIANCE_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(v)
    v.add_argument("--params", default=None, help="comma-separated parameter names (required, except for furnace: glow.emission,wall.reflectance)")
    v.add_argument("--out", required=True, help="output folder: results.csv, results.json, samples.pt, variance.png, bias.png, pixel_variance.png (with --fits: fits.csv, fits_summary.csv, fits.json, fits.png)")
    v.add_argument("--configs", default=None, metavar="SPEC,SPEC", help="configurations INTEGRATOR/ESTIMATOR/PAIRING[/KEY=VALUE...], comma-separated (default: " + ",".join(_study_defaults()[0]) + "; --fits: " + ",".join(_study_defaults()[2]) + "; furnace: the closed-form checks)")
    v.add_argument("--spp", default=None, metavar="N,N", help="comma-separated samples per pixel (default: " + ",".join(map(str, _study_defaults()[1])) + "; furnace: 1,4,16)")
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
    v.set_defaults(run=run_variance)

    a = sub.add_parser("ablation", help="compare sampling strategies at equal samples and equal time", description=ABLATION_DOC, epilog=ABLATION_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_scene_argument(a)
    a.add_argument("--out", required=True, help="output folder: ablation.csv, ablation.md, ablation.png")
    a.add_argument("--strategies", default=None, metavar="NAME,NAME", help="variants besides default (default: all): " + ", ".join(_ablation_names()))
    a.add_argument("--spp", default="8,16,32,64", metavar="N,N", help="samples per pixel, ascending (default: 8,16,32,64)")
    a.add_argument("--trials", type=int, default=2, help="seeds per strategy and spp (default: 2)")
    a.add_argument("--reference-spp", type=int, default=4096, help="spp of the reference, the defaults with other seeds (default: 4096)")
    a.add_argument("--resolution", type=parse_resolution, default=(64, 64), metavar="WxH", help="(default: 64x64)")
    a.add_argument("--max-depth", type=int, default=8, help="Neumann terms kept (default: 8)")
    a.add_argument("--seed", type=int, default=0, help="offsets every seed of the study (default: 0)")
    a.add_argument("--quiet", action="store_true", help="no progress bar")
    a.set_defaults(run=run_ablation)
    return parser


def _ablation_names() -> list[str]:
    from invrender.ablation.variants import VARIANTS

    return [v.name for v in VARIANTS if v.name != "default"]


def _study_defaults() -> tuple:
    from invrender.study import DEFAULT_CONFIGS, DEFAULT_SPP
    from invrender.study.fits import DEFAULT_FIT_CONFIGS

    return DEFAULT_CONFIGS, DEFAULT_SPP, DEFAULT_FIT_CONFIGS


ABLATION_DOC = """\
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

ABLATION_EPILOG = """\
examples:
  invrender ablation cornell_box --out runs/ablation                    # 1-2 minutes on 2 cores
  invrender ablation forward/cornell_far.toml --strategies adaptive --out runs/adaptive
  invrender ablation cornell_specular --strategies bsdf_only,emitter_only --spp 16,64,256 --out runs/mis
"""

FIT_EPILOG = """\
examples:
  invrender render cornell_box --resolution 64x64 --spp 1024 --out target.exr
  invrender fit --scene cornell_box --target target.exr --init reflectance=0.5 --init emission=5 \\
      --params red.reflectance,green.reflectance,white.reflectance,light.emission --out runs/cbox
  invrender fit optimize/cornell_random.toml --out runs/cornell_random
  invrender fit optimize/cornell_random.toml --out runs/cornell_random --resume     # after Ctrl-C
  invrender fit optimize/utah_bias.toml --out runs/utah_bias    # a model study: path vs utah
  torchrun --standalone --nproc-per-node 2 -m invrender fit optimize/cornell_views.toml --out runs/views
                                                # renders and gradients split across 2 processes

Defaults: 200 Adam steps on rho = sigmoid(x), eps = exp(x) (step 0.15, cosine decay), 16 then 64
spp, max_depth 8, relative L2 loss, path-replay gradients decorrelated from the loss's image.

Writes OUT/report.json (initial, recovered and, when a recipe knows it, true values with errors),
OUT/loss.png (loss and parameter error per step), OUT/final.exr (the recovered scene rendered) and
OUT/checkpoint.pt (every few steps and on Ctrl-C; --resume continues to the same result).
A recipe with [[variants]] runs one fit per variant into OUT/<label>/ and writes OUT/study.md and
OUT/study.json: each parameter channel's relative error under each variant.
"""

GRADCHECK_DOC = """\
Compare each gradient estimator (autodiff, replay) with central finite differences of a fixed random
pixel weighting sum(W * I), re-rendered with the same seed (common random numbers). Prints one row
per parameter component with the relative errors.
"""

BASELINE_DOC = """\
Rasterize a scene with pyrender (OpenGL, offscreen through EGL or OSMesa): the Utah approximation
as a rasterizer computes it (emitters as lights, one reflection, ambient eps0; no interreflection).
Writes linear radiance in the same convention as 'invrender render'.
"""

COMPARE_DOC = """\
Render a scene with pyrender, with the utah integrator, with path at max_depth 2 and with the full
path tracer; write one PNG with the images side by side over their differences to the full path,
and print a table of channel means and relative differences, the share of energy the Utah
approximation drops, and the ambient eps0 that best stands in for interreflection (least squares).
"""

VARIANCE_DOC = """\
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

VARIANCE_EPILOG = """\
examples:
  invrender variance cornell_box --params red.reflectance,light.emission --out runs/variance
  invrender variance cornell_box --params white.reflectance --configs path/replay/correlated,random_walk/replay/correlated/rr_depth=1 --spp 4,16,64 --out runs/rw
  invrender variance cornell_box --params red.reflectance --configs path/replay/decorrelated,path/replay/decorrelated/sampler=antithetic,path/replay/control_variate --at 0.95 --out runs/vr
  invrender variance furnace --out runs/furnace --tolerance 4
  invrender variance cornell_box --fits --params red.reflectance,green.reflectance,white.reflectance,light.emission --repeats 3 --out runs/fits

A configuration spec names its parts with '/', in any order: an integrator (path, random_walk, ...),
an estimator (replay, autodiff), a pairing (correlated: dl/dI from the differentiated render itself;
decorrelated: from an independent one, as fit does; control_variate: at a recursive control variate
carried along cv_steps=8 steps of cv_step=0.01 toward the point, as fit --control-variate does) and
KEY=VALUE render options (sampler=independent|stratified|antithetic, rr_depth=1, max_depth=-1, ...).
Left out: path, replay, decorrelated. With --fits a configuration becomes fit settings: integrator,
estimator, pairing (correlated: decorrelate false; control_variate: control_variate true),
max_depth and sampler; any other option is refused.
"""

#: AdaptiveSettings fields as render flags (only with --adaptive)
ADAPTIVE_OPTIONS = [
    ("pilot_spp", int, "with --adaptive: samples per pixel of the pilot pass, which only allocates (default: spp/8, from 4 to 16)"),
    ("rounds", int, "with --adaptive: passes after the pilot, each allocated from the samples before it (default: 2)"),
    ("target_error", float, "with --adaptive: relative standard error at which a pixel needs no more samples; --spp is then a cap (default: spend all of --spp)"),
    ("max_spp", int, "with --adaptive: most samples one pixel gets (default: 16 x --spp)"),
    ("floor", float, "with --adaptive: errors are relative to the pixel's mean + FLOOR x the image's mean (default: 1)"),
]

FIT_OPTIONS = [
    ("steps", int, "optimizer steps (default: 200)"),
    ("spp", int, "samples per pixel, first half of the steps (default: 16)"),
    ("spp_final", int, "samples per pixel, second half (default: 64)"),
    ("max_depth", int, "Neumann terms kept (default: 8)"),
    ("lr", float, "Adam step size for reflectances, logit units (default: 0.15)"),
    ("lr_emission", float, "Adam step size for emissions, log units (default: 0.15)"),
    ("lr_final", float, "the step sizes decay along a cosine to this fraction (default: 0.05)"),
    ("beta2", float, "Adam's second-moment decay (default: 0.95)"),
    ("integrator", str, "the model fitted: path, random_walk, utah, whitted or distributed (default: path)"),
    ("loss", str, "relative_l2, l2, l1 or ssim (default: relative_l2)"),
    ("estimator", str, "auto (default: autodiff where the recorded render fits in 512 MiB, else replay), replay or autodiff"),
    ("seed", int, "seed of every render (default: 0)"),
    ("decorrelate", "bool", "true: dl/dI from an independent render (unbiased gradients, default); false: from the same one"),
    ("checkpoint_every", int, "steps between checkpoints (default: 20)"),
    ("solver", str, "adam (gradient steps on re-traced renders, default), lm (Levenberg-Marquardt) or gauss_newton on path records"),
    ("rounds", int, "lm / gauss_newton: most record-and-solve rounds, round r at spp*4^r (default: 5)"),
    ("precision", float, "lm / gauss_newton: the rounds also wait until every standard error is below this fraction of its value (default: no such requirement)"),
    ("sampler", str, "pixel samples of every render or record: stratified (default), independent or antithetic (mirrored pairs)"),
    ("control_variate", "bool", "adam with decorrelate: true = take dl/dI at a recursive control-variate image (one more render per step; default: false)"),
]


def check_outputs(paths: list[str]) -> list[Path]:
    """Fail early (before a long render) on output paths that cannot be written."""
    from invrender.io.images import WRITE_SUFFIXES

    out = []
    for p in paths:
        path = Path(p)
        if path.suffix.lower() not in WRITE_SUFFIXES:
            raise ImageError(f"cannot write {p}: unknown image suffix {path.suffix or '(none)'!r} (use {', '.join(WRITE_SUFFIXES)})")
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
    scene = ir.load_scene(args.scene, resolution=args.resolution, ambient=args.ambient)
    # options not given fall back to the scene file's suggestions (scene.defaults), then to the
    # built-in defaults; its max_depth and rr_depth belong to its integrator (Mitsuba's path)
    defaults = scene.defaults
    spp = args.spp if args.spp is not None else defaults.get("spp", 64)
    same_integrator = args.integrator == defaults.get("integrator", "path")
    max_depth = args.max_depth if args.max_depth is not None else defaults.get("max_depth") if same_integrator else None
    rr_depth = args.rr_depth if args.rr_depth is not None else defaults.get("rr_depth") if same_integrator else None
    adaptive = _adaptive_settings(args)
    options = {k: v for k, v in (("strategy", args.strategy), ("hemisphere", args.hemisphere)) if v is not None}
    start = time.perf_counter()
    result = ir.render(
        scene, integrator=args.integrator, spp=spp, max_depth=max_depth, seed=args.seed, terms=args.terms,
        rr_depth=rr_depth, backend=args.backend, device=args.device, memory_mb=args.memory_mb, progress=not args.quiet, sampler=args.sampler,
        adaptive=adaptive, return_counts=adaptive is not None, **options,
    )  # fmt: skip
    seconds = time.perf_counter() - start
    image = result.image if adaptive is not None else result
    full = image.sum(0) if args.terms else image
    written = []
    for path in outputs:
        ir.write_image(path, full)
        if args.terms:
            for k in range(image.shape[0]):
                ir.write_image(path.with_name(f"{path.stem}.term{k}{path.suffix}"), image[k])
        if adaptive is not None:
            written += [p for p in write_sample_counts(path, result.spp) if p not in written]
    if not args.quiet:
        paths = scene.width * scene.height * spp
        print(f"{scene.name}: {scene.width}x{scene.height}, {spp} spp, {seconds:.2f} s ({paths / seconds / 1e6:.3g} M paths/s); mean RGB {_mean_rgb(full)}", file=sys.stderr)
        if adaptive is not None:
            counts = result.spp.float()
            print(f"adaptive: pilot {result.pilot_spp} spp + {len(result.passes)} rounds; samples per pixel {int(counts.min())} to {int(counts.max())} (mean {counts.mean():.4g}); "
                  f"estimated relative error median {result.error.median():.3g}, max {result.error.max():.3g}", file=sys.stderr)  # fmt: skip
        print("wrote " + ", ".join(str(p) for p in outputs + written) + (f" (+ {image.shape[0]} term images each)" if args.terms else ""), file=sys.stderr)
    return 0


def _adaptive_settings(args):
    """The AdaptiveSettings of ``render --adaptive`` (None without it; its options alone are an error)."""
    from invrender.transport.adaptive import AdaptiveSettings

    given = {name: getattr(args, name) for name, _, _ in ADAPTIVE_OPTIONS if getattr(args, name) is not None}
    if not args.adaptive:
        if given:
            raise ParameterError(f"--{next(iter(given)).replace('_', '-')} needs --adaptive")
        return None
    return AdaptiveSettings(**given)


def write_sample_counts(path: Path, counts) -> list[Path]:
    """Write the samples per pixel ``counts`` (H, W) beside the image ``path``: OUT_STEM.spp.png
    (a viridis map from 0 to the largest count) and, for an .exr ``path``, OUT_STEM.spp.exr (the
    counts themselves). Returns the paths written."""
    import invrender as ir
    from invrender.io.maps import write_count_map

    png = path.with_name(f"{path.stem}.spp.png")
    write_count_map(png, counts)
    out = [png]
    if path.suffix.lower() == ".exr":
        exr = path.with_name(f"{path.stem}.spp.exr")
        ir.write_image(exr, counts.float()[..., None].expand(*counts.shape, 3))
        out.append(exr)
    return out


def _mean_rgb(image) -> str:
    return ", ".join(f"{v:.4g}" for v in image.mean(dim=(0, 1)).tolist())


def parse_init(items: list[str]) -> dict:
    """``["NAME=v", "NAME=r,g,b"]`` -> {NAME: value}."""
    init = {}
    for item in items:
        key, sep, text = item.partition("=")
        values = _one_or_three_numbers(text)
        if not sep or not key or values is None:
            raise ParameterError(f"--init expects NAME=VALUE or NAME=R,G,B, got {item!r}")
        init[key.strip()] = values[0] if len(values) == 1 else values
    return init


def run_fit(args) -> int:
    import invrender as ir
    from invrender.recipes import load_dataset, load_fit_recipe, make_dataset
    from invrender.transport.ranks import barrier

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ImageError(f"cannot write to {out}: it is a file")
    settings = {name: getattr(args, name) for name, _, _ in FIT_OPTIONS if getattr(args, name) is not None}
    cameras, truth, extra = None, None, {}
    if args.recipe:
        if args.scene or args.target or args.params:
            raise ParameterError("give either a recipe or --scene/--target/--params, not both")
        recipe = load_fit_recipe(args.recipe)
        data = out / "dataset"
        if not (data / "manifest.json").is_file():
            if not args.quiet:
                print(f"rendering the dataset {recipe.dataset.path} into {data}", file=sys.stderr)
            make_dataset(recipe.dataset, data, progress=not args.quiet)
        barrier()  # in a process group rank 0 writes the dataset; the others read it
        scene, targets, cameras, truth = load_dataset(data)
        names, init = recipe.params, {**recipe.init, **parse_init(args.init)}
        settings = {**recipe.settings, **settings}
        extra["recipe"] = str(recipe.path)
        if recipe.variants:
            return _run_study(args, recipe, scene, targets, cameras, truth, names, init, settings, extra)
    else:
        if not (args.scene and args.target and args.params):
            raise ParameterError("fit needs a recipe, or all of --scene, --target and --params")
        targets = list(args.target)  # paths: fit reads them, and its errors name the file
        if args.resolution is None:
            height, width = ir.read_image(targets[0]).shape[:2]
        resolution = args.resolution or (width, height)
        scene = ir.load_scene(args.scene, resolution=resolution)
        names, init = [n.strip() for n in args.params.split(",") if n.strip()], parse_init(args.init)
        extra["targets"] = list(args.target)
    result = _fit_into(out, args, scene, targets, cameras, truth, names, init, settings, extra)
    return EXIT_INTERRUPTED if result is None else 0


def _fit_into(out: Path, args, scene, targets, cameras, truth, names, init, settings, extra):
    """One fit writing report.json, loss.png, the final render(s) and checkpoint.pt into ``out``;
    the FitResult, or None when interrupted (the checkpoint is saved)."""
    import invrender as ir
    from invrender.inverse.fit import fit
    from invrender.inverse.report import plot_correlation, plot_history, report_dict, write_json
    from invrender.recipes import apply_init

    apply_init(scene, names, init)
    try:
        result = fit(scene, targets, names, cameras=cameras, truth=truth, checkpoint=out / "checkpoint.pt", resume=args.resume, progress=not args.quiet, **settings)
    except KeyboardInterrupt:
        print(f"invrender: interrupted; checkpoint saved to {out / 'checkpoint.pt'} (continue with --resume)", file=sys.stderr)
        return None
    s = result.settings
    views = cameras or [result.scene.camera]
    for i, camera in enumerate(views):
        stem = "final" if len(views) == 1 else f"final_{i:02d}"
        image = ir.render(result.scene.with_camera(camera), s.integrator, spp=4 * s.spp_final, max_depth=s.max_depth, seed=s.seed + 1, progress=not args.quiet)
        ir.write_image(out / f"{stem}.exr", image)
        ir.write_image(out / f"{stem}.png", image)
    report = report_dict(result, **extra)
    write_json(out / "report.json", report)
    plot_history(result, out / "loss.png")
    figures = "loss.png, correlation.png" if plot_correlation(result, out / "correlation.png") else "loss.png"
    if not args.quiet:
        print(f"{report['steps']} steps in {report['seconds']:.1f} s, final loss {report['final_loss']:.4g}", file=sys.stderr)
        for name, value in result.params.items():
            err = f"  (rel. error {result.errors[name]:.2%})" if name in result.errors else ""
            print(f"  {name}: {_fmt(value)}{err}", file=sys.stderr)
        print(f"wrote {out}/report.json, {figures}, final EXR and PNG, checkpoint.pt", file=sys.stderr)
    return result


def _run_study(args, recipe, scene, targets, cameras, truth, names, init, settings, extra) -> int:
    """One fit per recipe variant into OUT/<label>/, then OUT/study.md and OUT/study.json."""
    import dataclasses

    from invrender.inverse.report import study_table, write_json, write_text

    results = {}
    for variant in recipe.variants:
        if not args.quiet:
            print(f"variant {variant.label!r}", file=sys.stderr)
        own = dataclasses.replace(scene, params={k: v.detach().clone() for k, v in scene.params.items()})
        result = _fit_into(
            Path(args.out) / variant.slug, args, own, targets, cameras, truth, names + [p for p in variant.params if p not in names],
            {**init, **variant.init}, {**settings, **variant.settings}, {**extra, "variant": variant.label},
        )  # fmt: skip
        if result is None:
            return EXIT_INTERRUPTED
        results[variant.label] = result
    markdown, data = study_table(results, truth)
    write_text(Path(args.out) / "study.md", markdown)
    write_json(Path(args.out) / "study.json", data)
    print(markdown)
    print(f"wrote {args.out}/study.md, study.json and one folder per variant", file=sys.stderr)
    return 0


def _fmt(value) -> str:
    flat = value.reshape(-1).tolist()
    return ", ".join(f"{v:.4g}" for v in flat[:6]) + (" ..." if len(flat) > 6 else "")


def run_gradcheck(args) -> int:
    import invrender as ir
    from invrender.inverse.gradcheck import format_rows, gradcheck

    scene = ir.load_scene(args.scene, resolution=args.resolution, ambient=args.ambient)
    estimators = [e.strip() for e in args.estimators.split(",") if e.strip()]
    rows = gradcheck(scene, args.params, estimators=estimators, spp=args.spp, max_depth=args.max_depth, seed=args.seed, h=args.step, integrator=args.integrator)
    print(format_rows(rows))
    worst = max(max(r.rel_errors.values()) for r in rows)
    print(f"largest relative error: {worst:.3e}")
    return 1 if args.tolerance is not None and worst > args.tolerance else 0


def run_baseline(args) -> int:
    import invrender as ir
    from invrender.baseline import pyrender_render

    outputs = check_outputs(args.out)
    scene = ir.load_scene(args.scene, resolution=args.resolution, ambient=args.ambient)
    image = pyrender_render(scene)
    for path in outputs:
        ir.write_image(path, image)
    if not args.quiet:
        print(f"{scene.name}: {scene.width}x{scene.height} rasterized by pyrender; mean RGB {_mean_rgb(image)}", file=sys.stderr)
        print("wrote " + ", ".join(str(p) for p in outputs), file=sys.stderr)
    return 0


def run_compare(args) -> int:
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


def run_dataset(args) -> int:
    from invrender.recipes import make_dataset

    manifest = make_dataset(args.recipe, args.out, progress=not args.quiet)
    if not args.quiet:
        print(f"wrote {len(manifest['views'])} view(s), truth.json and manifest.json to {args.out}", file=sys.stderr)
    return 0


def run_variance(args) -> int:
    import invrender as ir
    from invrender.inverse.report import write_json, write_text
    from invrender.study.furnace import FURNACE_CONFIGS, FURNACE_PARAMS, FURNACE_SPP, furnace_check
    from invrender.study.output import summary_text, write_study
    from invrender.study.plots import plot_study

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ImageError(f"cannot write to {out}: it is a file")
    fit_flags = (("--repeats", args.repeats), ("--steps", args.steps), ("--fit-spp", args.fit_spp))
    study_flags = (("--spp", args.spp), ("--trials", args.trials), ("--reference-spp", args.reference_spp), ("--reference-repeats", args.reference_repeats),
                   ("--pixel-param", args.pixel_param), ("--pixel-spp", args.pixel_spp), ("--no-pixel-maps", args.no_pixel_maps), ("--workers", args.workers))  # fmt: skip
    if args.fits:
        return _run_fit_study(args, out, study_flags)
    given = [flag for flag, value in fit_flags if value is not None]
    if given:
        raise ParameterError(f"{given[0]} applies to fits only (add --fits)")
    spp = None if args.spp is None else _int_list(args.spp, "--spp")
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
        scene = _variance_scene(args, resolution)
        study = ir.gradient_study(
            scene, args.params, _study_defaults()[0] if args.configs is None else args.configs, _study_defaults()[1] if spp is None else spp, trials,
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


def _variance_scene(args, resolution):
    """The scene of a study or fit study, after the checks of --params, --at and --init."""
    import invrender as ir

    if not args.params:
        scene = ir.load_scene(args.scene, resolution=resolution)
        raise ParameterError(f"variance needs --params NAME,NAME (the scene's: {', '.join(scene.params)})")
    if args.at is not None and args.init:
        raise ParameterError("give --at or --init, not both")
    return ir.load_scene(args.scene, resolution=resolution)


def _run_fit_study(args, out: Path, study_flags) -> int:
    """``invrender variance SCENE --fits``: a fit per configuration and repeat."""
    from invrender.study.fits import DEFAULT_FIT_CONFIGS, fit_study, fit_summary_text, write_fit_study

    if args.scene == "furnace":
        raise ParameterError("--fits does not apply to the furnace check (its gradients are checked against closed forms, not fitted)")
    given = [flag for flag, value in study_flags if value not in (None, False)]
    if given:
        raise ParameterError(f"{given[0]} applies to gradient studies, not to --fits (fits take --steps, --fit-spp, --repeats)")
    fit_spp = [16, 64] if args.fit_spp is None else _int_list(args.fit_spp, "--fit-spp")
    if len(fit_spp) not in (1, 2):
        raise ParameterError(f"--fit-spp takes one or two values (first half, second half of the steps), got {args.fit_spp!r}")
    scene = _variance_scene(args, (32, 32) if args.resolution is None else args.resolution)
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


def run_ablation(args) -> int:
    import invrender as ir
    from invrender.ablation import ablation, format_table, write_ablation

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ImageError(f"cannot write to {out}: it is a file")
    spp = tuple(_int_list(args.spp, "--spp"))
    scene = ir.load_scene(args.scene, resolution=args.resolution)
    result = ablation(scene, args.strategies, spp=spp, trials=args.trials, reference_spp=args.reference_spp, max_depth=args.max_depth, seed=args.seed, progress=not args.quiet)
    written = write_ablation(result, out)
    print(format_table(result), flush=True)
    if not args.quiet:
        print("wrote " + ", ".join(str(p) for p in written), file=sys.stderr)
    return 0


def _int_list(text: str, flag: str) -> list[int]:
    """``"1,4,16"`` -> [1, 4, 16]; an empty list is left to the study's own check."""
    try:
        return [int(p) for p in text.split(",") if p.strip()]
    except ValueError:
        raise ParameterError(f"{flag} expects comma-separated integers such as 4,8,16, got {text!r}") from None


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f"invrender: warning: {message}", file=sys.stderr)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_BAD_INPUT
    warnings.showwarning = _one_line_warning
    prefix = "invrender: error: "
    try:
        if args.command in ("render", "fit"):
            prefix = _join_process_group(args) or prefix
        return args.run(args)
    except InvRenderError as e:
        print(f"{prefix}{e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("invrender: interrupted; nothing was written", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        from invrender.transport.ranks import leave_process_group

        leave_process_group()  # a group left alive at exit aborts the process (gloo's threads)


def _join_process_group(args) -> str | None:
    """Under ``torchrun`` (docs/scale.md): join the process group, put a CUDA render on this rank's
    GPU, and leave the summaries and progress bars to rank 0 (its outputs are the only ones
    written). Returns the error prefix of this rank (None outside a group)."""
    from invrender.transport import ranks

    device = ranks.init_from_environment(getattr(args, "device", None))
    rank, world = ranks.world()
    if world == 1:
        return None
    if device is not None:
        args.device = str(device)
    if rank != 0:
        args.quiet = True
    return f"invrender: error (rank {rank} of {world}): "


def entry() -> None:
    """Console-script entry point."""
    sys.exit(main())


if __name__ == "__main__":
    entry()
