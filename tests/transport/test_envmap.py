"""The ``envmap`` emitter: Mitsuba 3's equirectangular environment map.

- A constant-valued map is the ``constant`` sky: the same images, and a convex diffuse cube under
  it has radiance rho L.
- Which texels a direction reads: Mitsuba's ``u = atan2(v.x, -v.z) / 2 pi``, ``v' = acos(v.y) /
  pi`` of ``v = to_world^-1 d``, columns texel-centred and periodic, rows at i / (h - 1) (the same
  lookup matched Mitsuba 3.9.1's ``eval`` to float rounding on random directions and rotations).
- Sampling: the pdf integrates to 1, a chi-square test of ``sample_from`` against
  ``pdf_escaped`` passes, and fails against the density of a plausible bug (no sin theta).
- Texel gradients: replay = autodiff, and one texel's gradient = central finite differences.
- Loading from TOML and Mitsuba XML; bad maps and rotations are one-line errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.plugins.emitters import checks
from invrender.plugins.emitters.envmap import Distribution, Envmap, padded, quaternion_of
from invrender.io import write_image
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, cube, rotate

L, RHO = 2.0, 0.5
CAMERA = Camera(origin=(3.0, 2.5, 3.5), target=(0, 0, 0), up=(0, 1, 0), fov=35.0)


def sky_map(h: int = 9, w: int = 16, seed: int = 0) -> torch.Tensor:
    """An HDR map with a sun: a smooth gradient plus one bright texel."""
    g = torch.Generator().manual_seed(seed)
    t = 0.2 + torch.rand(h, w, 3, generator=g)
    t[2, 5] = torch.tensor([40.0, 30.0, 20.0])
    return t


def scene_with(emitter: Emitter, resolution=(24, 24)):
    return build_scene([Mesh(*cube(), material="box")], {"box": RHO}, {"sky": emitter}, CAMERA, resolution, name="sky")


def light_of(emitter: Emitter) -> Envmap:
    scene = scene_with(emitter)
    return Envmap([0], [{"emission": scene.params["sky.emission"]}], [dict(scene.emitter_spec(0).constants)], scene.triangles)


# ---------------------------------------------------------------- a constant map is the constant sky


@pytest.mark.parametrize("integrator, rel", [("path", 1e-2), ("utah", 1e-2), ("whitted", 3e-2), ("random_walk", 1e-6)])
def test_a_constant_map_is_the_constant_sky(integrator, rel):
    constant = ir.render(scene_with(Emitter.of("constant", emission=L)), integrator, spp=64, max_depth=3, seed=3, progress=False)
    envmap = ir.render(scene_with(Emitter.of("envmap", emission=torch.full((4, 8, 3), L / 4), scale=4.0)), integrator, spp=64, max_depth=3, seed=3, progress=False)
    seen = ir.render(scene_with(Emitter.of("constant", emission=L)), spp=64, max_depth=1, seed=3, progress=False)
    cube_pixels, sky_pixels = (seen == 0).all(-1), (seen == L).all(-1)
    assert int(cube_pixels.sum()) > 100 and int(sky_pixels.sum()) > 100
    torch.testing.assert_close(envmap[sky_pixels], torch.full_like(envmap[sky_pixels], L), rtol=1e-6, atol=0)
    assert float(envmap[cube_pixels].mean()) == pytest.approx(RHO * L, rel=rel)  # the closed form
    assert float(envmap[cube_pixels].mean()) == pytest.approx(float(constant[cube_pixels].mean()), rel=2 * rel)


# ---------------------------------------------------------------- which texel a direction reads


def one_hot_light(h: int = 5, w: int = 8, **constants) -> tuple[Envmap, torch.Tensor]:
    """A map whose texel (i, j) holds (i * w + j, 0, 0) + 1, and its light."""
    t = torch.zeros(h, w, 3)
    t[..., 0] = torch.arange(h * w, dtype=torch.float32).reshape(h, w) + 1.0
    t[..., 1] = 1.0
    return light_of(Emitter.of("envmap", emission=t, **constants)), t[..., 0]


def test_which_texels_a_direction_reads_follow_mitsuba():
    light, T = one_hot_light()  # h = 5 rows: centres at theta = 0, 45, 90, 135, 180 degrees; w = 8 columns
    d = torch.tensor(
        [
            [0.0, 0.0, -1.0],  # -Z: u = 0 (the seam between columns 7 and 0), equator (row 2)
            [1.0, 0.0, 0.0],  # +X: u = 1/4, between columns 1 and 2
            [0.0, 0.0, 1.0],  # +Z: u = 1/2, between columns 3 and 4
            [-1.0, 0.0, 0.0],  # -X: u = 3/4, between columns 5 and 6
            [0.0, 1.0, 0.0],  # +Y: row 0 (the zenith), u = 0 as Mitsuba's atan2(0, 0)
            [0.0, -1.0, 0.0],  # -Y: the last row
        ]
    )
    half = lambda i, a, b: 0.5 * (T[i, a] + T[i, b])  # noqa: E731
    expected = torch.stack([half(2, 7, 0), half(2, 1, 2), half(2, 3, 4), half(2, 5, 6), half(0, 7, 0), half(4, 7, 0)])
    torch.testing.assert_close(light.escaped(d)[:, 0], expected)
    # a texel's centre reads that texel alone: u = (j + 0.5) / w, theta = pi i / (h - 1)
    for i, j in [(1, 0), (2, 3), (3, 6)]:
        u, theta = (j + 0.5) / 8, math.pi * i / 4
        phi = 2 * math.pi * u
        c = torch.tensor([[math.sin(phi) * math.sin(theta), math.cos(theta), -math.cos(phi) * math.sin(theta)]])
        assert float(light.escaped(c)[0, 0]) == pytest.approx(float(T[i, j]), rel=1e-5)
    # bilinear between rows: theta = 22.5 degrees at u = 1/16 (column 0's centre) is rows 0 and 1 half each
    c = torch.tensor([[math.sin(math.pi / 8) * math.sin(math.pi / 8), math.cos(math.pi / 8), -math.cos(math.pi / 8) * math.sin(math.pi / 8)]])
    assert float(light.escaped(c)[0, 0]) == pytest.approx(float(0.5 * (T[0, 0] + T[1, 0])), rel=1e-5)


def test_to_world_rotates_the_map():
    # to_world = 90 degrees about +Y maps local +X to world -Z: world -Z reads what local +X reads
    q = quaternion_of(rotate([0, 1, 0], 90), "test")
    light, T = one_hot_light(**q)
    d = torch.tensor([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    expected = torch.stack([0.5 * (T[2, 1] + T[2, 2]), 0.5 * (T[2, 3] + T[2, 4]), 0.5 * (T[0, 7] + T[0, 0])])  # local +X, +Z, +Y
    torch.testing.assert_close(light.escaped(d)[:, 0], expected)
    # tilting the map: 90 degrees about +X takes local +Y (the zenith row) to world +Z
    light, T = one_hot_light(**quaternion_of(rotate([1, 0, 0], 90), "test"))
    assert float(light.escaped(torch.tensor([[0.0, 0.0, 1.0]]))[0, 0]) == pytest.approx(float(0.5 * (T[0, 7] + T[0, 0])))


def test_small_maps_are_padded_as_mitsuba_pads_them():
    t = torch.arange(6, dtype=torch.float32).reshape(1, 2, 3)
    p = padded(t)
    assert p.shape == (3, 2, 3) and torch.equal(p[2], t[0])
    assert padded(torch.ones(3)).shape == (3, 2, 3)


# ---------------------------------------------------------------- sampling


@pytest.mark.parametrize("rotation", [None, ([0.3, 1.0, -0.2], 50.0)])
def test_the_sampling_pdf_integrates_to_one(rotation):
    q = quaternion_of(rotate(*rotation), "test") if rotation else {}
    light = light_of(Emitter.of("envmap", emission=sky_map(), **q))
    assert checks.pdf_integral(light) == pytest.approx(1.0, abs=2e-3 if rotation is None else 1e-2)


def test_sample_from_follows_pdf_escaped_by_chi_square():
    light = light_of(Emitter.of("envmap", emission=sky_map()))
    assert checks.chi_square_p(light) > 0.01
    # the test has power: against the density of a sampler that forgot sin(theta) it fails
    wrong = light_of(Emitter.of("envmap", emission=sky_map()))
    wrong.dist = [Distribution(padded(sky_map()), sin_weighted=False)]
    assert checks.pdf_integral(wrong) == pytest.approx(1.0, abs=1e-2)  # a density, just the wrong one
    assert checks.chi_square_p(light, pdf=wrong.pdf_escaped) < 1e-6
    assert checks.chi_square_p(wrong) > 0.01  # consistent with itself
    # the samples carry the pdf and radiance of their directions
    u = torch.rand(1000, 3, generator=torch.Generator().manual_seed(1))
    ls = light.sample_from(u, torch.zeros(1000, 3), torch.tensor([0.0, 1.0, 0.0]).expand(1000, 3), 1e-3)
    torch.testing.assert_close(ls.pdf, light.pdf_escaped(ls.wl))
    torch.testing.assert_close(ls.Le, light.escaped(ls.wl))
    assert bool(torch.isinf(ls.tmax).all())


def test_the_sun_is_sampled_by_its_share_of_the_light():
    light = light_of(Emitter.of("envmap", emission=sky_map()))
    u = torch.rand(20000, 3, generator=torch.Generator().manual_seed(2))
    wl = light.sample_from(u, torch.zeros(20000, 3), torch.tensor([0.0, 1.0, 0.0]).expand(20000, 3), 0.0).wl
    sampled = float((light.escaped(wl)[:, 0] > 5).float().mean())
    d, cell = checks._grid(256, 512, 1, 1)
    sun = light.escaped(d.float())[:, 0] > 5
    solid_angle = float(cell[sun].sum()) / (4 * math.pi)  # what uniform sampling would put there
    assert solid_angle < 0.03 and sampled > 8 * solid_angle, (solid_angle, sampled)


# ---------------------------------------------------------------- gradients


def grad_scene():
    return scene_with(Emitter.of("envmap", emission=sky_map(5, 8), scale=1.5), resolution=(16, 16))


@pytest.mark.parametrize("integrator", ["path", "utah"])
def test_texel_gradients_replay_equals_autodiff(integrator):
    grads = []
    W = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(4))
    for estimator in ("autodiff", "replay"):
        scene = grad_scene()
        t = scene.params["sky.emission"].requires_grad_(True)
        (W * ir.render(scene, integrator, spp=8, max_depth=3, seed=5, estimator=estimator, progress=False)).sum().backward()
        grads.append(t.grad.clone())
    assert float(grads[0].abs().sum()) > 0
    torch.testing.assert_close(grads[1], grads[0], rtol=1e-4, atol=1e-6)


def test_the_gradient_is_the_image_over_the_map():
    """The image is linear in the map with sampling fixed, so sum_k t_k d(sum W I)/dt_k = sum W I
    exactly, for next-event estimation, MIS and escaping rays alike."""
    W = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(4))
    for integrator in ("path", "utah", "random_walk"):
        scene = grad_scene()
        t = scene.params["sky.emission"].requires_grad_(True)
        loss = (W * ir.render(scene, integrator, spp=8, max_depth=3, seed=5, progress=False)).sum()
        loss.backward()
        assert float((t.grad * t.detach()).sum()) == pytest.approx(float(loss.detach()), rel=1e-4), integrator


def test_one_texels_gradient_matches_central_differences():
    """Common random numbers: with BSDF sampling the paths do not depend on the map (next-event
    estimation would re-sample by the perturbed map's density), so the differences are exact up
    to float rounding, and the texel's gradient matches them."""
    W = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(4))
    scene = grad_scene()
    integrator = {"type": "path", "strategy": "bsdf"}
    t = scene.params["sky.emission"].requires_grad_(True)
    (W * ir.render(scene, integrator, spp=32, max_depth=3, seed=7, progress=False)).sum().backward()
    i, j, c = 1, 2, 1  # a texel of the upper sky, seen by the cube's top and by the camera
    g = float(t.grad[i, j, c])
    h = 1e-2 * float(t.detach()[i, j, c])
    losses = []
    for s in (1, -1):
        values = t.detach().clone()
        values[i, j, c] += s * h
        with torch.no_grad():
            image = ir.render(scene.with_params({"sky.emission": values}), integrator, spp=32, max_depth=3, seed=7, progress=False)
            losses.append(float((W.double() * image.double()).sum()))
    fd = (losses[0] - losses[1]) / (2 * h)
    assert abs(g) > 1e-3
    assert fd == pytest.approx(g, rel=0.02), (fd, g)


