"""``invrender render``: render a scene to EXR/PNG (a front over :func:`invrender.render`)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from invrender.cli.common import (
    add_integrator_arguments, add_scene_argument, check_outputs, integrator_spec, integrators_epilog, mean_rgb, parse_device, parse_resolution, parse_rgb,
)  # fmt: skip
from invrender.errors import ParameterError

EPILOG = """\
examples:
  invrender render                                         # Cornell box, 256x256, 64 spp -> out.exr
  invrender render cornell_box --spp 256 --resolution 128x128 --out cbox.exr cbox.png
  invrender render forward/mesh_in_box.toml --max-depth -1 --out mesh.png
  invrender render bunny.ply --out bunny.png               # a mesh file (PLY, STL, OBJ, glTF) in the default studio
  invrender render scene.xml --out s.exr                   # the file's integrator, max_depth and sample_count
  invrender render furnace --integrator random_walk --max-depth 4 --terms --out furnace.exr
  invrender render cornell_box --integrator utah --ambient 0.05 --out utah.exr
  invrender render cornell_specular --spp 256 --out spec.png            # mirror, glass, glossy
  invrender render cornell_specular --integrator whitted --ambient 0.02 --out whitted.png
  invrender render cornell_specular --integrator distributed --out cook.png
  invrender render cornell_box --strategy emitter --hemisphere uniform --rr-depth -1 --out nee.png
  invrender render cornell_box --set rr_depth=3 --set strategy=emitter --out nee3.png
  invrender render cornell_box --integrator radiosity --set patches=4096 --set final_gather=true --out rad.png
  invrender render forward/cornell_far.toml --spp 64 --adaptive --out far.png   # + far.spp.png
  invrender render cornell_box --device cuda --backend warp --spp 4096 --out gpu.exr
  torchrun --standalone --nproc-per-node 4 -m invrender render cornell_box --spp 4096 --out big.exr
                                                # split across 4 processes; rank 0 writes (docs/scale.md)

max_depth counts Neumann terms as Mitsuba 3 does: 1 = emitters seen directly, 2 = + direct
illumination, ...; -1 = unbounded (paths end by Russian roulette only). With --terms, term k
(the light reflected k times, g(Mg)^k eps) is also written to OUT_STEM.termK.SUFFIX.

Every setting of the integrator is reachable with --set KEY=VALUE (listed below); --max-depth,
--rr-depth, --strategy and --hemisphere are shortcuts for the settings of those names.

Sampling strategies (docs/sampling.md): --sampler (pixel samples), --hemisphere (diffuse BSDF
sampling), --strategy (direct light by MIS, BSDF samples or emitter samples), --rr-depth -1 (no
Russian roulette); all estimate the same image. With --adaptive, --spp is the average number of
samples per pixel: a pilot pass estimates each pixel's variance, then --rounds passes spend the
samples where the estimated relative error is high (the image stays unbiased), and the samples
each pixel got are written to OUT_STEM.spp.png (and OUT_STEM.spp.exr for an .exr output).

