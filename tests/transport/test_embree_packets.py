"""The embree backend's packets (the compiled wrapper of ``invrender.backends.embree_native``)
against embreex's single rays and the torch backend: the same hits and shadow-ray answers on every
shipped scene and an 80k-triangle mesh, at batch sizes that leave partial packets, with rays that are
not traced (distance not positive or NaN), in packets of 16, 8 and 4 rays (Embree's AVX-512, AVX2
and SSE kernels, chosen by ``INVRENDER_EMBREE_CONFIG``); the same image; the fallback to embreex
said once."""

from __future__ import annotations

import os
import re

import pytest
import torch
import trimesh

import invrender as ir
from invrender.errors import ParameterError
from invrender.scene.camera import Camera
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh
from invrender.backends import accel, embree_native, packages
from invrender.backends.accel import make_intersector
from tests.transport.test_backends import SHIPPED, assert_same_hits, random_rays

built, why_not = embree_native.library()
needs_packets = pytest.mark.skipif(built is None, reason=f"Embree's packets do not build here: {why_not} ({embree_native.INSTALL_HINT})")
#: this CPU's widest vector instructions as torch sees them (AVX512, AVX2 or DEFAULT)
CAPABILITY = torch.backends.cpu.get_cpu_capability()
#: Embree's kernels each test of the answers runs on: its own choice (16 rays a packet with
#: AVX-512), AVX2's (8) and SSE's (4), where this CPU has them
WIDTHS = {
    "native": ("", {"AVX512": 16, "AVX2": 8}.get(CAPABILITY, 4)),
    "avx2": ("isa=avx2", 8),
    "sse": ("isa=sse4.2", 4),
}


@pytest.fixture(params=list(WIDTHS))
def lanes(request, monkeypatch) -> int:
    """Embree's device configured for one packet width (``INVRENDER_EMBREE_CONFIG``): that width."""
    config, width = WIDTHS[request.param]
    if request.param == "avx2" and CAPABILITY not in ("AVX2", "AVX512"):
        pytest.skip(f"this CPU has no AVX2 ({CAPABILITY})")
    monkeypatch.setenv(embree_native.CONFIG_ENV, config)
    return width


def both(triangles, monkeypatch):
    """(packets, embreex) intersectors of the same triangles."""
    packets = make_intersector(triangles, "embree", 1)
    monkeypatch.setenv(embree_native.ENV, "embreex")
    single = make_intersector(triangles, "embree", 1)
    monkeypatch.delenv(embree_native.ENV)
    assert packets.packets and not single.packets
    return packets, single


def test_the_packets_build_in_ci():
    """CI installs a compiler and Embree 3 (.ci/run): there the fast path must be the one tested."""
    if os.environ.get("CI"):
        assert built is not None, why_not


@needs_packets
@pytest.mark.parametrize("name", [*SHIPPED, "mesh"], ids=lambda n: os.path.basename(n).removesuffix(".toml"))
def test_packets_answer_as_embreex_does(name, monkeypatch):
    if name == "mesh":
        sphere = trimesh.creation.icosphere(subdivisions=6)  # 81,920 triangles
        box = trimesh.creation.box(extents=(4, 4, 4))
        scene = build_scene(
            [Mesh(sphere.vertices, sphere.faces, None, "grey"), Mesh(box.vertices, box.faces[:, ::-1], None, "grey", emitter="light")],
            {"grey": 0.5}, {"light": 1.0}, Camera(origin=(0, 0, 1.9)), (8, 8),
        )  # fmt: skip
    else:
        scene = ir.load_scene(name, resolution=(8, 8))
    packets, single = both(scene.triangles, monkeypatch)
    o, d = random_rays(scene, 5003, seed=4)  # 312 packets and a partial one of 11
    a, b = packets.intersect(o, d), single.intersect(o, d)
    assert a.t.dtype == torch.float32 and a.prim.dtype == torch.int64 and a.t.shape == (5003,)
    assert torch.isinf(a.t[~a.valid]).all() and (a.prim[~a.valid] == -1).all()
    assert_same_hits(scene, o, d, a, b)  # two Embree versions: ties between coplanar triangles may fall either way
    tmax = torch.rand(len(o), generator=torch.Generator().manual_seed(5)) * 2
    hit_a, hit_b = packets.occluded(o, d, tmax), single.occluded(o, d, tmax)
    assert 0.05 < hit_a.float().mean() < 0.95 and int((hit_a != hit_b).sum()) <= 2  # a hit at tmax itself may fall either way


