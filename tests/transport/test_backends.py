"""The intersection backends against each other: Warp's BVH hit for hit against Embree (on the CPU,
where both run), the same images from either, acceleration structures built once per geometry."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch
import trimesh

import invrender as ir
from invrender.errors import ParameterError
from invrender.scene.camera import Camera
from invrender.scene.scene import build_scene, scene_extent
from invrender.scene.shapes import Mesh
from invrender.backends import packages
from invrender.backends.accel import check_backend, intersector_for, make_intersector

FORWARD = Path(__file__).resolve().parents[2] / "forward"
SHIPPED = ["cornell_box", "cornell_specular", "furnace", *sorted(str(p) for p in FORWARD.glob("*.toml"))]


def random_rays(scene, n: int, seed: int):
    """Rays from points inside the scene's bounding box in uniform directions, plus camera rays."""
    g = torch.Generator().manual_seed(seed)
    c = scene.triangles.corners().reshape(-1, 3)
    lo, hi = c.min(0).values, c.max(0).values
    o = lo + (hi - lo) * (0.05 + 0.9 * torch.rand(n, 3, generator=g))
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=1)
    return o.contiguous(), d.contiguous()


def assert_same_hits(scene, o, d, a=None, b=None):
    """Hits ``a`` and ``b`` (default: embree's and warp's) of rays ``o``, ``d`` are the same."""
    a = a or make_intersector(scene.triangles, "embree", 1).intersect(o, d)
    b = b or make_intersector(scene.triangles, "warp").intersect(o, d)
    differ = a.prim != b.prim
    # the only licit difference: a tie between coplanar triangles at the same distance (the
    # Cornell boxes' bottom faces lie on the floor, seen by rays starting inside the boxes)
    assert (a.valid[differ] & b.valid[differ]).all()
    tri = scene.triangles
    na, nb = tri.normal[a.prim[differ]], tri.normal[b.prim[differ]]
    offset = ((tri.p0[b.prim[differ]] - tri.p0[a.prim[differ]]) * na).sum(1)
    assert ((na * nb).sum(1).abs() > 1 - 1e-6).all() and (offset.abs() < 1e-6).all(), "different triangles that are not coplanar ties"
    assert torch.allclose(a.t[differ], b.t[differ], rtol=1e-5)
    assert differ.float().mean() < 0.01
    hit = a.valid
    assert hit.sum() > len(o) // 5  # not a vacuous comparison
    assert torch.isinf(b.t[~hit]).all()
    # relative to the distance, or to 1% of the scene's size for hits closer than that (float32
    # positions carry an absolute error of ~1e-7 of the scene's size, whatever the distance); a
    # grazing ray's distance is ill-conditioned by 1/|cos|, so a few in 10^5 exceed 1e-5 (1.6e-5
    # measured) unless that factor is taken out
    same = hit & ~differ
    scale = a.t[same].clamp_min(1e-2 * scene_extent(scene.triangles))
    rel = (a.t[same] - b.t[same]).abs() / scale
    cos = (tri.normal[a.prim[same]] * d[same]).sum(1).abs()
    assert (rel * cos).max() < 1e-5, f"distances differ by {(rel * cos).max():.2e} relative (conditioned)"
    assert torch.quantile(rel, 0.999) < 1e-5 and rel.max() < 1e-4
    # one barycentric convention: the same hit points (to float rounding of the scene's size)
    k = a.prim[same]
    pa = tri.p0[k] + a.u[same, None] * tri.e1[k] + a.v[same, None] * tri.e2[k]
    pb = tri.p0[k] + b.u[same, None] * tri.e1[k] + b.v[same, None] * tri.e2[k]
    assert (pa - pb).abs().max() < 1e-5 * scene_extent(tri)


@pytest.mark.warp
@pytest.mark.parametrize("name", SHIPPED, ids=lambda n: Path(n).stem)
def test_warp_hits_equal_embree_on_shipped_scenes(name):
    scene = ir.load_scene(name, resolution=(8, 8))
    o, d = random_rays(scene, 20000, seed=1)
    assert_same_hits(scene, o, d)


