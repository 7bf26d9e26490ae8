"""Materials as a scene declares them: a type name, parameter values and constants.

A material is one of the registered material types (:data:`invrender.registry.MATERIALS`; the
built-in ones are in :mod:`invrender.materials`, one module each), named in scene files by
``type =`` (TOML) or by the Mitsuba plugin it stands for (XML). Its differentiable values
(reflectance-like factors) become entries of ``scene.params`` (``"<material>.<kind>"``, kinds in
:mod:`invrender.scene.kinds`); its constants (index of refraction, roughness) are fixed properties
of the scene. Each type declares both in its own module (:class:`Param`, :class:`Constant`); this
module reads them from the registry and never lists the types itself. ``invrender materials``
(and docs/scene_formats.md) print the table of types.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

from invrender import registry
from invrender.errors import SceneError
from invrender.scene.kinds import ParamKind


class Param(NamedTuple):
    """A differentiable parameter of a material type: its kind and default value (an RGB triple or
    one number)."""

    kind: ParamKind
    default: object


@dataclass(frozen=True)
class Constant:
    """A scalar constant of a material type: default and the open/closed interval it must lie in."""

    default: float
    low: float
    high: float
    low_open: bool = True
    high_open: bool = False

    def check(self, where: str, key: str, value) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
            raise SceneError(f"{where}: '{key}' must be a finite number, got {value!r}")
        v = float(value)
        below = v <= self.low if self.low_open else v < self.low
        above = v >= self.high if self.high_open else v > self.high
        if below or above:
            lo = "(" if self.low_open else "["
            hi = ")" if self.high_open else "]"
            high = "inf" if math.isinf(self.high) else f"{self.high:g}"
            raise SceneError(f"{where}: '{key}' must lie in {lo}{self.low:g}, {high}{hi}, got {v:g}")
        return v


#: material type name -> its plugin class (the registry, read by name)
MATERIAL_TYPES = registry.MATERIALS

DEFAULT_TYPE = "diffuse"


@dataclass(frozen=True)
class Material:
    """A material of a scene being built: its type, parameter values and constants.

    Attributes:
        type: a registered material type (:data:`invrender.registry.MATERIALS`).
        values: parameter key -> value (an RGB triple, one number, or an (h, w, 3) texture where
            the kind allows); missing keys take the type's defaults.
        constants: constant key -> value; missing keys take the type's defaults.
    """

    type: str = DEFAULT_TYPE
    values: dict = field(default_factory=dict)
    constants: dict = field(default_factory=dict)

    @staticmethod
    def of(type: str = DEFAULT_TYPE, where: str = "material", **entries) -> "Material":
        """A checked material from keyword entries, e.g. ``Material.of("glossy", roughness=0.2,
        specular_reflectance=[0.9, 0.8, 0.7])``; a :class:`SceneError` naming ``where`` and the key
        for an unknown type or key, or a constant out of range."""
        spec = material_type(type, where)
        unknown = sorted(set(entries) - set(spec.params) - set(spec.constants))
        if unknown:
            allowed = ", ".join(sorted({"type", *spec.params, *spec.constants}))
            raise SceneError(f"{where}: unknown key {unknown[0]!r} for a {type} material (allowed: {allowed})")
        values = {k: entries.get(k, default) for k, (_, default) in spec.params.items()}
        constants = {k: c.check(where, k, entries.get(k, c.default)) for k, c in spec.constants.items()}
        return Material(type, values, constants)

    @property
    def spec(self):
        """The material type's plugin class (its ``params``, ``constants``, ``lobes``, ...)."""
        return MATERIAL_TYPES[self.type]


def material_type(name, where: str = "material"):
    """The plugin class of material type ``name``; a one-line :class:`SceneError` naming ``where``
    and the known types otherwise."""
    return MATERIAL_TYPES.get(name, where)
