"""``tent``: the linear (triangle) filter, ``f(x) = max(0, 1 - |x| / r)``, radius 1 by default
(Mitsuba's ``tent``)."""

import torch

from invrender import registry
from invrender.core.rfilter import ReconstructionFilter
from invrender.plugins.filters.checks import MAX_RADIUS, check_positive


@registry.FILTERS.register
class Tent(ReconstructionFilter):
    """Args: radius: support radius r, pixels, in (0, 16]."""

    type_name = "tent"
    setting_names = ("radius",)

    def __init__(self, radius: float = 1.0):
        self.radius = check_positive(self.type_name, "radius", radius, MAX_RADIUS)

    def eval(self, x: torch.Tensor) -> torch.Tensor:
        return (1.0 - x.abs() / self.radius).clamp_min(0.0)
