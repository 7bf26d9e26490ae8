"""The per-vertex steps the integrators share: find the next vertex, add the emission seen there,
estimate direct light by sampling emitters, add the ambient term, continue along a BSDF sample.

Each step comments the term of ``I = g eps + gMg eps + ...`` it adds: a vertex at depth k (0 = the
camera ray's hit) sees emission in term k and gathers direct light into term k + 1.
"""

from __future__ import annotations

import torch

from invrender.core.queries import Hits
from invrender.core.bsdfs import BSDFSample, Lobe, ShadingPoint
from invrender.core.context import PathState, TransportContext
from invrender.core.film import Film
from invrender.core.lights import LightSample
from invrender.core.surface import Surface, surface_at
from invrender.vec import where_true


def power_heuristic(pdf_a: torch.Tensor, pdf_b: torch.Tensor) -> torch.Tensor:
    """MIS weight (N,) of strategy a against b (Veach's power heuristic, beta = 2)."""
    a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
    return torch.where(a2 > 0, a2 / (a2 + b2).clamp_min(1e-30), 0.0)


def next_vertex(ctx: TransportContext, state: PathState, film: Film, depth: int, mis: bool = False, nee_only: bool = False) -> tuple[PathState, Surface | None]:
    """Intersect ``state``'s rays (the vertex of index ``depth``): the paths that hit, and their
    surfaces (None when none did). The film is told of the new vertices (``Film.visit``).

    Paths whose ray leaves the scene end here; where the scene has emitters infinitely far away
    (a sky), they first add term ``depth``, the radiance arriving along the ray, weighted as
    :func:`add_emitted` weighs emission seen (``mis``, ``nee_only``). With the integrator's
    ``hide_emitters``, camera rays pass through emitting shapes (:func:`through_emitters`).
    """
    hits = ctx.accel.intersect(state.o, state.d)
    if depth == 0 and ctx.hide_emitters and ctx.lights.surfaces:
        hits = through_emitters(ctx, state, hits)
    if ctx.lights.infinite:
        missed = where_true(~hits.valid)
        if missed.numel():
            gone = state.select(missed)
            add_emitted(ctx, gone, None, depth, film, mis, nee_only)
    hit = where_true(hits.valid)
    state, hits = state.select(hit), hits.select(hit)
    if not state.count:
        return state, None
    s = surface_at(ctx.triangles, hits, state.d, ctx.textured, ctx.normals)
    film.visit(state.pixel, s)
    return state, s


#: emitting shapes a camera ray passes through with hide_emitters before it is taken as it is
MAX_HIDDEN_LAYERS = 8


def through_emitters(ctx: TransportContext, state: PathState, hits: Hits) -> Hits:
    """``hits`` of camera rays with the emitting shapes (either side) taken out, as Mitsuba's
    ``hide_emitters`` does: a ray that hits one goes on along the same direction from just past
    it, up to :data:`MAX_HIDDEN_LAYERS` times, and the camera sees what lies behind the light."""
    for _ in range(MAX_HIDDEN_LAYERS):
        on = hits.valid & (ctx.triangles.emitter.index_select(0, hits.prim.clamp_min(0)) >= 0)
        i = on.nonzero()[:, 0]
        if not i.numel():
            break
        d = state.d.index_select(0, i)
        t = hits.t.index_select(0, i)
        o = state.o.index_select(0, i) + (t + ctx.ray_offset)[:, None] * d
        again = ctx.accel.intersect(o, d)
        again = Hits(torch.where(again.valid, again.t + t + ctx.ray_offset, again.t), again.prim, again.u, again.v)  # distances from the camera
        hits = Hits(*(x.index_put((i,), y) for x, y in ((hits.t, again.t), (hits.prim, again.prim), (hits.u, again.u), (hits.v, again.v))))
    return hits


def add_emitted(ctx: TransportContext, state: PathState, s: Surface | None, depth: int, film: Film, mis: bool, nee_only: bool = False) -> None:
    """Term ``depth``: radiance seen along the rays, ``beta w Le``: emission of the surfaces ``s``
    they hit, or (``s`` None) of the emitters infinitely far away, for rays leaving the scene.

    With ``mis`` the weight w balances this BSDF-sampled ray against the emitter sample taken at
    the previous vertex (power heuristic); with ``nee_only`` that emitter sample alone estimated
    the term, so w = 0. Either way w is 1 for camera rays and after delta lobes, where no emitter
    sample competes; without either w = 1 everywhere (no emitter sampling). With the integrator's
    ``hide_emitters`` the camera rays (depth 0) add nothing.
    """
    if mis and nee_only:
        raise ValueError("add_emitted: mis and nee_only exclude each other")
    if depth == 0 and ctx.hide_emitters:
        return  # the camera does not see emitters directly
    emits = ctx.lights.emits(s) if s is not None else torch.ones_like(state.delta)
    if nee_only:
        emits = emits & state.delta  # camera rays (delta = True) and delta lobes only
    m = emits.nonzero()[:, 0]  # the one host-device synchronization here (the count of m)
    if not m.numel():
        return
    if s is not None:
        se = s.select(m)
        Le = ctx.lights.emitted(se)
    else:
        d = state.d.index_select(0, m)
        Le = ctx.lights.escaped(d)
        film.arrive(state.pixel[m], d)
    if mis and depth > 0:
        pdf_light = ctx.lights.pdf_hit(se) if s is not None else ctx.lights.pdf_escaped(d)  # the emitter sample's density, as a solid angle
        w = torch.where(state.delta[m], 1.0, power_heuristic(state.pdf_dir[m], pdf_light))[:, None]
        Le = w * Le
    film.add(depth, state.pixel[m], state.beta[m] * Le)