@pytest.mark.parametrize("integrator", ["path", "utah"])
def test_gradcheck_of_texels_with_next_event_estimation(integrator):
    """gradcheck's perturbed renders sample the map by the unperturbed density
    (``sampling_params``), so next-event estimation draws the same paths in every render and the
    central differences match both estimators within 2% (they were 5-31% off when the perturbed
    map re-sampled)."""
    from invrender.inverse.gradcheck import gradcheck

    rows = gradcheck(grad_scene(), ["sky.emission"], spp=32, max_depth=3, seed=7, integrator=integrator, max_components=12)
    assert len(rows) == 12 and min(abs(r.fd) for r in rows) > 0.1
    worst = max(max(r.rel_errors.values()) for r in rows)
    assert worst < 0.02, format(worst, ".3g")


def test_perturbed_sampling_is_what_gradcheck_freezes():
    """Without the frozen density a perturbed texel moves the light samples: the render with the
    perturbed map's own sampling differs from the one sampled by the unperturbed map, which differs
    from the unperturbed render only by the texel's linear term."""
    scene = grad_scene()
    values = scene.params["sky.emission"].detach().clone()
    values[0, 3] *= 3.0
    perturbed = scene.with_params({"sky.emission": values})
    kw = dict(spp=8, max_depth=3, seed=3, progress=False)
    own = ir.render(perturbed, "path", **kw)
    frozen = ir.render(perturbed, "path", sampling_params=dict(scene.params), **kw)
    base = ir.render(scene, "path", **kw)
    assert not torch.allclose(own, frozen, rtol=1e-3, atol=1e-4)
    # linear in the map with sampling fixed: twice the perturbation, twice the change
    values[0, 3] = 5.0 * scene.params["sky.emission"][0, 3]
    twice = ir.render(scene.with_params({"sky.emission": values}), "path", sampling_params=dict(scene.params), **kw)
    torch.testing.assert_close(twice - base, 2.0 * (frozen - base), rtol=1e-3, atol=1e-5)


