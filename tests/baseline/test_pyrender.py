"""The pyrender baseline against the path tracer's direct illumination and against hand-derived values.

pyrender's shading is not Lambertian (``mesh.frag``: diffuse ``0.96 (1 - F) rho / pi`` plus a GGX
specular lobe at roughness 1), so per-pixel comparisons divide pyrender's image by the documented
ratio ``pyrender_brdf_cos / (rho / pi cos)`` computed from each pixel's floor point.
"""

import math

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.baseline import emitter_lights, pyrender_brdf_cos, pyrender_render
from invrender.scene.camera import Camera
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, rectangle, rotate, scale, translate

RHO = (0.8, 0.5, 0.3)
EPS = 40.0
HEIGHT = 1.0
CAMERA = Camera(origin=(0.0, -1.6, 1.6), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov=45.0)


def quad(material, emitter=None, size=1.0, at=(0.0, 0.0, 0.0), facing_down=False):
    """A square of side ``2 size`` centred at ``at``, facing +z (or -z)."""
    v, f, uv = rectangle()
    m = translate(at) @ (rotate([1, 0, 0], 180) if facing_down else np.eye(4)) @ scale(size)
    return Mesh(v, f, uv, material, emitter).transformed(m)


def floor_scene(resolution=(48, 32), extra=(), reflectance=None, emission=None, camera=CAMERA):
    """Diffuse floor [-1, 1]^2 under a 0.1 x 0.1 emitter at height 1 facing down."""
    meshes = [quad("floor"), quad("lamp", "light", size=0.05, at=(0.0, 0.0, HEIGHT), facing_down=True), *extra]
    refl = {"floor": RHO, "lamp": (0.5, 0.5, 0.5), **(reflectance or {})}
    return build_scene(meshes, refl, emission or {"light": (EPS, EPS, EPS)}, camera, resolution)


def pixel_rays(scene):
    """Rays through pixel centres: origins and directions (H * W, 3)."""
    ys, xs = torch.meshgrid(torch.arange(scene.height), torch.arange(scene.width), indexing="ij")
    xy = torch.stack([xs.reshape(-1) + 0.5, ys.reshape(-1) + 0.5], 1).float()
    return scene.camera.generate_rays(xy, scene.width, scene.height)


def hit_plane(o, d, z, half):
    """Distance (N,) to the square |x|, |y| <= half in the plane at height z (inf when missed)."""
    t = (z - o[:, 2]) / d[:, 2]
    x = o + t[:, None] * d
    ok = (t > 0) & (x[:, 0].abs() <= half) & (x[:, 1].abs() <= half)
    return torch.where(ok, t, torch.full_like(t, math.inf))


def specular_ratio(scene, o, d, t, z):
    """(H, W, 3) pyrender shading / Lambertian shading at the hit points (plane at height z, normal +z)."""
    x = o + t[:, None] * d
    n = torch.tensor([0.0, 0.0, 1.0]).expand_as(x)
    wi = torch.tensor([0.0, 0.0, HEIGHT]) - x
    wi = wi / wi.norm(dim=1, keepdim=True)
    rho = torch.tensor(RHO).expand_as(x)
    ratio = pyrender_brdf_cos(rho, n, wi, -d) / (rho / math.pi * wi[:, 2:3])
    return ratio.reshape(scene.height, scene.width, 3)


def relative_difference(baseline, reference, mask):
    rel = (baseline - reference).abs() / reference.clamp_min(1e-12)
    return rel[mask.unsqueeze(-1).expand_as(rel)]


