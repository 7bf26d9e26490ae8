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
"""

from __future__ import annotations

import dataclasses
import time

import torch
import torch.autograd.forward_ad as fwAD

from invrender.diff import render
from invrender.study.configs import GradientConfig
from invrender.study.loss_gradients import LOSS_GRADIENTS, Objective


def gradient_sample(objective: Objective, names: list[str], config: GradientConfig, spp: int, seed: int) -> tuple[torch.Tensor, float]:
    """One gradient of the loss by ``config`` at ``spp`` samples per pixel from ``seed``.

    Args:
        names: the studied parameters (they require grad in ``objective.scene``).
    Returns:
        (the gradient flattened over ``names`` in order, (C,) float64; wall seconds it took).
    """
    params = [objective.scene.params[n] for n in names]
    for p in params:
        p.grad = None
    start = time.perf_counter()
    LOSS_GRADIENTS[config.gradient]().backward(objective, config, spp, seed)
    seconds = time.perf_counter() - start
    flat = torch.cat([(p.grad if p.grad is not None else torch.zeros_like(p)).detach().reshape(-1).double() for p in params])
    for p in params:
        p.grad = None
    return flat, seconds


def pixel_contributions(objective: Objective, name: str, config: GradientConfig, spp: int, seed: int) -> torch.Tensor:
    """Each pixel's contribution ``dl/dI * dI/dt`` to the derivative along ``t`` = all of parameter
    ``name``'s components moved together, for the gradient :func:`gradient_sample` draws with the
    same arguments.

    Returns:
        (H, W, 3) float64; its sum over pixels (and channels) is that derivative, and for a
        constant RGB parameter channel c summed over pixels is the gradient's component c.
    """
    scene = objective.scene
    with torch.no_grad(), fwAD.dual_level():
        params = {k: v.detach() for k, v in scene.params.items()}
        params[name] = fwAD.make_dual(params[name], torch.ones_like(params[name]))
        options = {k: v for k, v in config.render_kwargs().items() if k != "estimator"}  # no tape: estimators do not apply
        dual = render(dataclasses.replace(scene, params=params), spp=spp, seed=seed, progress=False, **options)
        image, tangent = fwAD.unpack_dual(dual)
        image = image.clone()
        tangent = torch.zeros_like(image) if tangent is None else tangent.clone()
    adjoint = LOSS_GRADIENTS[config.gradient]().adjoint(objective, config, spp, seed, image)
    return adjoint.double() * tangent.double()
