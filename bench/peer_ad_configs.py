"""Mitsuba 3's own differentiable-rendering test scenes, rendered by invrender and held to Mitsuba's
reference images with Mitsuba's thresholds.

    python bench/peer_ad_configs.py REFERENCES [--configs diffuse_albedo,crop_window] [--spp-scale 1.0]
                                   [--mesh rectangle.obj] [--json PATH]

``REFERENCES`` is the folder of Mitsuba's reference images (mitsuba-data's ``tests/integrators``:
``test_<config>_image_primal_ref.exr``, the primal image, and ``..._fwd_ref.exr``, the derivative of
the image in the configuration's parameter, made by Mitsuba with finite differences). Mitsuba's
test suite (``src/integrators/tests/test_ad_integrators.py``) renders a handful of small scenes
(a plane, a small sphere, a constant sky or an area light; 128 x 128, box filter, 1024 spp) and
checks three things per integrator; here invrender does the same with its own renderer:

- **primal**: the image against the primal reference;
- **forward**: the per-pixel derivative of the image in the parameter (forward-mode autodiff
  through invrender's torch bounce: the parameter's tangent is 1 in each channel, as Mitsuba adds
  one scalar to all three) against the derivative reference;
- **backward**: one gradient by path replay of ``mean(image * 1)`` against the reference's mean
  (128 spp, as Mitsuba's test).

The image metric is Mitsuba's: per pixel and channel ``|a - r| / max(|r|, eps)`` (eps 0.02 for
images, 0.2 for derivatives), its mean and its maximum each under the configuration's thresholds;
the gradient's relative error (eps 1e-3) under the configuration's backward threshold. Only the
configurations without visibility discontinuities are here (geometry is fixed in invrender); the
shading-normal rotation (``rotate_shading_normals_plane``) needs ``plane.normals`` as a parameter
and the mesh ``rectangle.obj`` of mitsuba-data's ``common/meshes`` (``--mesh``): where either is
missing the row says so. Figures are printed, never asserted; Mitsuba itself is not needed.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.autograd.forward_ad as fwAD

sys.path.insert(0, str(Path(__file__).parent))

from _measure import Results, add_json_option  # noqa: E402

import invrender as ir  # noqa: E402
from invrender.io.images import read_image  # noqa: E402

CAMERA = '<transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>'
SPHERE = '<shape type="sphere" id="sphere"><transform name="to_world"><scale value="0.25"/></transform></shape>'
#: the off-camera rectangle of the lit configurations: turned -90 degrees about y, at (1.25, 0, 1)
SIDE = '<transform name="to_world"><rotate y="1" angle="-90"/><translate value="1.25,0,1"/></transform>'
BOX_FILM = '<film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/><rfilter type="box"/><boolean name="sample_border" value="true"/></film>'
CROP_FILM = (
    '<film type="hdrfilm"><integer name="width" value="64"/><integer name="height" value="64"/>'
    '<rfilter type="gaussian"><float name="stddev" value="0.5"/></rfilter><boolean name="sample_border" value="true"/>'
    '<integer name="crop_width" value="32"/><integer name="crop_height" value="32"/>'
    '<integer name="crop_offset_x" value="32"/><integer name="crop_offset_y" value="20"/></film>'
)


@dataclass
class Config:
    """One of Mitsuba's test configurations, as invrender reads it.

    Attributes:
        name: Mitsuba's name (its reference images' stem).
        shapes: the scene's shapes and emitters (Mitsuba XML).
        param: the invrender parameter Mitsuba's key names.
        mean, max, bwd: Mitsuba's thresholds (image error mean and max, gradient error).
        depth: the path integrator's max_depth; res: image size; film: the film element.
        tangent: the parameter's tangent for theta = 1 (None: 1 in every channel).
    """

    name: str
    shapes: str
    param: str
    mean: float
    max: float
    bwd: float
    depth: int = 2
    res: int = 128
    film: str = BOX_FILM
    tangent: object = None
    spp: int = 1024
    needs: list = field(default_factory=list)

    def xml(self, mesh: str | None) -> str:
        shapes = self.shapes.replace("{mesh}", mesh or "")
        return (f'<scene version="3.0.0"><integrator type="path"><integer name="max_depth" value="{self.depth}"/></integrator>'
                f'<sensor type="perspective">{CAMERA}{self.film.format(res=self.res)}</sensor>{shapes}</scene>')  # fmt: skip


def _normals_tangent(normals: torch.Tensor) -> torch.Tensor:
    """d n / d theta of normals rotated by theta degrees about +y, at theta = 0: ``(pi / 180) y x n``."""
    y = torch.tensor([0.0, 1.0, 0.0], dtype=normals.dtype).expand_as(normals)
    return math.radians(1.0) * torch.linalg.cross(y, normals)


CONFIGS = [
    Config("diffuse_albedo", f'<shape type="rectangle" id="plane"><bsdf type="diffuse"/></shape>{SPHERE}<emitter type="constant" id="light"/>',
           "plane_bsdf.reflectance", 0.015, 0.25, 0.0005),
    Config("diffuse_albedo_g_i",
           f'<shape type="rectangle" id="plane"><bsdf type="diffuse"/></shape>{SPHERE}'
           f'<shape type="rectangle" id="green">{SIDE}<bsdf type="diffuse"><rgb name="reflectance" value="0.1,1.0,0.1"/></bsdf></shape>'
           '<emitter type="constant" id="light"><float name="radiance" value="3.0"/></emitter>',
           "green_bsdf.reflectance", 0.04, 0.4, 0.0005, depth=3),
    Config("area_light_radiance",
           f'<shape type="rectangle" id="plane"><bsdf type="diffuse"><rgb name="reflectance" value="1,1,1"/></bsdf></shape>{SPHERE}'
           f'<shape type="rectangle" id="light">{SIDE}<emitter type="area"><rgb name="radiance" value="3,3,3"/></emitter></shape>',
           "light.emission", 0.02, 0.4, 0.0005),
    Config("directly_visible_area_light_radiance", '<shape type="rectangle" id="light"><emitter type="area"><rgb name="radiance" value="1,1,1"/></emitter></shape>',
           "light.emission", 0.02, 0.2, 0.02),
    Config("point_light_intensity",
           f'<shape type="rectangle" id="plane"><bsdf type="diffuse"><rgb name="reflectance" value="1,1,1"/></bsdf></shape>{SPHERE}'
           '<emitter type="point" id="light"><point name="position" x="1.25" y="0" z="1"/><rgb name="intensity" value="5,5,5"/></emitter>',
           "light.emission", 0.02, 0.2, 0.002),
    Config("constant_emitter_radiance", f'<shape type="rectangle" id="plane"><bsdf type="diffuse"/></shape>{SPHERE}<emitter type="constant" id="light"/>',
           "light.emission", 0.02, 0.1, 0.02),
    Config("crop_window", '<shape type="rectangle" id="plane"><bsdf type="diffuse"/></shape><emitter type="constant" id="light"/>',
           "plane_bsdf.reflectance", 0.01, 0.2, 0.002, res=64, film=CROP_FILM),
    Config("rotate_shading_normals_plane",
           '<shape type="obj" id="plane"><string name="filename" value="{mesh}"/><bsdf type="diffuse"/></shape>'
           f'<shape type="rectangle" id="light">{SIDE}<emitter type="area"><rgb name="radiance" value="3,3,3"/></emitter></shape>',
           "plane_bsdf.normals", 0.02, 0.3, 0.00002, tangent=_normals_tangent, needs=["mesh"]),
]


def image_error(actual: torch.Tensor, reference: torch.Tensor, eps: float) -> tuple[float, float]:
    """Mitsuba's image metric: mean and max of ``|a - r| / max(|r|, eps)``."""
    e = (actual.double() - reference.double()).abs() / reference.double().abs().clamp_min(eps)
    return float(e.mean()), float(e.max())


