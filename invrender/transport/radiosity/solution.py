"""Radiosity of a scene: settings, the pipeline (patches -> form factors -> system -> solution) and
the solution object that renders, looks up and re-solves it by random walks.

The pipeline, run once per render by the ``radiosity`` integrator's pre-pass and by
:func:`radiosity`:

1. mesh the scene into patches (:mod:`~invrender.transport.radiosity.patches`), two sides each;
2. estimate the form factors between all sides by ray casting
   (:mod:`~invrender.transport.radiosity.form_factors`); patches and form factors depend on the geometry
   only, so they are cached per geometry and settings (a fit or a replayed gradient re-solves
   without re-casting);
3. average rho and eps over each side (textures too), differentiably;
4. keep the sides from which a chain of form factors leads to an emitter side (every other side
   has ``B = 0`` exactly) and solve ``(I - diag(rho) F) B = E`` on them
   (:mod:`~invrender.transport.radiosity.system`): exactly (``max_depth = -1``), or as the first
   ``max_depth`` terms of its Neumann series, counted as the path tracer counts them.

The image at a camera hit x on side i is ``eps(x) + rho(x) (F B)_i`` (docs/radiosity.md#rendering):
emission and reflectance at the point, the light gathered by the patch from all others.
"""

from __future__ import annotations

import dataclasses
import weakref
from collections import OrderedDict
from dataclasses import dataclass

import torch

from invrender.errors import ParameterError
from invrender.transport.bsdfs import Lobe
from invrender.transport.integrators.base import DepthSettings
from invrender.transport.radiosity.form_factors import FormFactors, FormFactorSettings, form_factors
from invrender.transport.radiosity.patches import MAX_PATCHES, Patches, mesh_patches, side_emission, side_reflectance
from invrender.transport.radiosity.random_walks import WalkEstimate, neumann_ulam
from invrender.transport.radiosity.system import SolveReport, SolverSettings, gather, neumann_terms, solve

#: target patch count when neither ``subdivision`` nor ``patches`` is given
DEFAULT_PATCHES = 1024
#: largest system (unknowns) accepted: its dense matrices take S^2 x 8 bytes each
MAX_UNKNOWNS = 8192


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
        """(subdivision, patches) as :func:`~invrender.transport.radiosity.patches.mesh_patches` takes them."""
        if self.subdivision is None and self.patches is None:
            return None, DEFAULT_PATCHES
        return self.subdivision, self.patches


