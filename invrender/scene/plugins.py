"""What a plugin declares about itself, and a plugin instance as a scene declares it.

Materials (:mod:`invrender.plugins.bsdfs`) and emitters (:mod:`invrender.plugins.emitters`) are plugins: each
type is a class that declares, in its own module, its type name, its differentiable parameters
(:class:`Param`: a kind of :mod:`invrender.scene.kinds` and a default) and its scalar constants
(:class:`Constant`: a default and a range), through :class:`Declared`. A scene holds one
:class:`PluginSpec` per material or emitter (its type, values and constants), checked against that
declaration when it is made (:meth:`PluginSpec.of`). This module reads the declarations from
:mod:`invrender.registry` and never lists a type itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple

from invrender.errors import SceneError, did_you_mean
from invrender.registry import Registry
from invrender.scene.kinds import ParamKind
from invrender.validate import FLOAT32_MAX


class Param(NamedTuple):
    """A differentiable parameter of a plugin type: its kind and default value (an RGB triple or
    one number). A plugin whose parameter cannot be a texture although its kind can declares it
    with the kind's RGB-only form (:data:`~invrender.scene.kinds.EMISSION_RGB` for emission)."""

    kind: ParamKind
    default: object


@dataclass(frozen=True)
class Constant:
    """A constant of a plugin type: default and the open/closed interval it must lie in.

    With ``size`` > 1 it is a vector of that many numbers (a light's ``position``, ``direction``),
    given as a list and kept as a tuple of floats, each in the interval; ``default`` is then a tuple.
    With ``names`` (name -> number) it may also be given as one of those names (a plastic's
    ``int_ior = "bk7"``); with ``boolean`` it is ``true``/``false`` only, kept as 1.0/0.0.
    """

    default: float | tuple
    low: float
    high: float
    low_open: bool = True
    high_open: bool = False
    size: int = 1
    names: dict | None = field(default=None, compare=False, hash=False)
    boolean: bool = False

    def check(self, where: str, key: str, value) -> float | tuple:
        if self.boolean:
            if not isinstance(value, bool) and value not in (0.0, 1.0):
                raise SceneError(f"{where}: '{key}' must be true or false, got {value!r}")
            return float(value)
        if self.names is not None and isinstance(value, str):
            if value.strip().lower() not in self.names:
                raise SceneError(f"{where}: unknown {key} {value!r} (a number or one of {', '.join(self.names)})")
            value = self.names[value.strip().lower()]
        if self.size > 1:
            if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != self.size:
                raise SceneError(f"{where}: '{key}' must be a list of {self.size} numbers, got {value!r}")
            items = [v.item() if hasattr(v, "item") else v for v in value]
            return tuple(Constant(0.0, self.low, self.high, self.low_open, self.high_open).check(where, key, v) for v in items)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
            raise SceneError(f"{where}: '{key}' must be a finite number, got {value!r}")
        v = float(value)
        if abs(v) > FLOAT32_MAX:
            raise SceneError(f"{where}: '{key}' is {v:g}, beyond float32's range (|x| <= {FLOAT32_MAX:.4g}): a render would compute with infinity")
        below = v <= self.low if self.low_open else v < self.low
        above = v >= self.high if self.high_open else v > self.high
        if below or above:
            lo = "(" if self.low_open else "["
            hi = ")" if self.high_open else "]"
            high = "inf" if math.isinf(self.high) else f"{self.high:g}"
            raise SceneError(f"{where}: '{key}' must lie in {lo}{self.low:g}, {high}{hi}, got {v:g}")
        return v


class Declared:
    """Mixin of plugin classes: the declarations every plugin type makes (class attributes)."""

    #: the ``type`` scene files name it by
    type_name: ClassVar[str]
    #: differentiable parameters: key -> :class:`Param` (kind, default)
    params: ClassVar[dict[str, Param]] = {}
    #: constants of the scene (numbers, or vectors of numbers): key -> :class:`Constant`
    constants: ClassVar[dict[str, Constant]] = {}
    #: one line for messages and the docs' tables
    doc: ClassVar[str] = ""
    #: keys a scene-file table of this type may hold besides ``type`` (parameters, their
    #: ``_texture`` forms where the kind allows one, constants); set for each subclass
    keys: ClassVar[frozenset[str]] = frozenset()

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        """The constants once each is checked on its own: a type whose defaults depend on other
        constants (a spot's ``beam_width``), whose constants constrain each other or whose values
        need a check of their own (an envmap that is zero everywhere) overrides this (``values``:
        the parameter values given or defaulted; ``given``: the constant keys the scene gave;
        raise :class:`SceneError` naming ``where``)."""
        return constants

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        texture_keys = {f"{k}_texture" for k, p in cls.params.items() if p.kind.texture}
        cls.keys = frozenset(cls.params) | texture_keys | frozenset(cls.constants)


