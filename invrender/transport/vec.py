"""Dot products and norms of (..., 3) vectors, written out per component.

``(a * b).sum(-1)`` and ``norm(dim=-1)`` reduce over a length-3 innermost axis, which torch's CPU
kernels handle several times slower than three multiplies and two adds; these helpers are the hot
path of every bounce. Likewise for gathers: 1-D tables are read with ``index_select`` (about 4x
faster than ``table[index]``), 2-D ones with :func:`rows`.
"""

from __future__ import annotations

import torch


def rows(table: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Rows ``table[index]`` of a (T, C) table for (N,) int64 ``index``: (N, C). For the narrow
    tables of the hot path (triangle records, RGB tables) torch's embedding lookup is 1.5-2.5x
    faster on the CPU than ``index_select`` or advanced indexing (which also allocates an index
    copy); never differentiable here (tables of constants)."""
    return torch.nn.functional.embedding(index, table)


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(...,) dot products of (..., 3) vectors."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def norm(a: torch.Tensor) -> torch.Tensor:
    """(...,) Euclidean lengths of (..., 3) vectors."""
    return dot(a, a).sqrt()


def normalize(a: torch.Tensor) -> torch.Tensor:
    """(..., 3) unit vectors along ``a`` (zero vectors stay zero)."""
    return a / norm(a).clamp_min(1e-30)[..., None]
