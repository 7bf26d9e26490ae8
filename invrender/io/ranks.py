"""Which process writes: this process's place in a torch.distributed group (docs/scale.md).

Inside a process group of several ranks every rank holds the same results and only rank 0 writes
files (:func:`invrender.io.atomic.atomic_file`) and shows progress. The collectives that split a
render across the ranks are in :mod:`invrender.core.ranks`, which builds on these.
"""

from __future__ import annotations

import torch


def distributed():
    """``torch.distributed`` when a process group of more than one rank is initialized, else None."""
    if not torch.distributed.is_available() or not torch.distributed.is_initialized():
        return None
    return torch.distributed if torch.distributed.get_world_size() > 1 else None


def world() -> tuple[int, int]:
    """(rank, world size) of this process: (0, 1) outside a process group."""
    dist = distributed()
    return (dist.get_rank(), dist.get_world_size()) if dist is not None else (0, 1)


def is_main() -> bool:
    """Is this the process that writes files and shows progress (rank 0, or the only one)?"""
    return world()[0] == 0


__all__ = ["distributed", "is_main", "world"]
