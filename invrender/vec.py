"""Dot products and norms of (..., 3) vectors, written out per component.

``(a * b).sum(-1)`` and ``norm(dim=-1)`` reduce over a length-3 innermost axis, which torch's CPU
kernels handle several times slower than three multiplies and two adds; these helpers are the hot
path of every bounce. Likewise for gathers: tables are read with ``index_select`` (for 1-D tables
about 4x faster than ``table[index]``).
"""

from __future__ import annotations

import torch


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(...,) dot products of (..., 3) vectors."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def norm(a: torch.Tensor) -> torch.Tensor:
    """(...,) Euclidean lengths of (..., 3) vectors."""
    return dot(a, a).sqrt()


def normalize(a: torch.Tensor) -> torch.Tensor:
    """(..., 3) unit vectors along ``a`` (zero vectors stay zero)."""
    return a / norm(a).clamp_min(1e-30)[..., None]
