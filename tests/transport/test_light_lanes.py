"""Emitters in lane form (:class:`~invrender.core.lights.LightLanes`): ``envmap``, ``point``, ``spot``
(with and without a projected image), ``projector`` and ``directional`` written once against the
array interface.

- Compiled (Dr.Jit's LLVM backend) and eager torch evaluations of the lane functions agree lane by
  lane: the emitters and texels chosen, and every float to rounding.
- The torch methods (``sample_from``, ``escaped``, ``pdf_escaped``, ``texels``) return what the lane
  functions return: the maths is written once.
- The delta lights' samples are their closed forms (``I / r^2``, Mitsuba's spot falloff, ``E``,
  the choice by power), computed here in float64 without the lane functions.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from invrender.backends import arrays
from invrender.core import compiled
from invrender.core.compiled import TORCH
from invrender.plugins.emitters import delta, envmap
from invrender.plugins.emitters.directional import Directional
from invrender.plugins.emitters.envmap import Envmap, quaternion_of
from invrender.plugins.emitters.point import Point
from invrender.plugins.emitters.projector import Projector
from invrender.plugins.emitters.spot import Spot
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, cube, rotate

N = 20000
OFFSET = 1e-3


@pytest.fixture(scope="module")
def triangles():
    scene = build_scene([Mesh(*cube(), material="box")], {"box": 0.5}, {"sky": Emitter.of("constant", emission=1.0)}, Camera(origin=(3, 2, 3), target=(0, 0, 0), up=(0, 1, 0), fov=35.0), (8, 8))
    return scene.triangles


def drjit():
    xp = arrays.drjit_arrays(torch.device("cpu"))
    if xp is None:
        pytest.skip("Dr.Jit's LLVM backend is unavailable")
    return xp


def unit(v) -> list[float]:
    a = np.asarray(v, dtype=np.float64)
    return (a / np.linalg.norm(a)).tolist()


def lanes_inputs(seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(N, 3, generator=g)
    x = 2.0 * torch.rand(N, 3, generator=g) - 1.0
    nx = torch.nn.functional.normalize(torch.randn(N, 3, generator=g), dim=1)
    return u, x, nx


def point_light(triangles):
    values = [{"emission": torch.tensor(v)} for v in ([1.0, 2.0, 3.0], [5.0, 0.5, 0.5], [0.2, 0.2, 0.2])]
    constants = [{"position": p} for p in ([0.0, 2.0, 0.0], [1.5, -0.5, 2.0], [-3.0, 0.0, 0.0])]
    return Point([0, 1, 2], values, constants, triangles)


def spot_light(triangles):
    values = [{"emission": torch.tensor(v)} for v in ([4.0, 3.0, 2.0], [1.0, 1.0, 6.0])]
    constants = [
        {"position": [0.0, 2.0, 0.0], "direction": unit([0.1, -1.0, 0.2]), "cutoff_angle": 25.0, "beam_width": 10.0},  # a falloff ramp
        {"position": [2.0, 0.5, -1.0], "direction": unit([-1.0, -0.2, 0.4]), "cutoff_angle": 35.0, "beam_width": 35.0},  # none
    ]
    return Spot([0, 1], values, constants, triangles)


def directional_light(triangles):
    values = [{"emission": torch.tensor(v)} for v in ([3.0, 3.0, 3.0], [0.5, 1.0, 0.25])]
    constants = [{"direction": unit(d)} for d in ([0.2, -1.0, 0.1], [-1.0, -0.3, 0.5])]
    return Directional([0, 1], values, constants, triangles)


def envmap_light(triangles):
    g = torch.Generator().manual_seed(3)
    sky = 0.2 + torch.rand(9, 16, 3, generator=g)
    sky[2, 5] = torch.tensor([40.0, 30.0, 20.0])  # a sun
    maps = [sky, 0.1 + torch.rand(5, 7, 3, generator=g), 0.3 + torch.rand(2, 1, 3, generator=g), torch.tensor([0.5, 0.7, 0.2])]
    constants = [
        {"scale": 1.0},
        {"scale": 2.0, **quaternion_of(rotate([0.3, 1.0, -0.2], 50.0), "test")},  # rotated, small and not square
        {"scale": 0.5, **quaternion_of(rotate([1.0, 0.0, 0.0], 90.0), "test")},  # padded to 3 x 2
        {"scale": 1.0},  # an RGB value: a 1 x 1 map
    ]
    return Envmap([0, 1, 2, 3], [{"emission": m} for m in maps], constants, triangles)


def textured_spot_light(triangles):
    """Two spots projecting images (one through its falloff ramp, one over a wide cone) and one
    without: the instance reads textures, the third emitter none."""
    g = torch.Generator().manual_seed(5)
    values = [{"emission": torch.rand(5, 7, 3, generator=g) * 4}, {"emission": torch.rand(3, 2, 3, generator=g) + 0.1}, {"emission": torch.tensor([1.0, 1.0, 6.0])}]
    constants = [
        {"position": [0.0, 2.0, 0.0], "direction": unit([0.1, -1.0, 0.2]), "up": unit([0.0, 0.2, 1.0]), "cutoff_angle": 25.0, "beam_width": 10.0},
        {"position": [0.5, -2.0, 0.3], "direction": unit([0.0, 1.0, 0.1]), "up": unit([1.0, 0.0, 0.0]), "cutoff_angle": 70.0, "beam_width": 70.0},
        {"position": [2.0, 0.5, -1.0], "direction": unit([-1.0, -0.2, 0.4]), "up": unit([0.0, 1.0, 0.0]), "cutoff_angle": 35.0, "beam_width": 35.0},
    ]
    return Spot([0, 1, 2], values, constants, triangles)


def projector_light(triangles):
    """A projector with an image (wide, through a wide field of view) and one with an RGB value."""
    g = torch.Generator().manual_seed(6)
    values = [{"emission": torch.rand(4, 9, 3, generator=g) + 0.05}, {"emission": torch.tensor([0.5, 1.0, 2.0])}]
    constants = [
        {"position": [0.0, 2.5, 0.5], "direction": unit([0.1, -1.0, -0.2]), "up": unit([0.0, 0.0, 1.0]), "fov": 100.0, "scale": 2.0},
        {"position": [-2.0, 0.0, 0.0], "direction": unit([1.0, 0.1, 0.0]), "up": unit([0.0, 1.0, 0.0]), "fov": 40.0, "scale": 1.0},
    ]
    return Projector([0, 1], values, constants, triangles)


def rgb_projector_light(triangles):
    """Projectors without images: rows of 32 floats (their frames), no texture table."""
    values = [{"emission": torch.tensor([0.5, 1.0, 2.0])}, {"emission": torch.tensor([3.0, 1.0, 1.0])}]
    constants = [
        {"position": [-2.0, 0.0, 0.0], "direction": unit([1.0, 0.1, 0.0]), "up": unit([0.0, 1.0, 0.0]), "fov": 60.0, "scale": 1.0},
        {"position": [0.3, 0.2, 2.0], "direction": unit([0.0, -0.2, -1.0]), "up": unit([1.0, 1.0, 0.0]), "fov": 120.0, "scale": 0.5},
    ]
    return Projector([0, 1], values, constants, triangles)


DELTA = {"point": point_light, "spot": spot_light, "directional": directional_light}
#: delta lights projecting images (their lanes read a texture table), and projectors without
TEXTURED = {"spot_texture": textured_spot_light, "projector": projector_light}
WIDE = {"projector_rgb": rgb_projector_light}


def close_lanes(a: torch.Tensor, b: torch.Tensor, rtol: float, atol: float) -> torch.Tensor:
    """(N,) bool: lanes where a and b agree (rows of a 2-D result all agree; equal infinities agree)."""
    ok = torch.isclose(a.double(), b.double(), rtol=rtol, atol=atol) | ((a == b) & torch.isinf(a))
    return ok.all(1) if ok.ndim == 2 else ok


def assert_agree(eager, compiled_, rtol=1e-5, atol=1e-6, share=1.0):
    """Per output, compiled and eager agree (Bool and UInt outputs exactly) on at least ``share``
    of the lanes."""
    for i, (a, b) in enumerate(zip(eager, compiled_)):
        assert a.shape == b.shape, (i, a.shape, b.shape)
        if a.dtype in (torch.bool, torch.int32, torch.int64):
            same = (a.long() == b.long()) if a.ndim == 1 else (a.long() == b.long()).all(1)
        else:
            assert bool(torch.isfinite(b).all()) or bool((torch.isfinite(b) | torch.isinf(a)).all()), i
            same = close_lanes(a, b, rtol, atol)
        assert float(same.float().mean()) >= share, (i, float(same.float().mean()))


# ---------------------------------------------------------------- delta lights


@pytest.mark.parametrize("kind", sorted(DELTA) + sorted(TEXTURED) + sorted(WIDE))
def test_delta_lanes_compiled_equal_eager_and_the_torch_method(kind, triangles):
    light = {**DELTA, **TEXTURED, **WIDE}[kind](triangles)
    ll = light.lanes()
    assert ll.delta and ll.escaped is None and ll.hit is None
    assert light.textured == (kind in TEXTURED) and len(ll.tables) == (4 if kind in TEXTURED else 2)
    assert light.width == (delta.ROW if kind in DELTA else delta.TEXTURED_ROW)
    u, x, nx = lanes_inputs()
    static = light._static
    args = (*light.lane_tables[:2], u[:, 0], x, nx, OFFSET)
    eager = compiled.evaluate(TORCH, delta.delta_geometry, *args, **static)
    jit = compiled.evaluate(drjit(), delta.delta_geometry, *args, **static)
    assert_agree(eager[:1], jit[:1], share=0.999)  # the emitters chosen
    same = eager[0].long() == jit[0].long()
    assert_agree([o[same] for o in eager], [o[same] for o in jit])
    # LightLanes.sample, both ways, and the torch method
    sample = lambda xp, t, *a: ll.sample(xp, t, *a)  # noqa: E731
    lane_args = (ll.tables, u[:, 0], u[:, 1], u[:, 2], x, nx, OFFSET)
    a, b = compiled.evaluate(TORCH, sample, *lane_args), compiled.evaluate(drjit(), sample, *lane_args)
    assert_agree([o[same] for o in a], [o[same] for o in b])
    ls = light.sample_from(u, x, nx, OFFSET)  # in the namespace compiled.run picks
    for got, want in zip((ls.o, ls.wl, ls.tmax, ls.Le, ls.pdf, ls.facing), compiled.evaluate(compiled.namespace(x.device), sample, *lane_args)):
        torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-7)
    assert bool(ls.delta.all())
    lit = ls.Le.amax(1) > 0
    assert float(lit.float().mean()) > 0.1 and bool(torch.isfinite(ls.Le).all()), float(lit.float().mean())


@pytest.mark.parametrize("kind", sorted(DELTA))
def test_delta_samples_are_the_closed_forms(kind, triangles):
    """The choice by power, the shadow ray and Le from the emitters' numbers in float64."""
    light = DELTA[kind](triangles)
    u, x, nx = lanes_inputs(1)
    ls = light.sample_from(u, x, nx, OFFSET)
    I = np.array([v["emission"].numpy() for v in light.values], dtype=np.float64)
    c = light.constants
    if kind == "point":
        power = 4.0 * I.mean(1)
    elif kind == "spot":
        sr = [2 * math.pi * (1 - math.cos(math.radians(k["cutoff_angle"]))) if k["beam_width"] == k["cutoff_angle"] else
              2 * math.pi * (1 + (math.sin(math.radians(k["beam_width"])) - math.sin(math.radians(k["cutoff_angle"]))) / math.radians(k["cutoff_angle"] - k["beam_width"])) for k in c]  # fmt: skip
        power = I.mean(1) * np.array(sr) / math.pi
    else:
        power = I.mean(1)  # the same scene radius for both
    cdf = np.cumsum(power) / power.sum()
    k = np.minimum(np.searchsorted(cdf, u[:, 0].numpy().astype(np.float64), side="right"), len(c) - 1)
    o = x.double().numpy() + OFFSET * nx.double().numpy()
    np.testing.assert_allclose(ls.pdf.numpy(), (power / power.sum())[k], rtol=1e-6)
    np.testing.assert_allclose(ls.o.numpy(), o, rtol=1e-6, atol=1e-6)
    if kind == "directional":
        wl = -np.array([k_["direction"] for k_ in c])[k]
        Le = I[k]
        np.testing.assert_allclose(ls.wl.numpy(), wl, atol=1e-6)
        assert bool(torch.isinf(ls.tmax).all())
    else:
        d = np.array([k_["position"] for k_ in c])[k] - o
        r = np.linalg.norm(d, axis=1)
        wl = d / r[:, None]
        Le = I[k] / (r * r)[:, None]
        if kind == "spot":
            axis = np.array([k_["direction"] for k_ in c])[k]
            theta = np.arccos(np.clip(-(wl * axis).sum(1), -1, 1))
            cut, beam = np.radians([k_["cutoff_angle"] for k_ in c])[k], np.radians([k_["beam_width"] for k_ in c])[k]
            f = np.where(theta <= beam, 1.0, np.where(theta < cut, (cut - theta) / np.maximum(cut - beam, 1e-30), 0.0))
            Le = Le * f[:, None]
            edge = (np.abs(theta - cut) < 1e-4) | (np.abs(theta - beam) < 1e-4)  # float32 may fall either side
            assert 0.2 < float((f > 0).mean()) < 0.9 and float(((f > 0) & (f < 1)).mean()) > 0.05
            wl, Le, got_wl, got_Le = wl[~edge], Le[~edge], ls.wl.numpy()[~edge], ls.Le.numpy()[~edge]
        else:
            got_wl, got_Le = ls.wl.numpy(), ls.Le.numpy()
        np.testing.assert_allclose(got_wl, wl, atol=1e-5)
        np.testing.assert_allclose(got_Le, Le, rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(ls.tmax.numpy(), r - OFFSET, rtol=1e-5)
    facing = (nx.double().numpy() * (-np.array([k_["direction"] for k_ in c])[k] if kind == "directional" else ls.wl.double().numpy())).sum(1) > 0
    if kind == "spot":
        facing &= ls.Le.numpy().max(1) > 0
    assert float((ls.facing.numpy() != facing).mean()) < 1e-3


# ---------------------------------------------------------------- envmap


def test_envmap_escaped_compiled_equals_eager_and_the_torch_methods(triangles):
    light = envmap_light(triangles)
    ll = light.lanes()
    assert not ll.delta and ll.hit is None
    _, _, d = lanes_inputs(2)
    d[:6] = torch.tensor([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])  # poles and seams
    which = tuple(range(4))
    eager = compiled.evaluate(TORCH, envmap.envmap_filters, light.lane_tables[1], d, which=which)
    jit = compiled.evaluate(drjit(), envmap.envmap_filters, light.lane_tables[1], d, which=which)
    index = lambda out: torch.stack([o for k in which for o in out[8 * k : 8 * k + 4]], dim=1)  # noqa: E731
    same = (index(eager).long() == index(jit).long()).all(1)
    assert float(same.float().mean()) >= 0.999
    assert_agree([o[same] for o in eager], [o[same] for o in jit], rtol=1e-5, atol=1e-5)
    escaped = lambda xp, t, d: ll.escaped(xp, t, d)  # noqa: E731
    (Le, pdf), (Le_j, pdf_j) = compiled.evaluate(TORCH, escaped, ll.tables, d), compiled.evaluate(drjit(), escaped, ll.tables, d)
    assert_agree((Le, pdf), (Le_j, pdf_j), rtol=1e-5, atol=1e-6, share=0.999)
    assert bool(torch.isfinite(Le).all() and torch.isfinite(pdf).all() and (pdf > 0).all())
    Le, pdf = compiled.evaluate(compiled.namespace(d.device), escaped, ll.tables, d)  # the namespace compiled.run picks
    torch.testing.assert_close(light.escaped(d), Le, rtol=1e-6, atol=1e-7)
    torch.testing.assert_close(light.pdf_escaped(d), pdf, rtol=1e-6, atol=0.0)
    # texels: indices into each map's own (unpadded) texels; reading them gives the radiance
    total = torch.zeros_like(Le)
    for k, v in enumerate(light.values):
        i, w = light.texels(k, d)
        e = v["emission"]
        assert int(i.max()) < (e.numel() // 3) and torch.allclose(w.sum(1), torch.ones(len(d)))
        total += (e.reshape(-1, 3)[i] * w[:, :, None]).sum(1) * light.scale[k]
    torch.testing.assert_close(total, Le, rtol=1e-5, atol=1e-6)


def test_envmap_sample_compiled_equals_eager_and_the_torch_method(triangles):
    light = envmap_light(triangles)
    ll = light.lanes()
    u, x, nx = lanes_inputs(3)
    sample = lambda xp, t, *a: ll.sample(xp, t, *a)  # noqa: E731
    args = (ll.tables, u[:, 0], u[:, 1], u[:, 2], x, nx, OFFSET)
    eager, jit = compiled.evaluate(TORCH, sample, *args), compiled.evaluate(drjit(), sample, *args)
    assert_agree(eager, jit, rtol=1e-5, atol=1e-5, share=0.999)
    o, wl, tmax, Le, pdf, facing = eager
    assert bool(torch.isfinite(wl).all() and torch.isfinite(Le).all() and (pdf > 0).all() and torch.isinf(tmax).all())
    torch.testing.assert_close(wl.norm(dim=1), torch.ones(N), rtol=1e-5, atol=0.0)
    # every map is sampled, by its probability
    k = torch.searchsorted(light._cdf, u[:, 0].contiguous(), right=True).clamp_max(3)
    assert torch.equal(torch.bincount(k, minlength=4) > 0, torch.tensor([p > 0 for p in light.choice]))
    ls = light.sample_from(u, x, nx, OFFSET)  # in the namespace compiled.run picks
    for got, want in zip((ls.o, ls.wl, ls.tmax, ls.Le, ls.pdf, ls.facing), compiled.evaluate(compiled.namespace(x.device), sample, *args)):
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
    # the samples carry the radiance and density of their directions
    torch.testing.assert_close(light.escaped(wl), Le, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(light.pdf_escaped(wl), pdf, rtol=1e-6, atol=0.0)


def test_envmap_radiance_stays_differentiable(triangles):
    light = envmap_light(triangles)
    for v in light.values:
        v["emission"].requires_grad_(True)
    u, x, nx = lanes_inputs(4)
    ls = light.sample_from(u[:500], x[:500], nx[:500], OFFSET)
    (ls.Le.sum() + light.escaped(ls.wl).sum()).backward()
    # the radiance is linear in the maps: sum_t t dL/dt = L
    total = sum(float((v["emission"].grad * v["emission"].detach()).sum()) for v in light.values)
    assert total == pytest.approx(2 * float(ls.Le.detach().sum()), rel=1e-5)
