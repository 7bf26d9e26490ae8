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

from collections.abc import Mapping

from invrender import registry
from invrender.core.rfilter import ReconstructionFilter
from invrender.errors import ParameterError
from invrender.plugins.filters import box, tent, gaussian, mitchell, lanczos  # noqa: F401  (registration order)
from invrender.plugins.filters.box import Box
from invrender.plugins.filters.gaussian import Gaussian
from invrender.plugins.filters.lanczos import Lanczos
from invrender.plugins.filters.mitchell import CatmullRom, Mitchell
from invrender.plugins.filters.tent import Tent


def make_filter(spec, where: str = "filter") -> ReconstructionFilter:
    """A :class:`ReconstructionFilter` from a spec (module docstring; None = the box); a one-line
    :class:`ParameterError` naming ``where`` for an unknown name or a bad setting."""
    if spec is None:
        return Box()
    if isinstance(spec, ReconstructionFilter):
        return spec
    if isinstance(spec, str):
        return registry.FILTERS.get(spec, where)()
    if isinstance(spec, Mapping):
        settings = dict(spec)
        if "type" not in settings:
            raise ParameterError(f"{where}: a mapping spec needs a 'type' key naming the filter (known: {', '.join(registry.FILTERS)}), got keys {sorted(settings)}")
        cls = registry.FILTERS.get(settings.pop("type"), where)
        try:
            return cls(**settings)
        except TypeError:
            known = ", ".join(cls.setting_names) or "none"
            raise ParameterError(f"{where}: filter {cls.type_name!r} has no setting {sorted(settings)[0]!r} (its settings: {known})") from None
    raise ParameterError(f"{where}: expected a filter name, a {{'type': name, ...}} mapping or a filter object, got {spec!r}")


__all__ = ["Box", "CatmullRom", "Gaussian", "Lanczos", "Mitchell", "Tent", "make_filter"]
