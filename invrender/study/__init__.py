"""Gradient-variance studies: how noisy and how biased each way of differentiating a Monte Carlo
image is, what it costs, and where in the image its noise comes from (``docs/gradient_variance.md``).

- :func:`gradient_study` runs configurations (:class:`GradientConfig`, or spec strings such as
  ``"path/replay/decorrelated"``) over independent trials and returns a :class:`GradientStudy`;
- :func:`furnace_check` compares measured bias and variance with the furnace's closed forms;
- :func:`fit_study` runs ``ir.fit`` with each configuration (mapped onto fit settings) and records
  the parameters' error against wall time;
- :mod:`invrender.study.output` and :mod:`invrender.study.plots` write the tables and figures.
"""

from invrender.study.configs import GradientConfig, parse_config, parse_configs
from invrender.study.fits import DEFAULT_FIT_CONFIGS, FitStudy, fit_settings, fit_study
from invrender.study.gradients import DEFAULT_CONFIGS, DEFAULT_LOSS, DEFAULT_SPP, LOSSES, GradientStudy, gradient_study
from invrender.study.loss_gradients import LOSS_GRADIENTS, LossGradient

__all__ = [
    "gradient_study", "GradientStudy", "GradientConfig", "parse_config", "parse_configs", "LOSS_GRADIENTS", "LossGradient",
    "DEFAULT_CONFIGS", "DEFAULT_LOSS", "DEFAULT_SPP", "LOSSES", "fit_study", "FitStudy", "fit_settings", "DEFAULT_FIT_CONFIGS",
]  # fmt: skip
