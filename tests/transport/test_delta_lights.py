"""Delta lights (``point``, ``spot``, ``directional``): sampled, never hit; closed forms.

- A diffuse floor of albedo rho lit by a point light of intensity I has radiance
  ``rho / pi * I cos(theta) / r^2`` at each point: direct light from a point has no variance, so a
  pixel is the average of that closed form over the pixel's footprint (the camera's jitter is the
  only randomness); by a directional light of irradiance E, ``rho / pi * E cos(theta)`` at every
  point: exactly, in every pixel.
- The spot's falloff is Mitsuba's (``spot.cpp``): 1 inside the beam, a linear ramp in angle to the
  cutoff, 0 beyond; an image lit by a spot is the point light's times the falloff.
- An occluder casts an exact shadow (zero) where it blocks the point.
- The image is linear in the intensity: autodiff, replay and path records agree on
  d(image)/dI = image / I, and a recorded image is the render.
- With an area light beside a point light, MIS and emitter sampling estimate the same image, the
  sum of the two lights' images; BSDF-only estimators are refused (they never hit a delta light).
- TOML and Mitsuba XML read them (and Mitsuba's ``direct`` integrator); bad inputs are one-line errors.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.plugins.emitters.spot import falloff
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, rectangle

RHO = 0.5
I = (1.0, 2.0, 3.0)
RES = 24
#: looking straight down at the floor z = 0, [-2, 2]^2 (the whole image on the floor)
CAMERA = Camera(origin=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov=50.0)
LAMP = (0.3, 0.2, 1.0)


def floor(half: float = 2.0, z: float = 0.0, material: str = "floor", emitter: str | None = None) -> Mesh:
    v, f, uv = rectangle()
    v = v * [half, half, 1.0] + [0.0, 0.0, z]
    return Mesh(v, f, uv, material=material, emitter=emitter)


def lit(emitter: Emitter, extra_meshes=(), extra_emitters=None, res: int = RES) -> ir.Scene:
    return build_scene([floor(), *extra_meshes], {"floor": RHO, "block": 0.5}, {"lamp": emitter, **(extra_emitters or {})}, CAMERA, (res, res), name="delta")


def footprint_points(res: int = RES, sub: int = 8) -> torch.Tensor:
    """(res, res, sub * sub, 3) the floor points seen through a sub x sub grid in each pixel."""
    s = (torch.arange(sub, dtype=torch.float32) + 0.5) / sub
    px = torch.arange(res, dtype=torch.float32)
    X = (px[None, :, None, None] + s[None, None, None, :]).expand(res, res, sub, sub)
    Y = (px[:, None, None, None] + s[None, None, :, None]).expand(res, res, sub, sub)
    xy = torch.stack([X.reshape(-1), Y.reshape(-1)], 1)
    o, d = CAMERA.generate_rays(xy, res, res)
    t = -o[:, 2] / d[:, 2]
    return (o + t[:, None] * d).reshape(res, res, sub * sub, 3)


def point_radiance(p: torch.Tensor, lamp=LAMP, intensity=I) -> torch.Tensor:
    """rho / pi * I cos(theta) / r^2 at floor points p (..., 3) (normal +z)."""
    to = torch.tensor(lamp) - p
    r2 = (to * to).sum(-1)
    cos = to[..., 2] / r2.sqrt()
    return RHO / math.pi * torch.tensor(intensity) * (cos / r2)[..., None]


def test_a_point_light_over_a_diffuse_floor_has_the_closed_form_radiance():
    img = ir.render(lit(Emitter.of("point", emission=I, position=LAMP)), spp=64, max_depth=2, seed=1, progress=False)
    expected = point_radiance(footprint_points()).mean(2)
    err = (img - expected).abs() / expected
    assert float(err.max()) < 1e-2 and float(err.mean()) < 2e-3  # the pixels' jitter only
    # the light's arithmetic: no cos -> ~15% off at the corners, no 1/r^2 -> factors of 2
    assert float(img.sum()) == pytest.approx(float(expected.sum()), rel=1e-3)
    # direct light from a point has no variance: another seed differs by the jitter only
    other = ir.render(lit(Emitter.of("point", emission=I, position=LAMP)), spp=64, max_depth=2, seed=2, progress=False)
    assert float(((other - img).abs() / expected).max()) < 2e-2


def test_a_directional_light_gives_rho_over_pi_E_cos_exactly():
    d = np.array([0.3, -0.2, -1.0])
    img = ir.render(lit(Emitter.of("directional", emission=I, direction=list(d))), spp=4, max_depth=2, seed=1, progress=False)
    cos = 1.0 / np.linalg.norm(d)  # the angle to the floor's normal +z
    expected = RHO / math.pi * torch.tensor(I) * cos
    torch.testing.assert_close(img, expected.expand_as(img), rtol=1e-5, atol=0)
    below = ir.render(lit(Emitter.of("directional", emission=I, direction=[0.0, 0.0, 1.0])), spp=1, max_depth=2, progress=False)
    assert float(below.abs().max()) == 0.0  # light travelling up never reaches the floor's front


def test_the_spot_falloff_is_mitsubas():
    c, b = 30.0, 10.0
    angles = torch.tensor([0.0, 5.0, 10.0, 15.0, 20.0, 29.0, 30.5, 60.0])
    got = falloff(torch.cos(torch.deg2rad(angles)), c, b)
    want = torch.tensor([1.0, 1.0, 1.0, 0.75, 0.5, 0.05, 0.0, 0.0])  # (c - theta) / (c - b) on the ramp
    torch.testing.assert_close(got, want, rtol=0, atol=1e-5)
    scene = lit(Emitter.of("spot", emission=I, position=LAMP, direction=[0.0, 0.0, -1.0], cutoff_angle=c, beam_width=b))
    assert scene.emitter_spec(0).constants["beam_width"] == b
    assert lit(Emitter.of("spot", cutoff_angle=c)).emitter_spec(0).constants["beam_width"] == 22.5  # Mitsuba's default: 3/4 of the cutoff
    c, b = 45.0, 25.0  # wide enough for the image: the beam, the ramp and the dark each cover many pixels
    scene = lit(Emitter.of("spot", emission=I, position=LAMP, direction=[0.0, 0.0, -1.0], cutoff_angle=c, beam_width=b))
    img = ir.render(scene, spp=64, max_depth=2, seed=1, progress=False)
    p = footprint_points()
    to = torch.tensor(LAMP) - p
    cos_axis = to[..., 2] / to.norm(dim=-1)  # the angle to the axis -z, seen from the light
    expected = (point_radiance(p) * falloff(cos_axis, c, b)[..., None]).mean(2)
    lit_pixels = expected[..., 0] > 0.02
    inside = (torch.rad2deg(torch.acos(cos_axis)) < b).all(-1)
    assert int(inside.sum()) > 20 and int((lit_pixels & ~inside).sum()) > 20 and int((expected[..., 0] == 0).sum()) > 20
    err = ((img - expected).abs() / expected)[lit_pixels]
    assert float(err.max()) < 2e-2 and float(err.mean()) < 3e-3
    assert float(img[expected[..., 0] == 0].abs().max()) <= float(expected.max()) * 2e-2  # dark beyond the cutoff (but the jittered rim)
    assert float(img.sum()) == pytest.approx(float(expected.sum()), rel=3e-3)


def test_an_occluder_casts_an_exact_shadow():
    lamp = (0.0, 0.0, 0.6)
    block = floor(half=0.2, z=0.4, material="block")  # its shadow: half-size 0.6 on the floor; seen by the camera: 0.23
    open_ = ir.render(lit(Emitter.of("point", emission=I, position=lamp)), spp=16, max_depth=2, seed=1, progress=False)
    shadowed = ir.render(lit(Emitter.of("point", emission=I, position=lamp), [block]), spp=16, max_depth=2, seed=1, progress=False)
    p = footprint_points()
    a = p[..., :2].abs().amax(-1)  # the floor points' distance (max norm) from the centre
    in_shadow = ((a > 0.25) & (a < 0.58)).all(-1)
    free = (a > 0.62).all(-1)
    assert int(in_shadow.sum()) >= 8 and int(free.sum()) > 300
    assert float(shadowed[in_shadow].abs().max()) == 0.0
    assert float(open_[in_shadow].min()) > 0.1
    torch.testing.assert_close(shadowed[free], open_[free], rtol=1e-5, atol=0)


@pytest.mark.parametrize("kind", ["point", "spot", "directional"])
def test_the_intensity_differentiates_and_records_exactly(kind):
    extra = {"direction": [0.2, 0.1, -1.0]} if kind != "point" else {}
    if kind != "directional":
        extra["position"] = LAMP
    scene = lit(Emitter.of(kind, emission=I, **extra), res=12)
    with torch.no_grad():
        plain = ir.render(scene, spp=4, max_depth=3, seed=5, progress=False)
    expected = plain.sum((0, 1)) / torch.tensor(I)
    intensity = scene.params["lamp.emission"].requires_grad_(True)
    for estimator in ("autodiff", "replay"):
        intensity.grad = None
        ir.render(scene, spp=4, max_depth=3, seed=5, estimator=estimator, progress=False).sum().backward()
        torch.testing.assert_close(intensity.grad, expected, rtol=1e-4, atol=0)
    intensity.requires_grad_(False)
    records = ir.record_paths(scene, params=["lamp.emission"], spp=4, max_depth=3, seed=5, progress=False)
    torch.testing.assert_close(records.image().float(), plain, rtol=1e-4, atol=1e-7)
    J = records.jacobian()["lamp.emission"]
    torch.testing.assert_close(J.float(), plain / torch.tensor(I), rtol=1e-4, atol=1e-7)
    doubled = records.image({"lamp.emission": 2.0 * torch.tensor(I)})
    torch.testing.assert_close(doubled.float(), 2.0 * plain, rtol=1e-4, atol=1e-7)


def test_mis_with_a_point_and_an_area_light_estimates_the_sum_of_both():
    panel = floor(half=0.5, z=1.5, material="floor", emitter="panel")
    panel = dataclasses.replace(panel, faces=panel.faces[:, ::-1].copy())  # facing down, towards the floor
    def scene_with(point: float, area: float) -> ir.Scene:
        return lit(Emitter.of("point", emission=[point * v for v in I], position=LAMP), [panel], {"panel": Emitter.of("area", emission=area)}, res=16)

    scene = scene_with(1.0, 4.0)
    kw = dict(spp=256, max_depth=2, progress=False)
    mis = ir.render(scene, "path", seed=1, **kw).mean((0, 1))
    nee = ir.render(scene, {"type": "path", "strategy": "emitter"}, seed=2, **kw).mean((0, 1))
    point_only = ir.render(scene_with(1.0, 0.0), seed=3, **kw).mean((0, 1))
    no_point = build_scene([floor(), panel], {"floor": RHO}, {"panel": Emitter.of("area", emission=4.0)}, CAMERA, (16, 16))
    area_only = ir.render(no_point, seed=4, spp=1024, max_depth=2, progress=False).mean((0, 1))
    total = point_only + area_only
    assert float(point_only.min()) > 0.01 and float(area_only.min()) > 0.02
    torch.testing.assert_close(mis, total, rtol=1.5e-2, atol=0)  # about 3 standard errors
    torch.testing.assert_close(nee, total, rtol=1.5e-2, atol=0)
    with pytest.raises(ir.ParameterError, match="BSDF samples only, which never hit a point light"):
        ir.render(scene, "random_walk", spp=1, progress=False)
    with pytest.raises(ir.ParameterError, match="BSDF samples only"):
        ir.render(scene, {"type": "path", "strategy": "bsdf"}, spp=1, progress=False)


XML_HEAD = '<scene version="3.0.0">{integrator}<sensor type="perspective"><float name="fov" value="50"/><transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>'
XML_FLOOR = '<shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>'


def xml_scene(tmp_path, emitters: str, integrator: str = "") -> str:
    path = tmp_path / "s.xml"
    path.write_text(XML_HEAD.format(integrator=integrator) + emitters + XML_FLOOR + "</scene>")
    return str(path)


def test_delta_lights_load_from_mitsuba_xml(tmp_path):
    xml = xml_scene(
        tmp_path,
        '<emitter type="point" id="a"><rgb name="intensity" value="1, 2, 3"/><point name="position" x="0.3" y="0.2" z="1"/></emitter>'
        '<emitter type="point" id="b"><transform name="to_world"><translate x="-1" y="0" z="2"/></transform></emitter>'
        '<emitter type="spot" id="c"><rgb name="intensity" value="5"/><float name="cutoff_angle" value="30"/>'
        '<transform name="to_world"><lookat origin="0, 0, 2" target="0, 1, 0" up="0, 1, 0"/></transform></emitter>'
        '<emitter type="directional" id="d"><rgb name="irradiance" value="0.5"/><vector name="direction" x="0" y="0" z="-2"/></emitter>'
        '<emitter type="directional" id="e"><transform name="to_world"><lookat origin="0, 0, 0" target="1, 0, 0" up="0, 0, 1"/></transform></emitter>',
        '<integrator type="direct"><integer name="bsdf_samples" value="3"/></integrator>',
    )
    scene = ir.load_scene(xml, resolution=(8, 8))
    assert [scene.emitter_spec(i).type for i in range(5)] == ["point", "point", "spot", "directional", "directional"]
    assert scene.emitter_spec(0).constants["position"] == pytest.approx((0.3, 0.2, 1.0))
    assert scene.emitter_spec(1).constants["position"] == pytest.approx((-1.0, 0.0, 2.0))
    spot = scene.emitter_spec(2).constants
    assert spot["position"] == pytest.approx((0.0, 0.0, 2.0)) and spot["direction"] == pytest.approx((0.0, 1.0, -2.0) / np.sqrt(5.0))
    assert spot["cutoff_angle"] == 30.0 and spot["beam_width"] == 22.5
    assert scene.emitter_spec(3).constants["direction"] == pytest.approx((0.0, 0.0, -1.0))
    assert scene.emitter_spec(4).constants["direction"] == pytest.approx((1.0, 0.0, 0.0))
    torch.testing.assert_close(scene.params["a.emission"], torch.tensor(I))
    torch.testing.assert_close(scene.params["d.emission"], torch.full((3,), 0.5))
    assert scene.defaults == {"integrator": "path", "max_depth": 2}  # Mitsuba's direct
    img = ir.render(scene, spp=4, seed=0, progress=False, **{k: v for k, v in scene.defaults.items() if k == "max_depth"})
    assert bool(torch.isfinite(img).all()) and float(img.min()) >= 0 and float(img.mean()) > 0.05


def test_the_same_point_light_from_xml_toml_and_python_renders_the_same(tmp_path):
    xml = xml_scene(tmp_path, '<emitter type="point"><rgb name="intensity" value="1, 2, 3"/><point name="position" x="0.3" y="0.2" z="1"/></emitter>')
    toml = tmp_path / "s.toml"
    toml.write_text(
        '[camera]\norigin = [0, 0, 3]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\nfov = 50\n'
        '[materials.floor]\nreflectance = 0.5\n'
        '[emitters.lamp]\ntype = "point"\nemission = [1, 2, 3]\nposition = [0.3, 0.2, 1]\n'
        '[[shapes]]\ntype = "rectangle"\nmaterial = "floor"\ntransform = [{ scale = 2 }]\n'
    )
    reference = ir.render(lit(Emitter.of("point", emission=I, position=LAMP), res=12), spp=4, max_depth=2, seed=0, progress=False)
    for path in (xml, str(toml)):
        scene = ir.load_scene(path, resolution=(12, 12))
        assert scene.emitter_spec(0).type == "point"
        torch.testing.assert_close(ir.render(scene, spp=4, max_depth=2, seed=0, progress=False, filter="box"), reference, rtol=1e-5, atol=1e-7)  # the XML's film has hdrfilm's gaussian


def test_mitsubas_direct_reads_only_what_keeps_the_mean(tmp_path):
    lamp = '<emitter type="point"/>'
    ok = ir.load_scene(xml_scene(tmp_path, lamp, '<integrator type="direct"><integer name="shading_samples" value="1"/><boolean name="hide_emitters" value="true"/></integrator>'))
    assert ok.defaults == {"integrator": "path", "max_depth": 2, "hide_emitters": True}
    # other sample counts load (the same image, another variance); where Mitsuba's own weighting
    # of delta lights differs (emitter_samples N counts a point light N times), a warning says so
    for prop, warning in [
        ('<integer name="emitter_samples" value="4"/>', r"emitter_samples 4 counts each point, spot or directional light 4 times \(mitsuba3 issue #1861\); invrender counts it once"),
        ('<integer name="shading_samples" value="2"/>', "emitter_samples 2 counts each point"),
        ('<integer name="emitter_samples" value="0"/>', "emitter_samples 0 counts each point, spot or directional light 0 times"),
    ]:
        with pytest.warns(UserWarning, match=warning):
            scene = ir.load_scene(xml_scene(tmp_path, lamp, f'<integrator type="direct">{prop}</integrator>'))
        assert scene.defaults == {"integrator": "path", "max_depth": 2}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no mirror or glass in the scene: bsdf_samples 0 changes nothing
        assert ir.load_scene(xml_scene(tmp_path, lamp, '<integrator type="direct"><integer name="bsdf_samples" value="0"/></integrator>')).defaults["max_depth"] == 2
    for prop, message in [
        ('<integer name="bsdf_samples" value="-1"/>', "'bsdf_samples' -1: a sample count is >= 0"),
        ('<integer name="max_depth" value="3"/>', "unsupported property 'max_depth' \\(supported: hide_emitters, shading_samples, emitter_samples, bsdf_samples\\)"),
    ]:
        with pytest.raises(ir.SceneError, match=message) as info:
            ir.load_scene(xml_scene(tmp_path, lamp, f'<integrator type="direct">{prop}</integrator>'))
        assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "emitters, words",
    [
        ('<emitter type="point"><rgb name="intensity" value="-1"/></emitter>', "'intensity' (emitted radiance eps) must be >= 0"),
        ('<emitter type="spot"><float name="cutoff_angle" value="180"/></emitter>', "'cutoff_angle' (the cone's half-angle, degrees) must lie in (0, 180), got 180"),
        ('<emitter type="spot"><float name="cutoff_angle" value="0"/></emitter>', "must lie in (0, 180), got 0"),
        ('<emitter type="spot"><float name="cutoff_angle" value="10"/><float name="beam_width" value="12"/></emitter>', "'beam_width' (12 degrees) must not exceed 'cutoff_angle' (10 degrees)"),
        ('<emitter type="spot"><texture type="bitmap" name="texture"><string name="filename" value="x.png"/></texture></emitter>', "x.png: file not found"),
        ('<emitter type="spot"><rgb name="texture" value="0.5"/></emitter>', "a spot light's 'texture' must be an image (a bitmap texture), got a colour"),
        ('<emitter type="spot"><transform name="to_world"><scale x="1" y="2" z="1"/></transform></emitter>', "must be a rotation, translation and uniform scale"),
        ('<emitter type="point"><point name="position" x="1" y="0" z="0"/><transform name="to_world"><translate x="1"/></transform></emitter>', "give one of 'position' and 'to_world', not both"),
        ('<emitter type="directional"><vector name="direction" x="0" y="0" z="0"/></emitter>', "'direction' must be a non-zero direction"),
        ('<emitter type="point"><float name="radius" value="1"/></emitter>', "unsupported property 'radius' (supported: intensity, position, to_world)"),
        ('<shape type="rectangle"><emitter type="point"/></shape>', "an emitter of type 'point' is a point or a direction (a delta light), not emitted by a shape: it is a child of <scene>"),
    ],
)
def test_bad_delta_lights_in_xml_are_one_line_errors(tmp_path, emitters, words):
    with pytest.raises(ir.SceneError) as info:
        ir.load_scene(xml_scene(tmp_path, emitters))
    assert words in str(info.value) and "\n" not in str(info.value)


def test_bad_delta_lights_in_toml_and_python_are_one_line_errors(tmp_path):
    def toml(lamp: str, shape_emitter: bool = False) -> str:
        path = tmp_path / f"s{len(list(tmp_path.iterdir()))}.toml"
        shape = '\nemitter = "lamp"' if shape_emitter else ""
        path.write_text(f'[materials.floor]\nreflectance = 0.5\n[emitters.lamp]\n{lamp}\n[[shapes]]\ntype = "rectangle"\nmaterial = "floor"{shape}\n')
        return str(path)

    cases = [
        (toml('type = "point"\nposition = [1, 2]'), "'position' must be a list of 3 numbers, got [1, 2]"),
        (toml('type = "point"\nposition = [1, "a", 2]'), "'position' must be a finite number, got 'a'"),
        (toml('type = "spot"\ncutoff_angle = 190'), "'cutoff_angle' must lie in (0, 180), got 190"),
        (toml('type = "spot"\ncutoff_angle = 20\nbeam_width = 25'), "'beam_width' (25 degrees) must not exceed 'cutoff_angle' (20 degrees)"),
        (toml('type = "directional"\ndirection = [0, 0, 0]'), "'direction' must be a non-zero direction"),
        (toml('type = "point"', shape_emitter=True), "shape names emitter 'lamp' of type 'point', which is a point or a direction (a delta light), not emitted by shapes"),
    ]
    for path, words in cases:
        with pytest.raises(ir.SceneError) as info:
            ir.load_scene(path)
        assert words in str(info.value) and "\n" not in str(info.value), str(info.value)
    with pytest.raises(ir.ParameterError, match="lamp.emission: emission eps must be >= 0"):
        lit(Emitter.of("point", emission=-1.0))
    with pytest.raises(ir.ParameterError, match="a point emitter's emission must be an RGB triple, not a texture"):
        lit(Emitter.of("point", emission=torch.ones(4, 4, 3)))
    with pytest.raises(ir.ParameterError, match="radiosity models emission from the scene's surfaces only: emitter 'lamp' is point"):
        ir.render(lit(Emitter.of("point")), "radiosity", spp=1, progress=False)
