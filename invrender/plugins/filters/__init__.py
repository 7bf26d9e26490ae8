"""The built-in reconstruction filters (Mitsuba 3's six), one module per family; importing this
package registers them in :data:`invrender.registry.FILTERS`.

Each module describes its filter completely: its type name, its settings with their defaults and
ranges, its radius and its 1-D weight ``eval(x)``. The splat that uses them (every pixel whose
centre lies within the radius, weights normalized per pixel) is the film's
(:mod:`invrender.core.rfilter`). docs/rendering.md#reconstruction-filters lists them.

A filter is given as a spec, accepted wherever a render is configured (``ir.render(filter=...)``,
a TOML scene's ``[film]``, a Mitsuba file's ``<rfilter>``)::

    "gaussian"                              # a name: its default settings
    {"type": "gaussian", "stddev": 0.3}     # a name and settings
    Gaussian(stddev=0.3)                    # an instance
"""

from invrender.registry import make_filter
from invrender.plugins.filters import box, tent, gaussian, mitchell, lanczos  # noqa: F401  (registration order)
from invrender.plugins.filters.box import Box
from invrender.plugins.filters.gaussian import Gaussian
from invrender.plugins.filters.lanczos import Lanczos
from invrender.plugins.filters.mitchell import CatmullRom, Mitchell
from invrender.plugins.filters.tent import Tent

__all__ = ["Box", "CatmullRom", "Gaussian", "Lanczos", "Mitchell", "Tent", "make_filter"]
