"""Gradient-variance studies: how noisy and how biased each way of differentiating a Monte Carlo
image is, what it costs, and where in the image its noise comes from (``docs/gradient_variance.md``).

- :func:`gradient_study` runs configurations (:class:`GradientConfig`, or spec strings such as
  ``"path/replay/decorrelated"``) over independent trials and returns a :class:`GradientStudy`;
- :func:`furnace_check` compares measured bias and variance with the furnace's closed forms;
- :func:`fit_study` runs ``ir.fit`` with each configuration (mapped onto fit settings, the
  integrator's own settings included) and records the parameters' error against wall time;
- :func:`fit_recipe` runs a fit recipe into a folder (its dataset, one fit or one per variant, the
  study table): what ``invrender fit RECIPE`` does;
- :mod:`invrender.study.output` and :mod:`invrender.study.plots` write the tables and figures.
"""

from invrender.study.configs import GradientConfig, parse_config, parse_configs
from invrender.study.fits import DEFAULT_FIT_CONFIGS, FitStudy, fit_settings, fit_study
from invrender.study.gradients import DEFAULT_CONFIGS, DEFAULT_LOSS, DEFAULT_SPP, LOSSES, GradientStudy, gradient_study
from invrender.study.loss_gradients import LOSS_GRADIENTS, LossGradient
from invrender.study.recipe_fits import RecipeFits, fit_recipe

__all__ = [
    "gradient_study", "GradientStudy", "GradientConfig", "parse_config", "parse_configs", "LOSS_GRADIENTS", "LossGradient",
    "DEFAULT_CONFIGS", "DEFAULT_LOSS", "DEFAULT_SPP", "LOSSES", "fit_study", "FitStudy", "fit_settings", "DEFAULT_FIT_CONFIGS",
    "fit_recipe", "RecipeFits",
]  # fmt: skip