@needs_packets
def test_the_packets_are_as_wide_as_the_cpu_traces_natively(lanes):
    """16 rays with AVX-512, 8 with AVX2 (emulated packets of 16 cost more there), else 4."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    assert make_intersector(scene.triangles, "embree", 1)._packets.lanes == lanes


@needs_packets
@pytest.mark.parametrize("n", [0, 1, 3, 5, 7, 9, 15, 16, 17, 4095, 4097])
def test_partial_packets_and_thread_splits(n, lanes):
    """Batches of any size (partial packets of every width), on one thread and split across two
    (from 4096 rays)."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    o, d = random_rays(scene, n, seed=n)
    reference = make_intersector(scene.triangles, "torch")
    want = reference.intersect(o, d)
    for threads in (1, 2):
        got = make_intersector(scene.triangles, "embree", threads).intersect(o, d)
        if n > 1000:
            assert_same_hits(scene, o, d, got, want)  # the Cornell box's coplanar ties may fall either way
        else:
            assert torch.equal(got.prim, want.prim)
            torch.testing.assert_close(got.t, want.t, rtol=1e-5, atol=1e-6)
        tmax = want.t.nan_to_num(posinf=3.0) * torch.where(torch.arange(n) % 2 == 0, 0.8, 1.2)  # before or past the closest hit
        assert torch.equal(make_intersector(scene.triangles, "embree", threads).occluded(o, d, tmax), reference.occluded(o, d, tmax))


@needs_packets
def test_rays_stored_by_columns_or_broadcast_are_read_through_their_strides():
    """The compiled bounce keeps its rays by columns ((3, N) viewed as (N, 3)) and a camera's
    origins may be one row broadcast: the wrapper reads every layout as the rows it stands for,
    split across threads too."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    o, d = random_rays(scene, 5000, seed=2)
    for threads in (1, 2):
        packets = make_intersector(scene.triangles, "embree", threads)
        want = packets.intersect(o.contiguous(), d.contiguous())
        got = packets.intersect(o.t().contiguous().t(), d.t().contiguous().t())
        assert torch.equal(got.prim, want.prim) and torch.equal(got.t, want.t)
        one = o[:1].expand(5000, 3)  # stride 0 along the rays
        assert torch.equal(packets.intersect(one, d).prim, packets.intersect(one.contiguous(), d).prim)
        tmax = want.t.nan_to_num(posinf=3.0) * 0.9
        assert torch.equal(packets.occluded(o.t().contiguous().t(), d.t().contiguous().t(), tmax), packets.occluded(o.contiguous(), d.contiguous(), tmax))


@needs_packets
def test_the_queries_leave_the_callers_float_mode_as_it_was():
    """Embree traces with denormals flushed to zero (as it asks), and the wrapper restores the
    calling thread's mode: torch's arithmetic in the same thread keeps its denormals."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    o, d = random_rays(scene, 100, seed=3)  # one thread: the query runs in this one
    packets = make_intersector(scene.triangles, "embree", 1)
    tiny = torch.tensor([1e-39])  # a float32 denormal
    hits = packets.intersect(o, d)
    packets.occluded(o, d, hits.t.nan_to_num(posinf=3.0) * 0.5)
    assert float(tiny * 1.0) > 0.0 and float(tiny * 2.0) == pytest.approx(2e-39, rel=1e-3)