def run(config: Config, refs: Path, mesh: str | None, spp_scale: float, seed: int) -> dict:
    """The three checks of one configuration; a dict of figures (or ``skipped``)."""
    if "mesh" in config.needs and not mesh:
        return {"skipped": "needs --mesh (mitsuba-data's common/meshes/rectangle.obj)"}
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{config.name}.xml"
        path.write_text(config.xml(mesh))
        scene = ir.load_scene(str(path))
    if config.param not in scene.params:
        return {"skipped": f"invrender has no parameter {config.param} here (has: {', '.join(scene.params)})"}
    primal_ref = read_image(refs / f"test_{config.name}_image_primal_ref.exr")
    fwd_ref = read_image(refs / f"test_{config.name}_image_fwd_ref.exr")
    spp = max(1, int(config.spp * spp_scale))
    out = {}
    value = scene.params[config.param].detach()
    tangent = torch.ones_like(value) if config.tangent is None else config.tangent(value)
    clock = time.perf_counter()
    with torch.no_grad(), fwAD.dual_level():
        params = {n: v.detach() for n, v in scene.params.items()}
        params[config.param] = fwAD.make_dual(value, tangent)
        primal, fwd = fwAD.unpack_dual(ir.render(scene.with_params(params), spp=spp, seed=seed, progress=False))
        primal, fwd = primal.clone(), (torch.zeros_like(primal) if fwd is None else fwd.clone())
    out["seconds"] = time.perf_counter() - clock
    if primal.shape != primal_ref.shape:
        return {"skipped": f"image {tuple(primal.shape)} against the reference's {tuple(primal_ref.shape)}"}
    out["primal"] = image_error(primal, primal_ref, 2e-2)
    out["forward"] = image_error(fwd, fwd_ref, 2e-1)
    # backward: d mean(image) / d theta by path replay at 128 spp, against the reference's mean
    leaf = value.clone().requires_grad_(True)
    image = ir.render(scene.with_params({config.param: leaf}), spp=128, seed=seed, estimator="replay", progress=False)
    image.mean().backward()
    grad = float((leaf.grad * tangent).sum())
    grad_ref = float(fwd_ref.double().mean())
    out["backward"] = (abs(grad - grad_ref) / max(abs(grad_ref), 1e-3), grad, grad_ref)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("references", type=Path, help="folder of Mitsuba's reference images (mitsuba-data tests/integrators)")
    parser.add_argument("--configs", default="", help="comma-separated configuration names (default: all)")
    parser.add_argument("--spp-scale", type=float, default=1.0, help="scale of Mitsuba's spp (1024)")
    parser.add_argument("--mesh", default=None, help="mitsuba-data's common/meshes/rectangle.obj (the shading-normal configuration)")
    parser.add_argument("--seed", type=int, default=0)
    add_json_option(parser)
    args = parser.parse_args()
    if not args.references.is_dir():
        parser.error(f"{args.references}: not a folder")
    chosen = [c for c in CONFIGS if not args.configs or c.name in args.configs.split(",")]
    results = Results("peer_ad_configs", f"Mitsuba 3's differentiable-rendering test scenes rendered by invrender against Mitsuba's references, spp x {args.spp_scale:g}")
    table = results.table("peer configurations", ["configuration", "parameter", "primal mean / max", "forward mean / max", "thresholds mean / max", "backward error (threshold)", "passed", "seconds"])
    print(f"{'configuration':38} {'primal mean/max':>16} {'forward mean/max':>17} {'thr mean/max':>13} {'backward (thr)':>18}  passed")
    for config in chosen:
        r = run(config, args.references, args.mesh, args.spp_scale, args.seed)
        if "skipped" in r:
            print(f"{config.name:38} skipped: {r['skipped']}")
            table.append([config.name, config.param, "", "", "", "", f"skipped: {r['skipped']}", ""])
            continue
        pm, px = r["primal"]
        fm, fx = r["forward"]
        be, g, gr = r["backward"]
        ok = {"primal": pm <= config.mean and px <= config.max, "forward": fm <= config.mean and fx <= config.max, "backward": be <= config.bwd}
        verdict = ", ".join(k for k, v in ok.items() if v) or "none"
        print(f"{config.name:38} {pm:7.4f}/{px:7.3f} {fm:8.4f}/{fx:7.3f} {config.mean:6.4f}/{config.max:5.2f} {be:9.2e} ({config.bwd:g})  {verdict}  [{r['seconds']:.1f} s; grad {g:.5g} vs {gr:.5g}]")
        table.append([config.name, config.param, f"{pm:.4f} / {px:.3f}", f"{fm:.4f} / {fx:.3f}", f"{config.mean} / {config.max}", f"{be:.2e} ({config.bwd:g})", verdict, round(r["seconds"], 1)])
    results.write(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