@dataclass(frozen=True)
class RadiositySolution:
    """A scene's radiosity solution (all tensors on the render device).

    The unknowns are the S patch sides that can receive light (side ``2k`` = patch k's front,
    ``2k + 1`` its back); every other side has ``B = 0``.

    Attributes:
        patches: the patches (P of them).
        form_factors: form factors between all 2P sides (sparse per-batch counts: standard errors,
            row sums, group form factors).
        sides: (S,) int64 the side of each unknown.
        unknown: (2P,) int64 the unknown of each side, S for sides with ``B = 0``.
        F: (S, S) float64 form factors between the unknowns.
        rho: (S, 3) reflectance of each unknown's side (patch average; differentiable).
        E: (S, 3) emitted radiance of each unknown's side (differentiable).
        B: (S, 3) float64 radiance leaving each side (radiosity / pi): the exact solution, or its
            first ``max_depth`` Neumann terms; differentiable in rho and E (exactly).
        H: (K, S + 1, 3) float64 radiance gathered by each side, ``F B``, per Neumann term of the
            light arriving (``H[k] = F T_k``, ``T_k = (diag(rho) F)^k E``; K = max_depth - 1), or
            all terms together in ``H[0]`` for the exact solution (K = 1); row S is zero.
        max_depth: Neumann terms kept (-1: exact).
        report: how the system was solved (None for a truncated series).
        settings: the settings it was computed with.
        scene: the scene (set by :func:`radiosity`; for :meth:`render`).
    """

    patches: Patches
    form_factors: FormFactors
    sides: torch.Tensor
    unknown: torch.Tensor
    F: torch.Tensor
    rho: torch.Tensor
    E: torch.Tensor
    B: torch.Tensor
    H: torch.Tensor
    max_depth: int
    report: SolveReport | None
    settings: RadiositySettings
    scene: object = None

    @property
    def area(self) -> torch.Tensor:
        """(S,) area of each unknown's side."""
        return self.form_factors.area[self.sides]

    @property
    def F_stderr(self) -> torch.Tensor:
        """(S, S) float64 standard errors of ``F`` (spread of the independent ray batches)."""
        return self.form_factors.stderr(self.sides)

    @property
    def row_sum(self) -> torch.Tensor:
        """(S,) float64 ``sum_j F_ij`` over all sides: the fraction of each side's hemisphere that
        sees the scene (1 in a closed enclosure)."""
        return self.form_factors.row_sum()[self.sides]

    def side_radiance(self) -> torch.Tensor:
        """(2P, 3) float64 ``B`` of every patch side (0 where it cannot receive light)."""
        return torch.cat([self.B, self.B.new_zeros(1, 3)])[self.unknown]

    def gathered(self, unknown: torch.Tensor, terms: int, per_term: bool = False) -> list[torch.Tensor] | torch.Tensor:
        """Radiance gathered at unknowns ``unknown`` (N,) int64 (S = none) from the first ``terms``
        Neumann terms of the arriving light (-1 = all): (N, 3) summed, or with ``per_term`` a list
        of (N, 3), one per term (light reflected 0, 1, ... times before arriving)."""
        K = self.H.shape[0]
        count = K if terms < 0 else min(terms, K)
        if per_term:
            return [self.H[k][unknown] for k in range(count)]
        if count == 0:
            return self.H.new_zeros(unknown.shape[0], 3)
        return self.H[:count].sum(0)[unknown] if count > 1 else self.H[0][unknown]

    def lookup(self, tri: torch.Tensor, p: torch.Tensor, front: torch.Tensor, triangles) -> torch.Tensor:
        """(N,) int64 unknown of the sides at points ``p`` (N, 3) of scene triangles ``tri`` (N,),
        seen from their front (``front`` (N,) bool) or back; S where B = 0."""
        patch = self.patches.locate(triangles, tri, p)
        return self.unknown[2 * patch + (~front).long()]

    def render(self, **options) -> torch.Tensor:
        """The scene rendered from this solution's settings by ``ir.render(scene, "radiosity", ...)``
        (``options``: ``spp``, ``seed``, ``resolution`` is the scene's; patches and form factors
        are reused from the cache). Returns (H, W, 3)."""
        if self.scene is None:
            raise ParameterError("this radiosity solution has no scene: compute it with ir.radiosity(scene, ...)")
        from invrender.diff import render
        from invrender.transport.integrators.radiosity import Radiosity

        return render(self.scene, Radiosity(**dataclasses.asdict(self.settings)), **options)

    def random_walk(self, estimator: str = "collision", transition="analog", walks: int = 1000, seed: int = 0, start=None, max_steps: int = 100000) -> WalkEstimate:
        """Estimate the exact solution B by Neumann-Ulam random walks on ``x = E + diag(rho) F x``
        (:func:`~invrender.transport.radiosity.random_walks.neumann_ulam`; channels are the three systems).

        Args:
            estimator: ``"collision"`` or ``"absorption"``.
            transition: ``"analog"`` (``p_ij = rho_i F_ij``), ``"uniform"``, or a matrix (S, S) or
                (3, S, S).
            walks: walks per unknown and channel.
            seed: the walks' seed.
            start: (k,) int64 unknowns to estimate; None = all.
        Returns:
            a :class:`~invrender.transport.radiosity.random_walks.WalkEstimate`, ``mean`` and ``stderr``
            (3, k).
        Raises:
            ParameterError: a transition matrix of the wrong shape, with negative entries, or one
                that gives infinite variance (spectral radius of ``m_ij^2 / p_ij`` >= 1).
        """
        M = self.rho.detach().double().T[:, :, None] * self.F[None]
        return neumann_ulam(M, self.E.detach().double().T, transition, estimator, walks, seed, start, max_steps)


def check_diffuse(scene) -> None:
    """A :class:`ParameterError` naming the first material radiosity cannot model (one whose BSDF
    is not purely diffuse) or the first emitter (one that does not emit from the patches)."""
    for i, name in enumerate(scene.materials):
        spec = scene.material_spec(i)
        if spec.spec.lobes != Lobe.DIFFUSE:
            raise ParameterError(f"radiosity models diffuse surfaces only: material {name!r} is {spec.type}")
    for i, name in enumerate(scene.emitters):
        spec = scene.emitter_spec(i)
        if not spec.spec.surface:
            raise ParameterError(f"radiosity models emission from the scene's surfaces only: emitter {name!r} is {spec.type}")


