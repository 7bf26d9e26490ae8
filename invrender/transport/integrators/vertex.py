"""The per-vertex steps the integrators share: find the next vertex, add the emission seen there,
estimate direct light by sampling emitters, add the ambient term, continue along a BSDF sample.

Each step comments the term of ``I = g eps + gMg eps + ...`` it adds: a vertex at depth k (0 = the
camera ray's hit) sees emission in term k and gathers direct light into term k + 1.
"""

from __future__ import annotations

import torch

from invrender.transport.bsdfs import BSDFSample, Lobe, ShadingPoint
from invrender.transport.context import PathState, TransportContext
from invrender.transport.film import Film
from invrender.transport.surface import Surface, surface_at


def power_heuristic(pdf_a: torch.Tensor, pdf_b: torch.Tensor) -> torch.Tensor:
    """MIS weight (N,) of strategy a against b (Veach's power heuristic, beta = 2)."""
    a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
    return torch.where(a2 > 0, a2 / (a2 + b2).clamp_min(1e-30), 0.0)


def next_vertex(ctx: TransportContext, state: PathState, film: Film) -> tuple[PathState, Surface | None]:
    """Intersect ``state``'s rays; paths whose ray leaves the scene end (no environment light).
    The film is told of the new vertices (``Film.visit``)."""
    hits = ctx.accel.intersect(state.o, state.d)
    hit = hits.valid.nonzero()[:, 0]
    state, hits = state.select(hit), hits.select(hit)
    if not state.count:
        return state, None
    s = surface_at(ctx.triangles, hits, state.d, ctx.textured)
    film.visit(state.pixel, s)
    return state, s


def add_emitted(ctx: TransportContext, state: PathState, s: Surface, depth: int, film: Film, mis: bool, nee_only: bool = False) -> None:
    """Term ``depth``: emission seen along the ray, ``beta w eps``.

    With ``mis`` the weight w balances this BSDF-sampled hit against the emitter sample taken at
    the previous vertex (power heuristic); with ``nee_only`` that emitter sample alone estimated
    the term, so w = 0. Either way w is 1 for camera rays and after delta lobes, where no emitter
    sample competes; without either w = 1 everywhere (no emitter sampling).
    """
    if mis and nee_only:
        raise ValueError("add_emitted: mis and nee_only exclude each other")
    emits = ctx.emits(s)
    if nee_only:
        emits = emits & state.delta  # camera rays (delta = True) and delta lobes only
    if not bool(emits.any()):
        return
    m = emits.nonzero()[:, 0]
    se = s.select(m)
    Le = ctx.emitted(se)
    if mis and depth > 0:
        pdf_light = ctx.lights.pdf_area.index_select(0, se.tri) * se.t * se.t / se.cos_o.clamp_min(1e-12)  # area -> solid angle
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
    """
    if ctx.lights is None:
        return
    if ctx.materials.any_delta_only:
        keep = ctx.materials.has(sp, Lobe.SMOOTH).nonzero()[:, 0]
        state, s, sp, u = state.select(keep), s.select(keep), sp.select(keep), u.index_select(0, keep)
    ls = ctx.lights.sample_from(u[:, 2:5], s.p, s.n, ctx.ray_offset)
    ok = ls.facing & ~ctx.accel.occluded(ls.o, ls.wl, ls.tmax)
    f_cos = ctx.materials.eval(sp, ls.wl)
    if mis:
        w = power_heuristic(ls.pdf, ctx.materials.pdf(sp, ls.wl).detach())
        weight = torch.where(ok, w / ls.pdf, 0.0)
    else:
        weight = torch.where(ok, 1.0 / ls.pdf, 0.0)
    Le = ctx.emission(ctx.triangles.emitter.index_select(0, ls.tri), ls.uv)
    film.add(term, state.pixel, (state.beta * weight[:, None]) * f_cos * Le)  # the constant factors first: autograd saves less


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
