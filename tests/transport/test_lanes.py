"""The bounce written once (invrender.core.lanes): its eager torch evaluation and its Dr.Jit
compilation give the same random bits and, within float rounding, the same bounce; the pieces
equal the torch expressions they stand for."""

from __future__ import annotations

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.backends import arrays
from invrender.core import compiled, fused, lanes, sampler

CPU = torch.device("cpu")
DRJIT = arrays.drjit_arrays(CPU)
needs_drjit = pytest.mark.skipif(DRJIT is None, reason="Dr.Jit (drjit with a libLLVM) is not available")
NAMESPACES = [arrays.TORCH] + ([DRJIT] if DRJIT is not None else [])


@pytest.mark.parametrize("xp", NAMESPACES, ids=lambda xp: xp.name)
def test_lane_uniforms_are_the_samplers_bit_for_bit(xp):
    keys = sampler.path_keys(7, torch.arange(5000), torch.arange(5000) % 13)
    keys = sampler.mirrored(keys, torch.arange(5000) % 3 == 0)  # mirrored keys draw 1 - u
    salts = sampler.bounce_salt_values(3, 7)
    got = torch.stack(compiled.evaluate(xp, lambda xp, k, s: tuple(lanes.uniform(xp, k, x) for x in s), keys, tuple(compiled.Opaque(s) for s in salts)), dim=1)
    assert torch.equal(got, sampler.uniform(keys, 3, 7))


@pytest.mark.parametrize("xp", NAMESPACES, ids=lambda xp: xp.name)
def test_the_light_pick_is_searchsorted(xp):
    g = torch.Generator().manual_seed(0)
    cdf = torch.cumsum(torch.rand(37, generator=g), 0)
    cdf[5] = cdf[4]  # a zero-probability triangle
    cdf = (cdf / cdf[-1]).float()
    tri = torch.arange(37) * 3 + 1
    u = torch.cat([torch.rand(4000, generator=g), cdf[:10], torch.tensor([0.0, 1.0 - 2**-24])]).float()
    (got,) = compiled.evaluate(xp, lambda xp, rows, u: (lanes.pick_light(xp, rows, 37, u),), lanes.light_rows(cdf, tri), u)
    expected = tri[torch.searchsorted(cdf, u, right=True).clamp_max(36)]
    assert torch.equal(got.long(), expected)


def _bounce_inputs(strategy: str):
    """The arguments of every :func:`fused.vertex` call of a small Cornell box render (the first
    vertex's with the stratified numbers of ``"stratified_direct"``)."""
    calls = []
    vertex = fused.vertex
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    try:
        fused.vertex = lambda *a, **k: (calls.append((a, k)), vertex(*a, **k))[1]
        ir.render(scene, spp=4, seed=3, max_depth=6, rr_depth=2, strategy=strategy, sampler="stratified_direct", progress=False)
    finally:
        fused.vertex = vertex
    return vertex, calls


@needs_drjit
@pytest.mark.parametrize("strategy", ["mis", "emitter", "bsdf"])
@pytest.mark.parametrize("tangents", [False, True])
def test_the_compiled_bounce_is_the_eager_one(strategy, tangents, monkeypatch):
    vertex, calls = _bounce_inputs(strategy)
    assert len(calls) >= 5 and any(a[8] for a, _ in calls) and any(not a[7] for a, _ in calls)  # roulette on, last bounce
    assert calls[0][1]["strata"] is not None and calls[1][1]["strata"] is None
    for a, k in calls:
        a = a[:-1] + (tangents,)
        monkeypatch.setenv(arrays.ENV, "drjit")
        got = vertex(*a, **k)
        monkeypatch.setenv(arrays.ENV, "torch")
        expected = vertex(*a, **k)
        for x, y in zip(got, expected):
            x, y = arrays.stacked(x), arrays.stacked(y)  # 3-vectors come as Columns
            if x is None:
                assert y is None
            elif x.dtype.is_floating_point:
                assert torch.allclose(x, y, rtol=2e-5, atol=1e-6 * float(y.abs().max().clamp_min(1.0)))
            else:  # the alive masks (the same roulette bits), indices
                assert torch.equal(x, y.to(x.dtype))