def test_next_event_estimation_and_escaping_rays_give_the_same_texel_gradients():
    """Two independent estimators of d(sum W I)/dt: path (the map sampled by its density, MIS) and
    random_walk (the map seen by escaping rays only) agree per texel within Monte Carlo error."""
    W = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(4))
    grads = []
    for integrator in ("path", "random_walk"):
        scene = grad_scene()
        t = scene.params["sky.emission"].requires_grad_(True)
        (W * ir.render(scene, integrator, spp=256, max_depth=3, seed=1, progress=False)).sum().backward()
        grads.append(t.grad.clone())
    big = grads[1] > 0.1 * float(grads[1].max())
    assert int(big.sum()) >= 20
    error = float(((grads[0] - grads[1]).abs() / grads[1])[big].max())
    assert error < 0.03, (error, int(big.sum()))


def test_path_records_keep_the_map_per_texel():
    """(The records' own tests: tests/estimators/test_records.py.)"""
    rec = ir.record_paths(grad_scene(), ["sky.emission"], spp=2, max_depth=2, progress=False)
    assert rec.jacobian()["sky.emission"].shape == (16, 16, 5, 8, 3)


# ---------------------------------------------------------------- loading


def test_an_envmap_loads_from_toml_and_xml(tmp_path):
    sky = sky_map()
    write_image(tmp_path / "sky.exr", sky)
    toml = tmp_path / "s.toml"
    toml.write_text(
        '[camera]\norigin = [3, 2.5, 3.5]\n[materials.box]\nreflectance = 0.5\n'
        '[emitters.sky]\ntype = "envmap"\nemission_texture = "sky.exr"\nscale = 2\nto_world = [{ rotate = { axis = [0, 1, 0], angle = 90 } }]\n'
        '[[shapes]]\ntype = "cube"\nmaterial = "box"\n'
    )
    xml = tmp_path / "s.xml"
    xml.write_text(
        '<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="35"/></sensor>'
        '<emitter type="envmap" id="sky"><string name="filename" value="sky.exr"/><float name="scale" value="2"/>'
        '<transform name="to_world"><rotate y="1" angle="90"/></transform></emitter><shape type="cube"/></scene>'
    )
    expected = quaternion_of(rotate([0, 1, 0], 90), "test")
    for path in (toml, xml):
        scene = ir.load_scene(str(path), resolution=(8, 8))
        spec = scene.emitter_spec(0)
        assert spec.type == "envmap" and spec.constants["scale"] == 2.0
        for k, v in expected.items():
            assert spec.constants[k] == pytest.approx(v, abs=1e-6), (path.suffix, k)
        torch.testing.assert_close(scene.params["sky.emission"], sky)
    # Mitsuba's dict of it (bench/mitsuba_ref.py's plugin_dict turns the tensor into a bitmap)
    d = Envmap.to_mitsuba({"emission": sky}, dict(spec.constants))
    assert d["type"] == "envmap" and d["scale"] == 2.0 and d["bitmap"] is sky
    np.testing.assert_allclose(np.asarray(d["to_world"])[:3, :3], rotate([0, 1, 0], 90)[:3, :3], atol=1e-6)


