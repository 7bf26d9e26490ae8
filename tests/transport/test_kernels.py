"""The compiled steps of a bounce (the lane functions of invrender.core.lanes and the plugins, run by
Dr.Jit) against their eager torch evaluation and the formulas they stand for: the random numbers
bit for bit, hit and emitter-sample geometry to float rounding, and the same images and gradients
with either; the fused bounce switches off with INVRENDER_KERNELS=torch (or steps), and none of it
needs Warp."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.backends import arrays, kernels
from invrender.backends.accel import make_intersector
from invrender.plugins.emitters.area import Area
from invrender.core.sampler import mirrored, path_keys, uniform
from invrender.core.surface import surface_at

FORWARD = Path(__file__).resolve().parents[2] / "forward"
CPU = torch.device("cpu")


@pytest.fixture
def reference(monkeypatch):
    """A context manager-free switch: call it to run everything as eager torch (the lane functions
    evaluated by torch, the torch bounce)."""

    def use_torch(on: bool = True) -> None:
        monkeypatch.setenv(kernels.ENV, "torch" if on else "warp")
        monkeypatch.setenv(arrays.ENV, "torch" if on else "drjit")

    return use_torch


def test_kernels_run_on_cpu_and_switch_off(reference, monkeypatch):
    assert kernels.fused_bounce(CPU)
    reference()
    assert not kernels.fused_bounce(CPU)
    reference(False)
    assert not kernels.fused_bounce(torch.device("meta"))  # no compiled backend there: torch runs
    monkeypatch.setenv(kernels.ENV, "wrap")
    with pytest.raises(ParameterError, match="INVRENDER_KERNELS must be 'warp', 'steps' or 'torch', got 'wrap'"):
        ir.render(ir.load_scene("cornell_box", resolution=(4, 4)), spp=1, progress=False)


def test_uniforms_equal_bit_for_bit(reference):
    pixel = torch.arange(50_000)
    keys = path_keys(7, pixel, pixel % 13)
    keys = mirrored(keys, pixel % 3 == 0)  # mirrored keys flip every bit of the hash
    for bounce, dims in ((0, 2), (3, 7), (40, 5)):
        fused = uniform(keys, bounce, dims)
        reference()
        expected = uniform(keys, bounce, dims)
        reference(False)
        assert fused.dtype == torch.float32 and fused.shape == (50_000, dims)
        assert torch.equal(fused, expected)
    assert 0.0 <= float(fused.min()) and float(fused.max()) < 1.0
    assert uniform(keys[:0], 1, 3).shape == (0, 3)


def _hits(scene, n=20_000, seed=0):
    g = torch.Generator().manual_seed(seed)
    c = scene.triangles.corners().reshape(-1, 3)
    lo, hi = c.min(0).values, c.max(0).values
    o = (lo + (hi - lo) * (0.05 + 0.9 * torch.rand(n, 3, generator=g))).contiguous()
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=1).contiguous()
    hits = make_intersector(scene.triangles, "embree", 1).intersect(o, d)
    keep = hits.valid
    return hits.select(keep), d[keep]


@pytest.mark.parametrize("name", ["cornell_box", str(FORWARD / "textured_floor.toml"), str(FORWARD / "mesh_in_box.toml")])
def test_hit_geometry_matches_the_reference(name, reference):
    scene = ir.load_scene(name, resolution=(8, 8))
    hits, d = _hits(scene)
    assert len(d) > 5_000
    fused = surface_at(scene.triangles, hits, d, with_uv=True)
    reference()
    expected = surface_at(scene.triangles, hits, d, with_uv=True)
    for field in ("p", "n", "ns", "cos_o", "uv"):
        a, b = getattr(fused, field), getattr(expected, field)
        assert a.shape == b.shape and a.dtype == b.dtype
        assert (a - b).abs().max() < 2e-6 * max(1.0, float(b.abs().max())), field
    assert torch.equal(fused.front, expected.front) and torch.equal(fused.tri, expected.tri)
    assert 0.02 < fused.front.float().mean() < 0.98  # both sides seen: the normal flip is exercised
    t = scene.triangles  # the formulas: p = p0 + u e1 + v e2, n = the front normal facing the ray's origin
    p0, e1, e2 = (getattr(t, k).index_select(0, hits.prim) for k in ("p0", "e1", "e2"))
    assert (fused.p - (p0 + hits.u[:, None] * e1 + hits.v[:, None] * e2)).abs().max() < 1e-5
    assert ((fused.n * d).sum(1) <= 0).all() and torch.allclose(fused.cos_o, -(fused.n * d).sum(1), atol=1e-6)
    untextured = surface_at(scene.triangles, hits, d, with_uv=False)
    assert untextured.uv.shape == (len(d), 2) and not untextured.uv.any()


@pytest.mark.parametrize("name", ["cornell_box", str(FORWARD / "two_lights.toml")])
def test_emitter_samples_match_the_reference(name, reference):
    scene = ir.load_scene(name, resolution=(8, 8))
    hits, d = _hits(scene, seed=1)
    s = surface_at(scene.triangles, hits, d)
    eps = [scene.params[f"{e}.emission"] for e in scene.emitters]
    lights = Area(list(range(len(eps))), [{"emission": e} for e in eps], [{} for _ in eps], scene.triangles)
    lights.textured = True  # uv at the points too
    u = torch.rand(len(d), 3, generator=torch.Generator().manual_seed(2))
    fused = lights.geometry(u, s.p, s.n, 1e-3)
    reference()
    expected = lights.geometry(u, s.p, s.n, 1e-3)
    assert torch.equal(fused.tri, expected.tri)  # the same emitter picked (the cdf search)
    assert len(set(fused.tri.tolist())) == lights.count  # every emissive triangle picked
    assert (fused.facing != expected.facing).float().mean() < 1e-3  # only rounding at cos = 0
    for field in ("uv", "o", "wl", "tmax"):
        a, b = getattr(fused, field), getattr(expected, field)
        assert (a - b).abs().max() < 2e-5 * max(1.0, float(b.abs().max())), field
    rel = (fused.pdf - expected.pdf).abs() / expected.pdf
    assert torch.quantile(rel[fused.facing], 0.999) < 1e-4  # grazing samples are ill-conditioned


@pytest.mark.parametrize("name", ["cornell_box", str(FORWARD / "textured_floor.toml")])
def test_images_and_gradients_agree(name, reference):
    scene = ir.load_scene(name, resolution=(16, 16))
    names = [n for n in scene.params if n.endswith(("reflectance", "emission"))][:3]

    def run():
        params = {n: scene.params[n].clone().requires_grad_(True) for n in names}
        work = dataclasses.replace(scene, params={**scene.params, **params})
        img = ir.render(work, spp=16, seed=3, progress=False, estimator="replay")
        (img**2).sum().backward()
        return img.detach(), [params[n].grad for n in names]

    img, grads = run()
    reference()
    img_ref, grads_ref = run()
    assert (img - img_ref).abs().max() < 1e-4 * float(img_ref.mean())
    for g, g_ref in zip(grads, grads_ref):
        assert (g - g_ref).abs().max() < 1e-3 * float(g_ref.abs().max())


def test_cosine_directions_and_ray_origins_match_the_reference(reference):
    from invrender.plugins.bsdfs.diffuse import Diffuse
    from invrender.core.context import TransportContext

    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    hits, d = _hits(scene, seed=3)
    s = surface_at(scene.triangles, hits, d)
    ctx = TransportContext.build(scene, CPU)
    sp = ctx.shading_point(s, -d)
    u = torch.rand(len(d), 2, generator=torch.Generator().manual_seed(4))
    bsdf = next(b for b in ctx.materials.bsdfs if isinstance(b, Diffuse))
    fused, o_fused, o_through = bsdf.sample(sp, u[:, 0], u), ctx.spawn(s, -d), ctx.spawn(s, d)
    reference()
    expected, o_expected, o_through_expected = bsdf.sample(sp, u[:, 0], u), ctx.spawn(s, -d), ctx.spawn(s, d)
    err = (fused.wi - expected.wi).abs().amax(1)  # normalize(n + s) is ill-conditioned where s ~ -n
    assert torch.quantile(err, 0.999) < 1e-6 and err.max() < 1e-4 and (fused.pdf - expected.pdf).abs().max() < 1e-4
    assert (fused.wi * sp.n).sum(1).min() > -1e-6  # about the normal, on its side
    assert torch.equal(fused.weight, expected.weight) and not fused.delta.any()
    assert (o_fused - o_expected).abs().max() < 1e-6 and (o_through - o_through_expected).abs().max() < 1e-6
    # n faces the rays' origins: back along -d the new ray starts in front, onward along d behind
    assert (((o_fused - s.p) * s.n).sum(1) > 0).all() and (((o_through - s.p) * s.n).sum(1) < 0).all()


def test_a_render_empties_drjits_pool_only_while_it_runs(monkeypatch):
    """Inside a render Dr.Jit's kernels run in the render's workers (its pool emptied); after it the
    pool has its size again, for Dr.Jit's other users in the process (Mitsuba loads scenes on it)."""
    if arrays.drjit_arrays(torch.device("cpu")) is None:
        pytest.skip("Dr.Jit's LLVM backend is unavailable")
    import drjit as dr

    from invrender.core import compiled

    seen = []
    original = compiled.run

    def spy(*a, **k):
        seen.append(dr.thread_count())
        return original(*a, **k)

    monkeypatch.setattr(compiled, "run", spy)
    before = dr.thread_count()
    try:
        dr.set_thread_count(3)
        ir.render(ir.load_scene("cornell_box", resolution=(16, 16)), spp=2, progress=False)
        assert dr.thread_count() == 3
        assert seen and set(seen) == {1}  # 1: the calling thread alone
    finally:
        dr.set_thread_count(before)