@pytest.mark.warp
def test_warp_hits_equal_embree_on_an_80k_triangle_mesh():
    sphere = trimesh.creation.icosphere(subdivisions=6)  # 81,920 triangles
    bumpy = sphere.vertices * (1 + 0.05 * torch.sin(torch.tensor(sphere.vertices[:, :1]) * 17).numpy())
    box = trimesh.creation.box(extents=(4, 4, 4))
    scene = build_scene(
        [Mesh(bumpy, sphere.faces, None, "grey"), Mesh(box.vertices, box.faces[:, ::-1], None, "grey", emitter="light")],
        {"grey": 0.5}, {"light": 1.0}, Camera(origin=(0, 0, 1.9)), (8, 8),
    )  # fmt: skip
    assert scene.triangles.count > 80000
    o, d = random_rays(scene, 20000, seed=2)
    assert_same_hits(scene, o, d)
    tmax = torch.rand(len(o)) * 3
    a = make_intersector(scene.triangles, "embree", 1).occluded(o, d, tmax)
    b = make_intersector(scene.triangles, "warp").occluded(o, d, tmax)
    assert 0.1 < a.float().mean() < 0.9 and (a != b).sum() <= 2  # a hit at tmax itself may fall either way


@pytest.mark.warp
def test_warp_occluded_equals_embree():
    scene = ir.load_scene("cornell_specular", resolution=(8, 8))
    o, d = random_rays(scene, 20000, seed=3)
    tmax = torch.rand(len(o)) * 2
    a = make_intersector(scene.triangles, "embree", 1).occluded(o, d, tmax)
    b = make_intersector(scene.triangles, "warp").occluded(o, d, tmax)
    assert 0.1 < a.float().mean() < 0.9 and (a != b).sum() <= 2


@pytest.mark.warp
@pytest.mark.parametrize("name", ["cornell_box", "cornell_specular"])
def test_warp_and_embree_render_the_same_image(name):
    scene = ir.load_scene(name, resolution=(24, 24))
    a = ir.render(scene, spp=8, seed=3, backend="embree", progress=False)
    b = ir.render(scene, spp=8, seed=3, backend="warp", progress=False)
    assert torch.allclose(a, b, rtol=1e-4, atol=1e-5), (a - b).abs().max()


@pytest.mark.warp
def test_warp_gradients_equal_embree():
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    target = ir.render(scene, spp=16, seed=9, progress=False)
    rho = scene.params["red.reflectance"].requires_grad_(True)
    grads = []
    for backend in ("embree", "warp"):
        rho.grad = None
        ((ir.render(scene, spp=4, seed=1, backend=backend, progress=False) - target) ** 2).mean().backward()
        grads.append(rho.grad.clone())
    rho.requires_grad_(False)
    assert torch.allclose(grads[0], grads[1], rtol=1e-4, atol=1e-9)


def test_acceleration_structure_is_built_once_per_geometry():
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    first = intersector_for(scene.triangles, "embree")
    ir.render(scene, spp=1, progress=False)
    assert intersector_for(scene.triangles.to("cpu"), "embree") is first
    assert intersector_for(scene.with_resolution((4, 4)).triangles, "embree") is first
    assert intersector_for(scene.triangles, "torch") is not first
    other = ir.load_scene("cornell_box", resolution=(8, 8))
    assert intersector_for(other.triangles, "embree") is not first  # another geometry, its own structure


def test_backend_errors():
    with pytest.raises(ParameterError, match="unknown intersection backend 'optix'.*embree, warp, torch"):
        check_backend("optix", torch.device("cpu"))
    with pytest.raises(ParameterError, match="embree backend runs on the CPU only"):
        check_backend("embree", torch.device("cuda"))
    assert check_backend(None, torch.device("cpu")) == "embree"
    assert check_backend(None, torch.device("cuda")) == ("warp" if packages.find("warp") else "torch")  # torch without warp-lang


