"""Kajiya's random walk: the plain Markov-chain estimator of the Neumann series.

At every vertex the emitted radiance seen along the ray is added with the path throughput; the
next direction is drawn from the BSDF, so the throughput gains the sample weight ``f cos / pdf``
(rho for a Lambertian surface) per bounce. No light sampling: deliberately minimal, the reference
the ``path`` integrator is checked against, and the bounce loop the richer integrators extend
through its hooks (:attr:`RandomWalk.emitter_mis`, :attr:`RandomWalk.emitter_nee_only` and
:meth:`RandomWalk.at_vertex`).
"""

from __future__ import annotations

import math

from invrender.errors import ParameterError

from invrender.core import fused
from invrender.core.context import PathState, TransportContext, russian_roulette
from invrender.core.film import Film
from invrender.plugins.integrators.base import Integrator, SamplingSettings
from invrender.plugins.integrators.vertex import absorbed, add_emitted, next_vertex, scattered
from invrender.core.lanes import DIRECT_DIMS
from invrender.core.sampler import uniform

#: random numbers drawn per vertex: 0-1 BSDF direction, 2-4 emitter sample, 5 roulette, 6 BSDF lobe
DIMS = 7


class RandomWalk(Integrator):
    name = "random_walk"
    Settings = SamplingSettings
    summary = "Kajiya's random walk: BSDF sampling only (the reference)"

    #: weight emitter hits against the previous vertex's emitter sample (path tracer: True)
    emitter_mis = False
    #: emitter hits count only where no emitter sample was taken (camera rays, after delta lobes):
    #: the previous vertex's emitter sample alone estimates direct light (path tracer, strategy "emitter")
    emitter_nee_only = False

    @property
    def samples_emitters(self) -> bool:
        """Does it sample emitters (next-event estimation)? Without, delta lights (a point, a spot, a
        direction: never hit by a ray) are refused (:meth:`prepare`)."""
        return False

    def prepare(self, ctx: TransportContext) -> TransportContext:
        delta = [light.type_name for light in ctx.lights.lights if not light.surface and not light.infinite]
        if delta and not self.samples_emitters:
            raise ParameterError(
                f"integrator {self.name!r} estimates light by BSDF samples only, which never hit a {delta[0]} light (a delta light): "
                "render with an integrator that samples emitters (path with strategy 'mis' or 'emitter')"
            )
        return ctx

    @property
    def fused_direct(self):
        """How the fused primal bounce (:mod:`invrender.core.fused`) estimates direct light
        for this integrator: False (no emitter samples: the random walk); None where a subclass's
        :meth:`at_vertex` does something of its own (the torch bounce runs)."""
        return False if type(self).at_vertex is RandomWalk.at_vertex else None

    def at_vertex(self, ctx: TransportContext, state: PathState, s, sp, u, depth: int, film: Film) -> PathState | None:
        """What a vertex adds before the path scatters on (nothing here; the path tracer adds direct
        light). Returns the paths that scatter on (None = all)."""
        return None

    def trace(self, ctx: TransportContext, state: PathState, film: Film) -> None:
        """Follow ``state``'s camera rays and add each term ``g(Mg)^k eps`` to ``film`` (by the fused
        bounce where it applies: :mod:`invrender.core.fused`)."""
        cfg = self.settings
        scene = self.fused_scene(ctx)
        if scene is not None and fused.takes(film, scene):
            fused.trace(ctx, scene, state, film, cfg)
            return
        rr_start = math.inf if cfg.rr_depth == -1 else cfg.rr_depth  # -1: no roulette
        depth = 0
        while state.count:
            state, s = next_vertex(ctx, state, film, depth, mis=self.emitter_mis, nee_only=self.emitter_nee_only)
            if s is None:
                break
            add_emitted(ctx, state, s, depth, film, mis=self.emitter_mis, nee_only=self.emitter_nee_only)  # term depth
            if not cfg.continues_after(depth):
                break
            u = uniform(state.keys, depth + 1, DIMS)
            if state.strata is not None:  # the first vertex's stratified numbers (sampler "stratified_direct")
                u[:, list(DIRECT_DIMS)] = state.strata
                state = state.replace(strata=None)
            sp = ctx.shading_point(s, -state.d)
            keep = self.at_vertex(ctx, state, s, sp, u, depth, film)  # terms depth + 1 (subclasses)
            if keep is not None:
                state, s, sp, u = state.select(keep), s.select(keep), sp.select(keep), u.index_select(0, keep)
            bs = ctx.materials.sample(sp, u[:, 6], u[:, 0:2])
            state = scattered(ctx, state, s, bs, film)
            state = russian_roulette(state, u[:, 5], depth, rr_start, absorbed(ctx, state))
            depth += 1
