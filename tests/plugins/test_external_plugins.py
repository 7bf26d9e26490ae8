"""Plugins defined outside the package: a material and an emitter are each one class plus its
registration, and then render, differentiate and pass the conformance checks with no change to the
package (integrators ask lobe flags, never types; escaped rays ask the emitters).

- ``test_coated``: a two-lobe material, a diffuse base under a smooth mirror coating that reflects
  a fixed fraction F (lobes DIFFUSE | DELTA_REFLECTION). Inside the furnace (a closed sphere that
  emits eps everywhere) its albedo is a = F + (1 - F) rho, so the path tracer's image with D terms
  is ``eps (1 - a^D) / (1 - a)`` and its derivative in rho ``eps (1 - F) sum_k k a^(k-1)``
  (docs/closed_forms.md, furnace); Whitted's (local model at the base, the coating followed) is
  ``eps sum_{k<D} F^k + (1 - F) rho eps sum_{k<D-1} F^k``.
- ``test_sky``: a uniform sky of radiance L, emitting from infinitely far and sampled uniformly over
  the sphere. A convex diffuse object under it has radiance ``rho L`` exactly (it sees only the sky),
  and the camera sees L where its rays leave the scene; the image is linear in L.
- ``test_albedo``: an integrator that shows ``scale x`` the diffuse albedo at the first hit.

Each also loads from the scene files through the registry: the material and the emitter by their
``type`` in TOML and their ``mitsuba_plugins`` in Mitsuba XML, the integrator from a fit recipe's
``[fit] integrator`` table (TOML) and from ``<integrator type=...>`` (XML, with its settings).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import pytest
import torch

import invrender as ir
from invrender.plugins.bsdfs import checks
from invrender.plugins.bsdfs.diffuse import Diffuse
from invrender.plugins.bsdfs.mirror import reflect
from invrender.cli import main
from invrender.errors import ParameterError
from invrender.recipes import load_fit_recipe
from invrender.registry import EMITTERS, INTEGRATORS, MATERIALS
from invrender.scene.kinds import REFLECTANCE
from invrender.scene.builtin import furnace
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.kinds import EMISSION
from invrender.scene.materials import Material
from invrender.scene.plugins import Constant, Param
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, cube
from invrender.core.bsdfs import BSDFSample, Lobe
from invrender.plugins.integrators import Integrator
from invrender.plugins.integrators.vertex import next_vertex
from invrender.core.lights import Light, LightSample
from invrender.vec import dot


class Coated(Diffuse):
    """A diffuse base under a mirror coating reflecting the fraction ``coat`` (F) of the light."""

    type_name = "test_coated"
    lobes = Lobe.DIFFUSE | Lobe.DELTA_REFLECTION
    constants = {"coat": Constant(0.3, 0.0, 1.0)}
    doc = "test: diffuse base under a partial mirror coating"

    def eval(self, sp, wi):
        return (1.0 - self.constant("coat", sp))[:, None] * super().eval(sp, wi)

    def pdf(self, sp, wi):
        return (1.0 - self.constant("coat", sp)) * super().pdf(sp, wi)

    def sample(self, sp, u_lobe, u_dir):
        F = self.constant("coat", sp)
        base = super().sample(sp, u_lobe, u_dir)  # weight rho: (1 - F) f cos / ((1 - F) pdf)
        coat = u_lobe < F
        wr = reflect(sp.wo, sp.n)
        wi = torch.where(coat[:, None], wr, base.wi)
        weight = torch.where(coat[:, None], 1.0, base.weight)  # F / F
        return BSDFSample(wi, weight, torch.where(coat, 0.0, (1.0 - F) * base.pdf), coat)

    def specular_lobes(self, sp):
        return [(reflect(sp.wo, sp.n), self.constant("coat", sp)[:, None].expand(-1, 3))]

    mitsuba_plugins = ("test_coated",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        rho = bsdf.colour("reflectance", REFLECTANCE, 0.5)
        coat = bsdf.number("coat", cls.constants["coat"], "the coating's reflectance")
        bsdf.finish(("reflectance", "coat"))
        return {"reflectance": rho, "coat": coat}


class Sky(Light):
    """Uniform radiance L from every direction, from infinitely far away."""

    type_name = "test_sky"
    params = {"emission": Param(EMISSION, 1.0)}
    doc = "test: a uniform sky"
    surface = False
    infinite = True

    @property
    def power(self) -> float:
        return float(self.values[0]["emission"].detach().mean()) * 4 * math.pi

    def L(self, n: int) -> torch.Tensor:
        return self.values[0]["emission"].expand(n, 3)

    def sample_from(self, u, x, nx, offset):
        z = 1.0 - 2.0 * u[:, 1]
        r = (1.0 - z * z).clamp_min(0.0).sqrt()
        phi = 2.0 * math.pi * u[:, 2]
        wl = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=1)
        n = x.shape[0]
        pdf = torch.full((n,), 1.0 / (4.0 * math.pi), device=x.device)
        return LightSample(x + offset * nx, wl, torch.full((n,), math.inf, device=x.device), dot(nx, wl) > 0, pdf, self.L(n))

    def escaped(self, d):
        return self.L(d.shape[0])

    def pdf_escaped(self, d):
        return torch.full((d.shape[0],), 1.0 / (4.0 * math.pi), device=d.device)

    mitsuba_plugins = ("test_sky",)

    @classmethod
    def from_mitsuba(cls, emitter) -> dict:
        L = emitter.colour("radiance", EMISSION, 1.0, texture=False)
        emitter.finish(("radiance",))
        return {"emission": L}


@dataclass(frozen=True)
class AlbedoSettings:
    """Attributes:
    scale: the factor on the albedo, > 0."""

    scale: float = 1.0

    def __post_init__(self):
        if not (isinstance(self.scale, (int, float)) and math.isfinite(self.scale) and self.scale > 0):
            raise ParameterError(f"scale must be a finite number > 0, got {self.scale!r}")


class Albedo(Integrator):
    """``scale`` times the diffuse albedo at the first hit (a first-hit AOV, differentiable in rho)."""

    name = "test_albedo"
    Settings = AlbedoSettings
    summary = "test: scale x the first hit's diffuse albedo"
    mitsuba_plugins = ("test_albedo",)

    @property
    def terms_kept(self) -> int:
        return 1

    def trace(self, ctx, state, film):
        state, s = next_vertex(ctx, state, film, 0)
        if s is not None:
            sp = ctx.shading_point(s, -state.d)
            film.add(0, state.pixel, self.settings.scale * ctx.materials.diffuse_reflectance(sp))


INTEGRATORS.unregister(Albedo.name)  # subclassing registered it; the tests below register it for themselves


@pytest.fixture(scope="module", autouse=True)
def registered():
    MATERIALS.register(Coated)
    EMITTERS.register(Sky)
    INTEGRATORS.register(Albedo)
    yield
    MATERIALS.unregister(Coated.type_name)
    EMITTERS.unregister(Sky.type_name)
    INTEGRATORS.unregister(Albedo.name)


RHO, F, EPS, D = 0.6, 0.3, 1.0, 4


def coated_furnace():
    scene = furnace(resolution=(8, 8), rho=RHO, eps=EPS)
    return dataclasses.replace(scene, material_specs=(Material.of("test_coated", coat=F),))


def test_the_two_lobe_material_passes_the_conformance_checks():
    bsdf = checks.instance(Coated, reflectance=RHO, coat=F)
    for theta_o in (0.0, 0.8, 1.35):
        assert checks.chi_square_p(bsdf, theta_o, seed=7) > 1e-3
    assert max(checks.weight_errors(bsdf, 0.5)[:2]) < 2e-3
    assert checks.delta_weight_gap(bsdf, 0.5) < 5e-3


def test_the_two_lobe_material_in_the_furnace_matches_the_closed_forms():
    a = F + (1 - F) * RHO
    scene = coated_furnace()
    path = ir.render(scene, spp=256, max_depth=D, seed=1, progress=False)
    assert float(path.mean()) == pytest.approx(EPS * (1 - a**D) / (1 - a), rel=1e-2)
    walk = ir.render(scene, spp=256, integrator="random_walk", max_depth=D, seed=2, progress=False)
    assert float(walk.mean()) == pytest.approx(EPS * (1 - a**D) / (1 - a), rel=1e-2)
    whitted = ir.render(scene, spp=4, integrator="whitted", max_depth=D, seed=3, progress=False)
    expected = EPS * sum(F**k for k in range(D)) + (1 - F) * RHO * EPS * sum(F**k for k in range(D - 1))
    assert float(whitted.mean()) == pytest.approx(expected, rel=1e-2)


@pytest.mark.parametrize("estimator", ["autodiff", "replay"])
def test_the_two_lobe_material_differentiates(estimator):
    a = F + (1 - F) * RHO
    scene = coated_furnace()
    rho = scene.params["wall.reflectance"].requires_grad_(True)
    ir.render(scene, spp=256, max_depth=D, seed=1, estimator=estimator, progress=False).mean().backward()
    expected = EPS * (1 - F) * sum(k * a ** (k - 1) for k in range(1, D)) / 3  # per channel of the mean
    torch.testing.assert_close(rho.grad, torch.full((3,), expected), rtol=2e-2, atol=0)


def sky_scene(L=2.0, rho=0.5):
    """A unit cube seen from a corner, under the test sky."""
    cam = Camera(origin=(3.0, 2.5, 3.5), target=(0, 0, 0), up=(0, 1, 0), fov=35.0)
    box = Mesh(*cube(), material="box")
    return build_scene([box], {"box": [rho] * 3}, {"sky": Emitter.of("test_sky", emission=L)}, cam, (24, 24), name="sky")


@pytest.mark.parametrize("integrator", [{"type": "path"}, {"type": "path", "strategy": "emitter"}, {"type": "random_walk"}])
def test_a_convex_object_under_the_sky_has_radiance_rho_L(integrator):
    scene = sky_scene()
    seen = ir.render(scene, spp=128, max_depth=1, seed=4, progress=False)  # the same camera rays: the sky (L) or the cube (0)
    cube_pixels, sky_pixels = (seen == 0).all(-1), (seen == 2.0).all(-1)
    assert int(cube_pixels.sum()) > 100 and int(sky_pixels.sum()) > 100
    img = ir.render(scene, integrator, spp=128, max_depth=3, seed=4, progress=False)
    assert float(img[cube_pixels].mean()) == pytest.approx(0.5 * 2.0, rel=3e-2)  # 3 standard errors of the emitter-only estimate
    assert bool((img[sky_pixels] == 2.0).all())


@pytest.mark.parametrize("estimator", ["autodiff", "replay"])
def test_the_sky_differentiates(estimator):
    """The image is linear in L: d(sum I)/dL = sum I / L, exactly for the same paths."""
    scene = sky_scene()
    L = scene.params["sky.emission"].requires_grad_(True)
    img = ir.render(scene, spp=16, max_depth=3, seed=5, estimator=estimator, progress=False)
    img.sum().backward()
    with torch.no_grad():
        plain = ir.render(scene, spp=16, max_depth=3, seed=5, progress=False)
    torch.testing.assert_close(L.grad, plain.sum((0, 1)) / 2.0, rtol=1e-4, atol=0)


def test_a_shape_cannot_name_an_emitter_from_outside_the_scene():
    cam = Camera(origin=(3.0, 2.5, 3.5), target=(0, 0, 0), up=(0, 1, 0), fov=35.0)
    with pytest.raises(ir.SceneError, match="emitter 'sky' of type 'test_sky', which emits from outside the scene"):
        build_scene([Mesh(*cube(), material="box", emitter="sky")], {"box": 0.5}, {"sky": Emitter.of("test_sky")}, cam, (8, 8))


def test_radiosity_refuses_a_sky():
    with pytest.raises(ir.ParameterError, match="emitter 'sky' is test_sky"):
        ir.render(sky_scene(), "radiosity", spp=1, progress=False)


TOML_SCENE = """
[camera]
origin = [3.0, 2.5, 3.5]
target = [0, 0, 0]
fov = 35

