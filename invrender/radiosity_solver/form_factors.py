"""Patch-to-patch form factors by stratified Monte Carlo ray casting, with their standard errors.

The form factor from side i to side j is the fraction of the cosine-weighted hemisphere above
side i, averaged over its area, that sees side j first (docs/closed_forms.md#form-factors):

    F_ij = (1 / A_i) int_(A_i) int_(H) V_j(x, w) cos(theta) / pi dw dA

Casting rays from uniformly distributed points of side i in cosine-distributed directions, the
fraction that hits side j first is an unbiased estimate of F_ij, occlusion included, since the
intersection backend returns the first surface along each ray. The rays of a side are cast in
``batches`` independent batches of m rays (m a power of 2). Each batch is randomized quasi-Monte
Carlo: an independently scrambled Sobol' set of m points in [0, 1)^4 (``torch.quasirandom``),
shifted at random (mod 1) for each side, whose first two coordinates give the direction (an
area-preserving map of the square onto cosine-distributed directions) and the last two the origin
(an area-preserving map onto the patch). Every batch is an unbiased estimate, the batches are
independent, and their spread gives each form factor's standard error
(docs/radiosity.md#form-factor-error); the error falls about as ``m^-0.75`` where plain Monte Carlo
gives ``m^-0.5`` (two unit squares: 0.4% at 16384 rays per side, 0.13% at 65536).

Emitter sides are few and their columns of F carry all direct light, so they cast more rays
(``emitter_rays``) and the form factors *towards* them come from their own rays by reciprocity,
``F_ij = A_j F_ji / A_i``: every ray leaving an emitter lands somewhere, so the light the scene
receives directly is estimated from many rays instead of from the few that happen to hit a small
emitter (docs/radiosity.md#form-factor-error).

Estimates are kept sparse, per (row side, column side, batch): memory grows with the number of
rays, not with the square of the number of sides. Random numbers come from a generator seeded by
the seed and the chunk of sides, so an estimate is a function of the seed and the patches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from invrender.errors import ParameterError
from invrender.radiosity_solver.patches import Patches
from invrender.validate import check_int

#: rays cast per batch of work (bounds memory)
RAYS_PER_CHUNK = 1 << 18
#: emitter sides cast up to this many times ``rays`` unless ``emitter_rays`` is given
EMITTER_RAY_FACTOR = 16
#: most rays cast from one patch side (4M: beyond that the form factors' noise is far below any
#: discretization error, and a full scene would cast more rays than a machine can in a day)
MAX_RAYS = 1 << 22


@dataclass(frozen=True)
class FormFactorSettings:
    """How form factors are estimated.

    Attributes:
        rays: rays cast from each patch side; rounded to ``batches`` times a power of 2.
        batches: independent batches per side whose spread gives the standard errors (>= 2).
        seed: seed of the rays' random numbers.
        emitter_rays: rays cast from each emitter side (whose columns of F then come from them by
            reciprocity); None = ``rays`` x (other sides per emitter side), at most 16 x ``rays``.
    """

    rays: int = 256
    batches: int = 4
    seed: int = 0
    emitter_rays: int | None = None

    def __post_init__(self):
        for name, low, high in (("rays", 1, MAX_RAYS), ("batches", 2, MAX_RAYS), ("seed", 0, None)):
            _check_int(name, getattr(self, name), low, high)
        if self.emitter_rays is not None:
            _check_int("emitter_rays", self.emitter_rays, 1, MAX_RAYS)
        if min(self.rays, self.emitter_rays or self.rays) < self.batches:
            raise ParameterError(f"form factor rays ({self.rays}, emitters {self.emitter_rays}) must be at least batches ({self.batches})")

    def per_batch(self, rays: int) -> int:
        """Rays per side and batch for ``rays`` rays per side: the nearest power of 2 to
        ``rays / batches`` (Sobol' sets are balanced at powers of 2)."""
        return 2 ** max(0, round(math.log2(rays / self.batches)))

    def rays_of_emitters(self, emitters: int, others: int) -> int:
        """Rays per emitter side: ``emitter_rays``, or by default ``rays`` times the number of other
        sides per emitter side, at most 16 (emitters that are few get many rays; a scene that
        mostly emits pays no extra)."""
        if self.emitter_rays is not None:
            return self.emitter_rays
        return self.rays * max(1, min(EMITTER_RAY_FACTOR, others // max(emitters, 1)))


@dataclass(frozen=True)
class FormFactors:
    """Monte Carlo form factors between all ``S = 2P`` patch sides (side ``2k`` = patch k's front,
    ``2k + 1`` its back), as sparse per-batch estimates: batch b's estimate of ``F_ij`` is the sum of
    ``value`` over the entries with ``(row, col, batch) = (i, j, b)``; F is the mean over batches.

    Attributes:
        row: (K,) int64 side i.
        col: (K,) int64 side j.
        batch: (K,) int64 batch.
        value: (K,) float64 contribution to batch ``batch``'s estimate of ``F_ij``.
        area: (S,) area of each side.
        rays: (S,) int64 rays cast from each side (all batches).
        reciprocal: (S,) bool sides whose column ``F_(., j)`` comes from their own rays by
            reciprocity (the emitter sides).
        batches: number of batches B.
    """

    row: torch.Tensor
    col: torch.Tensor
    batch: torch.Tensor
    value: torch.Tensor
    area: torch.Tensor
    rays: torch.Tensor
    reciprocal: torch.Tensor
    batches: int

    @property
    def sides(self) -> int:
        """S, the number of sides."""
        return int(self.area.shape[0])

    def _local(self, sides: torch.Tensor | None) -> tuple[int, torch.Tensor, torch.Tensor]:
        """Size n and the flat index ``i n + j`` of every entry in the sub-matrix on ``sides`` (n,),
        with the mask of entries inside it."""
        if sides is None:
            return self.sides, self.row * self.sides + self.col, torch.ones_like(self.row, dtype=torch.bool)
        local = torch.full((self.sides,), -1, dtype=torch.int64, device=self.area.device)
        local[sides] = torch.arange(len(sides), device=local.device)
        i, j = local[self.row], local[self.col]
        keep = (i >= 0) & (j >= 0)
        return len(sides), (i * len(sides) + j)[keep], keep

    def matrix(self, sides: torch.Tensor | None = None) -> torch.Tensor:
        """Dense ``F`` (n, n) float64 between ``sides`` (n,) int64 (None = all sides): the mean of
        the batches' estimates."""
        n, index, keep = self._local(sides)
        F = torch.zeros(n * n, dtype=torch.float64, device=self.area.device)
        return F.index_add_(0, index, self.value[keep] / self.batches).reshape(n, n)

    def stderr(self, sides: torch.Tensor | None = None) -> torch.Tensor:
        """Dense standard errors (n, n) float64 of ``matrix(sides)``'s entries: the standard
        deviation of the B batch estimates over sqrt(B)."""
        n, index, keep = self._local(sides)
        B = self.batches
        value = self.value[keep]  # one entry per (row, col, batch) at most; missing batches are zeros
        s1 = torch.zeros(n * n, dtype=torch.float64, device=self.area.device).index_add_(0, index, value)
        s2 = torch.zeros_like(s1).index_add_(0, index, value * value)
        var = ((s2 - s1 * s1 / B) / (B - 1)).clamp_min(0.0)
        return (var / B).sqrt().reshape(n, n)

    def row_sum(self) -> torch.Tensor:
        """(S,) float64 ``sum_j F_ij``: about the fraction of side i's hemisphere that sees the scene
        (1 inside a closed enclosure, up to the error of the estimates)."""
        return torch.zeros(self.sides, dtype=torch.float64, device=self.area.device).index_add_(0, self.row, self.value / self.batches)

    def group(self, source: torch.Tensor, target: torch.Tensor) -> tuple[float, float]:
        """The form factor from a group of sides to another, ``sum_(i, j) A_i F_ij / sum_i A_i``,
        and its standard error (from the spread of the batches' group estimates).

        Args:
            source, target: int64 side indices (or (S,) bool masks) of the two groups.
        """
        src, dst = self._mask(source), self._mask(target)
        keep = src[self.row] & dst[self.col]
        a = self.area.double()
        per_batch = torch.zeros(self.batches, dtype=torch.float64, device=a.device).index_add_(0, self.batch[keep], a[self.row[keep]] * self.value[keep])
        per_batch = per_batch / a[src].sum()
        return float(per_batch.mean()), float(per_batch.std() / math.sqrt(self.batches))

    def reachable(self, emitting: torch.Tensor) -> torch.Tensor:
        """(S,) bool: sides from which some chain of nonzero form factors leads to an emitting side
        (``emitting`` (S,) bool): every other side has radiosity exactly ``B = 0`` and can be left
        out of the system."""
        reach = emitting.clone()
        while True:
            grown = reach.clone()
            grown[self.row[reach[self.col]]] = True
            if bool((grown == reach).all()):
                return reach
            reach = grown

    def _mask(self, sides: torch.Tensor) -> torch.Tensor:
        if sides.dtype == torch.bool:
            return sides
        mask = torch.zeros(self.sides, dtype=torch.bool, device=self.area.device)
        mask[sides] = True
        return mask


def form_factors(patches: Patches, intersector, settings: FormFactorSettings, ray_offset: float, emitting: torch.Tensor | None = None) -> FormFactors:
    """Estimate the form factors between all patch sides by casting rays from each.

    Args:
        patches: the patches (their sides are the rays' sources and targets).
        intersector: an intersection backend over the scene's triangles (``intersect(o, d)``).
        settings: rays, batches, seed.
        ray_offset: distance rays start off their patch (against self-intersection).
        emitting: (2P,) bool emitter sides (cast ``emitter_rays``, their columns by reciprocity);
            None = none.
    """
    device = patches.corners.device
    S = 2 * patches.count
    B = settings.batches
    emitting = torch.zeros(S, dtype=torch.bool, device=device) if emitting is None else emitting.to(device)
    area = patches.area.double().repeat_interleave(2)
    rays = torch.empty(S, dtype=torch.int64, device=device)
    rows, cols, batches, values = [], [], [], []
    chunk = 0
    for emitter in (False, True):
        group = (emitting == emitter).nonzero()[:, 0]
        if not group.numel():
            continue
        others = int((~emitting).sum())
        m = settings.per_batch(settings.rays_of_emitters(group.numel(), others) if emitter else settings.rays)  # rays per side and batch
        rays[group] = B * m
        per_chunk = max(1, RAYS_PER_CHUNK // (B * m))
        for s0 in range(0, group.numel(), per_chunk):
            side = group[s0 : s0 + per_chunk]
            target, batch = _cast(patches, intersector, m, B, settings.seed * 1_000_003 + chunk, ray_offset, side)
            chunk += 1
            hit = target >= 0
            source = side.repeat_interleave(B * m)[hit]
            key, count = torch.unique((source * S + target[hit]) * B + batch[hit], return_counts=True)
            pair, b = key // B, key % B
            i, j = pair // S, pair % S
            value = count.double() / m  # batch b's estimate of F_ij from i's rays
            direct = emitter | ~emitting[j]  # towards an emitter, F comes from the emitter's rays
            rows += [i[direct]]
            cols += [j[direct]]
            batches += [b[direct]]
            values += [value[direct]]
            if emitter:  # reciprocity: F_ji = A_i F_ij / A_j for receivers j
                back = ~emitting[j]
                rows += [j[back]]
                cols += [i[back]]
                batches += [b[back]]
                values += [value[back] * area[i[back]] / area[j[back]]]
    return FormFactors(
        row=torch.cat(rows),
        col=torch.cat(cols),
        batch=torch.cat(batches),
        value=torch.cat(values),
        area=area,
        rays=rays,
        reciprocal=emitting,
        batches=B,
    )


def _cast(patches: Patches, intersector, m: int, B: int, seed: int, ray_offset: float, side: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Cast ``B m`` rays from each of ``side`` (n,) int64: the side each ray hits first (n B m,)
    int64 (-1 = none) and its batch (n B m,) int64, rays ordered side by side, then batch by batch."""
    n = side.shape[0]
    device = side.device
    gen = torch.Generator(device="cpu").manual_seed(seed)
    # randomized quasi-Monte Carlo: per batch an independently scrambled Sobol' set of m points in
    # [0, 1)^4 (direction, position), moved by an independent random shift per side (mod 1)
    sobol = torch.stack([torch.quasirandom.SobolEngine(4, scramble=True, seed=int(torch.randint(2**31, (1,), generator=gen))).draw(m) for _ in range(B)])
    shift = torch.rand(n, B, 1, 4, generator=gen)
    u = ((sobol[None] + shift) % 1.0).reshape(n * B * m, 4).to(device)
    u_dir, u_pos = u[:, 0:2], u[:, 2:4]
    # origins: uniform over the patch (area-preserving square-to-triangle map)
    patch = (side // 2).repeat_interleave(B * m)
    r = u_pos[:, 0].sqrt()
    p, _ = patches.points(torch.stack([r * (1 - u_pos[:, 1]), r * u_pos[:, 1]], dim=1), patch)
    # directions: cosine-distributed about the side's normal, as normalize(n + s) with s uniform on
    # the unit sphere (docs/closed_forms.md#hemisphere-integrals); the square-to-sphere map is
    # area-preserving, so well-spread points stay well spread
    sign = 1.0 - 2.0 * (side % 2).repeat_interleave(B * m).to(p.dtype)  # front +1, back -1
    normal = patches.normal[patch] * sign[:, None]
    z = 1.0 - 2.0 * u_dir[:, 0]
    rxy = (1.0 - z * z).clamp_min(0.0).sqrt()
    phi = (2.0 * math.pi) * u_dir[:, 1]
    d = normal + torch.stack([rxy * torch.cos(phi), rxy * torch.sin(phi), z], dim=1)
    d = d / d.norm(dim=1, keepdim=True).clamp_min(1e-12)
    hits = intersector.intersect(p + ray_offset * normal, d)
    hit = hits.valid
    target = patches.at(torch.where(hit, hits.prim, 0), hits.u, hits.v)
    back = (d * patches.normal[target]).sum(1) > 0  # arriving from behind the triangle
    target = torch.where(hit, 2 * target + back.long(), -1)
    return target, torch.arange(B, device=device).repeat_interleave(m).repeat(n)


def _check_int(name: str, value, low: int, high: int | None) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ParameterError(f"form factor {name} must be an integer >= {low}, got {value!r}")
    check_int("form factor ", name, value, None, high)


__all__ = ["FormFactors", "FormFactorSettings", "form_factors", "EMITTER_RAY_FACTOR"]
