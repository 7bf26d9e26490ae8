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
"""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

import invrender as ir
from invrender.materials import checks
from invrender.materials.diffuse import Diffuse
from invrender.materials.mirror import reflect
from invrender.registry import EMITTERS, MATERIALS
from invrender.scene.builtin import furnace
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.kinds import EMISSION
from invrender.scene.materials import Material
from invrender.scene.plugins import Constant, Param
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, cube
from invrender.transport.bsdfs import BSDFSample, Lobe
from invrender.transport.lights import Light, LightSample
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


class Sky(Light):
    """Uniform radiance L from every direction, from infinitely far away."""

    type_name = "test_sky"
    params = {"emission": Param(EMISSION, 1.0)}
    doc = "test: a uniform sky"
    surface = False

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


@pytest.fixture(scope="module", autouse=True)
def registered():
    MATERIALS.register(Coated)
    EMITTERS.register(Sky)
    yield
    MATERIALS.unregister(Coated.type_name)
    EMITTERS.unregister(Sky.type_name)


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
