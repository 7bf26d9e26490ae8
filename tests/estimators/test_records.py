"""Path records: the traced estimate as a polynomial in the parameters (docs/closed_forms.md#furnace).

- Furnace: every coefficient is the truncated Neumann series' ``eps rho^k`` term exactly (the
  random walk at fixed depth is a zero-variance estimator there).
- At the record point the polynomial is the render of the same seed; far from it, an unbiased
  estimate of the image there (against independent renders, within Monte Carlo error).
- Its Jacobian is exact: it equals autograd through the polynomial and the renderer's own gradient.
"""

from __future__ import annotations

import math

import pytest
import torch

import invrender as ir
from invrender.estimators.records import accumulate
from invrender.errors import ParameterError
from tests.conftest import furnace

CORNELL = ["white.reflectance", "red.reflectance", "green.reflectance", "light.emission"]


@pytest.mark.parametrize("rho, eps, depth", [(0.5, 1.0, 5), (0.8, 2.5, 7)])
def test_furnace_coefficients_are_the_neumann_terms(rho, eps, depth):
    scene = furnace(rho=rho, eps=eps, resolution=(8, 8))  # no roulette before the last term
    rec = ir.record_paths(scene, ["wall.reflectance", "glow.emission"], spp=4, max_depth=depth, integrator="random_walk", rr_depth=depth, progress=False)
    # one monomial per term k = 0 .. depth-1: rho^k eps with coefficient exactly 1 in every pixel
    assert rec.exponents.tolist() == [[k, 1] for k in range(depth)]
    torch.testing.assert_close(rec.coefficients, torch.ones_like(rec.coefficients), rtol=1e-6, atol=0)
    img = rec.image({"wall.reflectance": 0.3, "glow.emission": [1.0, 2.0, 3.0]})
    expected = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64) * (1 - 0.3**depth) / (1 - 0.3)
    torch.testing.assert_close(img, expected.expand_as(img), rtol=1e-6, atol=0)


def test_record_point_image_is_the_render_of_the_same_seed(cbox32):
    rec = ir.record_paths(cbox32, CORNELL, spp=16, max_depth=6, seed=3, progress=False)
    img = ir.render(cbox32, spp=16, max_depth=6, seed=3, progress=False)
    torch.testing.assert_close(rec.image().float(), img, rtol=1e-5, atol=1e-6)
    # the Cornell box with depth 6: monomials rho_w^a rho_r^b rho_g^c eps with a + b + c <= 5
    assert int(rec.exponents[:, :3].sum(1).max()) == 5 and bool((rec.exponents[:, 3] == 1).all())


def test_far_from_the_record_point_the_image_is_unbiased():
    """Recorded at grey 0.5 and emission 5, evaluated at the Cornell box's own values: channel means
    agree with independent renders there within 4 standard errors (4 seeds each side)."""
    scene = ir.load_scene("cornell_box", resolution=(24, 24))
    truth = {n: scene.params[n].clone() for n in CORNELL}
    start = ir.load_scene("cornell_box", resolution=(24, 24))
    with torch.no_grad():
        for n in CORNELL[:3]:
            start.params[n].fill_(0.5)
        start.params["light.emission"].fill_(5.0)
    far = torch.stack([ir.record_paths(start, CORNELL, spp=64, max_depth=8, seed=s, progress=False).image(truth).mean((0, 1)) for s in range(4)])
    ref = torch.stack([ir.render(scene, spp=64, max_depth=8, seed=10 + s, progress=False).double().mean((0, 1)) for s in range(4)])
    se = (far.var(0) / 4 + ref.var(0) / 4).sqrt()
    diff = (far.mean(0) - ref.mean(0)).abs()
    assert (diff < 4 * se + 1e-5).all(), (far.mean(0), ref.mean(0), se)
    assert (diff < 0.01 * ref.mean(0)).all()


