"""The reconstruction filter's interface and its splat: film positions -> the pixels a sample reaches.

A sample at continuous film position (x, y) (pixel units, pixel centres at i + 0.5) is added to
every pixel (i, j) whose centre lies within the filter's radius r on both axes,
``|i + 0.5 - x| <= r`` and ``|j + 0.5 - y| <= r``, with the separable weight
``f(i + 0.5 - x) f(j + 0.5 - y)``; the film divides each pixel's weighted sum by its sum of
weights (:meth:`invrender.core.film.Film.develop`). This is Mitsuba 3's image block (``put`` with
an unnormalized block, the film's weight channel divided out when it develops), with the filter
evaluated directly as its JIT variants do (no table).

The box of radius 1/2 is special: a sample lands in its own pixel only, with weight 1, and the
film keeps its plain per-pixel sums divided by spp (:attr:`ReconstructionFilter.is_box`).

The filters themselves are plugins (:mod:`invrender.plugins.filters`); this module is the
interface the film and the estimators use, so the core never imports a plugin.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import torch


class ReconstructionFilter(ABC):
    """A separable, symmetric pixel filter of finite support.

    Attributes:
        type_name: the plugin's name (Mitsuba's ``<rfilter type=...>``).
        radius: support radius in pixels: ``eval(x) = 0`` for ``|x| > radius``.
    """

    type_name: str = ""
    radius: float = 0.5

    @abstractmethod
    def eval(self, x: torch.Tensor) -> torch.Tensor:
        """The 1-D filter at offsets ``x`` (any shape, pixels; float64): same shape."""

    @property
    def is_box(self) -> bool:
        """True for the box of radius 1/2, which the film accumulates without weights."""
        return False

    @property
    def border_size(self) -> int:
        """Pixels the sampled area grows by on each side with ``sample_border``: Mitsuba's
        ``ceil(radius - 1/2)`` (less a tiny epsilon, so a radius of exactly k + 1/2 gives k)."""
        return max(0, math.ceil(self.radius - 0.5 - 2e-4))

    @property
    def taps(self) -> int:
        """Most pixels a sample reaches along one axis: ``floor(2 radius) + 1``."""
        return int(math.floor(2.0 * self.radius)) + 1

    def settings(self) -> dict:
        """The filter's settings (for ``repr`` and specs): none beyond its type by default."""
        return {}

    def __repr__(self) -> str:
        items = "".join(f", {k}={v!r}" for k, v in self.settings().items())
        return f"{type(self).__name__}(radius={self.radius!r}{items})"

    def __eq__(self, other) -> bool:
        return type(self) is type(other) and self.radius == other.radius and self.settings() == other.settings()

    def __hash__(self) -> int:
        return hash((type(self).__name__, self.radius, tuple(sorted(self.settings().items()))))

    @property
    def reach(self) -> int:
        """R: a sample in pixel i reaches pixels i - R .. i + R along an axis, ``ceil(radius + 1/2) - 1``
        (a pixel centre j + 1/2 within the radius of a position in [i, i + 1))."""
        return math.ceil(self.radius + 0.5) - 1

    def splat(self, xy: torch.Tensor, values: torch.Tensor, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The weighted sums the samples at film positions ``xy`` (N, 2) with ``values`` (N, C)
        add to the pixels of a ``width x height`` film: (pixel indices (M,) int64, sums (M, C)
        float64). The same sums as :meth:`footprint` then :meth:`Footprint.splat` (differentiable
        in ``values``), computed per source pixel: the samples of a pixel (consecutive in a
        chunk) give its block of (2R + 1)^2 sums as one matrix product by separability,
        ``B[a, b, c] = sum_n wy[n, a] (wx[n, b] v[n, c])``, and only the blocks are scattered to the
        pixels they reach (rows: the source pixels times (2R + 1)^2, not the samples times it)."""
        R = self.reach
        n = xy.shape[0]
        offsets = torch.arange(-R, R + 1, device=xy.device)
        cell = torch.floor(xy).long()  # (N, 2) the pixel each sample lies in (outside the film with sample_border)
        low = cell.amin(0)
        span = int(cell[:, 0].max() - low[0]) + 1
        key = (cell[:, 1] - low[1]) * span + (cell[:, 0] - low[0])
        if n > 1 and bool((key[1:] < key[:-1]).any()):  # the driver's chunks come sorted by pixel; others are sorted here
            key, order = key.sort(stable=True)
            xy, values, cell = xy[order], values[order], cell[order]
        cells, counts = torch.unique_consecutive(key, return_counts=True)
        group = torch.repeat_interleave(torch.arange(cells.shape[0], device=xy.device), counts)
        slot = torch.arange(n, device=xy.device) - (torch.cumsum(counts, 0) - counts)[group]  # index within its pixel
        width_of = int(counts.max())
        weights = []
        for axis in (0, 1):
            d = (cell[:, axis : axis + 1] + offsets).to(torch.float64) + 0.5 - xy[:, axis : axis + 1].to(torch.float64)  # (N, 2R + 1)
            w = self.eval(d)
            weights.append(torch.where(d.abs() <= self.radius, w, torch.zeros((), dtype=w.dtype, device=w.device)))
        wx, wy = weights
        v = values.to(torch.float64)
        taps, C = 2 * R + 1, v.shape[1]
        Wy = torch.zeros(cells.shape[0], width_of, taps, dtype=torch.float64, device=xy.device).index_put_((group, slot), wy)
        XV = torch.zeros(cells.shape[0], width_of, taps * C, dtype=torch.float64, device=xy.device).index_put_((group, slot), (wx[:, :, None] * v[:, None, :]).reshape(n, -1))
        blocks = torch.bmm(Wy.transpose(1, 2), XV)  # (G, 2R + 1 (y), (2R + 1) C (x, channel))
        cx, cy = cells % span + low[0], cells // span + low[1]
        ty = cy.reshape(-1, 1, 1) + offsets.reshape(1, -1, 1)
        tx = cx.reshape(-1, 1, 1) + offsets.reshape(1, 1, -1)
        inside = ((tx >= 0) & (tx < width) & (ty >= 0) & (ty < height)).reshape(-1)
        return (ty * width + tx).reshape(-1)[inside], blocks.reshape(-1, C)[inside]

    def footprint(self, xy: torch.Tensor, width: int, height: int) -> Footprint:
        """The pixels of a ``width x height`` film the samples at film positions ``xy`` (N, 2)
        reach, with their weights (:class:`Footprint`)."""
        p = xy.to(torch.float64) - 0.5  # positions relative to pixel centres
        k = torch.arange(self.taps, device=xy.device, dtype=torch.float64)
        axes = []
        for axis, size in ((0, width), (1, height)):
            c = p[:, axis : axis + 1]
            first = torch.ceil(c - self.radius)  # the first pixel whose centre is within the radius
            i = first + k  # (N, taps)
            inside = (i <= c + self.radius) & (i >= 0) & (i < size)
            w = torch.where(inside, self.eval(i - c), torch.zeros((), dtype=torch.float64, device=xy.device))
            axes.append((i.clamp(0, size - 1).long(), w))
        (ix, wx), (iy, wy) = axes
        index = (iy[:, :, None] * width + ix[:, None, :]).reshape(xy.shape[0], -1)
        weight = (wy[:, :, None] * wx[:, None, :]).reshape(xy.shape[0], -1)
        return Footprint(index, weight)


@dataclass(frozen=True)
class Footprint:
    """Where N samples land on the film.

    Attributes:
        index: (N, K) int64 flat pixel indices (row * width + column); entries of weight 0 may
            repeat a valid index (they add nothing).
        weight: (N, K) float64 filter weights ``f(dx) f(dy)`` (0 outside the radius or the film).
    """

    index: torch.Tensor
    weight: torch.Tensor

    def splat(self, values: torch.Tensor, out: torch.Tensor) -> None:
        """``out[index] += weight * values``: values (N, C), out (P, C) float64 (in place)."""
        v = values.to(torch.float64)
        out.index_add_(0, self.index.reshape(-1), (self.weight[:, :, None] * v[:, None, :]).reshape(-1, v.shape[1]))

    def weights_into(self, out: torch.Tensor) -> None:
        """``out[index] += weight``: the film's per-pixel sums of weights, out (P,) float64."""
        out.index_add_(0, self.index.reshape(-1), self.weight.reshape(-1))

    def gather(self, image: torch.Tensor) -> torch.Tensor:
        """``sum_k weight[:, k] image[index[:, k]]``: (N, C) from image (P, C); the adjoint of
        :meth:`splat`."""
        picked = image.index_select(0, self.index.reshape(-1)).reshape(*self.index.shape, image.shape[1])
        return (self.weight[:, :, None].to(image.dtype) * picked).sum(1)
