"""A film that accumulates the light-transport matrix of an environment map instead of an image.

Sampling never depends on a map's values (docs/architecture.md, detached sampling), so a
contribution that ends on the map, a ray that leaves the scene or an emitter sample of the map,
is ``w scale sum_j b_j t_j``: weights ``w`` fixed by the traced path, the map's ``scale``, and its
bilinear lookup at the contribution's direction (texels ``j``, filter weights ``b_j``). Rendered
with every texel set to 1 (and every other emitter dark) each such contribution *is* ``w scale``
(the weights ``b_j`` sum to 1). :class:`TexelFilm` scatters it into the rows of its pixel and the
columns of its four texels of a dense matrix

    A[c, p, t] += w_c scale b_t

per colour channel c, pixel p (of the film's rows) and texel t, so that the image under any map L
of the same sampling is ``I[p, c] = sum_t A[c, p, t] L[t, c]`` (divided by spp), equal to a render
of the same seed to float rounding. With a piecewise-constant basis of the map (``columns``: the
basis function each texel belongs to, ``L = B x``) the film scatters into the basis' columns
instead, ``A B``: the same images for every map of the basis, in fewer columns.

The integrators tell the film the direction of every contribution that may end on an emitter
infinitely far away just before adding it (``Film.arrive``, then ``Film.add`` with the same film
indices); the film looks up the texels there (``Light.texels``). A contribution that arrives without
an ``arrive`` is refused (an integrator that reads the map some other way).
"""

from __future__ import annotations

import threading

import torch

from invrender.errors import ParameterError
from invrender.core.film import Film
from invrender.vec import where_true


class TexelFilm(Film):
    """Accumulates ``A`` (3, P, n) float32 (channel, pixel row, column: a texel or a basis
    function), shared by the render's workers (additions under a lock).

    Args:
        matrix: (3, P, n), P the pixel rows (the film's width x height, or more: ``offset``).
        lookup: ``lookup(d) -> (index (N, 4) int64 into the T texels, weights (N, 4))`` of the
            map's bilinear filter along world directions ``d`` (N, 3).
        offset: the row of pixel 0 (views stacked in one matrix).
        width, height: the image's size (its pixels are ``offset .. offset + width * height - 1``).
        columns: (T,) int64 the column of each texel (a piecewise-constant basis); None: texel t
            is column t (n = T).
    """

    def __init__(self, matrix: torch.Tensor, lookup, width: int, height: int, offset: int = 0, columns: torch.Tensor | None = None):
        super().__init__(width, height, False, matrix.device)
        if matrix.ndim != 3 or matrix.shape[0] != 3 or matrix.shape[1] < offset + width * height:
            raise ValueError(f"TexelFilm: the matrix must be (3, >= {offset + width * height}, T), got {tuple(matrix.shape)}")
        self.matrix, self.lookup, self.offset = matrix, lookup, offset
        self.texels = matrix.shape[2]  # n, the columns
        self.columns = columns
        self._flat = matrix.view(3, -1)
        self._lock = threading.Lock()
        self._pending = threading.local()  # per worker thread: the last arrival's (film indices, texels, weights)

    def arrive(self, pixel: torch.Tensor, d: torch.Tensor) -> None:
        self._pending.value = (pixel, d)  # looked up in add, where only the contributions that are not 0 remain

    def add(self, term: int, pixel: torch.Tensor, radiance: torch.Tensor) -> None:
        pending = getattr(self._pending, "value", None)
        self._pending.value = None
        c = radiance.detach().float()
        live = (c != 0).any(1)
        if pending is None:
            if bool(live.any()):
                raise ParameterError("a contribution reached the transport matrix without its direction (an integrator that reads the map without Film.arrive, or an emitter left lit)")
            return
        at, d = pending
        if at.shape != pixel.shape:
            raise ValueError("TexelFilm: a contribution's film indices differ from its arrival's")
        keep = where_true(live)
        if not keep.numel():
            return
        if keep.numel() < pixel.numel():
            pixel, d, c = pixel.index_select(0, keep), d.index_select(0, keep), c.index_select(0, keep)
        index, weight = self.lookup(d)
        if self.columns is not None:
            index = self.columns[index]
        flat = ((pixel + self.offset) * self.texels)[:, None] + index  # (N, 4) entries of a channel's P x n
        value = torch.empty(3, *index.shape, dtype=torch.float32, device=c.device)  # (3, N, 4), contiguous
        torch.mul(c.t()[:, :, None], weight.float(), out=value)
        flat, value = flat.view(-1), value.view(3, -1)
        with self._lock:
            for k in range(3):  # 1-D additions by index: faster on the CPU than one along a (3, P n) matrix's dim 1
                self._flat[k].index_add_(0, flat, value[k])
