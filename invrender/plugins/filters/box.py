"""``box``: the pixel's own samples, each with weight 1 (radius 1/2; Mitsuba's ``box``).

The film keeps plain per-pixel sums for it (the fast path: no weights), so a box-filtered image
is the mean of the samples drawn in each pixel.
"""

import torch

from invrender import registry
from invrender.core.rfilter import ReconstructionFilter


@registry.FILTERS.register
class Box(ReconstructionFilter):
    """``f(x) = 1`` on ``[-1/2, 1/2)``, 0 elsewhere."""

    type_name = "box"
    setting_names = ()

    def __init__(self):
        self.radius = 0.5

    @property
    def is_box(self) -> bool:
        return True

    def eval(self, x: torch.Tensor) -> torch.Tensor:
        return ((x >= -0.5) & (x < 0.5)).to(x.dtype)
