"""How a loss gradient pairs the adjoint ``dl/dI`` with the differentiated image.

The gradient of a loss ``l(I)`` of a Monte Carlo image ``I`` is ``G = <dl/dI, dI/dtheta>``, summed
over pixels and channels. Both factors are estimated; a *pairing* says where each comes from:

- ``correlated``: both from one render (what ``loss(render(...)).backward()`` does). For
  ``l = 1/2 (I - T)^2`` per pixel, ``E[G] = (E[I] - T) E[dI/dtheta] + Cov(I, dI/dtheta)``: the
  covariance term is a bias of order ``1/N`` at N samples per pixel
  (docs/closed_forms.md#correlated-gradient-bias).
- ``decorrelated``: ``dl/dI`` from a render with an independent seed (``seed + 1``), the image
  differentiated at ``seed`` (what ``fit`` does): the two factors are independent, so for a loss
  whose ``dl/dI`` is affine in ``I`` (``l2``, ``relative_l2``) ``E[G]`` is the gradient at the
  expected image.

A pairing is a registered class (subclassing :class:`LossGradient` with a ``name`` registers it in
:data:`LOSS_GRADIENTS`); a gradient study's configurations name one, so a new way of forming the
gradient (a control variate, say) is a new subclass, and studies, spec strings and the command line
take it up by name.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import torch

from invrender.diff import backpropagate, render
from invrender.inverse.losses import loss_and_gradient, loss_gradient
from invrender.scene.scene import Scene

if TYPE_CHECKING:
    from invrender.study.configs import GradientConfig

#: pairing name -> class, filled by subclassing :class:`LossGradient`
LOSS_GRADIENTS: dict[str, type[LossGradient]] = {}


@dataclass(frozen=True)
class Objective:
    """What every trial of a study differentiates.

    Attributes:
        scene: the scene at the point where the gradient is taken; the studied parameters require
            grad and their ``.grad`` collects each trial's gradient.
        target: (H, W, 3) linear radiance.
        loss: ``"l2"``, ``"relative_l2"`` or ``"l1"`` (:func:`invrender.inverse.losses.image_loss`).
    """

    scene: Scene
    target: torch.Tensor
    loss: str


class LossGradient(ABC):
    """A way of pairing ``dl/dI`` with the differentiated image."""

    #: the name configurations use
    name: ClassVar[str]
    #: one line for help texts
    summary: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__:
            LOSS_GRADIENTS[cls.name] = cls

    @abstractmethod
    def backward(self, objective: Objective, config: GradientConfig, spp: int, seed: int) -> None:
        """Add one gradient sample of ``objective``'s loss to the ``.grad`` of every parameter of
        ``objective.scene`` that requires grad; ``seed`` is the differentiated image's seed."""

    @abstractmethod
    def adjoint(self, objective: Objective, config: GradientConfig, spp: int, seed: int, image: torch.Tensor) -> torch.Tensor:
        """The (H, W, 3) ``dl/dI`` that :meth:`backward` weights the image of ``seed`` with, given
        that image (detached): ``G = sum(adjoint * dI/dtheta)``. Per-pixel studies use it."""


class Correlated(LossGradient):
    name = "correlated"
    summary = "dl/dI from the differentiated render itself (biased at low spp)"

    def backward(self, objective, config, spp, seed):
        image = render(objective.scene, spp=spp, seed=seed, progress=False, **config.render_kwargs())
        loss_and_gradient(objective.loss, objective.target, image, image)

    def adjoint(self, objective, config, spp, seed, image):
        return loss_gradient(objective.loss, objective.target, image)[0]


class Decorrelated(LossGradient):
    name = "decorrelated"
    summary = "dl/dI from an independent render (seed + 1), as fit does"

    def backward(self, objective, config, spp, seed):
        integrator, settings = config.integrator_and_settings(spp, seed)
        backpropagate(objective.scene, self.adjoint(objective, config, spp, seed, None), integrator, settings, config.estimator)

    def adjoint(self, objective, config, spp, seed, image):
        with torch.no_grad():
            residual = render(objective.scene, spp=spp, seed=seed + 1, progress=False, **config.render_kwargs())
        return loss_gradient(objective.loss, objective.target, residual)[0]