def test_jacobian_is_exact(cbox32):
    rec = ir.record_paths(cbox32, CORNELL, spp=8, max_depth=5, seed=1, progress=False)
    values = {"white.reflectance": torch.tensor([0.3, 0.6, 0.7], dtype=torch.float64, requires_grad=True), "light.emission": torch.tensor([9.0, 4.0, 12.0], dtype=torch.float64, requires_grad=True)}
    weights = torch.rand(32, 32, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    (rec.image(values) * weights).sum().backward()
    jac = rec.jacobian({k: v.detach() for k, v in values.items()})
    for name, v in values.items():
        torch.testing.assert_close((jac[name] * weights).sum((0, 1)), v.grad, rtol=1e-9, atol=1e-12)
    # at the record point: the renderer's own gradient of the same seed (autodiff)
    scene = ir.load_scene("cornell_box", resolution=(32, 32))
    scene.params["red.reflectance"].requires_grad_(True)
    (ir.render(scene, spp=8, max_depth=5, seed=1, estimator="autodiff", progress=False).double() * weights).sum().backward()
    torch.testing.assert_close((rec.jacobian()["red.reflectance"] * weights).sum((0, 1)), scene.params["red.reflectance"].grad.double(), rtol=1e-4, atol=0)


def test_every_material_records(cbox32):
    """Mirror and glossy k_s are monomial factors too; glass (no parameter) only weights."""
    scene = ir.load_scene("cornell_specular", resolution=(16, 16), subdivisions=2)
    names = ["white.reflectance", "mirror.specular_reflectance", "glossy.specular_reflectance", "light.emission"]
    rec = ir.record_paths(scene, names, spp=8, max_depth=5, seed=2, progress=False)
    torch.testing.assert_close(rec.image().float(), ir.render(scene, spp=8, max_depth=5, seed=2, progress=False), rtol=1e-5, atol=1e-5)
    assert int(rec.exponents[:, 1].max()) >= 1 and int(rec.exponents[:, 2].max()) >= 1


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(params=["red.albedo"]), "unknown parameter 'red.albedo'"),
        (dict(params=["red.reflectance"], max_depth=-1), "finite max_depth"),
        (dict(params=["light.emission"], emission_texture=True), "textured emission"),
        (dict(params=["red.reflectance"], max_record_mb=0.01), "over max_record_mb"),
    ],
)
def test_bad_input_is_refused_before_tracing(kwargs, message):
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    if kwargs.pop("emission_texture", False):
        scene.params["light.emission"] = scene.params["light.emission"].detach().expand(2, 2, 3).clone()
    with pytest.raises(ParameterError, match=message):
        ir.record_paths(scene, progress=False, **kwargs)


def test_record_point_must_be_positive():
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    with torch.no_grad():
        scene.params["red.reflectance"][1] = 0.0
    with pytest.raises(ParameterError, match=r"red.reflectance must be > 0 in every channel"):
        ir.record_paths(scene, ["red.reflectance"], progress=False)
    rec = ir.record_paths(ir.load_scene("cornell_box", resolution=(8, 8)), ["red.reflectance"], spp=1, max_depth=2, progress=False)
    with pytest.raises(ParameterError, match="'light.emission' was not recorded"):
        rec.image({"light.emission": 1.0})
    assert math.isfinite(float(rec.image().sum()))


TEXTURED = ["floor.reflectance", "light.emission", "red.reflectance"]


