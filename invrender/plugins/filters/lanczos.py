"""``lanczos``: the windowed sinc ``f(x) = sinc(x) sinc(x / n)`` for |x| <= n lobes (radius n, 3 by
default; Mitsuba's ``lanczos`` with ``lobes``), ``sinc(t) = sin(pi t) / (pi t)``, 1 at 0."""

import math

import torch

from invrender import registry
from invrender.core.rfilter import ReconstructionFilter
from invrender.errors import ParameterError
from invrender.plugins.filters.checks import MAX_RADIUS


@registry.FILTERS.register
class Lanczos(ReconstructionFilter):
    """Args: lobes: the number of lobes n, an integer in [1, 16] (the radius)."""

    type_name = "lanczos"
    setting_names = ("lobes",)

    def __init__(self, lobes: int = 3):
        if isinstance(lobes, bool) or not isinstance(lobes, int) or not 1 <= lobes <= MAX_RADIUS:
            raise ParameterError(f"filter 'lanczos': lobes must be an integer in [1, {MAX_RADIUS:g}], got {lobes!r}")
        self.lobes = lobes
        self.radius = float(lobes)

    def settings(self) -> dict:
        return {"lobes": self.lobes}

    def eval(self, x: torch.Tensor) -> torch.Tensor:
        a = x.abs()
        x1 = math.pi * a.clamp_min(1e-7)  # pi |x| (clamped: 0/0 at the centre, where f = 1)
        x2 = x1 / self.radius
        value = torch.sin(x1) * torch.sin(x2) / (x1 * x2)
        value = torch.where(a < 1e-7, torch.ones_like(value), value)
        return torch.where(a > self.radius, torch.zeros_like(value), value)
