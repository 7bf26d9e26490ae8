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
from invrender.backends.arrays import TORCH
from invrender.scene.textures import DEFAULT, TextureSampling


#: the wrap modes by code, as the texture table of the compiled bounce holds them
WRAP_CODES = {"repeat": 0.0, "clamp": 1.0, "mirror": 2.0}


def _choose(xp, flag, a, b):
    """``flag ? a : b`` for a Python bool (chosen once) or a Bool array (per lane)."""
    if isinstance(flag, bool):
        return a if flag else b
    return xp.select(flag, a, b)


def wrap_lanes(xp, i, n, mode):
    """Texel indices ``i`` (Float holding integers) along an axis of ``n`` texels, wrapped by
    ``mode``: a :data:`WRAP_CODES` code (a number, or a Float per lane)."""
    repeat = i - n * xp.floor(i / n)
    if not isinstance(mode, float):  # per lane: every mode, then the lane's own
        m = i - (2.0 * n) * xp.floor(i / (2.0 * n))
        mirror = xp.select(m >= n, 2.0 * n - 1.0 - m, m)
        clamp = xp.minimum(xp.maximum(i, 0.0), n - 1.0)
        return xp.select(mode < 0.5, repeat, xp.select(mode < 1.5, clamp, mirror))
    if mode == WRAP_CODES["repeat"]:
        return repeat
    if mode == WRAP_CODES["clamp"]:
        return xp.minimum(xp.maximum(i, 0.0), n - 1.0)
    m = i - (2.0 * n) * xp.floor(i / (2.0 * n))
    return xp.select(m >= n, 2.0 * n - 1.0 - m, m)


def filter_lanes(xp, u, v, h, w, nearest, mode, to_uv):
    """The filter of an h x w texture at texture coordinates (u, v), written once against the array
    interface (:mod:`invrender.core.lanes`): four texel indices (UInt, ``row * w + column`` into the
    flattened texels) and their four weights (Float), which sum to 1 (module docstring).

    ``h``, ``w``: numbers or Floats per lane; ``nearest``: a bool or a Bool per lane; ``mode``: a
    :data:`WRAP_CODES` code, a number or a Float per lane; ``to_uv``: None or the affine map's six
    coefficients (numbers or Floats)."""
    if to_uv is not None:
        a, b, c, d, e, f = to_uv
        u, v = a * u + b * v + c, d * u + e * v + f
    x, y = u * w, (1.0 - v) * h
    x0, y0 = xp.floor(x - 0.5), xp.floor(y - 0.5)
    fx, fy = x - 0.5 - x0, y - 0.5 - y0
    i0, i1 = wrap_lanes(xp, y0, h, mode), wrap_lanes(xp, y0 + 1.0, h, mode)
    j0, j1 = wrap_lanes(xp, x0, w, mode), wrap_lanes(xp, x0 + 1.0, w, mode)
    weight = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy)
    rows = ((i0, j0), (i0, j1), (i1, j0), (i1, j1))
    if nearest is not False:  # the texel holding (x, y), weight 1
        i, j = wrap_lanes(xp, xp.floor(y), h, mode), wrap_lanes(xp, xp.floor(x), w, mode)
        zero = 0.0 * fx
        weight = tuple(_choose(xp, nearest, one, k) for one, k in zip((zero + 1.0, zero, zero, zero), weight))
        rows = tuple((_choose(xp, nearest, i, r), _choose(xp, nearest, j, c)) for r, c in rows)
    ww = xp.uint(w) if not isinstance(w, (int, float)) else int(w)
    return tuple(xp.uint(r) * ww + xp.uint(c) for r, c in rows), weight


def bilinear(h: int, w: int, uv: torch.Tensor, sampling: TextureSampling = DEFAULT) -> tuple[torch.Tensor, torch.Tensor]:
    """The filter of an h x w texture at ``uv`` (N, 2) under ``sampling`` (bilinear by default):
    texel indices (N, 4) int64 into the flattened (h * w) texels and their weights (N, 4), which
    sum to 1 (never differentiable): :func:`filter_lanes` as eager torch."""
    uv = uv.detach()
    index, weight = filter_lanes(TORCH, uv[:, 0], uv[:, 1], float(h), float(w), sampling.filter == "nearest", WRAP_CODES[sampling.wrap], sampling.to_uv)
    return torch.stack(index, dim=1).long(), torch.stack(weight, dim=1).to(uv.dtype)


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