def add_direct(ctx: TransportContext, state: PathState, s: Surface, sp: ShadingPoint, u: torch.Tensor, term: int, film: Film, mis: bool) -> None:
    """Term ``term``: direct light by sampling one point on an emitter per path (soft shadows),
    ``beta f cos_x eps cos_l / (r^2 pdf_area)`` if unoccluded, MIS-weighted against BSDF sampling
    when ``mis`` (else the emitter sample alone estimates the term).

    ``u`` (N, >= 5): dims 2 (emitter pick) and 3-4 (point). Every path casts its shadow ray and adds
    its (possibly zero) contribution: cheaper than compacting a dozen tensors to the ones that count.
    Vertices whose BSDF has delta lobes only (mirror, glass) are skipped: no emitter sample can
    hit a delta lobe (a BSDF with a smooth lobe beside its delta ones gathers through the smooth one).
    Vertices whose BSDF transmits through a smooth lobe (rough glass) also take samples behind
    their surface (:func:`behind_surface`).
    """
    if not ctx.lights.count:
        return
    if ctx.materials.any_delta_only:
        keep = ctx.materials.has(sp, Lobe.SMOOTH).nonzero()[:, 0]
        state, s, sp, u = state.select(keep), s.select(keep), sp.select(keep), u.index_select(0, keep)
    ls = ctx.lights.sample_from(u[:, 2:5], s.p, s.n, ctx.ray_offset)  # detached: the direction, pdf and shadow ray
    if ctx.materials.any_smooth_transmission:
        ls = behind_surface(ctx, ls, s, sp, u)
    ok = ls.facing & ~ctx.accel.occluded(ls.o, ls.wl, ls.tmax)
    f_cos = ctx.materials.eval(sp, ls.wl)
    if mis:
        w = power_heuristic(ls.pdf, ctx.materials.pdf(sp, ls.wl).detach())
        if ls.delta is not None:
            w = torch.where(ls.delta, 1.0, w)  # no BSDF sample hits a point or a direction
        weight = torch.where(ok, w / ls.pdf, 0.0)
    else:
        weight = torch.where(ok, 1.0 / ls.pdf, 0.0)
    if ctx.lights.infinite:
        film.arrive(state.pixel, ls.wl)
    film.add(term, state.pixel, (state.beta * weight[:, None]) * f_cos * ls.Le)  # the constant factors first: autograd saves less


def behind_surface(ctx: TransportContext, ls: LightSample, s: Surface, sp: ShadingPoint, u: torch.Tensor) -> LightSample:
    """``ls`` with the samples that lie behind the surface at vertices whose BSDF has a glossy
    transmission lobe drawn again from its other side: the same emitter point or direction (the
    same uniforms ``u``), its shadow ray offset to the side it leaves on and ``facing`` judged
    there, so light refracted through the surface is gathered; other samples are kept as they are."""
    i = (ctx.materials.has(sp, Lobe.GLOSSY_TRANSMISSION) & ~ls.facing).nonzero()[:, 0]
    if not i.numel():
        return ls
    back = ctx.lights.sample_from(u.index_select(0, i)[:, 2:5], s.p.index_select(0, i), -s.n.index_select(0, i), ctx.ray_offset)
    return LightSample(**{f: None if getattr(ls, f) is None else getattr(ls, f).index_put((i,), getattr(back, f)) for f in ls.__dataclass_fields__})


def add_ambient(ctx: TransportContext, state: PathState, sp: ShadingPoint, term: int, film: Film) -> None:
    """Term ``term``, the ambient stand-in for interreflection: a diffuse surface under uniform
    radiance eps0 reflects ``k_d eps0`` (nothing when the scene has no ambient radiance)."""
    if ctx.ambient is not None:
        film.add(term, state.pixel, state.beta * ctx.materials.diffuse_reflectance(sp) * ctx.ambient)


def scattered(ctx: TransportContext, state: PathState, s: Surface, bs: BSDFSample, film: Film) -> PathState:
    """The paths continued along BSDF samples ``bs``: throughput times the sample weight.

    The film sees the weight first (path replay differentiates everything the path gathers after
    this vertex through it).
    """
    film.scatter(state.pixel, bs.weight)
    weight = bs.weight.detach() if film.detach_throughput else bs.weight
    return state.replace(o=ctx.spawn(s, bs.wi), d=bs.wi, beta=state.beta * weight, pdf_dir=bs.pdf.detach(), delta=bs.delta)


def absorbed(ctx: TransportContext, state: PathState) -> torch.Tensor | None:
    """(N,) bool: paths that carry nothing any more (zero throughput: absorbed, total internal
    reflection's refracted branch, no valid direction), or None when no BSDF of the scene can
    produce a zero weight (flat Lambertian scenes: the weight is rho)."""
    if ctx.materials.all_diffuse and not ctx.triangles.any_smooth:
        return None
    return state.beta.detach().amax(dim=1) <= 0