[materials.box]
type = "test_coated"
reflectance = 0.6
coat = 0.25

[emitters.sky]
type = "test_sky"
emission = 2

[[shapes]]
type = "cube"
material = "box"
"""

XML_SCENE = """<scene version="3.0.0">
<integrator type="test_albedo"><float name="scale" value="2"/></integrator>
<sensor type="perspective"><float name="fov" value="35"/>
  <transform name="to_world"><lookat origin="3, 2.5, 3.5" target="0, 0, 0" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film></sensor>
<emitter type="test_sky" id="sky"><rgb name="radiance" value="2"/></emitter>
<shape type="cube"><bsdf type="test_coated" id="box"><float name="reflectance" value="0.6"/><float name="coat" value="0.25"/></bsdf></shape>
</scene>
"""


@pytest.mark.parametrize("suffix", [".toml", ".xml"])
def test_the_material_and_the_sky_load_from_scene_files(tmp_path, suffix):
    path = tmp_path / f"scene{suffix}"
    path.write_text(TOML_SCENE if suffix == ".toml" else XML_SCENE)
    scene = ir.load_scene(str(path), resolution=(16, 16))
    assert scene.material_spec(0).type == "test_coated" and scene.material_spec(0).constants == {"coat": 0.25}
    assert scene.emitter_spec(0).type == "test_sky" and scene.emitters == ("sky",)
    torch.testing.assert_close(scene.params["box.reflectance"], torch.full((3,), 0.6))
    torch.testing.assert_close(scene.params["sky.emission"], torch.full((3,), 2.0))
    img = ir.render(scene, "path", spp=4, max_depth=3, seed=0, progress=False)  # path, not the .xml file's test_albedo
    assert bool((img[0, 0] == 2.0).all())  # a corner pixel sees the sky


def test_the_integrator_renders_and_differentiates():
    scene = sky_scene(rho=0.5)
    rho = scene.params["box.reflectance"].requires_grad_(True)
    img = ir.render(scene, {"type": "test_albedo", "scale": 2.0}, spp=4, seed=0, progress=False)
    assert float(img.detach().min()) == pytest.approx(1.0) and float(img.detach().max()) == 2.0  # 2 x 0.5 on the cube; the sky (2) where rays leave
    img.sum().backward()
    on_cube = 2.0 - img.detach()  # the fraction f of a pixel's samples on the cube: its value is 2 f rho + 2 (1 - f)
    torch.testing.assert_close(rho.grad, 2.0 * on_cube.sum((0, 1)))  # d/drho of 2 f rho
    with pytest.raises(ParameterError, match="scale must be a finite number > 0"):
        ir.render(scene, {"type": "test_albedo", "scale": -1.0}, spp=1, progress=False)


def test_the_integrator_loads_from_a_fit_recipe_and_from_xml(tmp_path):
    dataset = tmp_path / "data.toml"
    dataset.write_text('scene = "cornell_box"\nresolution = [8, 8]\nspp = 4\n')
    recipe = tmp_path / "fit.toml"
    recipe.write_text('dataset = "data.toml"\nparams = ["red.reflectance"]\n[fit]\nintegrator = { type = "test_albedo", scale = 2.0 }\n')
    assert load_fit_recipe(recipe).settings["integrator"] == {"type": "test_albedo", "scale": 2.0}

    path = tmp_path / "scene.xml"
    path.write_text(XML_SCENE)
    assert ir.load_scene(str(path)).defaults == {"integrator": "test_albedo", "scale": 2.0}
    out = tmp_path / "out.exr"
    assert main(["render", str(path), "--spp", "2", "--out", str(out), "--quiet"]) == 0  # the file's integrator and settings
    assert float(ir.read_image(out).min()) == pytest.approx(2 * 0.6)  # scale x rho on the cube (the sky, 2, around it)
    bad = tmp_path / "bad.xml"
    bad.write_text(XML_SCENE.replace('value="2"/></integrator>', 'value="-1"/></integrator>'))
    with pytest.raises(ir.SceneError, match=r"bad.xml:2: .*'scale' must be a finite number > 0"):
        ir.load_scene(str(bad))