def test_bad_maps_and_rotations_are_one_line_errors(tmp_path):
    def error_of(fn):
        with pytest.raises(ir.InvRenderError) as e:
            fn()
        message = str(e.value)
        assert "\n" not in message
        return message

    def build(emission, **constants):
        return scene_with(Emitter.of("envmap", where="emitter 'sky'", emission=emission, **constants))

    assert "sky.emission: emission eps must be >= 0" in error_of(lambda: build(-sky_map()))
    bad = sky_map()
    bad[0, 0, 0] = float("nan")
    assert "sky.emission" in error_of(lambda: build(bad))
    assert "sky.emission" in error_of(lambda: build(torch.zeros(0, 4, 3)))
    assert "emitter 'sky': the envmap's emission is zero everywhere" in error_of(lambda: build(torch.zeros(4, 8, 3)))
    assert "'scale' must lie in (0, inf)" in error_of(lambda: build(sky_map(), scale=0.0))
    assert "unit quaternion" in error_of(lambda: build(sky_map(), rotation_w=0.5))
    # files: TOML (a scale step is no rotation; a missing map), XML (a scale transform, a zero map)
    write_image(tmp_path / "sky.exr", sky_map())
    write_image(tmp_path / "black.exr", torch.zeros(4, 8, 3))
    head = '[camera]\norigin = [3, 2.5, 3.5]\n[[shapes]]\ntype = "cube"\n[emitters.sky]\ntype = "envmap"\n'
    cases = {
        'emission_texture = "sky.exr"\nto_world = [{ scale = 2 }]\n': "must be a rotation",
        'emission_texture = "nope.exr"\n': "texture file not found",
        'emission_texture = "sky.exr"\nto_world = 5\n': "'to_world' must be a list of steps",
        'emission_texture = "sky.exr"\nto_world = [{ shear = 1 }]\n': "to_world[0]: unknown transform step 'shear'",
        'emission_texture = "black.exr"\n': "zero everywhere",
        'emission_texture = "sky.exr"\nscale = 1e39\n': "'scale' is 1e+39, beyond float32's range (|x| <= 3.403e+38)",
        'emission_texture = "sky.exr"\nscale = 1e38\n': "'scale' 1e+38 times the map's brightest texel",
    }
    for body, match in cases.items():
        p = tmp_path / "bad.toml"
        p.write_text(head + body)
        message = error_of(lambda: ir.load_scene(str(p)))
        assert match in message and "bad.toml" in message and "emitters.sky" in message, message
    xml_cases = {
        '<string name="filename" value="sky.exr"/><transform name="to_world"><scale value="2"/></transform>': "must be a rotation",
        '<string name="filename" value="black.exr"/>': "black.exr: the map is zero everywhere",
        '<string name="filename" value="nope.exr"/>': "file not found",
        '<string name="filename" value="sky.exr"/><float name="scale" value="-1"/>': "'scale' (the radiance's scale factor) must lie in (0, inf)",
        '<string name="filename" value="sky.exr"/><float name="scale" value="1e39"/>': "'scale' (the radiance's scale factor) is 1e+39, beyond float32's range",
    }
    for body, match in xml_cases.items():
        p = tmp_path / "bad.xml"
        p.write_text(f'<scene version="3.0.0"><emitter type="envmap" id="sky">{body}</emitter><shape type="cube"/></scene>')
        message = error_of(lambda: ir.load_scene(str(p)))
        assert match in message and "bad.xml" in message, message