def test_direct_light_agrees_with_path_tracer():
    scene = floor_scene()
    img = pyrender_render(scene)
    ref = ir.render(scene, integrator="path", max_depth=2, spp=64, seed=0, progress=False)
    assert img.shape == (32, 48, 3) and img.dtype == torch.float32
    o, d = pixel_rays(scene)
    t = hit_plane(o, d, 0.0, 1.0)
    corrected = img / specular_ratio(scene, o, d, t, 0.0)
    x = o + t.clamp_max(1e3)[:, None] * d
    # pixels wholly on the floor (away from its edges) and not behind the lamp
    floor = (x[:, :2].abs().max(1).values < 0.9) & ~torch.isfinite(hit_plane(o, d, HEIGHT, 0.08))
    mask = floor.reshape(32, 48) & (ref.mean(-1) > 0.05 * ref.mean(-1).max())
    assert int(mask.sum()) > 600
    rel = relative_difference(corrected, ref, mask)
    assert float(rel.max()) < 0.05, f"max {float(rel.max()):.4f} mean {float(rel.mean()):.4f}"
    assert float(rel.mean()) < 0.015
    # the analytic value at the floor point below the lamp: rho / pi * eps * A / h^2
    centre = ref.new_tensor(RHO) / math.pi * EPS * 0.01 / HEIGHT**2
    assert float(corrected[mask].max(0).values.sub(centre).abs().max()) < 0.03 * float(centre.max())


def test_shadows_of_an_occluder():
    blocker = quad("blocker", size=0.15, at=(0.0, 0.0, 0.5))
    scene = floor_scene(extra=[blocker], reflectance={"blocker": (0.2, 0.2, 0.2)})
    img = pyrender_render(scene)
    ref = ir.render(scene, integrator="path", max_depth=2, spp=64, seed=0, progress=False)
    o, d = pixel_rays(scene)
    t_floor, t_block = hit_plane(o, d, 0.0, 1.0), hit_plane(o, d, 0.5, 0.15)
    on_floor = t_floor < t_block
    x = o + t_floor.clamp_max(1e3)[:, None] * d
    r = x[:, :2].abs().max(1).values
    umbra = (on_floor & (r < 0.2)).reshape(32, 48)  # the 0.3 wide blocker at half height: shadow 0.6 wide
    clear = ~torch.isfinite(hit_plane(o, d, 0.5, 0.2)) & ~torch.isfinite(hit_plane(o, d, HEIGHT, 0.08))  # not near their silhouettes
    open_floor = (clear & (r > 0.45) & (r < 0.9)).reshape(32, 48)
    assert int(umbra.sum()) > 5 and int(open_floor.sum()) > 200
    peak = float(ref.max())
    assert float(img[umbra].max()) < 0.01 * peak and float(ref[umbra].max()) < 0.01 * peak
    corrected = img / specular_ratio(scene, o, d, t_floor, 0.0)
    rel = relative_difference(corrected, ref, open_floor & (ref.mean(-1) > 0.05 * ref.mean(-1).max()))
    assert float(rel.max()) < 0.05


def test_orientation_and_non_square_film():
    # red patch on the +x side (the camera's right), green patch at +y (far away: the top rows)
    red = quad("red", size=0.2, at=(0.6, 0.0, 0.001))
    green = quad("green", size=0.2, at=(0.0, 0.6, 0.001))
    scene = floor_scene(resolution=(24, 36), extra=[red, green], reflectance={"red": (0.9, 0.0, 0.0), "green": (0.0, 0.9, 0.0), "floor": (0.1, 0.1, 0.1)})
    img = pyrender_render(scene)
    ref = ir.render(scene, integrator="path", max_depth=2, spp=16, seed=0, progress=False)
    assert img.shape == ref.shape == (36, 24, 3)
    for image in (img, ref):
        is_red = (image[..., 0] > 3 * image[..., 1]) & (image[..., 0] > 0.02)
        is_green = (image[..., 1] > 3 * image[..., 0]) & (image[..., 1] > 0.02)
        rows, cols = torch.nonzero(is_red, as_tuple=True)
        assert float(cols.float().mean()) > 24 * 0.6
        rows, cols = torch.nonzero(is_green, as_tuple=True)
        assert float(rows.float().mean()) < 36 * 0.45
    masks = [(im[..., 0] > 3 * im[..., 1]) & (im[..., 0] > 0.02) for im in (img, ref)]
    iou = float((masks[0] & masks[1]).sum()) / float((masks[0] | masks[1]).sum())
    assert iou > 0.8