@needs_packets
@pytest.mark.parametrize("n", [0, 1, 17, 5003])
@pytest.mark.parametrize("ended", [None, 0.4, 1.0])
def test_closest_hits_compacted_as_they_are_answered(n, ended, lanes):
    """The packets' ``closest_hits`` writes the rays that hit (and those that missed) as it
    answers: the same rays, order and hits as the base class's compaction of ``intersect``, on one
    thread and split across two, untraceable rays among the misses; with ``alive``, the rays of
    paths that ended are neither (not traced: the base class compacts them away first)."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    o, d = random_rays(scene, n, seed=11)
    if n > 3:
        o[3] = float("nan")  # untraceable: a miss
    alive = None if ended is None else torch.rand(n, generator=torch.Generator().manual_seed(12)) >= ended
    for threads in (1, 2):
        packets = make_intersector(scene.triangles, "embree", threads)
        hits = packets.intersect(o, d)
        want = accel.Intersector.closest_hits(packets, o, d, misses=True, alive=alive)  # the base class's: intersect, then compact
        got = packets.closest_hits(o, d, misses=True, alive=alive)
        assert 0 < got.index.shape[0] < n or n < 17 or ended == 1.0
        assert torch.equal(got.index, want.index) and torch.equal(got.gone, want.gone), threads
        for a, b in zip((got.t, got.prim, got.u, got.v), (want.t, want.prim, want.u, want.v)):
            assert torch.equal(a, b)
        keep = hits.valid if alive is None else hits.valid & alive
        assert torch.equal(got.prim, hits.prim[keep]) and packets.closest_hits(o, d).gone is None
        assert torch.equal(got.gone, torch.nonzero(~hits.valid if alive is None else ~hits.valid & alive)[:, 0])
        if n > 3:
            assert (3 in got.gone.tolist()) == (alive is None or bool(alive[3]))


@needs_packets
@pytest.mark.parametrize("untraced", [0.0, 0.3, 0.97, 1.0])
def test_shadow_rays_not_traced_leave_their_lanes_to_others(untraced, lanes):
    """Shadow rays that are not traced (distance 0 or NaN, an origin past Embree's range) do not
    take a packet's lane: the traced ones fill packets of their own (a Cornell render's shadow
    rays are 30% untraced). Any mix, any position, one thread or two: the torch backend's
    answers."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    n = 4999
    o, d = random_rays(scene, n, seed=7)
    reference = make_intersector(scene.triangles, "torch")
    tmax = reference.intersect(o, d).t.nan_to_num(posinf=3.0) * torch.where(torch.arange(n) % 3 == 0, 0.8, 1.2)
    g = torch.Generator().manual_seed(8)
    skip = torch.rand(n, generator=g) < untraced
    kind = torch.randint(0, 3, (n,), generator=g)
    tmax = torch.where(skip & (kind == 0), 0.0, torch.where(skip & (kind == 1), float("nan"), tmax))
    o = torch.where((skip & (kind == 2))[:, None], torch.tensor([1e30, 0.0, 0.0]), o)
    want = reference.occluded(o, d, tmax) & ~skip
    assert 0.0 < float(want.float().mean()) or untraced == 1.0
    for threads in (1, 2):
        got = make_intersector(scene.triangles, "embree", threads).occluded(o, d, tmax)
        assert torch.equal(got, want), (untraced, threads)


