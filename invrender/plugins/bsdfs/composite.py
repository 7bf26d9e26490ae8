"""Materials made of nested materials (``blendbsdf``, ``mask``): what they share.

A composite type is written once in lane form, as every material is: its lane functions call the
nested types' own lane functions (bound when the form is built) on the keys of each nested
material, which the composite holds under a prefix per slot (Mitsuba's names: ``bsdf_0.``,
``bsdf_1.`` for a blend, ``bsdf.`` for a mask). So a blend of a diffuse and a mirror has the
parameters ``weight``, ``bsdf_0.reflectance`` and ``bsdf_1.specular_reflectance`` (scene
parameters ``NAME.bsdf_0.reflectance``, ...: the kind is the last part of the name, as always).

Each combination of nested types is its own material type, named with its arguments,
``"blendbsdf(diffuse,mirror)"``, ``"mask(blendbsdf(diffuse,mirror))"``: the registry builds it from
the registered base (:meth:`Composite.variant`, cached), so the compiled bounce's dispatch by type
sees one type per combination, each with one lane form, and a scene file may name one (TOML's
``type``). The registered name alone (``blendbsdf``, ``mask``) is the base's default nesting
(:attr:`Composite.default_nested`).
"""

from __future__ import annotations

import functools
from typing import ClassVar

from invrender.errors import SceneError
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe


def split_arguments(name: str, where: str) -> tuple[str, list[str]]:
    """``"base(a, b(c, d))"`` -> ``("base", ["a", "b(c,d)"])``: the top-level arguments, spaces
    dropped; a one-line :class:`SceneError` naming ``where`` for unbalanced parentheses."""
    text = "".join(name.split())
    base, _, rest = text.partition("(")
    if not rest.endswith(")"):
        raise SceneError(f"{where + ': ' if where else ''}material type {name!r} must read 'base(type, ...)'")
    args, depth, current = [], 0, ""
    for ch in rest[:-1]:
        depth += (ch == "(") - (ch == ")")
        if depth < 0:
            break
        if ch == "," and depth == 0:
            args.append(current)
            current = ""
        else:
            current += ch
    if depth != 0 or not current:
        raise SceneError(f"{where + ': ' if where else ''}material type {name!r} has unbalanced parentheses or an empty argument")
    return base, args + [current]


def nested_values(p: dict, prefix: str) -> dict:
    """The entries of ``p`` under ``prefix``, the prefix taken off."""
    n = len(prefix)
    return {k[n:]: v for k, v in p.items() if k.startswith(prefix)}


def nested_pair(p: dict, ps: dict, prefix: str) -> tuple[dict, dict]:
    """``(p, ps)`` of the nested material under ``prefix`` (one dict for both where ``p is ps``,
    so its form may skip its second evaluation as it would on its own)."""
    q = nested_values(p, prefix)
    return (q, q) if p is ps else (q, nested_values(ps, prefix))