def test_ambient_only_is_rho_eps0_and_textures_keep_their_orientation():
    # no emitters at all; a 2 x 2 texture: row 0 (top, v = 1) red | green, row 1 blue | white
    quadrants = torch.tensor([[[0.8, 0.1, 0.1], [0.1, 0.8, 0.1]], [[0.1, 0.1, 0.8], [0.5, 0.5, 0.5]]])
    tex = quadrants.repeat_interleave(4, 0).repeat_interleave(4, 1)  # 8 x 8: constant inside each quadrant
    top = Camera(origin=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov=30.0)
    scene = build_scene([quad("floor")], {"floor": tex}, {}, top, (32, 32))
    eps0 = torch.tensor([0.5, 1.0, 2.0])
    img = pyrender_render(scene, ambient=eps0)
    # the camera sees [-0.8, 0.8]^2: the quadrant centres (+-0.5) are at pixels 16 +- 10
    for (row, col), (i, j) in {(6, 6): (0, 0), (6, 25): (0, 1), (25, 6): (1, 0), (25, 25): (1, 1)}.items():
        expected = quadrants[i, j] * eps0
        assert torch.allclose(img[row, col], expected, rtol=0.02), (row, col, img[row, col], expected)
    scene.params["ambient.emission"] = eps0 * 2  # the default ambient comes from the scene
    assert torch.allclose(pyrender_render(scene)[6, 6], 2 * quadrants[0, 0] * eps0, rtol=0.02)
    assert float(pyrender_render(scene, ambient=0.0).abs().max()) == 0.0


def test_emitter_seen_directly_shows_eps_front_side_only():
    below = Camera(origin=(0.0, 0.0, 0.2), target=(0.0, 0.0, 1.0), up=(0.0, 1.0, 0.0), fov=8.0)
    scene = floor_scene(resolution=(16, 16), camera=below)
    img = pyrender_render(scene)
    ref = ir.render(scene, integrator="path", max_depth=1, spp=4, seed=0, progress=False)
    assert torch.allclose(img[6:10, 6:10], torch.full((4, 4, 3), EPS), rtol=1e-3)
    assert torch.allclose(img[6:10, 6:10], ref[6:10, 6:10], rtol=1e-3)
    above = Camera(origin=(0.0, 0.0, 2.0), target=(0.0, 0.0, 1.0), up=(0.0, 1.0, 0.0), fov=8.0)
    back = pyrender_render(scene.with_camera(above))
    assert float(back[6:10, 6:10].max()) < 1e-3 * EPS  # the back of the lamp: not emissive, unlit


def test_light_modes_agree_for_a_small_emitter():
    scene = floor_scene(resolution=(24, 16))
    lights = emitter_lights(scene, "center")
    assert lights.count == 1 and np.allclose(lights.intensity, EPS * 0.01) and np.allclose(lights.normal, [[0, 0, -1]])
    assert emitter_lights(scene, "triangles").count == 2 and np.allclose(emitter_lights(scene, 10).intensity.sum(0), EPS * 0.01)
    centre = pyrender_render(scene)
    for image in (pyrender_render(scene, point_lights="triangles"), pyrender_render(scene, point_lights=12)):  # 12 x 3 spots: two passes
        assert torch.allclose(image, centre, rtol=0.01, atol=1e-3 * float(centre.max()))
    point = pyrender_render(scene, lobe="point")  # isotropic: brighter off-axis by 1 / cos(theta_e)
    assert float(point[8, 12].mean()) == pytest.approx(float(centre[8, 12].mean()), rel=0.2)
    assert float(point.sum()) > float(centre.sum())


@pytest.mark.parametrize(
    "kwargs",
    [dict(point_lights="bogus"), dict(point_lights=0), dict(point_lights=True), dict(lobe="area"), dict(ambient=-1.0), dict(ambient=[1.0, 2.0])],
)
def test_bad_options_are_parameter_errors(kwargs):
    with pytest.raises(ir.ParameterError):
        pyrender_render(floor_scene(resolution=(8, 8)), **kwargs)