@pytest.mark.parametrize("integrator", ["path", "whitted"])
def test_textured_record_is_the_render_and_its_jacobian_is_exact(integrator):
    """Per-texel records: at the record point the image of the same seed (for Whitted too, whose
    paths split), and the texel Jacobian equals autograd through the polynomial."""
    scene = ir.load_scene("forward/textured_floor.toml", resolution=(16, 16))
    rec = ir.record_paths(scene, TEXTURED, spp=8, max_depth=5, seed=3, integrator=integrator, progress=False)
    torch.testing.assert_close(rec.image().float(), ir.render(scene, integrator, spp=8, max_depth=5, seed=3, progress=False), rtol=1e-5, atol=1e-6)
    assert len(rec.texel_terms) >= (2 if integrator == "path" else 1) and rec.texel_terms[0].texels.shape[1] == 1  # Whitted: one diffuse vertex
    values = {n: (scene.params[n].detach().double() * 0.8).requires_grad_(True) for n in TEXTURED}
    weights = torch.rand(16, 16, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    (rec.image(values) * weights).sum().backward()
    jac = rec.jacobian({k: v.detach() for k, v in values.items()})
    assert jac["floor.reflectance"].shape == (16, 16, 4, 4, 3)
    torch.testing.assert_close((jac["floor.reflectance"] * weights[:, :, None, None, :]).sum((0, 1)), values["floor.reflectance"].grad, rtol=1e-9, atol=1e-12)
    torch.testing.assert_close((jac["red.reflectance"] * weights).sum((0, 1)), values["red.reflectance"].grad, rtol=1e-9, atol=1e-12)


def test_textured_record_is_unbiased_away_from_the_record_point():
    """Recorded at a grey 0.5 floor, evaluated at the checker: channel means of the floor's pixels
    agree with independent renders of the checker within 4 standard errors."""
    scene = ir.load_scene("forward/textured_floor.toml", resolution=(16, 16))
    checker = scene.params["floor.reflectance"].detach().clone()
    grey = ir.load_scene("forward/textured_floor.toml", resolution=(16, 16))
    with torch.no_grad():
        grey.params["floor.reflectance"].fill_(0.5)
    far = torch.stack([ir.record_paths(grey, ["floor.reflectance"], spp=64, max_depth=6, seed=s, progress=False).image({"floor.reflectance": checker})[10:].mean((0, 1)) for s in range(4)])
    ref = torch.stack([ir.render(scene, spp=64, max_depth=6, seed=20 + s, progress=False).double()[10:].mean((0, 1)) for s in range(4)])
    se = (far.var(0) / 4 + ref.var(0) / 4).sqrt()
    assert ((far.mean(0) - ref.mean(0)).abs() < 4 * se + 1e-5).all(), (far.mean(0), ref.mean(0), se)


def test_textured_record_over_budget_names_the_parameter():
    scene = ir.load_scene("forward/textured_floor.toml", resolution=(16, 16))
    with pytest.raises(ParameterError, match=r"path record of floor.reflectance outgrew max_record_mb=0.05"):
        ir.record_paths(scene, ["floor.reflectance"], spp=64, max_depth=6, max_record_mb=0.05, progress=False)


def test_textured_record_follows_whitted_splits_at_glass():
    """The walls of the specular box textured: Whitted's split paths each keep their parent's
    textured vertices (the record film's branch), so the record is still the render."""
    scene = ir.load_scene("cornell_specular", resolution=(16, 16), subdivisions=2)
    scene.params["white.reflectance"] = torch.rand(2, 2, 3, generator=torch.Generator().manual_seed(0)) * 0.8 + 0.1
    names = ["white.reflectance", "light.emission", "mirror.specular_reflectance"]
    rec = ir.record_paths(scene, names, spp=8, max_depth=5, seed=2, integrator="whitted", progress=False)
    torch.testing.assert_close(rec.image().float(), ir.render(scene, "whitted", spp=8, max_depth=5, seed=2, progress=False), rtol=1e-5, atol=1e-6)


# ---------------------------------------------------------------- environment maps


def sky_scene(floor_texture: bool = False, sky: str = "envmap", resolution=(16, 16), camera=None):
    """A glossy cube on a floor under a 4 x 8 sky (or a constant sky), the sky visible behind;
    the floor's albedo a 2 x 2 texture when ``floor_texture``."""
    from invrender.scene.camera import Camera
    from invrender.scene.emitters import Emitter
    from invrender.scene.materials import Material
    from invrender.scene.scene import build_scene
    from invrender.scene.shapes import Mesh, cube, rectangle, rotate, scale, translate

    g = torch.Generator().manual_seed(1)
    floor = torch.rand(2, 2, 3, generator=g) * 0.6 + 0.2 if floor_texture else torch.tensor([0.5, 0.45, 0.4])
    emitter = Emitter.of("envmap", emission=0.3 + torch.rand(4, 8, 3, generator=g) * 2.0, scale=1.5) if sky == "envmap" else Emitter.of("constant", emission=[1.2, 1.0, 0.8])
    meshes = [
        Mesh(*cube(), material="box").transformed(translate([0, 0.0, 0]) @ scale(0.5)),
        Mesh(*rectangle(), material="floor").transformed(translate([0, -0.5, 0]) @ rotate([1, 0, 0], -90) @ scale(3.0)),
    ]
    materials = {"box": Material.of("glossy", specular_reflectance=[0.6, 0.5, 0.4], roughness=0.3), "floor": Material.of(reflectance=floor)}
    camera = camera or Camera(origin=(2.5, 1.2, 3.0), target=(0, 0, 0), up=(0, 1, 0), fov=50.0)
    return build_scene(meshes, materials, {"sky": emitter}, camera, resolution, name="sky_records")


@pytest.mark.parametrize("integrator", ["path", "utah", "random_walk", "whitted"])
def test_an_envmaps_record_is_the_render_and_linear_in_its_texels(integrator):
    """Every contribution that ends on the map (escaped rays, emitter samples of it) is linear in
    the four texels its direction reads: the record is the render of the same seed, and sum over
    texels of J * texel is the image (nothing else is textured); J equals the renderer's gradient."""
    scene = sky_scene()
    rec = ir.record_paths(scene, ["sky.emission"], spp=8, max_depth=3, seed=5, integrator=integrator, progress=False)
    image = ir.render(scene, integrator, spp=8, max_depth=3, seed=5, progress=False)
    torch.testing.assert_close(rec.image().float(), image, rtol=1e-5, atol=1e-6)
    assert [g.texels.shape[1] for g in rec.texel_terms] == [1] and rec.exponents.shape[0] <= 1  # degree 1 in the map
    J = rec.jacobian()["sky.emission"]
    assert J.shape == (16, 16, 4, 8, 3)
    torch.testing.assert_close((J * scene.params["sky.emission"].double()).sum((2, 3)), rec.image(), rtol=1e-9, atol=1e-12)
    weights = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(0))
    t = scene.params["sky.emission"].requires_grad_(True)
    (weights * ir.render(scene, integrator, spp=8, max_depth=3, seed=5, progress=False)).sum().backward()
    torch.testing.assert_close((J * weights.double()[:, :, None, None, :]).sum((0, 1)), t.grad.double(), rtol=1e-4, atol=1e-6)


