"""Looking up per-hit RGB values (rho or eps) from constant, textured or per-vertex parameters.

A parameter is a constant (3,), a texture (h, w, 3) over UVs, or a per-vertex attribute (V, 3)
(one row per scene vertex, :attr:`Triangles.vertex <invrender.scene.scene.Triangles.vertex>`),
interpolated barycentrically at the hit.

Textures are read through a :class:`~invrender.scene.textures.TextureSampling` (Mitsuba's bitmap options): an affine
``to_uv`` applied to the hit's UVs, a ``nearest`` or ``bilinear`` filter (the default) and a
``repeat`` (the default), ``clamp`` or ``mirror`` wrap of the texel indices. UVs follow OpenGL's
(and OBJ's, and trimesh's) convention: u runs left to right along columns, v bottom to top, and the
tensor is stored as images are, row 0 at the top; texel (i, j) has its centre at u = (j + 0.5) / w,
v = 1 - (i + 0.5) / h. With ``x = u w`` and ``y = (1 - v) h`` (Mitsuba's texel coordinates), the
nearest filter reads texel ``(floor y, floor x)``, the bilinear filter the four texels around
``(y - 0.5, x - 0.5)`` with tent weights; indices outside the image are wrapped: ``repeat`` modulo
the size, ``clamp`` to the border texel, ``mirror`` reflected (period twice the size: ..., 1, 0,
0, 1, ..., n - 1, n - 1, n - 2, ...). Every filter returns four indices and four weights (the
nearest filter one weight 1 and three 0), so the lookup has the same shapes whatever the options:
elementwise arithmetic, no data-dependent shapes. Lookups are differentiable in the values (each
result is a weighted sum of texels or vertex rows), never in the UVs or barycentrics.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from invrender.errors import SceneError
from invrender.scene.textures import DEFAULT, TextureSampling


def wrap(index: torch.Tensor, n: int, mode: str) -> torch.Tensor:
    """Texel indices ``index`` (int64, any shape) along an axis of ``n`` texels, wrapped by ``mode``."""
    if mode == "repeat":
        return index.remainder(n)
    if mode == "clamp":
        return index.clamp(0, n - 1)
    m = index.remainder(2 * n)  # mirror
    return torch.where(m >= n, 2 * n - 1 - m, m)


def bilinear(h: int, w: int, uv: torch.Tensor, sampling: TextureSampling = DEFAULT) -> tuple[torch.Tensor, torch.Tensor]:
    """The filter of an h x w texture at ``uv`` (N, 2) under ``sampling`` (bilinear by default):
    texel indices (N, 4) int64 into the flattened (h * w) texels and their weights (N, 4), which
    sum to 1 (never differentiable)."""
    st = sampling.transform(uv.detach())
    x, y = st[:, 0] * w, (1.0 - st[:, 1]) * h
    if sampling.filter == "nearest":
        i, j = wrap(torch.floor(y).long(), h, sampling.wrap), wrap(torch.floor(x).long(), w, sampling.wrap)
        index = (i * w + j)[:, None].expand(-1, 4)
        weight = torch.zeros_like(index, dtype=uv.dtype)
        return index, torch.cat([torch.ones_like(weight[:, :1]), weight[:, 1:]], dim=1)
    x, y = x - 0.5, y - 0.5
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    i0, j0 = y0.long(), x0.long()
    i0, i1 = wrap(i0, h, sampling.wrap), wrap(i0 + 1, h, sampling.wrap)
    j0, j1 = wrap(j0, w, sampling.wrap), wrap(j0 + 1, w, sampling.wrap)
    index = torch.stack([i0 * w + j0, i0 * w + j1, i1 * w + j0, i1 * w + j1], dim=1)
    weight = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], dim=1)
    return index, weight


def lookup(value: torch.Tensor, uv: torch.Tensor, sampling: TextureSampling = DEFAULT) -> torch.Tensor:
    """Values at ``uv`` (N, 2) of a constant (3,) or a texture (h, w, 3) read by ``sampling``: (N, 3)."""
    if value.ndim == 1:
        return value.expand(uv.shape[0], 3)
    index, weight = bilinear(value.shape[0], value.shape[1], uv, sampling)
    texels = value.reshape(-1, 3)[index]  # (N, 4, 3)
    return (texels * weight[:, :, None].to(texels.dtype)).sum(1)


def interpolate(value: torch.Tensor, corners: torch.Tensor, bary: torch.Tensor) -> torch.Tensor:
    """A per-vertex attribute ``value`` (V, 3) at hits inside triangles with vertex rows
    ``corners`` (N, 3) int64 and barycentric weights ``bary`` (N, 3) (summing to 1): (N, 3)."""
    rows = value.index_select(0, corners.reshape(-1)).reshape(-1, 3, value.shape[1])  # (N, 3 corners, 3)
    return (rows * bary.detach()[:, :, None].to(rows.dtype)).sum(1)


def gather_rgb(
    values: Sequence[torch.Tensor], index: torch.Tensor, uv: torch.Tensor, samplings: Sequence[TextureSampling | None] | None = None,
    corners: torch.Tensor | None = None, bary: torch.Tensor | None = None,
) -> torch.Tensor:  # fmt: skip
    """Per-hit RGB from a list of parameters.

    Args:
        values: K parameters, each (3,), (h, w, 3) or (V, 3) (per vertex).
        index: (N,) int64 which parameter each hit uses; -1 means zero.
        uv: (N, 2) texture coordinates of the hits.
        samplings: per parameter, how a texture is read (None = :data:`DEFAULT`).
        corners: (N, 3) int64 vertex rows of the hit triangles (needed by per-vertex parameters).
        bary: (N, 3) barycentric weights of those rows at the hits.
    Returns:
        (N, 3), differentiable in ``values``.
    """
    n = index.shape[0]
    zero = torch.zeros(3, device=index.device)
    table = torch.stack([v if v.ndim == 1 else zero for v in values] + [zero])  # (K + 1, 3); row K = "none"
    out = table.index_select(0, torch.where(index >= 0, index, len(values)))
    for k, v in enumerate(values):
        if v.ndim == 1:
            continue
        if v.ndim == 2 and (corners is None or bary is None):
            raise SceneError("a per-vertex parameter is looked up without the hits' triangle corners (a bug: the caller passes no corners)")
        at = (index == k).nonzero()[:, 0]  # one host-device synchronization (its count)
        if at.numel():
            if v.ndim == 2:
                part = interpolate(v, corners.index_select(0, at), bary.index_select(0, at))
            else:
                part = lookup(v, uv.index_select(0, at), (samplings[k] if samplings is not None else None) or DEFAULT)
            out = out.index_put((at,), part)
    return out if n else out.reshape(0, 3)
