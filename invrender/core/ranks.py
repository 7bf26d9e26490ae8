"""Rendering and fitting across processes and machines on torch.distributed (docs/scale.md).

Inside an initialized process group (``torchrun``, or ``torch.distributed.init_process_group`` in
the user's own program) every rank runs the same program on the same inputs. A render splits its
chunks of (pixel, sample) paths across the ranks (chunk c is traced by rank ``c mod world``); the
counter-based sampler makes each path's numbers a function of its ids alone, so the split is
invisible in the result. The film sums (float64) are then all-reduced, so every rank holds the
whole image; a gradient's per-rank parts are all-reduced the same way, so every rank holds the whole
gradient and a fit takes the same steps on every rank. Only rank 0 writes files
(:func:`invrender.io.atomic.atomic_file`) and shows progress (:func:`is_main`, from
:mod:`invrender.io.ranks`, the layer that writes). Outside a process group, or in a group
of one, nothing here does anything.

Collectives: gloo for tensors on the CPU, NCCL for CUDA tensors (the group's backend must suit the
device the render runs on).
"""

from __future__ import annotations

import os

import torch

from invrender.errors import ParameterError
from invrender.io.ranks import distributed, is_main, world
from invrender.validate import check_device


class _SumAcrossRanks(torch.autograd.Function):
    """All-reduce (sum) whose backward passes the gradient through unchanged: every rank computes
    the same loss of the same summed image, so each already holds the whole ``dl/dsum``, and the
    derivative of its own part is that gradient (the parts' derivatives are summed later, over the
    parameters: :func:`sum_gradients`)."""

    @staticmethod
    def forward(fctx, x: torch.Tensor) -> torch.Tensor:
        y = x.detach().clone()
        torch.distributed.all_reduce(y)
        return y

    @staticmethod
    def backward(fctx, grad: torch.Tensor) -> torch.Tensor:
        return grad


def sum_across_ranks(x: torch.Tensor) -> torch.Tensor:
    """The sum of ``x`` over the ranks (``x`` itself in one process); differentiable, with the
    per-rank derivative of :class:`_SumAcrossRanks`."""
    return x if distributed() is None else _SumAcrossRanks.apply(x)


def sum_gradients(grads: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Each rank's part of a gradient summed over the ranks, in place (name -> tensor)."""
    dist = distributed()
    if dist is not None:
        for g in grads.values():
            dist.all_reduce(g)
    return grads


def max_across_ranks(n: int, device) -> int:
    """The largest of each rank's ``n``."""
    dist = distributed()
    if dist is None:
        return n
    t = torch.tensor([n], dtype=torch.int64, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return int(t)


def barrier() -> None:
    """Wait until every rank gets here (after rank 0 wrote files the others read)."""
    dist = distributed()
    if dist is not None:
        dist.barrier()


def refuse(what: str) -> None:
    """A one-line :class:`ParameterError` when called inside a process group of several ranks, for
    work that does not split across them (``what`` names it)."""
    if distributed() is not None:
        raise ParameterError(f"{what} runs in one process; it is not available inside a torch.distributed group of {world()[1]} ranks")


_joined = False


def leave_process_group() -> None:
    """Destroy the group :func:`init_from_environment` created (nothing otherwise)."""
    global _joined
    if _joined and torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()
    _joined = False


def init_from_environment(device: str | None) -> torch.device | None:
    """Join the process group ``torchrun`` describes in the environment (``RANK``, ``WORLD_SIZE``,
    ``MASTER_ADDR``, ...), once: gloo for CPU renders, NCCL for CUDA ones. Returns the device of
    this rank (``cuda`` becomes ``cuda:LOCAL_RANK``; None = unchanged), or None without torchrun's
    environment (a single process: nothing to do)."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1 or "RANK" not in os.environ:
        return None
    check_device(device)
    cuda = device is not None and torch.device(device).type == "cuda"
    if cuda and not torch.cuda.is_available():
        raise ParameterError("device 'cuda' requested but torch has no CUDA device here")
    global _joined
    if not torch.distributed.is_initialized():
        torch.distributed.init_process_group(backend="nccl" if cuda else "gloo")
        _joined = True
    if cuda:
        local = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
        torch.cuda.set_device(local)
        return local
    return None


__all__ = [
    "world", "is_main", "sum_across_ranks", "sum_gradients", "max_across_ranks", "barrier", "refuse",
    "leave_process_group", "init_from_environment",
]  # fmt: skip
