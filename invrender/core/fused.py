"""The primal bounce of the random walk and the path tracer as one compiled kernel, where it applies.

Outside its ray queries, a bounce in eager torch is a few hundred small operations, each a pass
over megabytes of (N,) and (N, 3) tensors. When nothing needs those operations' autograd graph
or hooks, a bounce is instead:

1. the closest-hit query, the radiance of the emitters infinitely far away seen by the rays that
   leave the scene (one small kernel: :func:`invrender.core.lanes.escaped_vertex`), and the
   compaction to the rays that hit;
2. one kernel (:func:`vertex`: :func:`invrender.core.lanes.path_vertex`, written once against the
   array interface and compiled by Dr.Jit, or run as eager torch where Dr.Jit is missing:
   :mod:`invrender.core.compiled`): the hit's geometry and shading frame (interpolated normals),
   the emission seen there with its MIS weight (term k), one emitter sample, its shadow ray and the
   direct light it carries if unoccluded (term k + 1), the material's direction sample, the new
   ray, the throughput and Russian roulette. The materials and emitters are the plugins' own lane
   forms (:class:`~invrender.core.bsdf.LaneForm`, :class:`~invrender.core.lights.LightLanes`):
   each type present runs on every lane and a lane keeps its own type's answer (masks, no
   compaction); textures are read per lane (:class:`~invrender.core.lanes.TextureTable`; a
   render's one texture passes its row as values, not a table);
3. the shadow-ray query, the two film additions, and the compaction to the surviving paths.

The kernel draws the same counter-based numbers (the same salts, the same dimensions) and follows
the same expressions as the torch bounce of :class:`~invrender.plugins.integrators.random_walk.RandomWalk`
and :func:`~invrender.plugins.integrators.vertex.add_direct`, which stay the differentiable
reference (and the materials' torch methods are the same lane functions evaluated as eager torch):
the two give the same image within float rounding (``tests/transport/test_fused.py``; a roulette
decision that float rounding flips changes one path). Its compiled and eager evaluations agree lane
by lane (``tests/transport/test_lanes.py``, ``tests/plugins/test_lane_forms.py``).

It applies (:func:`tables`) on the CPU and CUDA unless switched off
(:func:`~invrender.backends.kernels.fused_bounce`), where the integrator's vertex step is the random walk's
or the path tracer's own (``fused_direct``), every material type gives its lane form
(:meth:`BSDF.lane_form <invrender.core.bsdf.BSDF.lane_form>`, its torch methods not overridden)
with parameters that are colours or textures, every emitter type gives its lane form
(:meth:`Light.lanes <invrender.core.lights.Light.lanes>`), the camera sees emitters (or, hiding
them, the scene has no emitting shapes: camera rays that leave add nothing), there is no ambient
term, no parameter is per vertex, and no parameter carries a gradient or a forward-mode tangent;
and, per chunk, where the film has no hooks but ``arrive`` (:func:`takes`: path records' and
replay's adjoint films have others; the transport matrix's film is told the direction of each
contribution that may end on an environment map, as the torch bounce tells it). Everywhere else the torch bounce runs. ``INVRENDER_KERNELS=steps`` (or
``torch``) switches it off; ``INVRENDER_BOUNCE=torch`` runs the kernel as eager torch.

**Derivatives carried forward.** In a scene lit by area emitters, a path is linear in each
Lambertian material's constant colour rho (each vertex on it multiplies the path by rho once) and
in each emitter's eps, whatever else it meets (a texture's, a mirror's, a glass's or a glossy
lobe's factors are constants of the path: ``FusedScene.rho`` and ``slot``), so each path counts
its throughput's factors of each rho as it scatters
(``counts``), and one more step per bounce turns a contribution C into
what two callers need: its derivatives, ``n C / rho_m`` and the factor beside eps, added per
pixel into a :class:`TangentFilm` inside one more kernel (:func:`jacobian_add`; path replay's gradient is then one
contraction with ``dl/dI``, no adjoint trace: :mod:`invrender.estimators.replay`), or its
monomial's code ``sum_s k_s R_s`` for a film that takes contributions by code (path records:
:func:`places`), instead of forward-mode autodiff.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from invrender.scene.kinds import param_name
from invrender.backends import kernels
from invrender.core.context import PathState, TransportContext
from invrender.core.film import Film
from invrender.core.ranks import sum_across_ranks, world
from invrender.core import compiled, lanes, shading
from invrender.backends.arrays import Columns, stacked, take
from invrender.core.compiled import Opaque
from invrender.core.bsdf import LaneBSDF, Lobe
from invrender.core.sampler import bounce_salt_values
from invrender.core.surface import carries_derivative
from invrender.vec import where_true

#: paths a chunk traced by the fused bounce holds at most on the CPU (about 300 bytes a path,
#: :data:`BYTES_PER_PATH`: 75 MiB a worker): its per-chunk cost (a few dozen launches and queries a
#: bounce, and the small calls of its last bounces) shrinks with the chunks' count; on the Cornell
#: box (128^2, 64 spp, 2 workers, AMD EPYC AVX-512, alternating in one process) 2^18 took 4% less
#: time than 2^17 (0.302 s against 0.316 s; a render's memory 155 MiB against 81 MiB over a small
#: render's) and 2^19 1% less again for 285 MiB; before the queries compacted their answers
#: (Intersector.closest_hits), 2^17 had been 7-15% faster than 2^16 and 2^18 no faster
CPU_CHUNK_PATHS = 1 << 18
#: a fused chunk's working set a path (the chunk's arrays a bounce; measured: 155 MiB for two
#: workers' chunks of 2^18), which sizes its chunks from ``RenderSettings.memory_mb``
BYTES_PER_PATH = 320
#: the same for a render that carries derivatives (path replay's gradient: its memory is what
#: replay promises to keep small): 56k paths, a gradient's increment 93-94 MiB and 0.60-0.63x
#: Mitsuba's prb (Cornell box 128^2, 64 spp, 2 workers; bench/gradient.py); 64k: 96-100 MiB,
#: 0.65-0.71x; 48k: 87 MiB, 0.78-0.82x; 128k: 164 MiB; 32k took 25-40% longer than 64k (a
#: compiled call's fixed cost, about 0.6 ms, paid per chunk and bounce)
CPU_TANGENT_CHUNK_PATHS = 7 << 13

#: random numbers drawn per vertex (as the random walk draws them: 0-1 BSDF direction, 2-4 emitter
#: sample, 5 roulette, 6 BSDF lobe)
DIMS = 7


@dataclass(frozen=True)
class FusedScene:
    """What the fused bounce reads of one render's scene.

    Attributes:
        rho: (M, 3) the materials' reflectance where some are Lambertian (their factors are
            linear in it), none one-sided or perturbed, and the emitters of the one type ``area``:
            the derivatives and monomial codes the bounce carries in the ``slot`` materials' and
            the emitters' parameters are then exact (:class:`TangentFilm`); the other materials'
            rows are zeros, their factors (a texture's, a mirror's, a glossy lobe's) constants of
            the paths. Else None (the primal image only).
        eps: (E, 3) the emitters' radiance where ``rho`` is given, else None.
        slot: (M,) per material whether its reflectance is a slot (an RGB constant of a
            Lambertian), where ``rho`` is given.
        mis: emission hit by BSDF samples is weighted against emitter samples (power heuristic).
        nee_only: emitter samples alone estimate direct light (emission counts on camera rays
            and after delta lobes only).
        nee: emitter samples are taken (next-event estimation).
        materials: per material type present, its :class:`~invrender.core.lanes.Material`.
        emitters: per emitter type present, its :class:`~invrender.core.lanes.Emitter`.
        absorbing: some BSDF weight can be zero (such paths end: not a flat scene of Lambertian
            colours).
        infinite: some emitter is infinitely far away (rays that leave the scene see it).
        lanes: the tables as the lane functions read them: triangles (T * 16,), per emitter type
            its tables and its share (:func:`~invrender.core.lanes.shares`), the material index (M * 4,), per material type its table, the vertex
            normals (T * 16,) or None with the shading frames' tables (:func:`invrender.core.shading.tables`), the textures (uvs, rows, texels) or None
            (:mod:`invrender.core.lanes`).
    """

    rho: torch.Tensor | None
    eps: torch.Tensor | None
    slot: tuple[bool, ...] | None
    mis: bool
    nee_only: bool
    nee: bool
    materials: tuple
    emitters: tuple
    absorbing: bool
    infinite: bool
    lanes: tuple


def scene_of(ctx: TransportContext, direct, hemisphere: str) -> FusedScene | None:
    """:func:`tables`, built once per render context (renders that share one, their chunks) and
    grad mode (a value that requires grad keeps a render off the fused bounce only where grad is
    on) and kernel choice."""
    key = (direct, hemisphere, torch.is_grad_enabled(), kernels.fused_bounce(ctx.triangles.p0.device))
    cache = ctx.__dict__.setdefault("_fused_scenes", {})
    if key not in cache:
        cache[key] = tables(ctx, direct, hemisphere)
    return cache[key]


def tables(ctx: TransportContext, direct, hemisphere: str) -> FusedScene | None:
    """The fused bounce's view of the render ``ctx``, or None where it does not apply (module
    docstring). ``direct``: the integrator's ``fused_direct`` (None: its vertex step is its own;
    ``False``: no emitter samples; ``"mis"`` or ``"emitter"``: the path tracer's strategies);
    ``hemisphere``: its diffuse sampling (the materials' lane forms follow it)."""
    if direct is None or not kernels.fused_bounce(ctx.triangles.p0.device):
        return None
    if (ctx.hide_emitters and ctx.lights.surfaces) or ctx.ambient is not None or ctx.per_vertex:
        return None  # camera rays through emitting shapes (hide_emitters) are the torch bounce's
    if ctx.normals_turn:
        return None  # differentiated normals, or sampling held at other ones: the torch bounce follows them
    emitters = _emitters(ctx.lights)
    if emitters is None:
        return None
    materials, forms, textures = ctx.materials, [], lanes.TextureTable()
    device = ctx.triangles.p0.device
    for bsdf in materials.bsdfs:
        form = bsdf.lane_form()
        if form is None or not _written_once(bsdf) or any(carries_derivative(v) for m in bsdf.values for v in m.values()):
            return None
        rows = lanes.material_rows(bsdf, form.keys, textures)
        if rows is None:
            return None
        table, layout = rows
        forms.append((lanes.Material(form, layout, bsdf.has(Lobe.SMOOTH), bsdf.has(Lobe.GLOSSY_TRANSMISSION)), table.to(device)))
    one_sided = materials.one_sided_rows()
    index = torch.stack([materials.slot_of.float(), materials.local_of.float(), one_sided.float(), torch.zeros_like(one_sided, dtype=torch.float32)], dim=1)
    rows = (
        _triangle_rows(ctx),
        tuple(t for _, t in emitters),
        tuple(tuple(Opaque(float(x)) for x in share) for share in lanes.shares(ctx.lights)),
        index.reshape(-1).contiguous(),
        tuple(t for _, t in forms),
        (ctx.normals.rows() if ctx.normals is not None else None, *shading.tables(ctx)),
        None if textures.empty else (lanes.uv_rows(ctx.triangles), *textures.tables(device, one_as_scalars=True)),
    )
    albedo, rho, eps, slot = materials.fused_albedo(), None, None, None
    if albedo is not None and len(emitters) == 1 and emitters[0][0].surface:  # the area emitter's eps rows: (E, 3)
        (rho, slot), eps = albedo, emitters[0][1][2].view(-1, 4)[:, :3]
        rho = rho.float()
    nee = direct in ("mis", "emitter") and ctx.lights.count > 0
    kinds = tuple(e for e, _ in emitters)
    flat = rho is not None and bool(slot.all()) and not ctx.triangles.any_smooth  # every material a Lambertian colour: no weight is 0
    return FusedScene(rho, eps, tuple(slot.tolist()) if slot is not None else None, direct == "mis", direct == "emitter", nee, tuple(m for m, _ in forms), kinds, not flat, any(e.infinite for e in kinds), rows)


def _emitters(lights) -> list | None:
    """Per emitter type of ``lights``, (its :class:`~invrender.core.lanes.Emitter`, its tables), or
    None where one has no lane form or a parameter that carries a derivative."""
    out = []
    for light in lights.lights:
        form = light.lanes()
        if form is None or any(carries_derivative(v) for m in light.values for v in m.values()):
            return None
        out.append((lanes.Emitter(form, light in lights.sampled, light.infinite, light.surface), form.tables))
    return out


def _triangle_rows(ctx) -> torch.Tensor:
    """The triangle table (:func:`~invrender.core.lanes.triangle_rows`) with the emitting flags and
    area densities of the scene's surface emitters (zeros without one)."""
    for light in ctx.lights.surfaces:
        form = light.lanes()
        if form is not None:
            return form.tables[0]
    t = ctx.triangles
    return t.derived("lane_rows_dark", lambda: lanes.triangle_rows(t.packed, t.material, t.emitter, torch.zeros_like(t.material, dtype=torch.bool), torch.zeros_like(t.area)))


def _written_once(bsdf) -> bool:
    """Are ``bsdf``'s torch methods its lane form's (not a subclass's own, which the compiled bounce
    would not follow)?"""
    return all(getattr(type(bsdf), m) is getattr(LaneBSDF, m) for m in ("eval", "pdf", "sample"))


def takes(film: Film, fused: FusedScene) -> bool:
    """Does ``film`` take the fused bounce's contributions: it has none of the hooks the torch
    bounce calls but ``arrive`` (``visit``, ``scatter``: the fused bounce tells ``arrive`` of each
    contribution that may end on an emitter infinitely far away, as the torch bounce does: the
    transport matrix's film), or it takes contributions by monomial code (:func:`places`) and the
    scene is Lambertian (``fused.rho``)?"""
    if not film.fused_bounce:
        return False
    if places(film) is not None or isinstance(film, TangentFilm):
        return fused.rho is not None
    cls = type(film)
    return cls.visit is Film.visit and cls.scatter is Film.scatter and not film.detach_throughput


def places(film: Film) -> torch.Tensor | None:
    """(S,) int64 the place of each slot's exponent in a monomial's code, for a film that takes the
    contributions by code (``film.fused_places``; path records, which then add each contribution
    with ``film.add_coded(term, index, code, radiance)``, code -1: none); else None."""
    return getattr(film, "fused_places", None)


class TangentFilm(Film):
    """A film that also keeps each pixel's derivatives in the scene's constant parameters (forward
    mode, in the fused kernels): :attr:`jacobian` (W * H, 3, S) float64, pixel by colour channel by
    *slot*, the M materials' reflectance (:meth:`BSDF.fused_albedo` rows) then the E emitters'
    emission (``triangles.emitter`` rows); channel c of a pixel depends on channel c of each slot
    only. Sums over paths, as the image (divide by spp for the image's derivative).

    Every factor of a Lambertian path is linear in one of them, so a contribution C with n factors
    of rho_m has derivative ``n C / rho_m`` (0 in a channel where rho_m is 0, as path replay
    gives there) and one with the factor eps_e the factor beside it; a path counts its throughput's
    factors per material as it scatters (:func:`jacobian_add`).
    """

    def __init__(self, width: int, height: int, slots: int, device):
        super().__init__(width, height, False, device)
        self.slots = slots
        #: floats a pixel holds: its 3 x S derivatives, padded to packets of 16 (one packet add each)
        self.row = -(-3 * slots // 16) * 16
        self.sums = compiled.Sums(width * height * self.row, device)

    @property
    def jacobian(self) -> torch.Tensor:
        """(W * H, 3, S) float64, a view of the pixels' rows."""
        return self.sums.tensor().view(-1, self.row)[:, : 3 * self.slots].view(-1, 3, self.slots)

    @staticmethod
    def merge(films: list[TangentFilm]) -> TangentFilm:
        out = Film.merge(films)
        total = out.sums.tensor()
        for other in films[1:]:
            total += other.sums.tensor()
        return out

    def summed_across_ranks(self) -> TangentFilm:
        if world()[1] > 1:
            total = self.sums.tensor()
            total.copy_(sum_across_ranks(total))
        return super().summed_across_ranks()


def slots(fused: FusedScene) -> int:
    """The Jacobian's slots of the scene: its materials, then its emitters (:class:`TangentFilm`)."""
    return 0 if fused.rho is None else fused.rho.shape[0] + fused.eps.shape[0]


def slot_index(scene, fused: FusedScene) -> dict[str, int]:
    """Parameter name -> its slot (``NAME.reflectance`` of the scene's Lambertian materials whose
    reflectance is an RGB constant (``fused.slot``), then ``NAME.emission`` of its emitters), the parameters
    whose derivatives and monomial codes the fused bounce carries; empty when its tables do not
    have one row per material and emitter."""
    if fused.rho is None or slots(fused) != len(scene.materials) + len(scene.emitters):
        return {}
    index = {param_name(m, "reflectance"): i for i, m in enumerate(scene.materials) if fused.slot[i]}
    index.update({param_name(e, "emission"): len(scene.materials) + i for i, e in enumerate(scene.emitters)})
    return index


def vertex(fused: FusedScene, hits: tuple, d, beta, pdf_dir, delta, keys, depth: int, more: bool, roulette: bool, offset: float, tangents: bool, strata=None) -> tuple:
    """One bounce of N paths: :func:`invrender.core.lanes.path_vertex` run by Dr.Jit or eager
    torch (:func:`invrender.core.compiled.run`).

    Args:
        hits: (prim, u, v, t) (N,) each: the paths' closest hits, all valid.
        d, beta: (N, 3) the rays' directions and the paths' throughputs; pdf_dir (N,) the pdf ``d``
            was sampled with; delta (N,) bool: ``d`` came from a delta lobe or the camera; keys
            (N,) int32 path keys; depth: the vertex's index (0: camera rays).
        more, roulette: do paths go on after it; does Russian roulette apply.
        strata: (N, 4) the numbers of :data:`~invrender.core.lanes.DIRECT_PAIRS` drawn in
            place of the hashed ones (``PathState.strata``), or None.
    Returns:
        (3-vectors as :class:`~invrender.backends.arrays.Columns`)
        emitted (N, 3) (term depth), shadow rays o (N, 3), d (N, 3), tmax (N,) and the direct light
        (N, 3) each adds if unoccluded (term depth + 1; tmax 0, a ray no backend traces, where the
        light sample adds nothing whatever the parameters), then the continued paths' o, d, beta
        (N, 3), pdf (N,), delta (N,) and alive (N,) bool (without ``more``: None, the direct light
        zero). With ``tangents``, then also what :func:`jacobian_add` and :func:`tangents_add`
        reads: the factors beside eps of the emission (N, 3) and of the direct light (N, 3), the
        emitters hit (N,) int32 (-1: none) and sampled (N,), and the materials hit (N,).
    """
    salts = tuple(Opaque(s) for s in bounce_salt_values(depth + 1, DIMS))
    static = dict(materials=fused.materials, emitters=fused.emitters, first=depth == 0, mis=fused.mis, nee_only=fused.nee_only,
                  nee=fused.nee, more=more, roulette=roulette, absorbing=fused.absorbing, tangents=tangents)  # fmt: skip
    given = None if strata is None else Columns.of(strata)
    out = compiled.run(lanes.path_vertex, keys.device, *fused.lanes, *hits, d, beta, pdf_dir, delta, keys, salts, given, float(offset), unstacked=True, **static)
    if not more:  # the emission alone: the other primal outputs are not read (the direct light: zero)
        out = (out[0], None, None, None, Columns(torch.zeros_like(c) for c in out[0]), None, None, None, None, None, None) + out[1:]
    return out


def jacobian_lanes(xp, sums, pixel, rho, emitted, direct, factor_e, emitter_hit, factor_d, emitter_sampled, material_hit, counts: tuple, active, occluded, *, materials: int, emitters: int, width: int, scatter: bool) -> tuple:
    """One vertex's derivatives in the scene's constant parameters (:class:`TangentFilm`), added
    to its pixel's row of ``sums``: a contribution C with n factors of rho_m has ``n C / rho_m``
    (0 in a channel where rho_m is 0), one with the factor eps_e the factor beside it.

    Args:
        sums: the film's rows (:class:`~invrender.core.compiled.Sums`), ``width`` floats a pixel
            (channel c, slot s at ``c S + s``); pixel: UInt the lane's pixel; rho: (M * 4,)
            Float the materials' rho rows (RGB and a pad); emitted, direct: 3 Floats the vertex's
            emission and direct light (counted where unoccluded); factor_e, factor_d: 3 Floats the
            factors beside eps of the two; emitter_hit, emitter_sampled: UInt the emitters hit and
            sampled (``0xFFFFFFFF``: none); material_hit: UInt the vertex's material (its direct
            light has one more factor of it); counts: M UInts the factors of each rho in the
            path's throughput; active: Bool the lanes to add; occluded: Bool the shadow rays'
            answers, or None (no emitter samples).
        scatter: the paths go on (their counts are returned with this vertex's material counted).
    Returns:
        with ``scatter``, the M counts after this vertex; else nothing.
    """
    lit = xp.ult(emitter_sampled, emitters) & ~occluded if occluded is not None else None
    lit_direct = tuple(xp.select(lit, direct[c], 0.0) for c in range(3)) if lit is not None else None
    zero = 0.0 * emitted[0]
    row = [zero] * width
    slots = materials + emitters
    for m in range(materials):
        r = xp.gather_rows(rho, xp.full(m, material_hit), 4)
        n = xp.float(counts[m])
        nd = xp.select(material_hit == m, n + 1.0, n)
        keep = nd > 0.0
        for c in range(3):
            c_m = n * emitted[c] if lit_direct is None else n * emitted[c] + nd * lit_direct[c]
            row[c * slots + m] = xp.select(keep & (r[c] > 0.0), c_m / r[c], 0.0)
    for e in range(emitters):
        for c in range(3):
            d_e = xp.select(emitter_hit == e, factor_e[c], 0.0)
            row[c * slots + materials + e] = d_e if lit is None else d_e + xp.select(lit & (emitter_sampled == e), factor_d[c], 0.0)
    xp.scatter_add_rows(sums, tuple(row), pixel, active)
    if not scatter:
        return ()
    return (tuple(counts[m] + xp.uint(xp.select(material_hit == m, 1.0, 0.0)) for m in range(materials)),)


def jacobian_add(film: TangentFilm, pixel, counts, rho, emitted, tangents: tuple, direct, occluded, scatter: bool):
    """One bounce's derivatives in the scene's constant parameters (slots 0 .. M - 1 the materials'
    rho, M .. the emitters' eps) added per pixel, channel and slot into ``film``
    (:func:`jacobian_lanes`, run by :func:`~invrender.core.compiled.run`).

    Args:
        pixel: (N,) int64 film index; counts: (N, M) int32 each path's throughput's factors of each
            rho; rho (M, 3); emitted, direct (N, 3) the bounce's contributions (``direct`` as the
            vertex gave it: the occluded samples are dropped here); tangents: the extra outputs of
            :func:`vertex`; occluded: (N,) bool the shadow rays' answers (None: no emitter
            samples); scatter: the paths go on.
    Returns:
        the counts after this vertex (its material counted where the paths ``scatter`` on).
    """
    n, materials = pixel.shape[0], rho.shape[0]
    if not n:
        return counts
    emitted_factor, emitter_hit, direct_factor, emitter_sampled, material_hit = tangents
    rows = torch.nn.functional.pad(rho.detach().float(), (0, 1)).reshape(-1)
    active = torch.ones(n, dtype=torch.bool, device=pixel.device)  # (False in a padded call's extra lanes)
    out = compiled.run(jacobian_lanes, pixel.device, film.sums, pixel, rows, emitted, direct, emitted_factor, emitter_hit, direct_factor, emitter_sampled,
                       material_hit, tuple(counts.unbind(1)), active, occluded, materials=materials, emitters=film.slots - materials, width=film.row, scatter=scatter)  # fmt: skip
    return out[0] if scatter else counts


def tangents_add(pixel, counts, rho, emitted, tangents: tuple, direct, occluded, scatter: bool, places: torch.Tensor):
    """One bounce's contributions' monomial codes ``sum_s k_s places[s]`` (``places`` (S,) int64;
    k_s the factors of slot s of :func:`jacobian_add`; -1 where there is no contribution: path
    records' codes), then each path's vertex material counted in ``counts`` (N, M) int32 (its
    throughput's factors of each rho) when the paths ``scatter`` on.

    Args:
        pixel: (N,) int64 film index; rho (M, 3); emitted, direct (N, 3) the bounce's contributions
            (``direct`` zero where occluded); tangents: the extra outputs of :func:`vertex`;
        occluded: (N,) bool the shadow rays' answers (None: no emitter samples).
    Returns:
        (codes of the emission (N,), of the direct light (N,)) int64, then the counts after this
        vertex.
    """
    n, materials = pixel.shape[0], rho.shape[0]
    _, emitter_hit, _, emitter_sampled, material_hit = tangents
    lit = emitter_sampled >= 0
    lit = lit & ~occluded if occluded is not None else torch.zeros_like(lit)
    hit = emitter_hit >= 0
    base = (counts.to(torch.int64) * places[:materials]).sum(1)
    to_emitter = places[materials:]
    code_e = torch.where(hit, base + to_emitter.index_select(0, emitter_hit.clamp(min=0)), -1)
    code_d = base + places.index_select(0, material_hit) + to_emitter.index_select(0, emitter_sampled.clamp(min=0))
    if scatter and n:
        counts.index_put_((torch.arange(n, device=pixel.device), material_hit.to(torch.int64)), torch.ones(n, dtype=counts.dtype, device=pixel.device), accumulate=True)
    return (code_e, torch.where(lit, code_d, -1)), counts


def trace(ctx: TransportContext, fused: FusedScene, state: PathState, film: Film, settings) -> None:
    """Follow ``state``'s camera rays with the fused bounce and add each term to ``film`` (and,
    into a :class:`TangentFilm`, each pixel's derivatives; a film with an ``arrive`` hook is told
    the direction of every contribution that may end on an emitter infinitely far away just before
    it); ``settings``: the integrator's (``max_depth``, ``rr_depth``). With ``hide_emitters`` (a
    scene without emitting shapes: :func:`tables`) camera rays that leave the scene add nothing."""
    rr_start = math.inf if settings.rr_depth == -1 else settings.rr_depth
    pixel, keys, o, d, beta, pdf, delta, strata = state.pixel, state.keys, state.o, state.d, state.beta, state.pdf_dir, state.delta, state.strata
    coded = places(film)
    tangents = isinstance(film, TangentFilm) or coded is not None
    rho = fused.rho
    arrives = fused.infinite and type(film).arrive is not Film.arrive
    at_once = not film.terms and not tangents and not arrives  # a bounce's two terms in one film addition
    counts = torch.zeros(rho.shape[0] if tangents else 0, keys.shape[0], dtype=torch.int32, device=keys.device).t()  # factors of each rho in beta, (N, M) by columns (as the kernels give them)
    # with materials of delta lobes only, shadow rays are cast from the others' vertices alone, as
    # the torch bounce casts them, where the queries are recorded (path replay's adjoint pass takes
    # the same queries in order); elsewhere all are passed, those vertices' with tmax 0, which no
    # backend traces (a compaction saved)
    recorded = ctx.accel.records("occluded")
    smooth = ctx.materials.has_rows(Lobe.SMOOTH).index_select(0, ctx.triangles.material) if ctx.materials.any_delta_only and recorded else None
    depth, alive = 0, None  # alive: the paths that go on, where some ended at the last vertex
    while keys.shape[0]:
        escape = fused.infinite and not (depth == 0 and ctx.hide_emitters)  # term depth for the rays that leave the scene
        # a synchronization: the count of rays that hit; the paths that ended are not traced and
        # drop out with the misses (one compaction a bounce)
        found = ctx.accel.closest_hits(o, d, misses=escape, alive=alive)
        if escape and found.gone.shape[0]:
            gone = found.gone
            args = [take(x, gone) for x in (d, beta, pdf, delta)]
            (seen,) = compiled.run(lanes.escaped_vertex, keys.device, fused.lanes[1], fused.lanes[2], *args, emitters=fused.emitters, first=depth == 0, mis=fused.mis, nee_only=fused.nee_only)
            at = pixel.index_select(0, gone)
            if arrives:
                film.arrive(at, stacked(args[0]))
            film.add(depth, at, seen)
        hit, prim, u, v, t = found.index, found.prim, found.u, found.v, found.t
        del found  # (a bounce's arrays are released as soon as they are read: a chunk's peak memory is one bounce's)
        if hit.shape[0] < keys.shape[0]:
            pixel, keys, d, beta, pdf, delta, counts = (take(x, hit) for x in (pixel, keys, d, beta, pdf, delta, counts))
            strata = None if strata is None else take(strata, hit)
            if not hit.shape[0]:
                break
        more = settings.continues_after(depth)
        out = vertex(fused, (prim, u, v, t), d, beta, pdf, delta, keys, depth, more, depth + 1 >= rr_start, ctx.ray_offset, tangents, strata=strata)
        strata = None  # the first vertex's alone
        emitted, shadow_o, shadow_d, shadow_t, direct, o, d, beta, pdf, delta, alive = out[:11]
        factors = out[11:]  # what jacobian_add and tangents_add read
        del out
        occluded = None
        if more and fused.nee:
            if smooth is None:
                occluded = ctx.accel.occluded(shadow_o, shadow_d, shadow_t)
            else:
                cast = where_true(smooth.index_select(0, prim))
                occluded = torch.zeros_like(keys, dtype=torch.bool)
                occluded[cast] = ctx.accel.occluded(*(take(x, cast) for x in (shadow_o, shadow_d, shadow_t)))
            # the occluded samples' direct light zeroed: a multiplication by 0 or 1 (the kernel's
            # direct light is finite: samples that add nothing are 0), several times faster on the
            # CPU than a fill by a boolean mask
            keep = (~occluded).to(torch.float32)
            if at_once:  # both terms in one image: one addition (5% of a render's CPU time), the occluded direct light dropped on the way,
                # written straight into the film's float64 (16% less than stacking, adding and converting)
                both = torch.empty(3, keep.shape[0], dtype=torch.float64, device=keep.device)
                for c in range(3):
                    torch.addcmul(emitted[c], direct[c], keep, out=both[c])
            else:
                for c in direct:
                    c.mul_(keep)
            del keep
        del shadow_o, shadow_t  # the shadow rays, once cast
        if coded is not None:  # path records: each contribution with its monomial's code
            (code_e, code_d), counts = tangents_add(pixel, counts, rho, emitted, factors, direct, occluded, more, places=coded)
            film.add_coded(depth, pixel, code_e, emitted.stacked())  # term depth
            if occluded is not None:
                film.add_coded(depth + 1, pixel, code_d, direct.stacked())  # term depth + 1
        elif occluded is not None and at_once:
            film.add(depth, pixel, both.t())
            del both
        else:
            film.add(depth, pixel, emitted.stacked())  # term depth
            if occluded is not None:
                if arrives:
                    film.arrive(pixel, shadow_d.stacked())
                film.add(depth + 1, pixel, direct.stacked())  # term depth + 1
            if tangents:
                counts = jacobian_add(film, pixel, counts, rho, emitted, factors, direct, occluded, more)
        del factors, emitted, shadow_d, direct, occluded, prim, u, v, t, hit
        if not more:
            break
        if not (depth + 1 >= rr_start or fused.absorbing):
            alive = None  # (every path goes on)
        depth += 1
