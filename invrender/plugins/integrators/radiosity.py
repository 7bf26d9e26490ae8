"""Radiosity as an integrator: the patch solution computed in the pre-pass, read at camera hits.

The pre-pass (:meth:`Radiosity.prepare`) meshes the diffuse scene into patches, estimates their
form factors by ray casting and solves ``(I - diag(rho) F) B = E``
(:func:`invrender.radiosity_solver.solution.solve_scene`; docs/radiosity.md); :func:`radiosity`
(``ir.radiosity``) runs the pre-pass alone and returns the solution. ``trace`` then follows each
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
from dataclasses import dataclass

import torch

from invrender.errors import ParameterError
from invrender.core.context import PathState, TransportContext
from invrender.core.driver import RenderSettings
from invrender.core.film import Film
from invrender.plugins.integrators.base import DepthSettings, Integrator
from invrender.plugins.integrators.vertex import add_emitted, next_vertex, scattered
from invrender.radiosity_solver.form_factors import FormFactorSettings
from invrender.radiosity_solver.patches import MAX_PATCHES
from invrender.radiosity_solver.solution import RadiositySolution, check_diffuse, solve_scene
from invrender.radiosity_solver.system import SolverSettings
from invrender.core.sampler import uniform

#: random numbers drawn per vertex (the random walk's layout): 0-1 BSDF direction, 6 BSDF lobe
DIMS = 7
#: target patch count when neither ``subdivision`` nor ``patches`` is given
DEFAULT_PATCHES = 1024


@dataclass(frozen=True)
class RadiositySettings(DepthSettings):
    """Settings of radiosity (the ``radiosity`` integrator and :func:`radiosity`).

    Attributes:
        max_depth: Neumann terms kept, counted as the path tracer counts them (1 = emitters seen,
            2 = + direct light, ...); -1 (default) = the exact solution of the system.
        subdivision: segments per scene-triangle edge (each triangle gives subdivision^2 patches),
            in [1, 64]; or
        patches: a target patch count (patches of about equal area); default 1024 when neither is
            given; giving both is an error.
        rays: form-factor rays cast from each patch side (rounded to ``batches`` x a power of 2).
        emitter_rays: rays cast from each emitter side, whose columns of F come from them by
            reciprocity; None = ``rays`` x (other sides per emitter side), at most 16 x ``rays``.
        batches: independent batches of those rays, for the form factors' standard errors.
        form_factor_seed: seed of the form-factor rays.
        method: solver: ``"auto"`` (direct up to 1024 unknowns, else Gauss-Seidel), ``"direct"``,
            ``"jacobi"``, ``"gauss_seidel"``, ``"neumann"``.
        tolerance: relative residual at which the iterative solvers stop.
        max_iterations: iterative solves that need more are an error.
        final_gather: at each camera hit, gather the patch radiosities along one cosine-sampled
            ray (one bounce of path tracing) instead of reading the hit patch's own.
    """

    max_depth: int = -1
    subdivision: int | None = None
    patches: int | None = None
    rays: int = 256
    emitter_rays: int | None = None
    batches: int = 4
    form_factor_seed: int = 0
    method: str = "auto"
    tolerance: float = 1e-10
    max_iterations: int = 10000
    final_gather: bool = False

    def __post_init__(self):
        super().__post_init__()
        if self.subdivision is not None and self.patches is not None:
            raise ParameterError("give radiosity either subdivision (segments per triangle edge) or patches (a target patch count), not both")
        for name, value, high in (("subdivision", self.subdivision, 64), ("patches", self.patches, MAX_PATCHES)):
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= high):
                raise ParameterError(f"radiosity {name} must be an integer in [1, {high}], got {value!r}")
        if not isinstance(self.final_gather, bool):
            raise ParameterError(f"final_gather must be true or false, got {self.final_gather!r}")
        self.form_factor_settings  # noqa: B018  (validates)
        self.solver_settings  # noqa: B018

    @property
    def form_factor_settings(self) -> FormFactorSettings:
        return FormFactorSettings(rays=self.rays, batches=self.batches, seed=self.form_factor_seed, emitter_rays=self.emitter_rays)

    @property
    def solver_settings(self) -> SolverSettings:
        return SolverSettings(method=self.method, tolerance=self.tolerance, max_iterations=self.max_iterations)

    @property
    def mesh(self) -> tuple[int | None, int | None]:
        """(subdivision, patches) as :func:`~invrender.radiosity_solver.patches.mesh_patches` takes them."""
        if self.subdivision is None and self.patches is None:
            return None, DEFAULT_PATCHES
        return self.subdivision, self.patches


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
        :class:`~invrender.radiosity_solver.solution.RadiositySolution`."""
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


def radiosity(scene, *, backend: str | None = None, device=None, params: dict | None = None, **options) -> RadiositySolution:
    """Solve the radiosity of a diffuse scene.

    Args:
        scene: a scene whose materials are all ``diffuse``.
        backend: intersection backend for the form factors (``"embree"``, ``"torch"``; None = the
            device's default).
        device: where to compute (None = the scene's device).
        params: parameter values to use instead of ``scene.params``.
        options: :class:`RadiositySettings` fields: ``subdivision`` or ``patches``, ``rays``,
            ``batches``, ``form_factor_seed``, ``method``, ``tolerance``, ``max_iterations``,
            ``max_depth``, ``final_gather`` (for :meth:`~invrender.radiosity_solver.solution.RadiositySolution.render`).
    Returns:
        a :class:`~invrender.radiosity_solver.solution.RadiositySolution`; its ``B`` is differentiable in every ``scene.params`` entry
        that requires grad.
    Raises:
        ParameterError: a non-diffuse material (named), settings out of range.
    """
    integrator = Radiosity(**options)
    device = torch.device(device) if device is not None else scene.device
    ctx = integrator.context(scene, RenderSettings(backend=backend), device, params)
    return dataclasses.replace(ctx.extra, scene=scene, integrator=integrator)


__all__ = ["DEFAULT_PATCHES", "Radiosity", "RadiositySettings", "radiosity"]
