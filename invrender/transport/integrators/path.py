"""The path tracer: BSDF sampling + next-event estimation, combined by multiple importance sampling.

At vertex x_k (k = 0 is the camera ray's hit) the Neumann term k+1 is estimated twice and the two
estimates are blended with the power heuristic: once by sampling a point on an emitter (NEE) and
once by following the cosine-weighted BSDF direction and seeing whether it hits an emitter. Russian
roulette ends paths from ``rr_depth`` on. Sampling never depends on rho or eps; gradients flow
through the factors rho(x_k) and eps(x_k) only (DESIGN.md decision 4).
"""

from __future__ import annotations

import dataclasses
import math

import torch

from invrender.transport import bsdf
from invrender.transport.context import PathState, TransportContext, russian_roulette
from invrender.transport.film import Film
from invrender.transport.sampler import uniform
from invrender.transport.surface import Surface, surface_at
from invrender.transport.vec import dot, norm


def power_heuristic(pdf_a: torch.Tensor, pdf_b: torch.Tensor) -> torch.Tensor:
    """MIS weight (N,) of strategy a against b (Veach's power heuristic, beta = 2)."""
    a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
    return torch.where(a2 > 0, a2 / (a2 + b2).clamp_min(1e-30), 0.0)


def trace(ctx: TransportContext, state: PathState, film: Film, ambient: torch.Tensor | None = None) -> None:
    """Follow ``state``'s camera rays and add each term ``g(Mg)^k eps`` to ``film``.

    ``ambient``: (3,) radiance eps0 arriving from every direction at the first vertex, reflected
    into term 1 as ``rho eps0`` (the Utah approximation's stand-in for interreflection); None = none.
    """
    settings = ctx.settings
    depth = 0
    while state.count:
        hits = ctx.accel.intersect(state.o, state.d)
        hit = hits.valid  # rays leaving the scene carry nothing (no environment light)
        state, hits = state.select(hit), hits.select(hit)
        if not state.count:
            break
        s = surface_at(ctx.triangles, hits, state.d, ctx.textured)

        # term k = depth, BSDF strategy: an emitter seen along the ray. Its MIS weight balances it
        # against NEE from the previous vertex; the camera ray (depth 0) has no competing strategy.
        emits = ctx.emits(s)
        if bool(emits.any()):
            m = emits.nonzero()[:, 0]
            se = s.select(m)
            w = 1.0
            if depth > 0:
                pdf_light = ctx.lights.pdf_area[se.tri] * se.t * se.t / se.cos_o.clamp_min(1e-12)
                w = power_heuristic(state.pdf_dir[m], pdf_light)[:, None]
            film.add(depth, state.pixel[m], state.beta[m] * w * ctx.emitted(se))
        if not settings.continues_after(depth):
            break

        u = uniform(state.keys, depth + 1, 6)
        rho = ctx.reflectance(s)
        if ambient is not None and depth == 0:
            # term 1, Utah's ambient: a Lambertian surface under uniform radiance eps0 reflects rho eps0
            film.add(1, state.pixel, state.beta * rho * ambient)

        # term k = depth + 1, light strategy: NEE towards a point on an emitter
        if ctx.lights is not None:
            _next_event(ctx, state, s, rho, u, depth + 1, film)

        # continue the path: cosine-weighted BSDF sample, weight f cos / pdf = rho
        film.reflect(state.pixel, rho)
        wi = bsdf.sample(s.n, u[:, 0:2])
        beta = state.beta * (rho.detach() if film.detach_throughput else rho)
        state = dataclasses.replace(state, o=ctx.spawn(s, wi), d=wi, beta=beta, pdf_dir=bsdf.pdf(s.n, wi))
        state = russian_roulette(state, u[:, 5], depth, settings.rr_depth)
        depth += 1


def _next_event(ctx: TransportContext, state: PathState, s: Surface, rho: torch.Tensor, u: torch.Tensor, term: int, film: Film):
    """Add ``beta f cos eps G V / pdf_light`` (MIS-weighted) for one emitter sample per path.

    Every path casts its shadow ray and adds its (possibly zero) contribution: cheaper here than
    compacting the dozen per-path tensors down to the samples that can contribute.
    """
    ls = ctx.lights.sample(u[:, 2], u[:, 3:5])
    o = s.p + ctx.ray_offset * s.n
    to_light = ls.p - o
    dist = norm(to_light).clamp_min(1e-12)
    wl = to_light / dist[:, None]
    cos_x = dot(s.n, wl)  # at the shading point
    cos_l = -dot(ls.n, wl)  # at the light: only its front side emits
    ok = (cos_x > 0) & (cos_l > 0)
    ok &= ~ctx.accel.occluded(o, wl, dist - ctx.ray_offset)
    pdf_light = ls.pdf_area * dist * dist / cos_l.clamp_min(1e-12)  # area -> solid angle
    pdf_bsdf = cos_x.clamp_min(0.0) / math.pi
    weight = torch.where(ok, power_heuristic(pdf_light, pdf_bsdf) * pdf_bsdf / pdf_light, 0.0)  # MIS w x cos/pi / pdf
    Le = ctx.emission(ctx.triangles.emitter[ls.tri], ls.uv)
    film.add(term, state.pixel, state.beta * rho * Le * weight[:, None])
