"""The normal equations of inverse lighting, accumulated view by view from a transport matrix's
halves (what :func:`invrender.inverse.map_fit.solve_map` solves).

Per colour channel c, over the rows that count (pixels some path links to the map, weighted by
``sqrt`` of their pixel weight) and the n columns of the map's basis:

    Gm = Abar^T Abar,   D = Delta^T Delta,   g = Abar^T b,   bb = b^T b

with ``Abar = (A1 + A2) / 2`` the halves' mean and ``Delta = (A1 - A2) / 2`` its Monte Carlo error,
so that ``H = Gm - D = sym(A1^T A2)`` (unbiased for ``A^T A``) and ``x^T D x = ||(A1 - A2) x||^2 / 4``
the noise of the images any map x predicts. Both are symmetric rank-k updates (BLAS ``syrk``: half
a matrix product each, together the cost of the one product ``A1^T A2``), over each view's nonzero
columns only. A view's halves are dropped once added: the memory is one view's ``24 P_v n`` bytes
plus the two float32 Gram matrices' ``24 n^2``, whatever the number of views.
"""

from __future__ import annotations

import dataclasses
import time

import torch
from scipy.linalg import blas

from invrender.estimators.map_basis import MapBasis
from invrender.estimators.transport_matrix import TransportMatrix, matrix_views, memory_budget, view_halves
from invrender.errors import ParameterError

#: bytes of the accumulated normal equations per n^2: Gm and D, 3 channels, float32
GRAM_BYTES = 24


@dataclasses.dataclass
class NormalEquations:
    """The accumulated normal equations of one map (module docstring).

    Attributes:
        basis: the columns' :class:`~invrender.estimators.map_basis.MapBasis` (n unknowns).
        Gm, D: (3, n, n) float32 (symmetric once :meth:`finish` ran).
        g: (3, n) float64.
        bb: (3,) float64.
        rows: (3,) int64 the rows that count per channel.
        flat: (3,) float64 the level of a flat map that matches the targets: ``sum b / sum Abar 1``
            over all pixels (the Tikhonov prior's default centre).
        views: per view (height, width).
        seconds: {"render": ..., "gram": ...}.
    """

    basis: MapBasis
    Gm: torch.Tensor
    D: torch.Tensor
    g: torch.Tensor
    bb: torch.Tensor
    rows: torch.Tensor
    flat: torch.Tensor
    views: list
    seconds: dict
    _sums: torch.Tensor = dataclasses.field(default_factory=lambda: torch.zeros(2, 3, dtype=torch.float64))
    _finished: bool = False

    @staticmethod
    def empty(basis: MapBasis) -> NormalEquations:
        n = basis.n
        z = lambda *s, dtype=torch.float64: torch.zeros(*s, dtype=dtype)  # noqa: E731
        return NormalEquations(basis, z(3, n, n, dtype=torch.float32), z(3, n, n, dtype=torch.float32), z(3, n), z(3), torch.zeros(3, dtype=torch.int64), z(3), [], {"render": 0.0, "gram": 0.0})

    @property
    def n(self) -> int:
        return self.basis.n

    def add(self, A1: torch.Tensor, A2: torch.Tensor, b: torch.Tensor, weight: torch.Tensor) -> None:
        """Add one view: its halves (3, P_v, n) float32, targets ``b`` (P_v, 3) (the light off the
        map already subtracted) and pixel weights (P_v, 3) >= 0."""
        clock = time.perf_counter()
        total = A1 + A2  # 2 Abar; its entries are >= 0, so 0 only where both halves are
        self._sums[0] += b.double().sum(0)
        self._sums[1] += 0.5 * total.sum((1, 2)).double()
        # the rows and columns some path of some channel links to the map: the others add nothing
        # (the entries are >= 0, so a row or column is 0 where its sum is: two sums, no mask of A)
        rows = ((total.sum((0, 2)) > 0) & (weight > 0).any(1)).nonzero()[:, 0]
        if not rows.numel():
            self.seconds["gram"] += time.perf_counter() - clock
            return
        cols = (total.sum((0, 1)) > 0).nonzero()[:, 0]
        first, last = int(cols[0]), int(cols[-1]) + 1
        span = slice(first, last) if last - first <= 1.25 * cols.numel() else None  # a band of the map: a slice is faster
        r = weight.index_select(0, rows).float().sqrt().T[:, :, None]  # (3, rows, 1)
        mean = (total.index_select(1, rows)[:, :, span] if span else total.index_select(1, rows)[:, :, cols]) * (0.5 * r)
        del total
        delta = (A1.index_select(1, rows)[:, :, span] if span else A1.index_select(1, rows)[:, :, cols]) * r - mean
        if span:
            cols = torch.arange(first, last)
        bw = (b.index_select(0, rows).T * r[:, :, 0]).contiguous()  # (3, rows)
        counted = (weight.index_select(0, rows) > 0).sum(0)  # (3,) the rows that count per channel
        for c in range(3):
            self.g[c].index_add_(0, cols, (bw[c] @ mean[c]).double())
            self.bb[c] += float(bw[c].double().square().sum())
            self.rows[c] += int(counted[c])
            for gram, part in ((self.Gm, mean[c]), (self.D, delta[c])):
                upper = torch.from_numpy(blas.ssyrk(1.0, part.numpy().T, trans=0))  # part^T part, upper triangle
                if span:
                    gram[c][span, span] += upper
                else:
                    gram[c].index_put_((cols[:, None], cols[None, :]), upper, accumulate=True)
        self.seconds["gram"] += time.perf_counter() - clock

    def finish(self) -> NormalEquations:
        """Fill the lower triangles (syrk fills the upper) and the flat level; returns itself."""
        if not self._finished:
            for gram in (self.Gm, self.D):
                for c in range(3):
                    gram[c] += gram[c].triu(1).T  # syrk wrote the upper triangle only
            self.flat = self._sums[0] / self._sums[1].clamp_min(1e-30)
            self._finished = True
        return self

    def H(self, c: int, index: torch.Tensor | None = None) -> torch.Tensor:
        """(n, n) float64 ``sym(A1^T A2) = Gm - D`` of channel c (rows and columns ``index`` only)."""
        Gm, D = self.Gm[c], self.D[c]
        if index is not None:
            Gm, D = Gm[index][:, index], D[index][:, index]
        return Gm.double() - D.double()


