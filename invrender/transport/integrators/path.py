"""The path tracer: BSDF sampling + next-event estimation, combined by multiple importance sampling.

At vertex x_k (k = 0 is the camera ray's hit) the Neumann term k+1 is estimated twice and the two
estimates are blended with the power heuristic (Veach and Guibas 1995): once by sampling a point on
an emitter (next-event estimation, skipped at delta vertices) and once by following the BSDF sample
and seeing whether it hits an emitter. Russian roulette ends paths from ``rr_depth`` on. Sampling
never depends on rho or eps; gradients flow through the BSDF and emission factors only.
"""

from __future__ import annotations

from invrender.transport.integrators.random_walk import RandomWalk
from invrender.transport.integrators.vertex import add_direct


class Path(RandomWalk):
    name = "path"
    summary = "path tracer: BSDF sampling + next-event estimation with MIS, Russian roulette (default)"
    emitter_mis = True

    def at_vertex(self, ctx, state, s, sp, u, depth, film):
        add_direct(ctx, state, s, sp, u, depth + 1, film, mis=True)  # term depth + 1, light strategy
        return None
