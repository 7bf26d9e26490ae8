"""One trial of a gradient study: a gradient sample, its cost, and its per-pixel contributions.

**Per-pixel contributions.** A gradient is a sum over pixels, ``G = sum_p c_p`` with
``c_p = <dl/dI_p, dI_p/dtheta>`` (summed over the pixel's channels). Reverse mode (autodiff or
replay) delivers only the sum; the per-pixel terms need the Jacobian column ``dI/dtheta`` as an
image, which is what forward mode computes: one render under ``torch.autograd.forward_ad`` with the
tangent of the chosen parameter set to ones gives ``dI/dt`` for every pixel at the cost of about one
render with duals (no tape is kept). For a constant RGB parameter, channel c of the image depends
on channel c of the parameter only, so channel c of ``dl/dI * dI/dt`` is pixel p's contribution to
the gradient's component c, and their sum over channels is its contribution to the derivative along
all channels together. Different pixels trace independent paths (the counter-based sampler), so the
``c_p`` are independent and the per-pixel variances add up to the variance of that derivative: the
map says which pixels the gradient's noise comes from.

**Threads.** A study draws several trials at once, one per core (:mod:`invrender.study.gradients`),
each thread with an :class:`Objective` of its own (its own leaf tensors, so that gradients do not
mix). Forward mode's dual level is global to the process, so the forward-mode renders of
:func:`pixel_contributions` take turns (a lock); everything else runs side by side.
"""

from __future__ import annotations

import dataclasses
import threading
import time

import torch
import torch.autograd.forward_ad as fwAD

from invrender.estimators import render
from invrender.study.configs import GradientConfig
from invrender.study.loss_gradients import LOSS_GRADIENTS, Objective

#: one forward-mode dual level at a time in the process
_FORWARD_AD = threading.Lock()


def gradient_sample(objective: Objective, names: list[str], config: GradientConfig, spp: int, seed: int) -> tuple[torch.Tensor, float, float]:
    """One gradient of the loss by ``config`` at ``spp`` samples per pixel from ``seed``.

    Args:
        names: the studied parameters (they require grad in ``objective.scene``).
    Returns:
        (the gradient flattened over ``names`` in order, (C,) float64; the CPU seconds of the
        calling thread and the wall seconds it took, both without the pairing's untimed
        preparation (:meth:`LossGradient.prepare`)). The CPU seconds are the gradient's whole cost
        when it is traced in the calling thread alone, as a study's workers trace it
        (single-threaded torch, one core: :mod:`invrender.study.gradients`).
    """
    params = [objective.scene.params[n] for n in names]
    for p in params:
        p.grad = None
    pairing = LOSS_GRADIENTS[config.gradient]()
    prepared = pairing.prepare(objective, config, spp, seed)
    cpu, wall = time.thread_time(), time.perf_counter()
    pairing.backward(objective, config, spp, seed, prepared)
    cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
    flat = torch.cat([(p.grad if p.grad is not None else torch.zeros_like(p)).detach().reshape(-1).double() for p in params])
    for p in params:
        p.grad = None
    return flat, cpu, wall


def pixel_contributions(objective: Objective, name: str, config: GradientConfig, spp: int, seed: int) -> torch.Tensor:
    """Each pixel's contribution ``dl/dI * dI/dt`` to the derivative along ``t`` = all of parameter
    ``name``'s components moved together, for the gradient :func:`gradient_sample` draws with the
    same arguments.

    Returns:
        (H, W, 3) float64; its sum over pixels (and channels) is that derivative, and for a
        constant RGB parameter channel c summed over pixels is the gradient's component c.
    """
    scene = objective.scene
    with _FORWARD_AD, torch.no_grad(), fwAD.dual_level():
        params = {k: v.detach() for k, v in scene.params.items()}
        params[name] = fwAD.make_dual(params[name], torch.ones_like(params[name]))
        options = {k: v for k, v in config.render_kwargs().items() if k != "estimator"}  # no tape: estimators do not apply
        dual = render(dataclasses.replace(scene, params=params), spp=spp, seed=seed, progress=False, **options)
        image, tangent = fwAD.unpack_dual(dual)
        image = image.clone()
        tangent = torch.zeros_like(image) if tangent is None else tangent.clone()
    adjoint = LOSS_GRADIENTS[config.gradient]().adjoint(objective, config, spp, seed, image)
    return adjoint.double() * tangent.double()
