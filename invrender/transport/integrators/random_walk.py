"""Kajiya's random walk: the plain Markov-chain estimator of the Neumann series.

At every vertex the emitted radiance seen along the ray is added with the path throughput; the
next direction is drawn from the cosine-weighted BSDF, so the throughput gains exactly rho per
bounce. No light sampling: deliberately minimal, the reference the ``path`` integrator is checked
against.
"""

from __future__ import annotations

import dataclasses

from invrender.transport import bsdf
from invrender.transport.context import PathState, TransportContext, russian_roulette
from invrender.transport.film import Film
from invrender.transport.sampler import uniform
from invrender.transport.surface import surface_at


def trace(ctx: TransportContext, state: PathState, film: Film) -> None:
    """Follow ``state``'s camera rays and add each term ``g(Mg)^k eps`` to ``film``."""
    settings = ctx.settings
    depth = 0
    while state.count:
        hits = ctx.accel.intersect(state.o, state.d)
        hit = hits.valid  # rays leaving the scene carry nothing (no environment light)
        state, hits = state.select(hit), hits.select(hit)
        if not state.count:
            break
        s = surface_at(ctx.triangles, hits, state.d, ctx.textured)

        # term k = depth: emission seen along the ray, weighted by the throughput
        film.add(depth, state.pixel, state.beta * ctx.emitted(s))
        if not settings.continues_after(depth):
            break

        # next direction from the cosine-weighted BSDF: weight f cos / pdf = rho
        rho = ctx.reflectance(s)
        film.reflect(state.pixel, rho)
        u = uniform(state.keys, depth + 1, 6)
        wi = bsdf.sample(s.n, u[:, 0:2])
        beta = state.beta * (rho.detach() if film.detach_throughput else rho)
        state = dataclasses.replace(state, o=ctx.spawn(s, wi), d=wi, beta=beta)
        state = russian_roulette(state, u[:, 5], depth, settings.rr_depth)
        depth += 1