def normal_bytes(pixels_per_view: int, columns: int) -> int:
    """Bytes of the streamed normal equations: one view's halves (``24 P_v n``) and the Gram
    matrices (``24 n^2``)."""
    return 24 * pixels_per_view * columns + GRAM_BYTES * columns * columns


def _targets_rows(targets: list[torch.Tensor], views: list[tuple[int, int]]) -> None:
    if len(targets) != len(views):
        raise ParameterError(f"{len(targets)} target(s) for a transport matrix of {len(views)} view(s): give one target per view")
    for i, (t, (H_, W_)) in enumerate(zip(targets, views)):
        if tuple(t.shape) != (H_, W_, 3):
            raise ParameterError(f"target {i} is {tuple(t.shape)}, its view renders {H_} x {W_} x 3")
        if not bool(torch.isfinite(t).all()):
            raise ParameterError(f"target {i} contains NaN or Inf values")


def _pixel_weight(mask, size) -> torch.Tensor:
    h, w = size
    return torch.ones(h * w, 3) if mask is None else mask.float().reshape(-1, 1).expand(-1, 3)


def from_matrix(tm: TransportMatrix, targets: list[torch.Tensor], masks: list[torch.Tensor] | None = None) -> NormalEquations:
    """The normal equations of a kept transport matrix ``tm`` for ``targets`` (one (H, W, 3) linear
    image per view) and optional per-view pixel weights ``masks`` (H, W)."""
    _targets_rows(targets, tm.views)
    basis = tm.basis if tm.basis is not None else MapBasis.of_texels(*tm.shape)
    out = NormalEquations.empty(basis)
    s = tm.starts
    for v, size in enumerate(tm.views):
        b = targets[v].detach().float().reshape(-1, 3)
        if tm.offset is not None:
            b = b - tm.offset[s[v] : s[v + 1]]
        out.add(tm.halves[0][:, s[v] : s[v + 1]], tm.halves[1][:, s[v] : s[v + 1]], b, _pixel_weight(None if masks is None else masks[v], size))
    out.views = list(tm.views)
    out.seconds["render"] = tm.seconds
    return out.finish()


def normal_equations(
    scene,
    emitter: str,
    targets: list[torch.Tensor],
    *,
    cameras=None,
    masks: list[torch.Tensor] | None = None,
    basis: MapBasis | None = None,
    memory_mb: float | None = None,
    extra_bytes: int = 0,
    **render,
) -> NormalEquations:
    """The normal equations streamed: each view's halves rendered (:func:`~invrender.estimators.
    transport_matrix.view_halves`, ``render``: integrator, spp, max_depth, seed, sampling_map,
    progress), added and dropped. Refused before any work, in one line with the figure, when
    :func:`normal_bytes` of the largest view plus ``extra_bytes`` exceeds ``memory_mb``."""
    views, basis = matrix_views(scene, emitter, cameras, render.get("spp", 64), render.get("seed", 0), basis)
    sizes = [(v.height, v.width) for v in views]
    _targets_rows(targets, sizes)
    largest = max(h * w for h, w in sizes)
    need, budget = normal_bytes(largest, basis.n) + int(extra_bytes), memory_budget(memory_mb)
    if need > budget:
        h, w = basis.shape
        raise ParameterError(
            f"inverse lighting of a {h}x{w} map in {basis.n} unknowns from views of {largest} pixels needs {need / 2**30:.2f} GiB "
            f"(24 x pixels x unknowns for a view's halves + 72 x unknowns^2 for the normal equations and their solve), over the {budget / 2**30:.2f} GiB budget: "
            "lower the unknowns, or use smaller views or a coarser map"
        )
    out = NormalEquations.empty(basis)
    clock = time.perf_counter()
    for part in view_halves(scene, emitter, cameras=cameras, basis=basis, **render):
        out.seconds["render"] += time.perf_counter() - clock
        b = targets[part.index].detach().float().reshape(-1, 3).to(part.halves[0].device)
        if part.offset is not None:
            b = b - part.offset
        out.add(part.halves[0].cpu(), part.halves[1].cpu(), b.cpu(), _pixel_weight(None if masks is None else masks[part.index], part.size))
        del part
        clock = time.perf_counter()
    out.views = sizes
    return out.finish()

