"""Which of a bounce's compiled steps renders use: the switch ``INVRENDER_KERNELS``.

The steps of a bounce that never carry a gradient are written once against the array interface
(:mod:`invrender.backends.arrays`) and run compiled by Dr.Jit or as eager torch
(:mod:`invrender.core.compiled`, ``INVRENDER_BOUNCE``). Single steps (a hit's geometry, an
emitter sample, the camera's samples, the random numbers) always run that way; the fused bounce
(:mod:`invrender.core.fused`: a whole path vertex in one kernel, and the derivatives it carries
forward) applies where :func:`fused_bounce` says so. Nothing here needs Warp (which remains only
as an intersection backend, :mod:`invrender.backends.warp_bvh`).
"""

from __future__ import annotations

import os

import torch

from invrender.errors import ParameterError

#: set INVRENDER_KERNELS=steps (or torch) to render without the fused bounce: the torch bounce,
#: its single steps compiled as ever
ENV = "INVRENDER_KERNELS"
#: the values INVRENDER_KERNELS takes (default: warp, the fused bounce where it applies; the name
#: is the one it had when the kernels were Warp's); ``steps`` and ``torch`` now mean the same
CHOICES = ("warp", "steps", "torch")


def fused_bounce(device: torch.device) -> bool:
    """May renders on ``device`` (CPU or CUDA) trace with the fused bounce
    (:mod:`invrender.core.fused`), ``INVRENDER_KERNELS`` being neither ``steps`` nor ``torch``?
    Another value of the variable than ``warp``, ``steps`` or ``torch`` is a one-line
    :class:`~invrender.errors.ParameterError` (first met when a render's context is built, before
    any work)."""
    choice = os.environ.get(ENV, "warp")
    if choice not in CHOICES:
        raise ParameterError(f"{ENV} must be 'warp', 'steps' or 'torch', got {choice!r}")
    return choice == "warp" and device.type in ("cpu", "cuda")
