"""Material types as a scene declares them: which parameters and constants each type has.

A material is one of the types below, named in scene files by ``type =`` (TOML) or by the Mitsuba
plugin it stands for (XML). Its differentiable values (reflectance-like factors) become entries of
``scene.params`` (``"<material>.<kind>"``, kinds in :mod:`invrender.scene.kinds`); its constants
(index of refraction, roughness) are fixed properties of the scene. How each type scatters light is
its BSDF in :mod:`invrender.transport.bsdfs`.

=============  =========================================  ==========================================
type           differentiable parameters                  constants
=============  =========================================  ==========================================
``diffuse``    ``reflectance`` rho (RGB or texture),      --
               default 0.5
``mirror``     ``specular_reflectance`` (RGB), default 1  --
``dielectric`` --                                         ``ior`` > 0, interior over exterior
                                                          (exterior 1.0), default 1.5
``glossy``     ``specular_reflectance`` (RGB), default 1  ``roughness`` GGX alpha in (0, 1],
                                                          default 0.1
=============  =========================================  ==========================================

They correspond to Mitsuba 3's ``diffuse``, ``conductor`` and ``roughconductor`` with
``material = "none"`` (Fresnel 1), and smooth ``dielectric``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from invrender.errors import SceneError
from invrender.scene.kinds import REFLECTANCE, SPECULAR_REFLECTANCE, ParamKind


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


@dataclass(frozen=True)
class MaterialType:
    """One material type.

    Attributes:
        name: the ``type`` name.
        params: differentiable parameters: key -> (kind, default value).
        constants: scalar constants: key -> :class:`Constant`.
        delta: scatters only into discrete directions (no emitter sampling at its vertices).
        doc: one line.
    """

    name: str
    params: dict[str, tuple[ParamKind, float]]
    constants: dict[str, Constant]
    delta: bool
    doc: str

    @property
    def keys(self) -> set[str]:
        """Keys a material table of this type may hold (besides ``type``)."""
        texture_keys = {f"{k}_texture" for k, (kind, _) in self.params.items() if kind.texture}
        return set(self.params) | texture_keys | set(self.constants)


MATERIAL_TYPES: dict[str, MaterialType] = {
    t.name: t
    for t in (
        MaterialType("diffuse", {"reflectance": (REFLECTANCE, 0.5)}, {}, False, "Lambertian, two-sided: f = rho / pi"),
        MaterialType("mirror", {"specular_reflectance": (SPECULAR_REFLECTANCE, 1.0)}, {}, True, "perfect specular reflector, two-sided"),
        MaterialType("dielectric", {}, {"ior": Constant(1.5, 0.0, math.inf, True, True)}, True, "smooth glass: Fresnel reflection and refraction"),
        MaterialType(
            "glossy",
            {"specular_reflectance": (SPECULAR_REFLECTANCE, 1.0)},
            {"roughness": Constant(0.1, 0.0, 1.0, True, False)},
            False,
            "GGX rough conductor, Fresnel 1, two-sided",
        ),
    )
}

DEFAULT_TYPE = "diffuse"


@dataclass(frozen=True)
class Material:
    """A material of a scene being built: its type, parameter values and constants.

    Attributes:
        type: a key of :data:`MATERIAL_TYPES`.
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
    def spec(self) -> MaterialType:
        return MATERIAL_TYPES[self.type]


def material_type(name, where: str = "material") -> MaterialType:
    """The :class:`MaterialType` called ``name``; a one-line :class:`SceneError` naming ``where`` otherwise."""
    if not isinstance(name, str) or name not in MATERIAL_TYPES:
        raise SceneError(f"{where}: unknown material type {name!r} (known: {', '.join(MATERIAL_TYPES)})")
    return MATERIAL_TYPES[name]
