"""Render settings and the per-render context shared by the integrators."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from invrender.errors import ParameterError
from invrender.scene.scene import AMBIENT, Scene, Triangles, scene_extent
from invrender.transport.accel import make_intersector
from invrender.transport.lights import EmitterSampler
from invrender.transport.surface import Surface
from invrender.transport.textures import gather_rgb
from invrender.transport.vec import dot

INTEGRATORS = ("path", "random_walk", "utah")


@dataclass(frozen=True)
class RenderSettings:
    """How to render.

    Attributes:
        integrator: ``"path"`` (NEE + MIS + Russian roulette), ``"random_walk"`` (BSDF sampling
            only) or ``"utah"`` (direct light + ambient ``rho eps0``: at most two terms).
        spp: samples (paths) per pixel, > 0.
        max_depth: Neumann terms kept, counted as Mitsuba counts: 1 = emitters seen directly,
            2 = + direct illumination, ...; -1 = unbounded (ended by Russian roulette only).
        seed: seed of the counter-based random numbers.
        rr_depth: Russian roulette starts after this many terms (Mitsuba's ``rr_depth``, default 5).
        terms: return one image per Neumann term, shape (K, H, W, 3), summing to the full image.
        backend: intersection backend ``"embree"`` or ``"torch"``; None = the device's default.
        chunk_paths: paths traced per chunk; None = sized by ``memory_mb``.
        memory_mb: memory budget for one chunk's working set, MiB.
        progress: show a progress bar (rate, ETA) on renders that take longer than a second.
    """

    integrator: str = "path"
    spp: int = 64
    max_depth: int = 8
    seed: int = 0
    rr_depth: int = 5
    terms: bool = False
    backend: str | None = None
    chunk_paths: int | None = None
    memory_mb: float = 512.0
    progress: bool = True

    def __post_init__(self):
        if self.integrator not in INTEGRATORS:
            raise ParameterError(f"unknown integrator {self.integrator!r} (known: {', '.join(INTEGRATORS)})")
        for name in ("spp", "max_depth", "seed", "rr_depth"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ParameterError(f"{name} must be an integer, got {value!r}")
        if self.spp <= 0:
            raise ParameterError(f"spp must be positive, got {self.spp}")
        if self.max_depth == 0 or self.max_depth < -1:
            raise ParameterError(f"max_depth must be >= 1, or -1 for unbounded, got {self.max_depth}")
        if self.integrator == "utah" and self.max_depth != 1:
            object.__setattr__(self, "max_depth", 2)  # the Utah approximation keeps two terms at most
        if self.rr_depth < 1:
            raise ParameterError(f"rr_depth must be >= 1, got {self.rr_depth}")
        if self.seed < 0:
            raise ParameterError(f"seed must be >= 0, got {self.seed}")
        if self.chunk_paths is not None and self.chunk_paths <= 0:
            raise ParameterError(f"chunk_paths must be positive, got {self.chunk_paths}")
        if not self.memory_mb > 0:
            raise ParameterError(f"memory_mb must be positive, got {self.memory_mb}")

    def replace(self, **changes) -> "RenderSettings":
        return dataclasses.replace(self, **changes)

    def continues_after(self, depth: int) -> bool:
        """May a path whose last vertex has index ``depth`` (0 = first hit) add terms beyond ``depth``?"""
        return self.max_depth == -1 or depth + 1 < self.max_depth


@dataclass(frozen=True)
class TransportContext:
    """Everything an integrator reads while tracing one render.

    Attributes:
        triangles: scene geometry on the render device.
        accel: the intersection backend.
        lights: the emitter sampler (None when nothing emits).
        rho: per-material reflectance parameters (differentiable), indexed by ``triangles.material``.
        eps: per-emitter emission parameters (differentiable), indexed by ``triangles.emitter``.
        ambient: (3,) the Utah approximation's ambient radiance eps0 (differentiable), or None.
        ray_offset: distance new rays start off a surface, to avoid self-intersection.
        settings: the render settings.
        textured: does any rho or eps vary over UVs (else hits skip texture coordinates)?
    """

    triangles: Triangles
    accel: object
    lights: EmitterSampler | None
    rho: list[torch.Tensor]
    eps: list[torch.Tensor]
    ambient: torch.Tensor | None
    ray_offset: float
    settings: RenderSettings
    textured: bool

    @staticmethod
    def build(scene: Scene, settings: RenderSettings, device: torch.device, embree_threads: int | None = None, params: dict | None = None) -> "TransportContext":
        """The context for rendering ``scene`` on ``device`` (parameters moved differentiably).

        ``embree_threads``: threads each Embree query is split across (None = one per core).
        ``params``: values to use instead of ``scene.params`` (same names; all or some).
        """
        tris = scene.triangles.to(device)
        values = {**scene.params, **(params or {})}
        rho = [values[f"{m}.reflectance"].to(device) for m in scene.materials]
        eps = [values[f"{e}.emission"].to(device) for e in scene.emitters]
        lights = EmitterSampler(tris, eps)
        return TransportContext(
            triangles=tris,
            accel=make_intersector(tris, settings.backend, embree_threads),
            lights=lights if lights.count else None,
            rho=rho,
            eps=eps,
            ambient=values[AMBIENT].to(device) if AMBIENT in values else None,
            ray_offset=1e-4 * max(scene_extent(tris), 1e-3),
            settings=settings,
            textured=any(p.ndim == 3 for p in rho + eps),
        )

    def reflectance(self, s: Surface) -> torch.Tensor:
        """rho at the hits (N, 3)."""
        return gather_rgb(self.rho, self.triangles.material[s.tri], s.uv)

    def emission(self, emitter: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """eps (N, 3) of emitters ``emitter`` (N,) int64 (-1 = none) at ``uv`` (N, 2)."""
        return gather_rgb(self.eps, emitter, uv)

    def emitted(self, s: Surface) -> torch.Tensor:
        """eps leaving the hits back along the rays (N, 3): zero on back sides and non-emitters."""
        return self.emission(torch.where(s.front, self.triangles.emitter[s.tri], -1), s.uv)

    def emits(self, s: Surface) -> torch.Tensor:
        """(N,) bool: is the hit on the emitting side of an emitter?"""
        return s.front & (self.triangles.emitter[s.tri] >= 0)

    def spawn(self, s: Surface, wi: torch.Tensor) -> torch.Tensor:
        """Origins (N, 3) of new rays leaving ``s`` in directions ``wi``, offset off the surface."""
        side = torch.where(dot(s.n, wi) >= 0, self.ray_offset, -self.ray_offset)
        return s.p + side[:, None] * s.n


@dataclass(frozen=True)
class PathState:
    """The live paths of one chunk (loop state of the bounce loop).

    Attributes:
        keys: (N,) int64 counter-based random keys, one per path.
        pixel: (N,) int64 flat pixel index each path contributes to.
        o: (N, 3) origin of the current ray.
        d: (N, 3) unit direction of the current ray.
        beta: (N, 3) path throughput: the product of BSDF sample weights (rho) / RR survival so far.
        pdf_dir: (N,) solid-angle pdf with which ``d`` was sampled (for MIS); unused at depth 0.
    """

    keys: torch.Tensor
    pixel: torch.Tensor
    o: torch.Tensor
    d: torch.Tensor
    beta: torch.Tensor
    pdf_dir: torch.Tensor

    def select(self, mask: torch.Tensor) -> "PathState":
        """The paths where ``mask`` (N,) is True (compaction: dead paths are dropped, not masked)."""
        index = mask.nonzero()[:, 0]
        return PathState(*(getattr(self, f).index_select(0, index) for f in self.__dataclass_fields__))

    @property
    def count(self) -> int:
        return int(self.keys.shape[0])


def russian_roulette(state: PathState, u: torch.Tensor, depth: int, rr_depth: int) -> PathState:
    """Unbiased Russian roulette after vertex ``depth`` once ``depth + 1 >= rr_depth``.

    Survival probability ``q = min(max_c beta_c, 0.95)`` from the detached throughput (Mitsuba's
    rule); survivors' throughput is divided by q. ``u`` (N,) uniforms.
    """
    if depth + 1 < rr_depth:
        return state
    q = state.beta.detach().amax(dim=1).clamp(max=0.95)
    alive = u < q
    state = state.select(alive)
    return dataclasses.replace(state, beta=state.beta / q[alive][:, None])