def test_a_padded_map_folds_back_onto_its_texels():
    """A 1 x 2 map (padded to 3 rows as Mitsuba pads): the record keeps the map's own 2 texels."""
    scene = sky_scene()
    scene.params["sky.emission"] = torch.tensor([[[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]]])
    rec = ir.record_paths(scene, ["sky.emission"], spp=4, max_depth=2, seed=1, progress=False)
    torch.testing.assert_close(rec.image().float(), ir.render(scene, spp=4, max_depth=2, seed=1, progress=False), rtol=1e-5, atol=1e-6)
    assert rec.jacobian()["sky.emission"].shape == (16, 16, 1, 2, 3)


@pytest.mark.parametrize("sky", ["envmap", "constant"])
def test_a_sky_and_a_textured_floor_record_together(sky):
    """Degrees per parameter: a contribution ends on the sky (degree 1 in its map, or its constant)
    and carries k factors of the floor's texture; the record is the render, and its Jacobians equal
    autograd through the polynomial away from the record point."""
    scene = sky_scene(floor_texture=True, sky=sky)
    names = ["floor.reflectance", "sky.emission", "box.specular_reflectance"]
    rec = ir.record_paths(scene, names, spp=8, max_depth=4, seed=2, progress=False)
    torch.testing.assert_close(rec.image().float(), ir.render(scene, spp=8, max_depth=4, seed=2, progress=False), rtol=1e-5, atol=1e-6)
    if sky == "envmap":
        assert max(g.texels.shape[1] for g in rec.texel_terms) >= 2  # a sky texel times floor texels
    values = {n: (scene.params[n].detach().double() * 0.8).requires_grad_(True) for n in names}
    weights = torch.rand(16, 16, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    (rec.image(values) * weights).sum().backward()
    jac = rec.jacobian({k: v.detach() for k, v in values.items()})
    for n in names:
        axes = (0, 1)
        w = weights[:, :, None, None, :] if jac[n].ndim == 5 else weights
        torch.testing.assert_close((jac[n] * w).sum(axes), values[n].grad, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("scene_name, names", [("cornell_box", CORNELL), ("forward/textured_floor.toml", ["floor.reflectance", "light.emission"])])
def test_passes_accumulate_into_the_record_of_all_their_samples(scene_name, names):
    """Passes over disjoint sample ranges of one seed (independent sampler: sample k's numbers do
    not depend on the pass) accumulate into the record of all the samples: the same polynomial
    (texel tables too), to float rounding; passes at another record point are its spp-weighted mean."""
    scene = ir.load_scene(scene_name, resolution=(12, 12))
    kw = dict(max_depth=5, seed=7, sampler="independent", progress=False)
    whole = ir.record_paths(scene, names, spp=12, **kw)
    passes = [ir.record_paths(scene, names, spp=n, first_sample=a, **kw) for a, n in ((0, 2), (2, 4), (6, 6))]
    acc = accumulate(passes)
    assert acc.spp == 12 and acc.exponents.shape == whole.exponents.shape
    at = {n: torch.rand(scene.params[n].shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 0.8 + 0.1 for n in names}
    torch.testing.assert_close(acc.image(at), whole.image(at), rtol=1e-9, atol=1e-12)
    for n in names:
        torch.testing.assert_close(acc.jacobian(at)[n], whole.jacobian(at)[n], rtol=1e-9, atol=1e-12)
    assert bool(whole.texel_terms) == (scene_name != "cornell_box")
    assert [g.pixel.numel() for g in acc.texel_terms] == [g.pixel.numel() for g in whole.texel_terms]
    # a pass at another record point (other values): the mean of the polynomials, weighted by spp
    other = scene.with_params({n: at[n].float() for n in names})
    far = ir.record_paths(other, names, spp=4, first_sample=12, **kw)
    mixed = accumulate([whole, far])
    assert mixed.spp == 16 and mixed.record_values[names[0]].equal(far.record_values[names[0]])
    torch.testing.assert_close(mixed.image(at), (12 * whole.image(at) + 4 * far.image(at)) / 16, rtol=1e-9, atol=1e-12)
    assert not torch.allclose(far.image(at), whole.image(at), rtol=1e-3)  # independent samples: a different estimate
    with pytest.raises(ParameterError, match="cannot accumulate"):
        accumulate([whole, ir.record_paths(scene, names[:1], spp=2, **kw)])