def test_a_radiance_hdr_map_loads(tmp_path):
    cv2 = pytest.importorskip("cv2")
    sky = sky_map()
    cv2.imwrite(str(tmp_path / "sky.hdr"), np.ascontiguousarray(sky.numpy()[..., ::-1]))  # OpenCV writes BGR
    (tmp_path / "s.toml").write_text('[camera]\norigin = [3, 2.5, 3.5]\n[emitters.sky]\ntype = "envmap"\nemission_texture = "sky.hdr"\n[materials.box]\nreflectance = 0.5\n[[shapes]]\ntype = "cube"\nmaterial = "box"\n')
    loaded = ir.load_scene(str(tmp_path / "s.toml")).params["sky.emission"]
    error = (loaded - sky).abs() / sky.amax(-1, keepdim=True)  # RGBE: 8-bit mantissas under the pixel's shared exponent
    assert float(error.max()) < 1e-2
    (tmp_path / "bad.hdr").write_bytes(b"#?RADIANCE\nnot an image")
    (tmp_path / "s.toml").write_text((tmp_path / "s.toml").read_text().replace("sky.hdr", "bad.hdr"))
    with pytest.raises(ir.SceneError, match=r"emitters.sky\]: cannot read image .*bad.hdr: not a valid HDR \(Radiance RGBE\) file$"):
        ir.load_scene(str(tmp_path / "s.toml"))


def test_cli_a_scale_beyond_float32_is_refused_before_rendering(tmp_path):
    """``invrender render`` of a scene whose envmap scale is 1e39: one line naming the file, the
    key and the value, exit 2, no image written (it used to render, then fail at the write)."""
    from tests.conftest import refused

    write_image(tmp_path / "sky.exr", sky_map())
    scene = tmp_path / "bright.toml"
    scene.write_text('[camera]\norigin = [3, 2.5, 3.5]\n[[shapes]]\ntype = "cube"\n[emitters.sky]\ntype = "envmap"\nemission_texture = "sky.exr"\nscale = 1e39\n')
    line = refused(tmp_path, "render", str(scene), "--spp", "1", "--resolution", "8x8", out="out/image.exr")
    assert line == f"invrender: error: {scene} [emitters.sky]: 'scale' is 1e+39, beyond float32's range (|x| <= 3.403e+38): a render would compute with infinity"