@pytest.mark.parametrize("backend", ["embree", "torch", pytest.param("warp", marks=pytest.mark.warp)])
def test_a_shadow_ray_with_no_length_is_not_occluded(backend, monkeypatch):
    """Every backend answers False for a distance that is not positive (the fused bounce sets 0
    where a light sample adds nothing) or NaN, and traces the others as usual."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    o = torch.tensor([[0.0, 0.0, 0.0]]).repeat(20, 1)
    d = torch.tensor([[0.0, 1.0, 0.0]]).repeat(20, 1)  # up, towards the ceiling ~1 away
    tmax = torch.tensor([5.0, 0.0, -1.0, float("nan"), 5.0] * 4)
    for mode in ("packets", "embreex") if backend == "embree" else ("",):
        if mode:
            monkeypatch.setenv(embree_native.ENV, mode)
        hit = make_intersector(scene.triangles, backend, 1).occluded(o, d, tmax)
        assert hit.tolist() == [True, False, False, False, True] * 4, (backend, mode)


@pytest.mark.parametrize(
    "config, message",
    [
        ("isa=foo", "INVRENDER_EMBREE_CONFIG='isa=foo': isa 'foo' is not one of sse2, sse4.2, avx, avx2, avx512, avx512skx"),
        ("max_isa=AVX2", "max_isa 'AVX2' is not one of"),
        ("verbose", "'verbose' is not key=value (Embree's device settings, e.g. isa=avx2)"),
        ("isa=", "'isa=' is not key=value"),
        ("threads=many", "INVRENDER_EMBREE_CONFIG='threads=many': Embree: no device"),
    ],
)
@needs_packets
def test_an_embree_configuration_embree_cannot_take_is_one_line(config, message, monkeypatch):
    """Embree would quietly take its SSE kernels for an ``isa`` it does not know: refused by name
    before; a setting Embree refuses is a one-line error naming the variable, not a traceback."""
    monkeypatch.setenv(embree_native.CONFIG_ENV, config)
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    with pytest.raises(ParameterError, match=re.escape(message)):
        make_intersector(scene.triangles, "embree", 1)


def test_the_embree_query_switch(monkeypatch, capsys):
    monkeypatch.setenv(embree_native.ENV, "sse")
    with pytest.raises(ParameterError, match="INVRENDER_EMBREE='sse' is not one of packets, embreex"):
        embree_native.mode()
    monkeypatch.setenv(embree_native.ENV, "embreex")
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    assert not make_intersector(scene.triangles, "embree", 1).packets
    assert capsys.readouterr().err == ""  # asked for: no note


def test_without_a_compiler_the_backend_keeps_embreex_and_says_so_once(monkeypatch, capsys):
    monkeypatch.setattr(embree_native, "_loaded", [None, "no C++ compiler found"])
    monkeypatch.setattr(packages, "_noted", set())
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    first = make_intersector(scene.triangles, "embree", 1)
    make_intersector(scene.triangles, "embree", 1)
    assert not first.packets and accel.missing("embree") is None
    err = capsys.readouterr().err.splitlines()
    assert err == [f"invrender: note: the embree backend traces single rays through embreex: no C++ compiler found ({embree_native.INSTALL_HINT} for Embree's packets)"]


def test_a_wrapper_that_does_not_compile_is_reported_not_raised(monkeypatch, tmp_path):
    bad = tmp_path / "broken.cpp"
    bad.write_text("this is not C++\n")
    monkeypatch.setattr(embree_native, "SOURCE", bad)
    monkeypatch.setenv("INVRENDER_CACHE", str(tmp_path / "cache"))
    lib, why = embree_native._build_and_load()
    if built is None:
        assert lib is None  # no compiler or no Embree here: said before compiling
    else:
        assert lib is None and why.startswith("the wrapper does not compile (") and "\n" not in why
    assert not list((tmp_path / "cache").rglob("*.so"))  # nothing half-written is left to load


@needs_packets
def test_packets_render_the_image_embreex_renders(lanes, monkeypatch):
    """Packets of every width (Embree's AVX-512, AVX2 and SSE kernels) render embreex's image."""
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    a = ir.render(scene, spp=8, seed=3, backend="embree", progress=False)
    monkeypatch.setenv(embree_native.ENV, "embreex")
    b = ir.render(scene, spp=8, seed=3, backend="embree", progress=False)
    torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)
