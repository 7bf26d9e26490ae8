"""Looking up per-hit RGB values (rho or eps) from constant or textured parameters.

A parameter is either a constant (3,) or a texture (h, w, 3) over UVs. Textures are filtered
bilinearly with repeat wrapping. UVs follow OpenGL's (and OBJ's, and trimesh's) convention: u runs
left to right along columns, v bottom to top, and the tensor is stored as images are, row 0 at the
top; texel (i, j) has its centre at u = (j + 0.5) / w, v = 1 - (i + 0.5) / h. Lookups are differentiable in the values
(each result is a weighted sum of four texels), never in the UVs.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch


def bilinear(h: int, w: int, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The bilinear filter of an h x w texture at ``uv`` (N, 2): texel indices (N, 4) int64 into
    the flattened (h * w) texels and their weights (N, 4), which sum to 1 (never differentiable)."""
    x = uv[:, 0].detach() * w - 0.5
    y = (1.0 - uv[:, 1].detach()) * h - 0.5
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    i0, j0 = y0.long().remainder(h), x0.long().remainder(w)
    i1, j1 = (i0 + 1).remainder(h), (j0 + 1).remainder(w)
    index = torch.stack([i0 * w + j0, i0 * w + j1, i1 * w + j0, i1 * w + j1], dim=1)
    weight = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], dim=1)
    return index, weight


def lookup(value: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Values at ``uv`` (N, 2) of a constant (3,) or a texture (h, w, 3): (N, 3)."""
    if value.ndim == 1:
        return value.expand(uv.shape[0], 3)
    index, weight = bilinear(value.shape[0], value.shape[1], uv)
    texels = value.reshape(-1, 3)[index]  # (N, 4, 3)
    return (texels * weight[:, :, None].to(texels.dtype)).sum(1)


def gather_rgb(values: Sequence[torch.Tensor], index: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Per-hit RGB from a list of parameters.

    Args:
        values: K parameters, each (3,) or (h, w, 3).
        index: (N,) int64 which parameter each hit uses; -1 means zero.
        uv: (N, 2) texture coordinates of the hits.
    Returns:
        (N, 3), differentiable in ``values``.
    """
    n = index.shape[0]
    zero = torch.zeros(3, device=index.device)
    table = torch.stack([v if v.ndim == 1 else zero for v in values] + [zero])  # (K + 1, 3); row K = "none"
    out = table.index_select(0, torch.where(index >= 0, index, len(values)))
    for k, v in enumerate(values):
        if v.ndim == 3:
            at = (index == k).nonzero()[:, 0]  # one host-device synchronization (its count)
            if at.numel():
                out = out.index_put((at,), lookup(v, uv.index_select(0, at)))
    return out if n else out.reshape(0, 3)
