"""Mirrors, glass and the thin lens against closed forms (docs/closed_forms.md#mirror, #fresnel).

- A mirror shows an emitter at its reflected position with radiance ``k_s eps``.
- A glass slab at normal incidence reflects ``F = ((n - 1)/(n + 1))^2`` off its front face
  (max_depth 2) and ``2F / (1 + F)`` with all its internal reflections.
- A thin lens renders the plane of focus as the pinhole does, and blurs what lies off it.
"""

from __future__ import annotations

import math

import pytest
import torch

import invrender as ir
from invrender.scene.camera import Camera
from invrender.scene.materials import Material
from invrender.scene.scene import build_scene
from invrender.scene.shapes import primitive, rotate, scale, translate

LE = (4.0, 2.0, 1.0)
KS = (0.9, 0.6, 0.3)


def mirror_scene(resolution=(48, 48)):
    """A 2 x 2 mirror at the origin tilted to face (0, 1, 1)/sqrt(2); a 0.6 x 0.6 emitter at y = 2
    facing down; the camera on +z looking down -z sees the emitter only in the mirror."""
    shapes = [
        primitive("rectangle", "mirror").transformed(rotate([1, 0, 0], -45)),
        primitive("rectangle", "black", "lamp").transformed(translate([0, 2, 0]) @ rotate([1, 0, 0], 90) @ scale(0.3)),
    ]
    camera = Camera(origin=(0, 0, 3), target=(0, 0, 0), up=(0, 1, 0), fov=40)
    materials = {"mirror": Material.of("mirror", specular_reflectance=KS), "black": 0.0}
    return build_scene(shapes, materials, {"lamp": LE}, camera, resolution, name="mirror")


def expected_mirror_coverage(scene, sub: int = 4) -> torch.Tensor:
    """Fraction (H, W) of each pixel whose reflected ray hits the emitter, computed here by hand:
    ray -> plane of the mirror -> reflect -> plane y = 2 -> inside the emitter square."""
    w, h = scene.resolution
    fy, fx = torch.meshgrid((torch.arange(h * sub) + 0.5) / sub, (torch.arange(w * sub) + 0.5) / sub, indexing="ij")
    xy = torch.stack([fx.reshape(-1), fy.reshape(-1)], 1)
    o, d = scene.camera.generate_rays(xy, w, h)
    n = torch.tensor([0.0, 1.0, 1.0]) / math.sqrt(2)
    t = -(o @ n) / (d @ n)
    p = o + t[:, None] * d
    on_mirror = (p[:, 0].abs() <= 1) & ((p[:, 1] ** 2 + p[:, 2] ** 2).sqrt() <= 1)
    r = d - 2 * (d @ n)[:, None] * n
    t2 = (2 - p[:, 1]) / r[:, 1]
    q = p + t2[:, None] * r
    hit = on_mirror & (r[:, 1] > 0) & (q[:, 0].abs() < 0.3) & (q[:, 2].abs() < 0.3)
    return hit.float().reshape(h, sub, w, sub).mean((1, 3))