class Composite(LaneBSDF):
    """A material type made of nested material types (the module docstring). Subclasses declare
    :attr:`slots`, :attr:`own_params`, :attr:`own_constants`, :attr:`default_nested`, their own
    lobes (:meth:`own_lobes`) and lane functions; :meth:`variant` builds the type of given nested
    types. An instance holds one nested BSDF per slot (:attr:`nested`), over the same materials."""

    #: each nested material's key prefix (Mitsuba's traversal names)
    slots: ClassVar[tuple[str, ...]]
    #: the composite's own parameters and constants, besides the nested ones
    own_params: ClassVar[dict] = {}
    own_constants: ClassVar[dict] = {}
    #: the nested types of the registered name alone
    default_nested: ClassVar[tuple[str, ...]]
    #: the nested types' classes of this type
    nested_types: ClassVar[tuple[type, ...]] = ()
    _variants: ClassVar[dict]

    @classmethod
    def own_lobes(cls, nested: tuple[type, ...]) -> Lobe:
        """The lobes of the composite of ``nested`` types (default: theirs together)."""
        lobes = Lobe(0)
        for t in nested:
            lobes |= t.lobes
        return lobes

    @classmethod
    def declare(cls, nested: tuple[type, ...]) -> None:
        """Set this class's nested types, parameters, constants, lobes and scene-file keys."""
        for t in nested:
            if not issubclass(t, LaneBSDF):
                raise SceneError(f"a {cls.base_name()} can nest materials written in lane form only, not {t.type_name!r}")
        cls.nested_types = tuple(nested)
        cls.params = {**cls.own_params, **{pre + k: v for pre, t in zip(cls.slots, nested) for k, v in t.params.items()}}
        cls.constants = {**cls.own_constants, **{pre + k: v for pre, t in zip(cls.slots, nested) for k, v in t.constants.items()}}
        cls.lobes = cls.own_lobes(nested)
        texture_keys = {f"{k}_texture" for k, p in cls.params.items() if p.kind.texture}
        cls.keys = frozenset(cls.params) | texture_keys | frozenset(cls.constants)

    @classmethod
    def base_name(cls) -> str:
        return cls.type_name.partition("(")[0]

    @classmethod
    def variant(cls, name: str, where: str = "") -> type:
        """The type of ``name`` (``"base(type, ...)"``, one nested type per slot, each any material
        type, composites too), built once."""
        from invrender.registry import MATERIALS

        base, args = split_arguments(name, where)
        if len(args) != len(cls.slots):
            raise SceneError(f"{where + ': ' if where else ''}a {base} nests {len(cls.slots)} material type(s), got {len(args)} in {name!r}")
        nested = tuple(MATERIALS.get(a, where) for a in args)
        canonical = f"{base}({','.join(t.type_name for t in nested)})"
        if canonical not in cls._variants:
            variant = type(f"{cls.__name__}_{len(cls._variants)}", (cls,), {"type_name": canonical, "__module__": cls.__module__})
            variant.declare(nested)
            cls._variants[canonical] = variant
        return cls._variants[canonical]

    def __init__(self, values, constants, flat=False, sampling=None, sampling_values=None, texture_sampling=None):
        super().__init__(values, constants, flat, sampling, sampling_values, texture_sampling)
        #: per slot, the nested materials (the same materials, the keys under its prefix)
        self.nested = [
            t([nested_values(v, pre) for v in self.values], [nested_values(c, pre) for c in self.constants], flat, sampling,
              [nested_values(v, pre) for v in self.sampling_values], [nested_values(s, pre) for s in self.texture_sampling])
            for pre, t in zip(self.slots, self.nested_types)
        ]  # fmt: skip

    def nested_forms(self) -> tuple[LaneForm, ...]:
        return tuple(n.lane_form() for n in self.nested)

    def nested_keys(self, forms) -> tuple:
        """The nested forms' keys under their prefixes."""
        return tuple((pre + k, size) for pre, f in zip(self.slots, forms) for k, size in f.keys)

    def bound(self, forms) -> dict:
        """What the lane functions are bound with: the nested forms' functions (compared by what
        they compute: :func:`invrender.core.lanes.signature`) and prefixes."""
        return {"evals": tuple(f.eval for f in forms), "samples": tuple(f.sample for f in forms), "worlds": tuple(f.world for f in forms), "prefixes": self.slots}

    def lane_rows(self, key: str, sampling: bool, device):
        """A nested material's derived key (its tables), asked of it without the prefix."""
        for pre, n in zip(self.slots, self.nested):
            if key.startswith(pre):
                return n.lane_rows(key[len(pre):], sampling, device)
        return None

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        """Each nested type resolves its own constants (a plastic's sampling weight from its values)."""
        out = dict(constants)
        for pre, t in zip(cls.slots, cls.nested_types):
            n = len(pre)
            mine = t.resolve(f"{where} ({pre[:-1]})", nested_values(values, pre), nested_values(constants, pre), {g[n:] for g in given if g.startswith(pre)})
            out.update({pre + k: v for k, v in mine.items()})
        return out

    @classmethod
    def nested_mitsuba(cls, values: dict, constants: dict) -> list[dict]:
        """The nested materials as Mitsuba dictionaries (their types' ``to_mitsuba``)."""
        return [t.to_mitsuba(nested_values(values, pre), nested_values(constants, pre)) for pre, t in zip(cls.slots, cls.nested_types)]

    @staticmethod
    def nested_entries(materials) -> dict:
        """Loader entries of nested :class:`~invrender.scene.materials.Material` objects under the
        prefixes of the composite that holds them (``zip`` of prefixes and materials)."""
        return {pre + k: v for pre, m in materials for k, v in {**m.values, **m.constants}.items()}


def with_frame(fn, world: bool, frame):
    """``fn`` with the shading frame bound where its form needs it (:attr:`LaneForm.world`)."""
    return functools.partial(fn, frame=frame) if world else fn
