"""Radiosity as an integrator: the patch solution computed in the pre-pass, read at camera hits.

The pre-pass (:meth:`Radiosity.prepare`) meshes the diffuse scene into patches, estimates their
form factors by ray casting and solves ``(I - diag(rho) F) B = E``
(:func:`invrender.transport.radiosity.solution.solve_scene`; docs/radiosity.md). ``trace`` then follows each
camera ray to its first hit x on side i of a patch and adds

    term 0:              eps(x)                      (emission seen)
    terms 1 ... D - 1:   rho(x) (F T_(k-1))_i        (light gathered by the patch, reflected at x)

with ``T_k = (diag(rho) F)^k E``, or ``rho(x) (F B)_i`` at once for the exact solution
(``max_depth = -1``). With ``final_gather`` the camera hit instead scatters one cosine-sampled ray
(weight rho(x), as the path tracer's BSDF sample) and the same lookup is made where it lands,
one term later: the patch discretization then shows only through the light arriving at x.

Every factor is differentiable (eps and rho at the point, B by the adjoint system), so ``autodiff``
and ``replay`` both give the exact gradient of this estimate (replay re-solves the system in its
backward pass, from cached form factors).
"""

from __future__ import annotations

import dataclasses

import torch

from invrender.errors import ParameterError
from invrender.transport.context import PathState, TransportContext
from invrender.transport.film import Film
from invrender.transport.integrators.base import Integrator
from invrender.transport.integrators.vertex import add_emitted, next_vertex, scattered
from invrender.transport.radiosity.solution import RadiositySettings, check_diffuse, solve_scene
from invrender.transport.sampler import uniform

#: random numbers drawn per vertex (the random walk's layout): 0-1 BSDF direction, 6 BSDF lobe
DIMS = 7


class Radiosity(Integrator):
    name = "radiosity"
    Settings = RadiositySettings
    summary = "radiosity: diffuse patches, ray-cast form factors, (I - rho F) B = E solved, exact gradients"
    not_recordable = "its image is a rational function of rho (the solved system), not a polynomial"

    def context(self, scene, settings, device, params=None) -> TransportContext:
        check_diffuse(scene)
        return super().context(scene, settings, device, params)

    def prepare(self, ctx: TransportContext) -> TransportContext:
        """Mesh, form factors (cached per geometry) and the solve: ``ctx.extra`` is a
        :class:`~invrender.transport.radiosity.solution.RadiositySolution`."""
        return dataclasses.replace(ctx, extra=solve_scene(ctx, self.settings))

    def render(self, scene, settings, device, params=None, keep=None) -> torch.Tensor:
        if settings.terms and self.settings.max_depth == -1:
            raise ParameterError("radiosity's exact solution is not split into Neumann terms: give a finite max_depth with terms=True")
        return super().render(scene, settings, device, params, keep)

    def trace(self, ctx: TransportContext, state: PathState, film: Film) -> None:
        """Add each camera path's radiosity estimate (per Neumann term when the film keeps terms)."""
        cfg, solution = self.settings, ctx.extra
        per_term = bool(getattr(film, "terms", False))
        depth = 0
        while state.count:
            state, s = next_vertex(ctx, state, film, depth)
            if s is None:
                return
            add_emitted(ctx, state, s, depth, film, mis=False)  # term depth: eps(x)
            if not cfg.continues_after(depth):
                return
            sp = ctx.shading_point(s, -state.d)
            if cfg.final_gather and depth == 0:
                u = uniform(state.keys, depth + 1, DIMS)
                state = scattered(ctx, state, s, ctx.materials.sample(sp, u[:, 6], u[:, 0:2]), film)  # weight rho(x)
                depth += 1
                continue
            # terms depth + 1, ...: rho(x) times what the patch side gathers, (F T_k)_i
            rho = ctx.materials.diffuse_reflectance(sp)
            side = solution.lookup(s.tri, s.p, s.front, ctx.triangles)
            remaining = -1 if cfg.max_depth == -1 else cfg.max_depth - 1 - depth
            if per_term:
                for k, H in enumerate(solution.gathered(side, remaining, per_term=True)):
                    film.add(depth + 1 + k, state.pixel, state.beta * rho * H.to(rho.dtype))
            else:
                film.add(depth + 1, state.pixel, state.beta * rho * solution.gathered(side, remaining).to(rho.dtype))
            return
