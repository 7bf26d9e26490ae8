"""``mitchell`` and ``catmullrom``: the Mitchell-Netravali cubics (Mitchell and Netravali,
"Reconstruction filters in computer graphics", SIGGRAPH 1988), radius 2.

For |x| < 1: ``((12 - 9B - 6C)|x|^3 + (-18 + 12B + 6C)|x|^2 + (6 - 2B)) / 6``; for 1 <= |x| < 2:
``((-B - 6C)|x|^3 + (6B + 30C)|x|^2 + (-12B - 48C)|x| + (8B + 24C)) / 6``; 0 beyond.
``mitchell``: B = C = 1/3 by default (Mitsuba's ``B``, ``C``); ``catmullrom``: B = 0, C = 1/2.
The cubics have negative lobes, so a pixel can come out negative at a sharp edge.
"""

import torch

from invrender import registry
from invrender.core.rfilter import ReconstructionFilter
from invrender.plugins.filters.checks import check_finite


@registry.FILTERS.register
class Mitchell(ReconstructionFilter):
    """Args: B, C: the cubic's two parameters (finite numbers)."""

    type_name = "mitchell"
    setting_names = ("B", "C")

    def __init__(self, B: float = 1.0 / 3.0, C: float = 1.0 / 3.0):
        self.B, self.C = check_finite(self.type_name, "B", B), check_finite(self.type_name, "C", C)
        self.radius = 2.0

    def settings(self) -> dict:
        return {"B": self.B, "C": self.C}

    def eval(self, x: torch.Tensor) -> torch.Tensor:
        B, C = self.B, self.C
        a = x.abs()
        a2, a3 = a * a, a * a * a
        near = (12.0 - 9.0 * B - 6.0 * C) * a3 + (-18.0 + 12.0 * B + 6.0 * C) * a2 + (6.0 - 2.0 * B)
        far = (-B - 6.0 * C) * a3 + (6.0 * B + 30.0 * C) * a2 + (-12.0 * B - 48.0 * C) * a + (8.0 * B + 24.0 * C)
        value = torch.where(a < 1.0, near, far) / 6.0
        return torch.where(a < 2.0, value, torch.zeros_like(value))


@registry.FILTERS.register
class CatmullRom(Mitchell):
    """The Mitchell-Netravali cubic with B = 0, C = 1/2 (no settings)."""

    type_name = "catmullrom"
    setting_names = ()

    def __init__(self):
        super().__init__(0.0, 0.5)

    def settings(self) -> dict:
        return {}