def test_repeated_queries_answer_the_adjoint_pass_from_the_primal_pass(monkeypatch):
    """Path replay without kept radiance traces a chunk twice; the second trace (adjoint) casts the
    first's rays again and gets the recorded answers: the backend is asked once per ray. (The
    Cornell box's gradient is otherwise carried forward by the fused bounce, one trace and no
    replay: that is switched off here, and checked at the end.)"""
    from invrender.estimators import replay
    from invrender.estimators.replay import replay_gradient
    from invrender.backends import accel
    from invrender.core.driver import RenderSettings
    from invrender.plugins.integrators import make_integrator

    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    calls = {"intersect": 0, "occluded": 0}
    for kind in calls:
        original = getattr(accel.EmbreeIntersector, kind)

        def counted(self, *args, _kind=kind, _original=original):
            calls[_kind] += 1
            return _original(self, *args)

        monkeypatch.setattr(accel.EmbreeIntersector, kind, counted)
    compacting = accel.EmbreeIntersector.closest_hits

    def counted_hits(self, *args, **kwargs):  # a closest-hit query compacted as it is answered
        calls["intersect"] += self.packets  # (without packets it asks intersect, counted there)
        return compacting(self, *args, **kwargs)

    monkeypatch.setattr(accel.EmbreeIntersector, "closest_hits", counted_hits)
    tangent_slots = replay.tangent_slots
    monkeypatch.setattr(replay, "tangent_slots", lambda *args, **kwargs: None)
    integrator, settings = make_integrator("path", max_depth=4), RenderSettings(spp=4, seed=1, progress=False, chunk_paths=512)
    with torch.no_grad():
        integrator.render(scene, settings, torch.device("cpu"))
    forward = dict(calls)
    calls.update(intersect=0, occluded=0)
    name = "red.reflectance"
    grads = replay_gradient(scene, integrator, settings, torch.device("cpu"), {name: scene.params[name]}, torch.ones(16, 16, 3))
    assert calls == forward and forward["intersect"] >= 4 * 2  # per chunk, per bounce: one query, not two
    assert grads[name].abs().sum() > 0

    # with a forward render of the same seed: it kept the radiances and the shadow rays' answers,
    # so the backward pass asks only for closest hits
    p = scene.params[name].clone().requires_grad_(True)
    work = dataclasses.replace(scene, params={**scene.params, name: p})
    image = ir.render(work, max_depth=4, spp=4, seed=1, progress=False, chunk_paths=512, estimator="replay")
    calls.update(intersect=0, occluded=0)
    image.sum().backward()
    assert calls == {"intersect": forward["intersect"], "occluded": 0}
    assert torch.allclose(p.grad, grads[name], rtol=1e-5)

    # the fused bounce's forward-mode derivatives: the backward pass traces nothing
    monkeypatch.setattr(replay, "tangent_slots", tangent_slots)
    p.grad = None
    image = ir.render(work, max_depth=4, spp=4, seed=1, progress=False, chunk_paths=512, estimator="replay")
    assert calls["intersect"] == 2 * forward["intersect"]  # the forward render's own queries
    image.sum().backward()
    assert calls["intersect"] == 2 * forward["intersect"] and torch.allclose(p.grad, grads[name], rtol=1e-5)

    mask = torch.rand(1001, generator=torch.Generator().manual_seed(5)) < 0.3
    assert torch.equal(accel._unpack_bits(accel._pack_bits(mask), 1001), mask) and accel._pack_bits(mask).numel() == 126

    queries = accel.RepeatedQueries(make_intersector(scene.triangles, "embree", 1))
    o, d = random_rays(scene, 100, seed=0)
    queries.intersect(o, d)
    queries.repeat()
    with pytest.raises(RuntimeError, match="differs from its primal pass"):
        queries.intersect(o[:50], d[:50])
