"""A piecewise-constant basis of an environment map: the unknowns of inverse lighting at a budget.

An (h, w) map has T = h w texels; fitting every one is a T x T problem per channel, which at
64 x 128 (8,192 texels) no longer fits a few seconds on a few cores. :class:`MapBasis` partitions
the texel grid into n square blocks of a quadtree (the leaves), each one unknown: the map is
``L = B x`` with ``B`` (T, n) the 0/1 membership of texels in leaves. Blocks of one size everywhere
are the scaling functions of a Haar basis at that level; a block split into its four children adds
the three Haar details of that block, so a quadtree of n leaves is a Haar basis truncated to a
budget of n kept coefficients. :meth:`MapBasis.refined` spends a budget where a first estimate of
the map puts its power (a sun), which is where full resolution matters.
"""

from __future__ import annotations

import dataclasses
import heapq

import numpy as np
import torch

from invrender.plugins.emitters.envmap import texel_solid_angles
from invrender.errors import ParameterError


@dataclasses.dataclass(frozen=True, eq=False)
class MapBasis:
    """The leaves of a quadtree over an (h, w) texel grid.

    Attributes:
        shape: (h, w).
        blocks: (n, 3) int64 per leaf its top row, left column and size (a power of 2; blocks at
            the grid's bottom and right edges are clipped to it).
    """

    shape: tuple[int, int]
    blocks: np.ndarray

    @property
    def n(self) -> int:
        """The number of unknowns (leaves)."""
        return int(self.blocks.shape[0])

    @property
    def texels(self) -> int:
        return self.shape[0] * self.shape[1]

    @property
    def is_texels(self) -> bool:
        """Every leaf a single texel (the map's own texels, n = T)."""
        return self.n == self.texels

    @staticmethod
    def of_texels(h: int, w: int) -> MapBasis:
        """The map's own texels, leaf t = texel t (row-major)."""
        i, j = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        return MapBasis((h, w), np.stack([i.ravel(), j.ravel(), np.ones(h * w, dtype=np.int64)], 1).astype(np.int64))

    @staticmethod
    def uniform(h: int, w: int, budget: int) -> MapBasis:
        """Blocks of the smallest size k (1, 2, 4, ...) whose count ``ceil(h/k) ceil(w/k)`` is at
        most ``budget`` (the map's own texels where they fit)."""
        if not isinstance(budget, int) or isinstance(budget, bool) or budget < 1:
            raise ParameterError(f"the unknowns' budget must be an integer >= 1, got {budget!r}")
        k = 1
        while -(-h // k) * -(-w // k) > budget:
            k *= 2
        if k == 1:
            return MapBasis.of_texels(h, w)
        i, j = np.meshgrid(np.arange(0, h, k), np.arange(0, w, k), indexing="ij")
        return MapBasis((h, w), np.stack([i.ravel(), j.ravel(), np.full(i.size, k)], 1).astype(np.int64))

    def columns(self) -> torch.Tensor:
        """(T,) int64 the leaf of each texel (row-major): what a TexelFilm scatters into."""
        h, w = self.shape
        out = np.full((h, w), -1, dtype=np.int64)
        for leaf, (i, j, k) in enumerate(self.blocks):
            out[i : i + k, j : j + k] = leaf
        return torch.from_numpy(out.reshape(-1))

    def matrix(self):
        """B, (T, n) scipy.sparse CSR 0/1: texel t belongs to leaf ``columns()[t]``."""
        import scipy.sparse as sp

        col = self.columns().numpy()
        return sp.csr_matrix((np.ones(self.texels), (np.arange(self.texels), col)), shape=(self.texels, self.n))

    def expand(self, x: torch.Tensor) -> torch.Tensor:
        """(T, ...) the texels of leaf values ``x`` (n, ...)."""
        return x[self.columns().to(x.device)]

    def haar(self, chunk: int = 256):
        """``(W B, details)``: the orthonormal 2-D Haar transform W of the texel grid (T x T: per
        level each 2 x 2 group of the level's scaling coefficients (a, b, c, d) becomes
        ``(a + b + c + d) / 2`` and the three details ``(a - b + c - d) / 2``, ``(a + b - c - d) / 2``,
        ``(a - b - c + d) / 2``, down to a grid one texel high or wide) applied to the leaves'
        membership B: a (T, n) scipy.sparse CSR whose row t is coefficient t as a function of the
        leaf values (rows of details finer than a leaf are 0), and ``details`` (T,) bool, the rows
        that are details (the rest: the top grid's scaling coefficients). W is orthonormal, so
        ``(W B)^T (W B) = B^T B``, the leaves' texel counts. The map's height and width must be
        powers of 2."""
        import scipy.sparse as sp

        h, w = self.shape
        check_haar(h, w)
        col = self.columns().numpy().reshape(h, w)
        parts = []
        for start in range(0, self.n, chunk):
            leaves = np.arange(start, min(self.n, start + chunk))
            X = (col[:, :, None] == leaves[None, None, :]).astype(np.float64)  # (h, w, m) membership
            coefficients, details = _haar_levels(X)
            parts.append(sp.csr_matrix(coefficients))
        return sp.hstack(parts, format="csr"), details

    def refined(self, texels: torch.Tensor, budget: int) -> MapBasis:
        """This basis with the leaves of most power split into their four children (and those
        again), greedily, while the leaf count stays within ``budget``: power = the map ``texels``
        (T, 3) (a first estimate) times solid angle, summed over the leaf and the channels. A
        sun's block is split down to single texels first."""
        h, w = self.shape
        T = self.texels
        if texels.shape[0] != T:
            raise ValueError(f"refined: the map has {texels.shape[0]} texels, the basis {T}")
        power = (texels.detach().double().clamp_min(0).sum(1) * texel_solid_angles(h, w)).reshape(h, w).numpy()
        # a summed-area table: each block's power in O(1)
        table = np.zeros((h + 1, w + 1))
        table[1:, 1:] = power.cumsum(0).cumsum(1)

        def block_power(i: int, j: int, k: int) -> float:
            i1, j1 = min(i + k, h), min(j + k, w)
            return float(table[i1, j1] - table[i, j1] - table[i1, j] + table[i, j])

        leaves = [tuple(int(v) for v in b) for b in self.blocks]
        heap = [(-block_power(*b), b) for b in leaves if b[2] > 1]
        heapq.heapify(heap)
        kept = {b for b in leaves}
        count = len(leaves)
        while heap:
            _, (i, j, k) = heapq.heappop(heap)
            half = k // 2
            children = [(i + a, j + c, half) for a in (0, half) for c in (0, half) if i + a < h and j + c < w]
            if count - 1 + len(children) > budget:
                continue  # a smaller block (fewer children in range) may still fit
            kept.remove((i, j, k))
            kept.update(children)
            count += len(children) - 1
            for child in children:
                if half > 1:
                    heapq.heappush(heap, (-block_power(*child), child))
        blocks = np.array(sorted(kept), dtype=np.int64)
        return MapBasis(self.shape, blocks)


def check_haar(h: int, w: int) -> None:
    """A one-line :class:`ParameterError` unless an h x w map has a Haar basis (:meth:`MapBasis.haar`)."""
    if h & (h - 1) or w & (w - 1):
        raise ParameterError(f"the Haar basis needs a map whose height and width are powers of 2, got {h} x {w}")


def _haar_levels(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The orthonormal 2-D Haar coefficients (T, m) of ``X`` (h, w, m), the details level by level
    (finest first) then the top grid's scaling coefficients, and which rows are details (T,)."""
    rows, details, cur = [], [], X
    while cur.shape[0] >= 2 and cur.shape[1] >= 2:
        a, b, c, d = cur[0::2, 0::2], cur[0::2, 1::2], cur[1::2, 0::2], cur[1::2, 1::2]
        for part in ((a - b + c - d) / 2, (a + b - c - d) / 2, (a - b - c + d) / 2):
            rows.append(part.reshape(-1, X.shape[2]))
            details.append(np.ones(part.shape[0] * part.shape[1], dtype=bool))
        cur = (a + b + c + d) / 2
    rows.append(cur.reshape(-1, X.shape[2]))
    details.append(np.zeros(cur.shape[0] * cur.shape[1], dtype=bool))
    return np.concatenate(rows), np.concatenate(details)
