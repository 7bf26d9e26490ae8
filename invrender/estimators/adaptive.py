"""Adaptive sampling under the estimators: autodiff records the rounds, replay re-traces them.

The adaptive image is ``sum_r w_r X_r`` with fixed weights ``w_r = 1/R`` and each round's pixel
estimate ``X_r`` the mean of its ``n_r`` samples (:mod:`invrender.core.adaptive`). The counts
are sampling decisions made from detached values, so the derivative of the image is
``sum_r w_r dX_r/dtheta`` at fixed counts, an unbiased estimate of ``dI/dtheta``; path replay gets
it by replaying each round with ``dl/dI * w_r / n_r`` as its per-path adjoint.
"""

from __future__ import annotations

import dataclasses

import torch

from invrender.scene.scene import Scene
from invrender.core.adaptive import AdaptiveResult, AdaptiveSettings, adaptive_render
from invrender.core.driver import RenderSettings
from invrender.plugins.integrators import Integrator


def render_adaptive(
    scene: Scene, integrator: Integrator, settings: RenderSettings, adaptive: AdaptiveSettings, device: torch.device, differentiable: list[str], estimator: str,
) -> AdaptiveResult:  # fmt: skip
    """The adaptive render of ``scene``, differentiable in the parameters ``differentiable`` by
    ``estimator`` (``"replay"`` or ``"autodiff"``; nothing to differentiate: a plain render)."""
    if not differentiable or estimator == "autodiff":
        return adaptive_render(integrator, scene, settings, adaptive, device)
    holder: dict = {}
    image = _AdaptiveReplay.apply(scene, integrator, settings, adaptive, device, differentiable, holder, *(scene.params[n] for n in differentiable))
    return dataclasses.replace(holder["result"], image=image)


class _AdaptiveReplay(torch.autograd.Function):
    @staticmethod
    def forward(fctx, scene, integrator, settings, adaptive, device, names, holder, *values):
        result = adaptive_render(integrator, scene, settings, adaptive, device, params=dict(zip(names, values)))
        holder["result"] = result
        fctx.scene, fctx.integrator, fctx.settings, fctx.device, fctx.names, fctx.passes = scene, integrator, settings, device, names, result.passes
        fctx.save_for_backward(*values)
        return result.image

    @staticmethod
    def backward(fctx, grad_image):
        from invrender.estimators.replay import replay_gradient

        values = dict(zip(fctx.names, fctx.saved_tensors))
        h, w = grad_image.shape[:2]
        totals = {n: torch.zeros_like(v) for n, v in values.items()}
        for plan in fctx.passes:
            # round r's pixel p is w_r / n_r,p times the sum of its paths: replay with spp 1 and
            # the adjoint scaled per pixel
            scale = (1.0 / (len(fctx.passes) * plan.count.to(grad_image.device, grad_image.dtype))).reshape(h, w, 1)
            grads = replay_gradient(fctx.scene, fctx.integrator, fctx.settings.replace(spp=1, plan=plan), fctx.device, values, grad_image * scale)
            for n, total in totals.items():
                total += grads[n].to(total.device, total.dtype)
        return (None, None, None, None, None, None, None, *(totals[n] for n in fctx.names))
