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
- ``control_variate``: as ``decorrelated``, but ``dl/dI`` is taken at the recursive control variate
  of Nicolet et al. 2023 (:class:`invrender.inverse.control_variates.RecursiveControlVariate`, what
  ``fit(control_variate=True)`` uses) instead of at a plain render. That estimate lives along a
  fit's sequence of steps, so the pairing builds one: ``cv_steps`` steps of ``cv_step`` (in the
  units fit steps in: logit of a reflectance, log of an emission, every channel) toward the point
  where the gradient is taken, each rendering the new and the previous values with the same numbers,
  then the last step at the point itself (seed ``seed + 1``). Every step's values are fixed before
  its numbers are drawn; the weights alpha come from pixel means of the earlier steps' squared
  differences, which share noise with the earlier estimate, a second-order effect of order
  1/(pixels) (not measurable here: docs/gradient_variance.md). Only the last step is
  timed (its two renders and the differentiated one: what each step of such a fit costs); the
  earlier steps are the ones a fit would have taken anyway. How much it buys depends on the steps:
  small steps near the fit's end are where it pays, and a fit (``--fits``) measures that directly.

A pairing is a registered class (subclassing :class:`LossGradient` with a ``name`` registers it in
:data:`LOSS_GRADIENTS`); a gradient study's configurations name one, so a new way of forming the
gradient is a new subclass, and studies, spec strings and the command line take it up by name.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import torch

from invrender.estimators import backpropagate, render
from invrender.errors import ParameterError
from invrender.inverse import params as P
from invrender.inverse.control_variates import RecursiveControlVariate
from invrender.inverse.losses import loss_and_gradient, loss_gradient
from invrender.scene.scene import Scene

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
    """A way of pairing ``dl/dI`` with the differentiated image. Its methods take the study's
    ``config``, a :class:`~invrender.study.configs.GradientConfig` (which names the pairing, so
    this module does not import it)."""

    #: the name configurations use
    name: ClassVar[str]
    #: one line for help texts
    summary: ClassVar[str] = ""
    #: the pairing's own spec options and their defaults (``KEY=VALUE`` parts that do not go to the render)
    options: ClassVar[dict[str, object]] = {}
    #: the :class:`~invrender.inverse.fit.FitSettings` fields that make a fit pair ``dl/dI`` this
    #: way (None: a fit cannot; fit studies refuse the pairing)
    fit_settings: ClassVar[dict[str, object] | None] = None

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__:
            LOSS_GRADIENTS[cls.name] = cls

    @classmethod
    def check_options(cls, label: str, options: dict) -> None:
        """A one-line :class:`ParameterError` for an option value the pairing cannot use."""

    def prepare(self, objective: Objective, config, spp: int, seed: int) -> object:
        """Untimed work a trial needs before its gradient (what earlier steps of a fit would have
        done); passed to :meth:`backward` and :meth:`adjoint` as ``prepared``. Default: none."""
        return None

    @abstractmethod
    def backward(self, objective: Objective, config, spp: int, seed: int, prepared: object = None) -> None:
        """Add one gradient sample of ``objective``'s loss to the ``.grad`` of every parameter of
        ``objective.scene`` that requires grad; ``seed`` is the differentiated image's seed."""

    @abstractmethod
    def adjoint(self, objective: Objective, config, spp: int, seed: int, image: torch.Tensor, prepared: object = None) -> torch.Tensor:
        """The (H, W, 3) ``dl/dI`` that :meth:`backward` weights the image of ``seed`` with, given
        that image (detached): ``G = sum(adjoint * dI/dtheta)``. Per-pixel studies use it (without
        ``prepared``, the pairing prepares itself)."""


class Correlated(LossGradient):
    name = "correlated"
    summary = "dl/dI from the differentiated render itself (biased at low spp)"
    fit_settings: ClassVar[dict[str, object] | None] = {"decorrelate": False}

    def backward(self, objective, config, spp, seed, prepared=None):
        image = render(objective.scene, spp=spp, seed=seed, progress=False, **config.render_kwargs())
        loss_and_gradient(objective.loss, objective.target, image, image)

    def adjoint(self, objective, config, spp, seed, image, prepared=None):
        return loss_gradient(objective.loss, objective.target, image)[0]


class Decorrelated(LossGradient):
    name = "decorrelated"
    summary = "dl/dI from an independent render (seed + 1), as fit does"
    fit_settings: ClassVar[dict[str, object] | None] = {"decorrelate": True}

    def backward(self, objective, config, spp, seed, prepared=None):
        integrator, settings = config.integrator_and_settings(spp, seed, objective.scene)
        backpropagate(objective.scene, self.adjoint(objective, config, spp, seed, None, prepared), integrator, settings, config.estimator)

    def adjoint(self, objective, config, spp, seed, image, prepared=None):
        with torch.no_grad():
            residual = render(objective.scene, spp=spp, seed=seed + 1, progress=False, **config.render_kwargs())
        return loss_gradient(objective.loss, objective.target, residual)[0]


#: seeds of a control-variate chain's earlier steps: ``seed + 1 + j * CHAIN_SEED_STRIDE`` for the
#: step j steps before the last; odd, so never a differentiated image's seed, and apart from every
#: other trial's seeds for up to 2^22 trials
CHAIN_SEED_STRIDE = 2**23


class ControlVariate(Decorrelated):
    name = "control_variate"
    summary = "dl/dI at a recursive control variate (Nicolet et al. 2023) built along cv_steps steps of cv_step toward the point, as fit(control_variate=True) takes it"
    options: ClassVar[dict[str, object]] = {"cv_steps": 8, "cv_step": 0.01}
    fit_settings: ClassVar[dict[str, object] | None] = {"decorrelate": True, "control_variate": True}

    @classmethod
    def check_options(cls, label, options):
        steps, step = options["cv_steps"], options["cv_step"]
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ParameterError(f"configuration {label!r}: cv_steps must be an integer >= 1, got {steps!r}")
        if isinstance(step, bool) or not isinstance(step, (int, float)) or not step >= 0:
            raise ParameterError(f"configuration {label!r}: cv_step must be a number >= 0, got {step!r}")

    def prepare(self, objective, config, spp, seed):
        """The control variate after the chain's first ``cv_steps`` steps (the last is the gradient's)."""
        scene = objective.scene
        names = [n for n, p in scene.params.items() if p.requires_grad]
        options = {k: v for k, v in config.render_kwargs().items() if k != "estimator"}

        def render_at(values: dict, render_seed: int, n: int) -> torch.Tensor:
            with torch.no_grad():
                work = dataclasses.replace(scene, params={**scene.params, **values})
                return render(work, spp=n, seed=render_seed, progress=False, **options)

        cv = RecursiveControlVariate(render_at)
        steps, step = config.pairing_options["cv_steps"], float(config.pairing_options["cv_step"])
        raw = {n: P.to_raw(n, scene.params[n].detach()) for n in names}
        for j in range(steps, 0, -1):  # j steps before the point
            cv({n: P.from_raw(n, raw[n] - j * step) for n in names}, seed + 1 + j * CHAIN_SEED_STRIDE, spp)
        return cv

    def adjoint(self, objective, config, spp, seed, image, prepared=None):
        cv = prepared if prepared is not None else self.prepare(objective, config, spp, seed)
        scene = objective.scene
        values = {n: p.detach() for n, p in scene.params.items() if p.requires_grad}
        return loss_gradient(objective.loss, objective.target, cv(values, seed + 1, spp))[0]