def solve_scene(ctx, settings: RadiositySettings) -> RadiositySolution:
    """The radiosity solution of the scene in ``ctx`` (a TransportContext), differentiable in its
    reflectance and emission parameters whatever the caller's grad mode (path replay re-solves
    inside a backward pass)."""
    patches, factors, emitting = _geometry(ctx, settings)
    with torch.enable_grad():
        rho_side = side_reflectance(ctx, patches)
        E_side = side_emission(ctx, patches)
        sides = factors.reachable(emitting).nonzero()[:, 0]
        S = int(sides.shape[0])
        if S > MAX_UNKNOWNS:
            raise ParameterError(f"radiosity system has {S} unknowns, more than {MAX_UNKNOWNS}: use fewer patches")
        unknown = torch.full((2 * patches.count,), S, dtype=torch.int64, device=sides.device)
        unknown[sides] = torch.arange(S, device=sides.device)
        F = factors.matrix(sides)
        rho, E = rho_side[sides].double(), E_side[sides].double()
        D = settings.max_depth
        if D == -1:
            if S and float(rho.detach().max()) >= 1.0:
                raise ParameterError("radiosity's exact solve needs every reflectance below 1 (a closed scene with rho = 1 never loses light); use a finite max_depth")
            B, report = solve(F, rho, E, settings.solver_settings)
            H = gather(F, B)[None]
        else:
            T = neumann_terms(F, rho, E, D)  # (D, S, 3): light reflected 0 ... D-1 times
            B, report = T.sum(0), None
            H = torch.stack([gather(F, T[k]) for k in range(D - 1)]) if D > 1 else F.new_zeros(0, S, 3)
        H = torch.cat([H, H.new_zeros(H.shape[0], 1, 3)], dim=1)  # row S: sides with B = 0
    return RadiositySolution(patches, factors, sides, unknown, F, rho, E, B, H, D, report, settings)


#: (geometry key) -> (weak reference to the vertex tensor, (patches, form factors, emitter sides)); least recently used first
_CACHE: OrderedDict = OrderedDict()
_CACHE_SIZE = 4


def _geometry(ctx, settings: RadiositySettings) -> tuple[Patches, FormFactors, torch.Tensor]:
    """Patches, form factors and the (2P,) bool emitter sides of ``ctx``'s geometry, computed once
    per geometry and settings."""
    p0 = ctx.triangles.p0
    subdivision, target = settings.mesh
    key = (id(p0), p0._version, str(p0.device), getattr(ctx.accel, "name", type(ctx.accel).__name__), subdivision, target, settings.form_factor_settings, ctx.ray_offset)
    hit = _CACHE.get(key)
    if hit is not None and hit[0]() is p0:
        _CACHE.move_to_end(key)
        return hit[1]
    patches = mesh_patches(ctx.triangles, subdivision, target)
    emitting = torch.zeros(2 * patches.count, dtype=torch.bool, device=patches.tri.device)
    emitting[0::2] = ctx.triangles.emitter[patches.tri] >= 0  # fronts of emitters, whatever their current value
    value = (patches, form_factors(patches, ctx.accel, settings.form_factor_settings, ctx.ray_offset, emitting), emitting)
    _CACHE[key] = (weakref.ref(p0), value)
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return value


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
            ``max_depth``, ``final_gather`` (for :meth:`RadiositySolution.render`).
    Returns:
        a :class:`RadiositySolution`; its ``B`` is differentiable in every ``scene.params`` entry
        that requires grad.
    Raises:
        ParameterError: a non-diffuse material (named), settings out of range.
    """
    from invrender.transport.driver import RenderSettings
    from invrender.transport.integrators.radiosity import Radiosity

    integrator = Radiosity(**options)
    device = torch.device(device) if device is not None else scene.device
    ctx = integrator.context(scene, RenderSettings(backend=backend), device, params)
    return dataclasses.replace(ctx.extra, scene=scene)


__all__ = ["RadiositySettings", "RadiositySolution", "radiosity", "solve_scene", "check_diffuse", "DEFAULT_PATCHES"]
