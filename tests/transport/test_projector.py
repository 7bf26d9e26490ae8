"""Projected images: the ``projector`` emitter and ``spot`` lights with a texture (Mitsuba's
``projector`` and spot ``texture``).

- Their radiance at points equals Mitsuba 3.9.1's ``sample_direction`` (llvm_ad_rgb), hard-coded
  from a run of Mitsuba here (a rotated frame, a non-square image read bilinearly, a projector
  with ``fov_axis`` y and a scaled ``to_world``).
- Closed forms: a constant image lights a plane facing the projector with ``pi scale E / z^2``
  inside the frustum and nothing outside; the image's orientation (first row towards ``up`` for a
  projector, towards ``-up`` for a spot); the power.
- The radiance is linear in the texels and differentiable in them.
- Mitsuba XML, TOML and Python load them; bad input is a one-line error.

(Compiled == eager lane by lane: tests/transport/test_light_lanes.py; the fused bounce ==
the torch one: tests/transport/test_fused.py.)
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.io import write_image
from invrender.plugins.emitters.projector import Projector
from invrender.plugins.emitters.spot import Spot
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, cube

#: a 3 x 4 image (rows, columns), as given to Mitsuba
TEXTURE = torch.tensor([
    [[0.7251, 0.9972, 0.8757], [0.3252, 0.4002, 0.9736], [0.1053, 0.9212, 0.8971], [0.5679, 0.403, 0.3784]],
    [[0.3549, 0.5451, 0.6045], [0.6535, 1.0955, 0.8927], [0.7222, 1.089, 0.3153], [0.2602, 0.7125, 0.1439]],
    [[0.1357, 0.6149, 0.5662], [1.0172, 0.7292, 0.6141], [0.5969, 0.3475, 0.1118], [0.2924, 0.792, 0.3006]],
])  # fmt: skip
POINTS = torch.tensor([[0.3, -0.2, 0.1], [0.9, 1.1, -0.4], [0.0, 0.5, 0.0], [-0.4, 0.2, 0.3], [0.5, 0.6, 0.7], [1.5, -0.3, 0.2], [0.05, 0.4, -0.3], [0.6, 0.0, 0.0]])
#: Mitsuba's lookat(origin, target, up) of both lights
ORIGIN, TARGET, UP = [0.2, 1.5, 0.4], [0.4, 0.0, 0.1], [0.0, 0.0, 1.0]
#: Mitsuba 3.9.1's sample_direction at POINTS of a projector (irradiance TEXTURE (raw), fov 50,
#: fov_axis y, scale 2, to_world lookat x scale(1.5))
MITSUBA_PROJECTOR = [[2.122734, 3.401986, 1.586037], [0.0, 0.0, 0.0], [4.302132, 6.66608, 2.083865], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.235765, 1.86997, 1.623714], [3.17152, 4.188538, 2.51203], [2.714823, 3.843737, 2.960477]]
#: ... and of a spot (intensity (2, 1, 0.5), texture TEXTURE (raw), cutoff 40, beam width 25, to_world lookat)
MITSUBA_SPOT = [[0.457217, 0.35958, 0.116177], [0.0, 0.0, 0.0], [0.871669, 0.67439, 0.35933], [0.143163, 0.129881, 0.068215], [0.751017, 0.221647, 0.035937], [0.110756, 0.119181, 0.014905], [0.494275, 0.351522, 0.266004], [0.505727, 0.413068, 0.093865]]


@pytest.fixture(scope="module")
def triangles():
    scene = build_scene([Mesh(*cube(), material="box")], {"box": 0.5}, {"sky": Emitter.of("constant", emission=1.0)}, Camera(origin=(3, 2, 3), target=(0, 0, 0), up=(0, 1, 0), fov=35.0), (8, 8))
    return scene.triangles


def light_of(spec: Emitter, triangles, values=None):
    cls = {"projector": Projector, "spot": Spot}[spec.type]
    return cls([0], [values or {k: torch.as_tensor(v, dtype=torch.float32) for k, v in spec.values.items()}], [dict(spec.constants)], triangles)


def radiance_at(light, points: torch.Tensor) -> torch.Tensor:
    """Le (N, 3) arriving at ``points`` from the light (normals towards it, no offset)."""
    position = torch.tensor(light.constants[0]["position"], dtype=torch.float32)
    nx = torch.nn.functional.normalize(position - points, dim=1)
    return light.sample_from(torch.rand(len(points), 3), points, nx, 0.0).Le


def test_projector_and_textured_spot_are_mitsubas(triangles):
    direction = (np.array(TARGET) - ORIGIN).tolist()
    fov_x = math.degrees(2 * math.atan(math.tan(math.radians(25.0)) * 4 / 3))  # fov 50 along y, aspect 4 / 3
    projector = Emitter.of("projector", emission=TEXTURE, fov=fov_x, scale=2.0 * 1.5, position=ORIGIN, direction=direction, up=UP)
    torch.testing.assert_close(radiance_at(light_of(projector, triangles), POINTS), torch.tensor(MITSUBA_PROJECTOR), rtol=2e-5, atol=1e-6)
    spot = Emitter.of("spot", emission=TEXTURE * torch.tensor([2.0, 1.0, 0.5]), cutoff_angle=40.0, beam_width=25.0, position=ORIGIN, direction=direction, up=UP)
    torch.testing.assert_close(radiance_at(light_of(spot, triangles), POINTS), torch.tensor(MITSUBA_SPOT), rtol=2e-5, atol=1e-6)


def test_a_constant_image_lights_a_facing_plane_evenly_inside_the_frustum(triangles):
    """On the plane z = depth facing a projector along -z: irradiance ``Le cos = pi scale E /
    depth^2`` inside the frustum |x| < depth tan(fov/2), |y| < depth tan(fov/2) / aspect, 0 outside."""
    E, scale, fov, depth = torch.tensor([0.3, 0.6, 0.9]), 1.7, 70.0, 2.5
    image = E.expand(2, 5, 3).clone()  # aspect 5 / 2
    light = light_of(Emitter.of("projector", emission=image, fov=fov, scale=scale, position=[1.0, 2.0, 3.0], direction=[0.0, 0.0, -1.0], up=[0.0, 1.0, 0.0]), triangles)
    g = torch.Generator().manual_seed(0)
    half_w = depth * math.tan(math.radians(fov / 2))
    half_h = half_w / 2.5
    xy = (torch.rand(4000, 2, generator=g) * 2 - 1) * torch.tensor([1.3 * half_w, 1.3 * half_h])
    points = torch.cat([xy + torch.tensor([1.0, 2.0]), torch.full((4000, 1), 3.0 - depth)], dim=1)
    Le = radiance_at(light, points).double()
    cos = depth / (points.double() - torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)).norm(dim=1)
    inside = (xy[:, 0].abs() < half_w * (1 - 1e-5)) & (xy[:, 1].abs() < half_h * (1 - 1e-5))
    outside = (xy[:, 0].abs() > half_w * (1 + 1e-5)) | (xy[:, 1].abs() > half_h * (1 + 1e-5))
    expected = math.pi * scale * E.double() / depth**2
    torch.testing.assert_close(Le[inside] * cos[inside, None], expected.expand(int(inside.sum()), 3), rtol=2e-5, atol=0)
    assert bool((Le[outside] == 0).all()) and 0.4 < float(inside.float().mean()) < 0.8
    # power: scale mean(E) times the image's area at depth 1
    assert light.power == pytest.approx(scale * float(E.mean()) * (2 * math.tan(math.radians(fov / 2))) ** 2 / 2.5, rel=1e-6)


@pytest.mark.parametrize("kind", ["projector", "spot"])
def test_the_image_lands_oriented_as_in_mitsuba(kind, triangles):
    """Images of two rows (red over blue) and of two columns (green, blue) sent along -z with up +y,
    so that the light's local +x is the world's -x: a projector's first row lands towards +y and
    its first column towards local +x (upright seen from behind it), a spot's towards -y and local
    -x (turned by 180 degrees)."""
    rows = torch.tensor([[[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]]]).expand(2, 2, 3).clone()
    columns = torch.tensor([[[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]]).expand(2, 2, 3).clone()
    frame = dict(position=[0.0, 0.0, 0.0], direction=[0.0, 0.0, -1.0], up=[0.0, 1.0, 0.0])
    extra = {"fov": 60.0} if kind == "projector" else {"cutoff_angle": 40.0}
    at = torch.tensor([[0.0, 0.3, -1.0], [0.0, -0.3, -1.0], [-0.3, 0.0, -1.0], [0.3, 0.0, -1.0]])  # +y, -y, local +x, local -x
    up, down, _, _ = radiance_at(light_of(Emitter.of(kind, emission=rows, **frame, **extra), triangles), at).tolist()
    _, _, plus_x, minus_x = radiance_at(light_of(Emitter.of(kind, emission=columns, **frame, **extra), triangles), at).tolist()
    red_up = up[0] > 4 * up[2] and down[2] > 4 * down[0]
    green_plus_x = plus_x[1] > 4 * plus_x[2] and minus_x[2] > 4 * minus_x[1]
    red_down = down[0] > 4 * down[2] and up[2] > 4 * up[0]
    green_minus_x = minus_x[1] > 4 * minus_x[2] and plus_x[2] > 4 * plus_x[1]
    if kind == "projector":
        assert red_up and green_plus_x, (up, down, plus_x, minus_x)
    else:
        assert red_down and green_minus_x, (up, down, plus_x, minus_x)


@pytest.mark.parametrize("kind", ["projector", "spot"])
def test_the_radiance_is_differentiable_in_the_texels(kind, triangles):
    texture = TEXTURE.clone().requires_grad_(True)
    direction = (np.array(TARGET) - ORIGIN).tolist()
    extra = {"fov": 60.0} if kind == "projector" else {"cutoff_angle": 40.0}
    light = light_of(Emitter.of(kind, emission=TEXTURE, position=ORIGIN, direction=direction, up=UP, **extra), triangles, {"emission": texture})
    Le = radiance_at(light, POINTS)
    Le.sum().backward()
    # linear in the texels: sum_t t dL/dt = L, and texels no point reads get no gradient
    assert float((texture.grad * TEXTURE).sum()) == pytest.approx(float(Le.detach().sum()), rel=1e-5)
    assert float(Le.detach().sum()) > 1 and int((texture.grad == 0).all(2).sum()) > 0


def _xml(tmp_path, emitter: str) -> str:
    path = tmp_path / "s.xml"
    path.write_text(
        '<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="50"/><transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>'
        + emitter
        + '<shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape></scene>'
    )
    return str(path)


def test_mitsuba_xml_toml_and_python_load_them(tmp_path):
    write_image(tmp_path / "slide.exr", TEXTURE)
    frame = '<transform name="to_world"><scale value="1.5"/><lookat origin="0.2, 1.5, 0.4" target="0.4, 0, 0.1" up="0, 0, 1"/></transform>'
    scene = ir.load_scene(_xml(tmp_path,
        f'<emitter type="projector" id="p"><texture type="bitmap" name="irradiance"><string name="filename" value="slide.exr"/></texture>'
        f'<float name="fov" value="50"/><string name="fov_axis" value="y"/><float name="scale" value="2"/>{frame}</emitter>'
        '<emitter type="projector" id="q"><rgb name="irradiance" value="0.5, 1, 2"/></emitter>'
        '<emitter type="spot" id="s"><rgb name="intensity" value="2, 1, 0.5"/><texture type="bitmap" name="texture"><string name="filename" value="slide.exr"/></texture>'
        '<float name="cutoff_angle" value="40"/><transform name="to_world"><lookat origin="0.2, 1.5, 0.4" target="0.4, 0, 0.1" up="0, 0, 1"/></transform></emitter>'), resolution=(8, 8))  # fmt: skip
    p, q, s = (scene.emitter_spec(i).constants for i in range(3))
    direction = np.array(TARGET) - ORIGIN
    direction /= np.linalg.norm(direction)
    up = np.array(UP) - direction * direction[2]
    assert p["position"] == pytest.approx(ORIGIN) and p["direction"] == pytest.approx(direction) and p["up"] == pytest.approx(up / np.linalg.norm(up))
    assert p["fov"] == pytest.approx(math.degrees(2 * math.atan(math.tan(math.radians(25.0)) * 4 / 3))) and p["scale"] == pytest.approx(3.0)
    torch.testing.assert_close(scene.params["p.emission"], TEXTURE)
    # no fov: Mitsuba's 50 mm lens on a square (1 x 1) image; no to_world: along +z from the origin
    assert q["fov"] == pytest.approx(math.degrees(2 * math.atan(0.5 * math.hypot(36, 24) / 50 / math.sqrt(2))))
    assert q["direction"] == pytest.approx((0, 0, 1)) and q["position"] == pytest.approx((0, 0, 0))
    torch.testing.assert_close(scene.params["s.emission"], TEXTURE * torch.tensor([2.0, 1.0, 0.5]))
    assert s["cutoff_angle"] == 40.0 and s["up"] == pytest.approx(up / np.linalg.norm(up))
    # TOML: the image as emission_texture
    toml = tmp_path / "s.toml"
    toml.write_text(
        '[camera]\norigin = [0, 0, 3]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\nfov = 50\n[materials.floor]\nreflectance = 0.5\n'
        '[emitters.p]\ntype = "projector"\nemission_texture = "slide.exr"\nposition = [0, 0, 2]\ndirection = [0, 0, -1]\nup = [0, 1, 0]\nfov = 40\nscale = 2\n'
        '[[shapes]]\ntype = "rectangle"\nmaterial = "floor"\n'
    )
    loaded = ir.load_scene(str(toml), resolution=(16, 16))
    torch.testing.assert_close(loaded.params["p.emission"], TEXTURE)
    image = ir.render(loaded, spp=4, max_depth=2, seed=0, progress=False)
    assert bool(torch.isfinite(image).all()) and float(image.mean()) > 0.01


@pytest.mark.parametrize(
    "emitter, words",
    [
        ('<emitter type="projector"><texture type="bitmap" name="irradiance"><string name="filename" value="missing.exr"/></texture></emitter>', "missing.exr: file not found"),
        ('<emitter type="projector"><float name="fov" value="180"/></emitter>', "'fov' must lie in (0, 180) degrees, got 180"),
        ('<emitter type="projector"><float name="fov" value="0"/></emitter>', "'fov' must lie in (0, 180) degrees, got 0"),
        ('<emitter type="projector"><float name="fov" value="nan"/></emitter>', "<float name=\"fov\">: values must be finite, got 'nan'"),
        ('<emitter type="projector"><float name="scale" value="-1"/></emitter>', "'scale' (the irradiance's scale factor) must lie in (0, inf), got -1"),
        ('<emitter type="projector"><rgb name="irradiance" value="-1"/></emitter>', "'irradiance' (emitted radiance eps) must be >= 0"),
        ('<emitter type="projector"><float name="fov" value="40"/><string name="focal_length" value="50mm"/></emitter>', "give either 'fov' or 'focal_length', not both"),
        ('<emitter type="projector"><transform name="to_world"><scale x="-1" y="1" z="1"/></transform></emitter>', "must not mirror (negative determinant)"),
        ('<emitter type="projector"><transform name="to_world"><scale x="1" y="2" z="1"/></transform></emitter>', "must be a rotation, translation and uniform scale"),
        ('<emitter type="projector"><float name="radius" value="1"/></emitter>', "unsupported property 'radius'"),
        ('<emitter type="spot"><texture type="bitmap" name="texture"><string name="filename" value="slide.exr"/><string name="filter_type" value="nearest"/></texture></emitter>', "filter_type, wrap_mode and to_uv are not supported"),
        ('<emitter type="spot"><texture type="bitmap" name="texture"><string name="filename" value="slide.exr"/></texture><transform name="to_world"><scale x="-1" y="1" z="1"/></transform></emitter>', "must not mirror"),
    ],
)
def test_bad_projected_images_in_xml_are_one_line_errors(tmp_path, emitter, words):
    write_image(tmp_path / "slide.exr", TEXTURE)
    with pytest.raises(ir.SceneError) as info:
        ir.load_scene(_xml(tmp_path, emitter))
    assert words in str(info.value) and "\n" not in str(info.value), str(info.value)


def test_bad_projected_images_in_python_are_one_line_errors():
    for kind, entries, words in [
        ("projector", {"fov": 180.0}, "'fov' must lie in (0, 180), got 180"),
        ("projector", {"fov": float("nan")}, "'fov' must be a finite number, got nan"),
        ("projector", {"scale": 0.0}, "'scale' must lie in (0, inf), got 0"),
        ("projector", {"direction": [0.0, 1.0, 0.0], "up": [0.0, 2.0, 0.0]}, "'up' (0.0, 2.0, 0.0) must not be parallel to 'direction'"),
        ("spot", {"emission": torch.ones(2, 2, 3), "direction": [0.0, -1.0, 0.0]}, "'up' (0.0, 1.0, 0.0) must not be parallel to 'direction'"),
    ]:
        with pytest.raises(ir.SceneError) as info:
            Emitter.of(kind, **entries)
        assert words in str(info.value) and "\n" not in str(info.value), str(info.value)
    Emitter.of("spot", direction=[0.0, -1.0, 0.0])  # without an image, up is read by nothing
    nan = torch.ones(2, 3, 3)
    nan[0, 1, 2] = float("nan")
    for kind in ("projector", "spot"):
        with pytest.raises(ir.ParameterError, match="lamp.emission: values must be finite"):
            build_scene([Mesh(*cube(), material="box")], {"box": 0.5}, {"lamp": Emitter.of(kind, emission=nan)}, Camera(origin=(3, 2, 3), target=(0, 0, 0), up=(0, 1, 0), fov=35.0), (8, 8))