"""

#: AdaptiveSettings fields as render flags (only with --adaptive)
ADAPTIVE_OPTIONS = [
    ("pilot_spp", int, "with --adaptive: samples per pixel of the pilot pass, which only allocates (default: spp/8, from 4 to 16)"),
    ("rounds", int, "with --adaptive: passes after the pilot, each allocated from the samples before it (default: 2)"),
    ("target_error", float, "with --adaptive: relative standard error at which a pixel needs no more samples; --spp is then a cap (default: spend all of --spp)"),
    ("max_spp", int, "with --adaptive: most samples one pixel gets (default: 16 x --spp)"),
    ("floor", float, "with --adaptive: errors are relative to the pixel's mean + FLOOR x the image's mean (default: 1)"),
]


def add_parser(sub) -> None:
    r = sub.add_parser(
        "render", help="render a scene to EXR/PNG", description="Render a scene by Monte Carlo path tracing and write the image(s).",
        epilog=EPILOG + integrators_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter,
    )  # fmt: skip
    add_scene_argument(r)
    r.add_argument("--out", nargs="+", default=["out.exr"], metavar="PATH", help="output image(s): .exr (linear float32) and/or .png (sRGB, clipped) (default: out.exr)")
    r.add_argument("--spp", type=int, default=None, help="samples per pixel (default: the scene file's, e.g. a Mitsuba sampler's sample_count, else 64)")
    r.add_argument("--max-depth", type=int, default=None, help="the integrator's max_depth: Neumann terms kept, Mitsuba's count; -1 = unbounded (default: the scene file's, else 8; utah: 2)")
    r.add_argument("--resolution", type=parse_resolution, default=None, metavar="WxH", help="image size in pixels (default: the scene's)")
    add_integrator_arguments(r, default="the scene file's, else path")
    r.add_argument("--ambient", type=parse_rgb, default=None, metavar="R,G,B", help="ambient radiance eps0 for --integrator utah, whitted or distributed (one number or R,G,B; default: the scene's, else 0)")
    r.add_argument("--seed", type=int, default=0, help="random seed; the image is a pure function of it (default: 0)")
    r.add_argument("--rr-depth", type=int, default=None, help="the integrator's rr_depth: Russian roulette starts after this many terms; -1 = no roulette (path, random_walk, distributed; default: the scene file's, else 5)")
    r.add_argument("--filter", default=None, metavar="NAME", help="the film's reconstruction filter: box, tent, gaussian, mitchell, catmullrom or lanczos at their default settings (default: the scene's: a Mitsuba file's <rfilter>, its gaussian when it has none, else box)")
    r.add_argument("--sampler", default="stratified", help="pixel samples: stratified (correlated multi-jittered: every spp stratified, default), independent, antithetic (pairs whose second path draws 1 - u for every number of the first), or stratified_direct (stratified, and the first vertex's BSDF and emitter samples too: less noise in direct light)")
    r.add_argument("--strategy", default=None, help="the path tracer's strategy for direct light: mis (emitter and BSDF samples by multiple importance sampling, default), bsdf (BSDF samples only) or emitter (emitter samples only)")
    r.add_argument("--hemisphere", default=None, help="the integrator's hemisphere: diffuse BSDF sampling, cosine (default) or uniform over the hemisphere (path, random_walk, distributed)")
    r.add_argument("--adaptive", action="store_true", help="adaptive sampling: --spp samples per pixel on average, spent where the estimated error is high; writes OUT_STEM.spp.png")
    for name, kind, doc in ADAPTIVE_OPTIONS:
        r.add_argument(f"--{name.replace('_', '-')}", dest=name, type=kind, default=None, metavar=name.upper(), help=doc)
    r.add_argument("--terms", action="store_true", help="also write one image per Neumann term (OUT_STEM.termK.SUFFIX)")
    r.add_argument("--device", default="cpu", type=parse_device, help="torch device: cpu, cuda or cuda:N (default: cpu)")
    r.add_argument("--backend", default=None, help="intersection backend: embree (CPU only; its default), warp (NVIDIA Warp BVH, CUDA or CPU; the default on CUDA) or torch (brute force, any device: the reference)")
    r.add_argument("--memory-mb", type=float, default=512.0, help="memory budget of one chunk of paths, MiB (default: 512)")
    r.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    r.set_defaults(run=run, group=True)


def run(args) -> int:
    import invrender as ir
    from invrender.estimators.defaults import DEFAULT_INTEGRATOR, file_integrator, scene_spp
    from invrender import first_use

    outputs = check_outputs(args.out)
    scene = ir.load_scene(args.scene, resolution=args.resolution, ambient=args.ambient)
    # settings not given fall back to the scene file's (scene.defaults), then to the integrator's
    # defaults; the file's settings belong to its integrator; invrender.render reports overrides
    file_name, file_settings = file_integrator(scene)
    spp = scene_spp(scene, args.spp)
    base = {"type": file_name or DEFAULT_INTEGRATOR, **file_settings}
    flags = {"max_depth": args.max_depth, "rr_depth": args.rr_depth, "strategy": args.strategy, "hemisphere": args.hemisphere}
    spec = integrator_spec(args, base, flags)
    adaptive = adaptive_settings(args)
    start, compiling = time.perf_counter(), first_use.seconds()
    result = ir.render(
        scene, integrator=spec, spp=spp, seed=args.seed, terms=args.terms, backend=args.backend, device=args.device, memory_mb=args.memory_mb,
        progress=not args.quiet, sampler=args.sampler, adaptive=adaptive, return_counts=adaptive is not None, filter=args.filter,
    )  # fmt: skip
    # a first use's compiles and kernel loads (first_use.py) are not rendering: reported apart
    compiling = first_use.seconds() - compiling
    seconds = time.perf_counter() - start - compiling
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
        file_spp = scene.defaults.get("spp")
        overridden = f"; --spp overrides the file's {file_spp} spp" if file_spp is not None and file_spp != spp else ""
        setup = f" + {compiling:.1f} s compiling kernels on first use" if compiling >= 0.5 else ""
        print(f"{scene.name}: {scene.width}x{scene.height}, {spp} spp, {seconds:.2f} s ({paths / seconds / 1e6:.3g} M paths/s){setup}; mean RGB {mean_rgb(full)}{overridden}", file=sys.stderr)
        if adaptive is not None:
            counts = result.spp.float()
            print(f"adaptive: pilot {result.pilot_spp} spp + {len(result.passes)} rounds; samples per pixel {int(counts.min())} to {int(counts.max())} (mean {counts.mean():.4g}); "
                  f"estimated relative error median {result.error.median():.3g}, max {result.error.max():.3g}", file=sys.stderr)  # fmt: skip
        print("wrote " + ", ".join(str(p) for p in outputs + written) + (f" (+ {image.shape[0]} term images each)" if args.terms else ""), file=sys.stderr)
    return 0


def adaptive_settings(args):
    """The AdaptiveSettings of ``render --adaptive`` (None without it; its options alone are an error)."""
    from invrender.core.adaptive import AdaptiveSettings

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
