"""Autodiff across ranks: the recorded render's gradient summed over a torch.distributed group.

In one process ``autodiff`` is torch recording the render itself. Split across ranks, each rank
records only its own chunks, so its part of ``dl/dtheta`` must be added to the others': this
function wraps the recorded render so that its backward pass returns the all-reduced parameter
gradient (every rank then holds the whole of it, as path replay's ranks do).
"""

from __future__ import annotations

import torch

from invrender.scene.scene import Scene
from invrender.core.driver import RenderSettings
from invrender.plugins.integrators import Integrator
from invrender.core.ranks import sum_gradients, world


def autodiff_render(scene: Scene, integrator: Integrator, settings: RenderSettings, device, names: list[str]) -> torch.Tensor:
    """The image ``integrator`` renders, recorded by autograd for the parameters ``names``; inside a
    process group of several ranks its backward pass sums the ranks' gradients."""
    if world()[1] == 1:
        return integrator.render(scene, settings, device)
    return _AutodiffAcrossRanks.apply(scene, integrator, settings, device, names, *(scene.params[n] for n in names))


class _AutodiffAcrossRanks(torch.autograd.Function):
    @staticmethod
    def forward(fctx, scene, integrator, settings, device, names, *values):
        leaves = [v.detach().requires_grad_(True) for v in values]
        with torch.enable_grad():
            image = integrator.render(scene, settings, device, params=dict(zip(names, leaves)))
        fctx.image, fctx.leaves, fctx.names = image, leaves, names
        return image.detach()

    @staticmethod
    def backward(fctx, grad_image):
        # a rank whose chunks met no parameter (or that traced none: small images are fewer
        # chunks than ranks) recorded nothing, and its part is zero
        recorded = fctx.image.requires_grad
        parts = torch.autograd.grad(fctx.image, fctx.leaves, grad_image, allow_unused=True) if recorded else [None] * len(fctx.leaves)
        grads = sum_gradients({n: g if g is not None else torch.zeros_like(v) for n, g, v in zip(fctx.names, parts, fctx.leaves)})
        del fctx.image, fctx.leaves
        return (None, None, None, None, None, *grads.values())
