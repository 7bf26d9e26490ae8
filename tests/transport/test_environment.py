"""Emitters infinitely far away: the ``constant`` environment and ``hide_emitters``.

- A convex diffuse object (a cube) under a constant environment L has radiance ``rho L`` exactly: it
  sees nothing but the sky (docs/closed_forms.md). The random walk estimates it with zero variance
  (cosine sampling: every path escapes with weight rho); the estimators that sample the sky (path,
  utah, whitted, distributed) within their Monte Carlo error.
- The camera sees L where its rays leave the scene, and black there with ``hide_emitters``, which
  leaves the object's radiance as it was (the sky still lights it).
- The image is linear in L: d(sum I)/dL = sum I / L for the same paths, by both estimators.
"""

from __future__ import annotations

import pytest
import torch

import invrender as ir
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, cube

L, RHO = 2.0, 0.5
CAMERA = Camera(origin=(3.0, 2.5, 3.5), target=(0, 0, 0), up=(0, 1, 0), fov=35.0)


def sky_scene(**emitter):
    return build_scene([Mesh(*cube(), material="box")], {"box": RHO}, {"sky": Emitter.of("constant", emission=L, **emitter)}, CAMERA, (24, 24), name="sky")


@pytest.fixture(scope="module")
def masks():
    """(cube pixels, sky pixels): where every camera ray of the 64-spp renders hits the cube / leaves."""
    seen = ir.render(sky_scene(), spp=64, max_depth=1, seed=3, progress=False)
    cube_pixels, sky_pixels = (seen == 0).all(-1), (seen == L).all(-1)
    assert int(cube_pixels.sum()) > 100 and int(sky_pixels.sum()) > 100
    return cube_pixels, sky_pixels


@pytest.mark.parametrize(
    "integrator, rel",
    [("random_walk", 1e-6), ("path", 1e-2), ({"type": "path", "strategy": "emitter"}, 3e-2), ("utah", 1e-2), ("whitted", 3e-2), ("distributed", 3e-2)],
)
def test_a_convex_diffuse_object_under_a_constant_sky_has_radiance_rho_L(masks, integrator, rel):
    cube_pixels, sky_pixels = masks
    img = ir.render(sky_scene(), integrator, spp=64, max_depth=3, seed=3, progress=False)
    assert float(img[cube_pixels].mean()) == pytest.approx(RHO * L, rel=rel)  # rel: about 3 standard errors
    assert bool((img[sky_pixels] == L).all())


def test_hide_emitters_hides_the_sky_from_the_camera_only(masks):
    cube_pixels, sky_pixels = masks
    shown = ir.render(sky_scene(), spp=64, max_depth=3, seed=3, progress=False)
    hidden = ir.render(sky_scene(), {"type": "path", "hide_emitters": True}, spp=64, max_depth=3, seed=3, progress=False)
    assert bool((hidden[sky_pixels] == 0).all())
    # the same paths (the fused bounce renders the one, the torch bounce the other: float rounding)
    torch.testing.assert_close(hidden[cube_pixels], shown[cube_pixels], rtol=1e-5, atol=1e-6)
    with pytest.raises(ir.ParameterError, match="hide_emitters must be true or false"):
        ir.render(sky_scene(), {"type": "path", "hide_emitters": "yes"}, spp=1, progress=False)