@pytest.mark.parametrize("integrator", ["path", "whitted", "distributed"])
def test_mirror_shows_the_emitter_times_specular_reflectance(integrator):
    scene = mirror_scene()
    img = ir.render(scene, integrator, spp=16, max_depth=3, seed=1, progress=False)
    cover = expected_mirror_coverage(scene)
    # pixels well inside (they and their neighbours fully covered) and well outside the image
    pad = torch.nn.functional.pad(cover[None, None], (1, 1, 1, 1), value=0.5)[0, 0]
    around = torch.stack([pad[1:-1, 1:-1], pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    inside, outside = (around == 1).all(0), (around == 0).all(0)
    assert inside.sum() > 30 and outside.sum() > 1000
    target = torch.tensor(LE) * torch.tensor(KS)
    torch.testing.assert_close(img[inside], target.expand(int(inside.sum()), 3), rtol=1e-5, atol=1e-5)
    assert float(img[outside].abs().max()) == 0.0
    # the image of the emitter sits where the mirror puts it (centroid within a tenth of a pixel)
    ys, xs = torch.meshgrid(torch.arange(48.0), torch.arange(48.0), indexing="ij")
    lum = img.mean(2)
    for grid, c in ((xs, cover), (ys, cover)):
        assert abs(float((grid * lum).sum() / lum.sum()) - float((grid * c).sum() / c.sum())) < 0.1


def slab_scene(ior=1.5, resolution=(16, 16)):
    """A wide glass slab (z in [-2, 0]) seen at near-normal incidence (fov 4 degrees) from z = 3,
    a wide emitter at z = 4 behind the camera facing the slab; nothing else."""
    shapes = [
        primitive("cube", "glass").transformed(translate([0, 0, -1]) @ scale([50, 50, 1])),
        primitive("rectangle", "black", "lamp").transformed(translate([0, 0, 4]) @ rotate([1, 0, 0], 180) @ scale(20)),
    ]
    camera = Camera(origin=(0, 0, 3), target=(0, 0, 0), up=(0, 1, 0), fov=4)
    materials = {"glass": Material.of("dielectric", ior=ior), "black": 0.0}
    return build_scene(shapes, materials, {"lamp": LE}, camera, resolution, name="slab")


def fresnel_at_pixels(scene, ior):
    """Exact Fresnel reflectance at each pixel centre's incidence angle (tiny, but counted)."""
    w, h = scene.resolution
    fy, fx = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(w) + 0.5, indexing="ij")
    _, d = scene.camera.generate_rays(torch.stack([fx.reshape(-1), fy.reshape(-1)], 1), w, h)
    ci = d[:, 2].abs().double()
    ct = (1 - (1 - ci * ci) / ior**2).sqrt()
    rs = (ci - ior * ct) / (ci + ior * ct)
    rp = (ior * ci - ct) / (ior * ci + ct)
    return (0.5 * (rs * rs + rp * rp)).reshape(h, w)


@pytest.mark.parametrize("ior", [1.5, 1.33])
def test_slab_front_reflectance_is_fresnel_at_normal_incidence(ior):
    scene = slab_scene(ior)
    F0 = ((ior - 1) / (ior + 1)) ** 2
    F = fresnel_at_pixels(scene, ior)
    assert float((F - F0).abs().max()) < 2e-5  # the view is close enough to normal incidence
    # Whitted splits deterministically: every pixel is exactly F Le
    img = ir.render(scene, "whitted", spp=4, max_depth=2, progress=False)
    torch.testing.assert_close(img.double(), (F[..., None] * torch.tensor(LE, dtype=torch.float64)).expand_as(img), rtol=1e-4, atol=1e-6)
    # the path tracer picks reflection with probability F: F Le in the mean
    img = ir.render(scene, "path", spp=1024, max_depth=2, progress=False)
    est = img.double().mean((0, 1)) / torch.tensor(LE, dtype=torch.float64)
    se = math.sqrt(F0 * (1 - F0) / (16 * 16 * 1024))
    assert float((est - F0).abs().max()) < 4 * se


def test_slab_with_internal_reflections_reflects_2F_over_1_plus_F():
    """All the light bouncing inside the slab and leaving through the front: F + (1-F)^2 F / (1 - F^2)."""
    scene = slab_scene(1.5)
    F = float(fresnel_at_pixels(scene, 1.5).mean())
    img = ir.render(scene, "whitted", spp=1, max_depth=30, progress=False)
    total = float(img.double().mean() / (sum(LE) / 3))
    assert abs(total - 2 * F / (1 + F)) < 2e-4 * total
    # path tracer, unbounded with roulette: the same in the mean
    img = ir.render(scene, "path", spp=512, max_depth=-1, progress=False)
    est = img.double().mean((0, 1)) / torch.tensor(LE, dtype=torch.float64)
    assert float((est - 2 * F / (1 + F)).abs().max()) < 0.05 * 2 * F / (1 + F)


def lens_scene(aperture, focus, plane_z=0.0):
    """An emitting checkerboard plane (texture) at z = plane_z facing a camera on +z at z = 3."""
    checker = torch.zeros(8, 8, 3)
    checker[(torch.arange(8)[:, None] + torch.arange(8)[None, :]) % 2 == 0] = 1.0
    shapes = [primitive("rectangle", "black", "board").transformed(translate([0, 0, plane_z]))]
    camera = Camera(origin=(0, 0, 3), target=(0, 0, 0), up=(0, 1, 0), fov=30, aperture_radius=aperture, focus_distance=focus)
    return build_scene(shapes, {"black": 0.0}, {"board": checker}, camera, (32, 32), name="lens")


def test_thin_lens_focus_plane_is_sharp_and_off_plane_blurs():
    pinhole = ir.render(lens_scene(0.0, 3.0), spp=16, max_depth=1, progress=False)
    # aperture 0 is the pinhole
    torch.testing.assert_close(ir.render(lens_scene(0.0, 1.0), spp=16, max_depth=1, progress=False), pinhole)
    # the board lies on the plane of focus: every lens point sees the same board point per sample
    focused = ir.render(lens_scene(0.3, 3.0), spp=16, max_depth=1, progress=False)
    torch.testing.assert_close(focused, pinhole, atol=2e-3, rtol=0)
    # focused elsewhere, edges blur: the image loses contrast, keeps (most of) its mean
    blurred = ir.render(lens_scene(0.3, 1.5), spp=64, max_depth=1, progress=False)
    assert float((blurred - pinhole).abs().mean()) > 0.1
    assert float(blurred.std()) < 0.8 * float(pinhole.std())
    assert abs(float(blurred.mean()) - float(pinhole.mean())) < 0.05 * float(pinhole.mean())


def test_thin_lens_is_used_by_every_integrator():
    scene = lens_scene(0.3, 1.5)
    ref = ir.render(scene, "path", spp=4, max_depth=1, progress=False)
    for name in ("random_walk", "utah", "whitted", "distributed"):
        torch.testing.assert_close(ir.render(scene, name, spp=4, max_depth=1, progress=False), ref)


def test_backends_agree_through_mirrors_glass_and_glossy():
    """Embree and the brute-force torch backend trace the same specular paths (same seed)."""
    scene = ir.load_scene("cornell_specular", resolution=(16, 16), subdivisions=2)
    a = ir.render(scene, spp=8, max_depth=6, backend="embree", progress=False)
    b = ir.render(scene, spp=8, max_depth=6, backend="torch", progress=False)
    assert float((a - b).abs().mean()) < 1e-5 * float(a.mean())
