"""``gaussian``: a truncated Gaussian, Mitsuba 3's default filter (stddev 1/2, radius 4 stddev).

Its weight: ``f(x) = max(0, exp(-x^2 / (2 s^2)) - exp(-r^2 / (2 s^2)))`` with r = 4 s: the value at the radius
is subtracted so that the filter falls to 0 there continuously. (Mitsuba's CPU variants evaluate
the exponential with a polynomial fit; the two agree to about 1e-7 of the peak.)
"""

import math

import torch

from invrender import registry
from invrender.core.rfilter import ReconstructionFilter
from invrender.plugins.filters.checks import MAX_RADIUS, check_positive


@registry.FILTERS.register
class Gaussian(ReconstructionFilter):
    """Args: stddev: standard deviation s, pixels, in (0, 4] (radius 4 s, at most 16)."""

    type_name = "gaussian"
    setting_names = ("stddev",)

    def __init__(self, stddev: float = 0.5):
        self.stddev = check_positive(self.type_name, "stddev", stddev, MAX_RADIUS / 4.0)
        self.radius = 4.0 * self.stddev

    def settings(self) -> dict:
        return {"stddev": self.stddev}

    def eval(self, x: torch.Tensor) -> torch.Tensor:
        alpha = -1.0 / (2.0 * self.stddev**2)
        return (torch.exp(alpha * x * x) - math.exp(alpha * self.radius**2)).clamp_min(0.0)