def test_an_unknown_bounce_evaluator_is_a_one_line_error(monkeypatch):
    monkeypatch.setenv(arrays.ENV, "jax")
    with pytest.raises(ParameterError, match="INVRENDER_BOUNCE must be 'drjit' or 'torch', got 'jax'"):
        compiled.namespace(CPU)


def test_without_drjit_the_bounce_runs_as_eager_torch(monkeypatch):
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    image = ir.render(scene, spp=8, seed=1, progress=False)
    monkeypatch.setattr(arrays, "_namespaces", {"llvm": None, "cuda": None})
    assert compiled.namespace(CPU) is arrays.TORCH
    again = ir.render(scene, spp=8, seed=1, progress=False)
    assert (image - again).abs().max() < 1e-5 * float(image.max())



@needs_drjit
def test_a_literal_output_keeps_its_kind_of_call_frozen_and_fills_every_lane(monkeypatch):
    """Under a sky with no emitting shape a vertex's emission is a literal 0, and a replay returns
    a literal with its recording's width: such outputs come back as their value, filled over the
    call's lanes, and the bounce's kinds of call stay frozen (with a matrix's halves traced side by
    side they were traced again on every call: its renders spent a third of their time so)."""
    from invrender.core import compiled
    from invrender.scene.builtin import sky_map, sky_spheres

    monkeypatch.setattr(compiled, "_FROZEN", {})
    from invrender.scene.camera import Camera

    scene = sky_spheres((32, 32), (8, 16), subdivisions=2, sky=torch.ones(8, 16, 3))
    camera = Camera(origin=(0.0, 0.35, 4.2), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")
    hidden = {"type": "path", "hide_emitters": True}
    threads = torch.get_num_threads()
    torch.set_num_threads(2)  # the matrix's halves traced side by side, as outside the tests
    try:
        matrices = [ir.lighting.transport_matrix(scene, "sky", cameras=[camera], integrator=hidden, spp=spp, max_depth=3) for spp in (1, 2, 1)]
    finally:
        torch.set_num_threads(threads)
    assert float(matrices[0].halves[0].sum()) > 0 and torch.equal(matrices[0].halves[1], matrices[2].halves[1])
    kinds = [v for k, v in compiled._FROZEN.items() if getattr(k[1], "__name__", "") == "path_vertex"]
    assert kinds and all(v is not compiled._TRACED for v in kinds)


def _row_sums(xp, sums, index, active, v0, v1, *, width):
    """Rows of ``width`` floats made of two arrays (then zeros), added to ``sums``; nothing out."""
    zero = 0.0 * v0
    row = (v0, v1) + tuple(v0 * float(k) + v1 if k % 7 == 0 else zero for k in range(2, width))
    xp.scatter_add_rows(sums, row, index, active)
    return ()


@pytest.mark.parametrize("xp", NAMESPACES, ids=lambda xp: xp.name)
@pytest.mark.parametrize("lanes_count", [300, 6000])  # padded to FREEZE_LANES (padded lanes inactive), and not
@pytest.mark.parametrize("width", [16, 48])  # one packet of 16 floats a row, and three
def test_rows_are_added_per_index_in_float64_by_both_evaluators(xp, lanes_count, width):
    """The accumulator a render's bounces add their per-pixel derivatives to: every active lane's
    row lands in its index's row, as float64 sums (repeated indices summed), and inactive lanes
    add nothing, compiled and as eager torch; two calls accumulate."""
    g = torch.Generator().manual_seed(lanes_count + width)
    rows = 97
    index = torch.randint(0, rows, (lanes_count,), generator=g)
    v0, v1 = torch.rand(lanes_count, generator=g), torch.rand(lanes_count, generator=g) * 1e-3
    active = torch.rand(lanes_count, generator=g) < 0.8
    sums = compiled.Sums(rows * width, CPU)
    for _ in range(2):
        assert compiled.evaluate(xp, _row_sums, sums, index, active, v0, v1, width=width) == ()
    full = torch.stack([v0, v1] + [v0 * float(k) + v1 if k % 7 == 0 else torch.zeros_like(v0) for k in range(2, width)], 1).double()
    expected = torch.zeros(rows, width, dtype=torch.float64).index_add_(0, index[active], full[active]) * 2
    got = sums.tensor().view(rows, width)
    assert float(expected.abs().max()) > 0 and torch.allclose(got, expected, rtol=1e-12, atol=0)


@needs_drjit
def test_every_tensor_a_compiled_call_wraps_is_held_by_the_caller():
    """Copies and narrowings made to pass tensors to Dr.Jit are handed to the caller to keep until
    the call's arrays are released (freed by Dr.Jit inside a launch, torch's deleter waits for the
    GIL: two render workers deadlocked)."""
    held: list = []
    rows = torch.rand(5000, 3)  # (N, 3) by rows: its columns are copies
    DRJIT.from_torch(rows, lanes=True, held=held)
    index = DRJIT.from_torch(torch.arange(5000), lanes=True, held=held)  # int64: narrowed inside the kernel
    strided = torch.rand(5000, 2)[:, 0]
    DRJIT.from_torch(strided, lanes=True, held=held)
    assert len(held) == 5 and all(t.is_contiguous() for t in held)
    assert torch.equal(held[3], torch.arange(5000)) and torch.equal(held[4], strided)
    assert torch.equal(DRJIT.to_torch(index + 0).long(), torch.arange(5000))


def _lookups(xp, rows, texels, u, v, texture):
    """The lookups of texture ``texture`` (a Float per lane: -1 none) at (u, v): (the RGB,)."""
    zero = 0.0 * u
    return (lanes.texture_lookup(xp, rows, texels, (u, v))(texture, (zero + 0.1, zero + 0.2, zero + 0.3)),)


@pytest.mark.parametrize("xp", NAMESPACES, ids=lambda xp: xp.name)
@pytest.mark.parametrize("sampling", [None, ("nearest", "mirror", (2.0, 0.5, 0.1, -0.3, 3.0, 0.2)), ("bilinear", "clamp", None)], ids=["bilinear-repeat", "nearest-mirror-affine", "bilinear-clamp"])
def test_one_texture_is_read_without_a_row_gather_and_reads_as_the_table(xp, sampling):
    """A render's one texture hands its row to the bounce as scalars (no gather a lane): every
    lookup equals the same texture's read through a table of two rows, bit for bit, in each
    evaluator; lanes without the texture (id -1) keep their constant."""
    from invrender.scene.textures import TextureSampling

    g = torch.Generator().manual_seed(3)
    tex = torch.rand(5, 7, 3, generator=g)
    how = None if sampling is None else TextureSampling(*sampling)
    one, two = lanes.TextureTable(), lanes.TextureTable()
    assert one.add(tex, how) == 0 and two.add(tex, how) == 0 and two.add(torch.rand(3, 2, 3, generator=g), None) == 1
    (row, texels_one), (table, texels_two) = one.tables(CPU, one_as_scalars=True), two.tables(CPU, one_as_scalars=True)
    assert isinstance(one.tables(CPU)[0], torch.Tensor)  # (a normal map's table: rows gathered by lane)
    assert isinstance(row, tuple) and len(row) == 11 and isinstance(table, torch.Tensor)
    n = 5000
    u, v = torch.rand(n, generator=g) * 3 - 1, torch.rand(n, generator=g) * 3 - 1  # outside [0, 1] too: the wrap modes
    texture = torch.where(torch.rand(n, generator=g) < 0.2, -1.0, 0.0)
    got = compiled.evaluate(xp, _lookups, row, texels_one, u, v, texture)[0]
    want = compiled.evaluate(xp, _lookups, table, texels_two, u, v, texture)[0]
    assert torch.equal(got, want)
    assert torch.equal(got[texture < 0], torch.tensor([0.1, 0.2, 0.3]).expand(int((texture < 0).sum()), 3))
    assert float(got[texture >= 0].std()) > 0.1  # the texture's values, not a constant