@dataclass(frozen=True)
class PluginSpec:
    """One plugin instance of a scene being built: its type, parameter values and constants.

    Attributes:
        type: a registered type name.
        values: parameter key -> value (an RGB triple, one number, or an (h, w, 3) texture where
            the kind allows); missing keys take the type's defaults.
        constants: constant key -> value; missing keys take the type's defaults.
    """

    #: the registry its types are found in, and what one is called in messages (subclasses set them)
    registry: ClassVar[Registry]
    noun: ClassVar[str]
    default_type: ClassVar[str]

    type: str = ""
    values: dict = field(default_factory=dict)
    constants: dict = field(default_factory=dict)

    def __post_init__(self):
        if not self.type:
            object.__setattr__(self, "type", self.default_type)

    @classmethod
    def of(cls, type: str | None = None, where: str | None = None, **entries):
        """A checked instance from keyword entries, e.g. ``Material.of("glossy", roughness=0.2,
        specular_reflectance=[0.9, 0.8, 0.7])``; a :class:`SceneError` naming ``where`` and the key
        for an unknown type or key, or a constant out of range."""
        type = cls.default_type if type is None else type
        where = cls.noun if where is None else where
        spec = cls.registry.get(type, where)
        unknown = sorted(set(entries) - set(spec.params) - set(spec.constants))
        if unknown:
            allowed = ", ".join(sorted({"type", *spec.params, *spec.constants}))
            raise SceneError(f"{where}: unknown key {unknown[0]!r}{did_you_mean(unknown[0], {*spec.params, *spec.constants})} for a {type} {cls.noun} (allowed: {allowed})")
        values = {k: entries.get(k, p.default) for k, p in spec.params.items()}
        constants = {k: c.check(where, k, entries.get(k, c.default)) for k, c in spec.constants.items()}
        constants = spec.resolve(where, values, constants, {k for k in spec.constants if k in entries})
        return cls(spec.type_name, values, constants)  # a name with arguments as the registry spells it: "blendbsdf(diffuse,mirror)"

    @property
    def spec(self):
        """The type's plugin class (its ``params``, ``constants``, ...)."""
        return self.registry[self.type]


def _number(x) -> str:
    return ("inf" if x > 0 else "-inf") if isinstance(x, float) and math.isinf(x) else f"{x:g}" if isinstance(x, (int, float)) else str(x)


def _default(value) -> str:
    if isinstance(value, (list, tuple)):
        return "(" + ", ".join(_number(v) for v in value) + ")"
    return _number(value)


def _interval(c: Constant) -> str:
    if c.boolean:
        return "{false, true}"
    interval = f"{'(' if c.low_open else '['}{_number(c.low)}, {_number(c.high)}{')' if c.high_open else ']'}"
    return f"{interval} or a named medium" if c.names else interval


def plugin_table(plugins: Registry, extra: tuple[str, object] | None = None) -> str:
    """A Markdown table of the registered types of ``plugins`` (materials or emitters): type,
    what it is, its parameters (kind, symbol, default; textures where the kind allows them), its
    constants (default and range), the Mitsuba plugins it reads (its own ``mitsuba_plugins``) and,
    with ``extra = (heading, fn)``, a column ``fn(cls)``. The docs' tables are this function's
    output (``invrender plugins``), so they cannot drift from the plugins."""
    head = "| type | what it is | parameters | constants | Mitsuba XML |" + (f" {extra[0]} |" if extra else "")
    rows = [head, "|---" * (head.count("|") - 1) + "|"]
    for name, cls in plugins.items():
        params = "<br>".join(
            f"`{k}` {p.kind.symbol}" + (f" in (0, {_number(p.kind.upper)}]" if p.kind.positive else "") + f", default {_default(p.default)}"
            + (" (one number" if p.kind.grey else " (RGB") + (" or texture)" if p.kind.texture else ")") for k, p in cls.params.items()
        )
        constants = "<br>".join(f"`{k}`{f' ({c.size} numbers)' if c.size > 1 else ''} in {_interval(c)}, default {str(bool(c.default)).lower() if c.boolean else _default(c.default)}" for k, c in cls.constants.items())
        mitsuba = ", ".join(f"`{m}`" for m in vars(cls).get("mitsuba_plugins", ()))
        row = f"| `{name}` | {cls.doc} | {params or '--'} | {constants or '--'} | {mitsuba or '--'} |"
        rows.append(row + (f" {extra[1](cls)} |" if extra else ""))
    return "\n".join(rows) + "\n"