def test_hide_emitters_hides_area_lights_seen_directly():
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    direct = ir.render(scene, spp=4, max_depth=1, seed=0, progress=False)
    assert float(direct.max()) > 1.0  # the light is in view
    for integrator in ("path", "whitted", "utah", "random_walk", "distributed"):
        hidden = ir.render(scene, {"type": integrator, "hide_emitters": True, "max_depth": 1}, spp=4, seed=0, progress=False)
        assert float(hidden.abs().max()) == 0.0, integrator
    # as Mitsuba's: the camera sees through the light to the (dim) ceiling behind it; elsewhere nothing changes
    seen = ir.render(scene, spp=16, max_depth=1, seed=0, progress=False)  # the same camera rays as below
    light, away = (seen > 1.0).all(-1), (seen == 0).all(-1)
    shown = ir.render(scene, spp=16, seed=0, progress=False)
    hidden = ir.render(scene, {"type": "path", "hide_emitters": True}, spp=16, seed=0, progress=False)
    assert 0.0 < float(hidden[light].mean()) < 0.5 < 5.0 < float(shown[light].mean())
    # paths whose camera ray misses the light are the same paths (to float rounding: the fused bounce is compiled)
    torch.testing.assert_close(hidden[away], shown[away], rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("estimator", ["autodiff", "replay"])
def test_the_sky_differentiates(estimator):
    scene = sky_scene()
    radiance = scene.params["sky.emission"].requires_grad_(True)
    ir.render(scene, spp=8, max_depth=3, seed=5, estimator=estimator, progress=False).sum().backward()
    with torch.no_grad():
        plain = ir.render(scene, spp=8, max_depth=3, seed=5, progress=False)
    torch.testing.assert_close(radiance.grad, plain.sum((0, 1)) / L, rtol=1e-4, atol=0)


def test_a_constant_sky_loads_from_toml_and_xml(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text('[camera]\norigin = [3, 2.5, 3.5]\n[materials.box]\nreflectance = 0.5\n[emitters.sky]\ntype = "constant"\nemission = 2\n[[shapes]]\ntype = "cube"\nmaterial = "box"\n')
    xml = tmp_path / "s.xml"
    xml.write_text(
        '<scene version="3.0.0"><integrator type="path"><boolean name="hide_emitters" value="true"/></integrator>'
        '<sensor type="perspective"><float name="fov" value="35"/></sensor>'
        '<emitter type="constant" id="sky"><rgb name="radiance" value="2"/></emitter><shape type="cube"/></scene>'
    )
    for path in (toml, xml):
        scene = ir.load_scene(str(path), resolution=(8, 8))
        assert scene.emitter_spec(0).type == "constant" and "sky.emission" in scene.params
        torch.testing.assert_close(scene.params["sky.emission"], torch.full((3,), 2.0))
    assert ir.load_scene(str(xml)).defaults["hide_emitters"] is True
    bad = tmp_path / "bad.xml"
    bad.write_text(xml.read_text().replace('<emitter type="constant" id="sky"><rgb name="radiance" value="2"/></emitter><shape type="cube"/>',
                                           '<shape type="cube"><emitter type="constant"/></shape>'))  # fmt: skip
    with pytest.raises(ir.SceneError, match="emits from outside the scene: it is a child of <scene>"):
        ir.load_scene(str(bad))


def test_bad_constant_skies_are_one_line_errors():
    with pytest.raises(ir.ParameterError, match="sky.emission: a constant emitter's emission must be an RGB triple, not a texture"):
        sky_scene_with = build_scene([Mesh(*cube(), material="box")], {"box": RHO}, {"sky": Emitter.of("constant", emission=torch.ones(4, 4, 3))}, CAMERA, (8, 8))
        del sky_scene_with
    with pytest.raises(ir.ParameterError, match="sky.emission: emission eps must be >= 0"):
        sky_scene_radiance = sky_scene()
        sky_scene_radiance = build_scene([Mesh(*cube(), material="box")], {"box": RHO}, {"sky": Emitter.of("constant", emission=-1.0)}, CAMERA, (8, 8))
        del sky_scene_radiance
    with pytest.raises(ir.ParameterError, match="radiosity models emission from the scene's surfaces only: emitter 'sky' is constant"):
        ir.render(sky_scene(), "radiosity", spp=1, progress=False)


def test_path_records_hold_the_sky_as_a_linear_factor():
    """Records re-evaluate the render exactly, and its Jacobian in L is the image over L (linear)."""
    scene = sky_scene()
    record = ir.record_paths(scene, ["sky.emission", "box.reflectance"], spp=8, max_depth=3, seed=1, progress=False)
    img = ir.render(scene, spp=8, max_depth=3, seed=1, progress=False)
    torch.testing.assert_close(record.image().float(), img, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(record.jacobian()["sky.emission"].float(), img / L, rtol=1e-5, atol=1e-6)
