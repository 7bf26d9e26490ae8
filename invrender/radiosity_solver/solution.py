"""Radiosity of a scene: the pipeline (patches -> form factors -> system -> solution) and the
solution object that looks it up, renders it again and re-solves it by random walks.

The pipeline, run once per render by the ``radiosity`` integrator's pre-pass
(:mod:`invrender.plugins.integrators.radiosity`, which holds its settings and ``ir.radiosity``):

1. mesh the scene into patches (:mod:`~invrender.radiosity_solver.patches`), two sides each;
2. estimate the form factors between all sides by ray casting
   (:mod:`~invrender.radiosity_solver.form_factors`); patches and form factors depend on the geometry
   only, so they are cached per geometry and settings (a fit or a replayed gradient re-solves
   without re-casting);
3. average rho and eps over each side (textures too), differentiably;
4. keep the sides from which a chain of form factors leads to an emitter side (every other side
   has ``B = 0`` exactly) and solve ``(I - diag(rho) F) B = E`` on them
   (:mod:`~invrender.radiosity_solver.system`): exactly (``max_depth = -1``), or as the first
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
from invrender.core.bsdfs import Lobe
from invrender.core.driver import RenderSettings
from invrender.radiosity_solver.form_factors import FormFactors, form_factors
from invrender.radiosity_solver.patches import Patches, mesh_patches, side_emission, side_reflectance
from invrender.radiosity_solver.random_walks import WalkEstimate, neumann_ulam
from invrender.radiosity_solver.system import SolveReport, gather, neumann_terms, solve

#: largest system (unknowns) accepted: its dense matrices take S^2 x 8 bytes each
MAX_UNKNOWNS = 8192


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
        settings: the settings it was computed with (a
            :class:`~invrender.plugins.integrators.radiosity.RadiositySettings`).
        scene: the scene (set by ``ir.radiosity``; for :meth:`render`).
        integrator: the radiosity integrator that computed it (set by ``ir.radiosity``; for
            :meth:`render`).
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
    settings: object
    scene: object = None
    integrator: object = None

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

    def render(self, spp: int = 64, seed: int = 0, *, device=None, **options) -> torch.Tensor:
        """The scene rendered again by the integrator that computed this solution (patches and form
        factors are reused from the cache; the resolution is the scene's).

        Args:
            spp, seed: as ``ir.render``.
            device: where to render; None = the scene's device.
            options: further :class:`~invrender.core.driver.RenderSettings` fields
                (``progress``, ``backend``, ``sampler``, ``terms``, ``chunk_paths``, ``memory_mb``).
        Returns:
            (H, W, 3) float32 linear radiance; autograd records it where a parameter requires grad
            (for path replay, render with ``ir.render(scene, "radiosity", estimator="replay")``).
        """
        if self.scene is None or self.integrator is None:
            raise ParameterError("this radiosity solution has no scene: compute it with ir.radiosity(scene, ...)")
        known = {f.name for f in dataclasses.fields(RenderSettings)} - {"spp", "seed", "plan"}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ParameterError(f"unknown render setting {unknown[0]!r} of a radiosity solution (known: spp, seed, device, {', '.join(sorted(known))})")
        device = torch.device(device) if device is not None else self.scene.device
        return self.integrator.render(self.scene, RenderSettings(spp=spp, seed=seed, **options), device)

    def random_walk(self, estimator: str = "collision", transition="analog", walks: int = 1000, seed: int = 0, start=None, max_steps: int = 100000) -> WalkEstimate:
        """Estimate the exact solution B by Neumann-Ulam random walks on ``x = E + diag(rho) F x``
        (:func:`~invrender.radiosity_solver.random_walks.neumann_ulam`; channels are the three systems).

        Args:
            estimator: ``"collision"`` or ``"absorption"``.
            transition: ``"analog"`` (``p_ij = rho_i F_ij``), ``"uniform"``, or a matrix (S, S) or
                (3, S, S).
            walks: walks per unknown and channel.
            seed: the walks' seed.
            start: (k,) int64 unknowns to estimate; None = all.
        Returns:
            a :class:`~invrender.radiosity_solver.random_walks.WalkEstimate`, ``mean`` and ``stderr``
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


def solve_scene(ctx, settings) -> RadiositySolution:
    """The radiosity solution of the scene in ``ctx`` (a TransportContext) with ``settings`` (a
    :class:`~invrender.plugins.integrators.radiosity.RadiositySettings`: its ``mesh``,
    ``form_factor_settings``, ``solver_settings`` and ``max_depth``), differentiable in the scene's
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


def _geometry(ctx, settings) -> tuple[Patches, FormFactors, torch.Tensor]:
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


__all__ = ["RadiositySolution", "solve_scene", "check_diffuse", "MAX_UNKNOWNS"]
