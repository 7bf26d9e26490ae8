"""Image losses and their gradients through the Monte Carlo estimate.

Losses compare a rendered image (H, W, 3) with a target: ``l2`` (mean squared error), ``l1`` (mean
absolute error), ``relative_l2`` (squared error over the squared target plus 0.01: every pixel's
error counts relative to its brightness, so dark pixels and dark colour channels weigh as much as
bright ones on HDR images; the weights are fixed, so the objective stays an unbiased weighted L2) and ``ssim`` (1 - SSIM, kornia's 11x11 gaussian window).

**Decorrelation.** The gradient of ``l(I)`` is ``<dl/dI (I), dI/dtheta>``. If the same Monte Carlo
image supplies both factors, their noise is correlated and the product is biased: for
``l = 1/2 (I - T)^2`` the bias of the gradient is ``Cov(I, dI/dtheta) / N`` per pixel (in the furnace,
``dl/deps`` is biased by ``eps rho / ((1 - rho)^2 N)`` at N samples per pixel for the analog random walk; docs/closed_forms.md#correlated-gradient-bias).
Taking ``dl/dI`` from one image (:func:`loss_gradient`) and differentiating an independent one
(another seed; :func:`loss_and_gradient` with two images, or
:func:`invrender.estimators.backpropagate`, which ``fit`` uses) makes the gradient unbiased.
"""

from __future__ import annotations

import torch

from invrender.errors import ParameterError, did_you_mean

LOSSES = ("l2", "l1", "relative_l2", "ssim")


def image_loss(name: str, image: torch.Tensor, target) -> torch.Tensor:
    """Scalar loss between ``image`` and ``target``, both (H, W, 3) linear; ``target`` may be a
    :class:`~invrender.inverse.targets.Target` (a photograph, a mask), whose per-pixel weights
    turn each residual into the file's encoded units and zero the pixels that do not count (the
    mean stays over every pixel): ``l2`` and ``l1`` of the weighted residual, ``relative_l2`` of it
    over ``sqrt(T^2 + 0.01)`` for a linear target (over 1 for an encoded one: ``Target.norm``),
    ``ssim`` of the masked linear images."""
    if not isinstance(target, torch.Tensor):
        if target.plain:
            target = target.linear
        else:
            return _weighted_loss(name, image, target)
    if name == "l2":
        return torch.nn.functional.mse_loss(image, target)
    if name == "l1":
        return torch.nn.functional.l1_loss(image, target)
    if name == "relative_l2":
        return ((image - target) ** 2 / (target**2 + 0.01)).mean()
    if name == "ssim":
        import kornia

        a, b = image.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None]
        scale = max(float(target.detach().max()), 1e-6)  # SSIM's constants assume a [0, 1] range
        return kornia.losses.ssim_loss(a / scale, b / scale, window_size=min(11, _odd(min(image.shape[:2]))), reduction="mean")
    raise ParameterError(f"unknown loss {name!r}{did_you_mean(name, LOSSES)} (known: {', '.join(LOSSES)})")


def _weighted_loss(name: str, image: torch.Tensor, target) -> torch.Tensor:
    """:func:`image_loss` against a Target that is not plain."""
    d = (image - target.linear) * target.weight
    if name == "l2":
        return (d**2).mean()
    if name == "l1":
        return d.abs().mean()
    if name == "relative_l2":
        return (d / target.norm()).pow(2).mean()
    if name == "ssim":
        m = target.mask[..., None]
        return image_loss("ssim", image * m, target.linear * m)
    raise ParameterError(f"unknown loss {name!r}{did_you_mean(name, LOSSES)} (known: {', '.join(LOSSES)})")


def _odd(n: int) -> int:
    return n if n % 2 else n - 1


def loss_and_gradient(loss: str, target: torch.Tensor, residual_image: torch.Tensor, differentiable_image: torch.Tensor) -> torch.Tensor:
    """Back-propagate ``l`` through ``differentiable_image`` with ``dl/dI`` taken at ``residual_image``.

    Pass the same tensor twice for the plain (correlated) gradient, or an independent render (no
    grad needed) as ``residual_image`` for the decorrelated one. Calls ``backward`` and returns the
    loss value at ``residual_image`` (detached).
    """
    dl_dI, value = loss_gradient(loss, target, residual_image)
    (dl_dI * differentiable_image).sum().backward()
    return value


def loss_gradient(loss: str, target: torch.Tensor, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(dl/dI, l)`` at ``image``: the (H, W, 3) adjoint image and the scalar loss, detached."""
    probe = image.detach().requires_grad_(True)
    with torch.enable_grad():
        value = image_loss(loss, probe, target)
        (dl_dI,) = torch.autograd.grad(value, probe)
    return dl_dI, value.detach()
