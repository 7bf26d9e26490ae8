"""Mitsuba BSDFs onto invrender's materials, through the material registry.

BSDFs (``<bsdf type=...>``)
    Each registered material type (:data:`invrender.registry.MATERIALS`) names the Mitsuba
    plugins it stands for in ``mitsuba_plugins`` and reads them in its ``from_mitsuba`` (whose
    docstring, in the material's module of :mod:`invrender.plugins.bsdfs`, says which properties it
    takes); ``invrender.registry.MATERIALS`` is also what the message for an unsupported type
    lists. A material reads its ``<bsdf>`` through a :class:`BsdfReader`, whose getters are the
    vocabulary below, so every material's messages say the same things the same way:

    - colours: ``<rgb>``, ``<float>``, a constant ``<spectrum>``, or a bitmap texture where the
      parameter may be one (:mod:`.textures`);
    - indices of refraction: positive numbers or Mitsuba's named media (:data:`NAMED_IOR`);
    - conductors: ``material``, Mitsuba's named metals (``"Au"``, ``"Cu"``, ...: the RGB values
      of :mod:`invrender.plugins.bsdfs.metals`) or ``"none"`` (Fresnel 1, Mitsuba 3's default), or
      the complex index given as ``eta`` (default 0) and ``k`` (default 1), each an ``<rgb>``, a
      ``<float>`` or a constant ``<spectrum>``, >= 0; ``material`` other than none beside
      ``eta``/``k`` is an error (as in Mitsuba);
    - any property the material does not list is an error (as in Mitsuba).

    ``twosided`` wrapping one BSDF (or two references to the same one) is accepted, the material
    is the nested one; like Mitsuba, it cannot wrap a BSDF that transmits (a dielectric) or
    another ``twosided``. A material whose transmission depends on its values (``principled``:
    ``spec_trans``) says itself in its ``from_mitsuba_twosided``, which also marks it two-sided.

Deviations from Mitsuba
    - invrender's diffuse, mirror, glossy and plastic materials are two-sided: one-sided Mitsuba
      materials (diffuse, conductor, roughconductor, plastic, roughplastic without ``twosided``)
      are rendered two-sided (Mitsuba renders their back side black).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from invrender import registry
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj, Ref
from invrender.scene.formats.mitsuba.reader import PluginReader
from invrender.scene.formats.mitsuba.textures import bitmap
from invrender.scene.materials import PERTURBATIONS, Material, NormalPerturbation, normal_map_problem
from invrender.scene.textures import DEFAULT

#: Mitsuba 3's named indices of refraction (include/mitsuba/render/ior.h; Hecht, Optics, ~589 nm)
NAMED_IOR = {
    "vacuum": 1.0,
    "helium": 1.000036,
    "hydrogen": 1.000132,
    "air": 1.000277,
    "carbon dioxide": 1.00045,
    "water": 1.3330,
    "acetone": 1.36,
    "ethanol": 1.361,
    "carbon tetrachloride": 1.461,
    "glycerol": 1.4729,
    "benzene": 1.501,
    "silicone oil": 1.52045,
    "bromine": 1.661,
    "water ice": 1.31,
    "fused quartz": 1.458,
    "pyrex": 1.470,
    "acrylic glass": 1.49,
    "polypropylene": 1.49,
    "bk7": 1.5046,
    "sodium chloride": 1.544,
    "amber": 1.55,
    "pet": 1.5750,
    "diamond": 2.419,
}

#: the wrapper plugin, read here: every other BSDF plugin is a material type's (``mitsuba_plugins``)
TWOSIDED = "twosided"
#: the wrappers that perturb their nested BSDF's shading normal, read here into its material's
#: ``perturbation`` (:class:`~invrender.scene.materials.NormalPerturbation`)
PERTURBING = PERTURBATIONS


def plugins() -> dict:
    """Mitsuba BSDF plugin name -> the registered material class that reads it: the names in its
    ``mitsuba_plugins``, declared in its own class body (a subclass does not inherit its parent's
    aliases); a class registered later takes a name over."""
    return {name: cls for cls in registry.MATERIALS.values() for name in vars(cls).get("mitsuba_plugins", ())}


def material(ctx: Context, bsdf: Obj, owner: str | None) -> int:
    """The key of ``bsdf``'s material (converting it once; references share it)."""
    key = id(bsdf)
    ctx.check_broken(bsdf)
    if key not in ctx.materials:
        ctx.materials[key] = (bsdf, convert_bsdf(ctx, bsdf), owner)
    return key


def convert_bsdf(ctx: Context, bsdf: Obj, outer: Obj | None = None) -> Material:
    """The :class:`Material` of a ``<bsdf>``: ``twosided`` unwrapped, any other plugin read by the
    material class that names it in ``mitsuba_plugins`` (its ``from_mitsuba``; inside a
    ``twosided`` ``outer``, then its ``from_mitsuba_twosided`` where it has one)."""
    known = plugins()
    if bsdf.type in PERTURBING:
        return _perturbed(ctx, bsdf, outer)
    if bsdf.type == TWOSIDED:
        inner = ctx.nested(bsdf, "bsdf")
        if not inner or len(inner) > 2 or (len(inner) == 2 and inner[0] is not inner[1]):
            raise ctx.error(bsdf.node, "twosided must wrap one BSDF (two different sides are not supported: invrender's materials are two-sided)", bsdf)
        inner_cls = known.get(inner[0].type)
        # a material whose transmission depends on its values says itself (from_mitsuba_twosided)
        if inner[0].type == TWOSIDED or (inner_cls is not None and _transmits(inner_cls) and not hasattr(inner_cls, "from_mitsuba_twosided")):
            # as Mitsuba's twosided, which rejects BSDFs with a transmission component
            raise ctx.error(inner[0].node, f"twosided cannot wrap a {inner[0].type} BSDF", bsdf)
        ctx.finish(bsdf, (), ("bsdf",))
        spec = convert_bsdf(ctx, inner[0], outer=bsdf)
        if inner[0].type in PERTURBING:  # the map perturbs the frame turned to the side the ray arrives from
            if _transmits(spec.spec) and not hasattr(spec.spec, "from_mitsuba_twosided"):
                raise ctx.error(inner[0].node, f"twosided cannot wrap a {inner[0].type} of a BSDF that transmits", bsdf)
            spec = dataclasses.replace(spec, perturbation=dataclasses.replace(spec.perturbation, on_turned=True))
        return dataclasses.replace(spec, one_sided=False)
    if bsdf.type not in known:
        raise ctx.error(bsdf.node, f"unsupported bsdf type {bsdf.type!r} (supported: {', '.join([*known, TWOSIDED, *PERTURBING])})", bsdf)
    cls = known[bsdf.type]
    entries = cls.from_mitsuba(BsdfReader(ctx, bsdf))
    if outer is not None and hasattr(cls, "from_mitsuba_twosided"):
        entries = cls.from_mitsuba_twosided(entries, lambda message: ctx.error(bsdf.node, message, outer))
    # a plugin standing for several types names the one it read (roughconductor: its distribution;
    # a material of nested ones: theirs, and whether it is one-sided by theirs)
    type_name = entries.pop("type", cls.type_name)
    one_sided = entries.pop("one_sided", None)
    spec = Material.of(type_name, f"{ctx.where}:{bsdf.node.line}: {bsdf.describe()}", **entries)
    # Mitsuba's BSDFs are black from behind unless wrapped in twosided; those that transmit are two-sided
    return dataclasses.replace(spec, one_sided=not _transmits(spec.spec) if one_sided is None else one_sided)


def _perturbed(ctx: Context, bsdf: Obj, outer: Obj | None) -> Material:
    """Mitsuba's ``normalmap`` (the texture ``normalmap``, a bitmap or a ``rawconstant``: tangent-space
    normals encoded ``(n + 1) / 2``) or ``bumpmap`` (one nested texture: a height, ``scale`` default 1) around one BSDF, with
    ``flip_invalid_normals`` and ``use_shadowing_function`` (default true): the nested BSDF's
    material with the perturbation (:mod:`invrender.core.shading` gives the conventions). One
    perturbation per material; a normal map's texel not a number or of length below 0.01 (no
    direction: a grey texel) is an error."""
    inner = ctx.nested(bsdf, "bsdf")
    if len(inner) != 1:
        raise ctx.error(bsdf.node, f"{bsdf.type} must wrap exactly one BSDF", bsdf)
    if inner[0].type in PERTURBING:
        raise ctx.error(inner[0].node, f"a {inner[0].type} inside a {bsdf.type} is not supported (one normal perturbation per material)", bsdf)
    if bsdf.type == "normalmap":
        prop = bsdf.props.get("normalmap")
        texture = ctx.resolve(prop.value) if prop is not None and isinstance(prop.value, (Ref, Obj)) else None
        if texture is None or texture.tag != "texture":
            raise ctx.error(bsdf.node if prop is None else prop.node, "normalmap needs a <texture name=\"normalmap\" type=\"bitmap\">", bsdf)
        bsdf.used.add("normalmap")
    else:
        textures = ctx.nested(bsdf, "texture")
        if len(textures) != 1:
            raise ctx.error(bsdf.node, "bumpmap needs exactly one nested <texture> (the height)", bsdf)
        texture = textures[0]
    if texture.type == "rawconstant":  # one value everywhere (Mitsuba's tests: the identity map 0.5 0.5 1)
        value = ctx.take(texture, "value", ("vector", "point", "rgb", "float"), "a <vector>")
        texels = np.broadcast_to(np.asarray(0.5 if value is None else value.value, dtype=np.float64), (1, 1, 3)).copy()
        ctx.finish(texture, ("value",))
        name = "rawconstant"
    elif texture.type == "bitmap":
        texels = bitmap(ctx, texture)
        name = texture.props["filename"].value
    else:
        raise ctx.error(texture.node, f"a {bsdf.type}'s texture must be a bitmap or a rawconstant, got {texture.type!r}", bsdf)
    where = f"{ctx.where}:{texture.node.line}: {bsdf.type} {name!r}"
    if bsdf.type == "normalmap" and (problem := normal_map_problem(texels)) is not None:
        raise ctx.error(texture.node, f"{name}: {problem}", bsdf)
    scale = float(ctx.get(bsdf, "scale", "float", 1.0)) if bsdf.type == "bumpmap" else 1.0
    if not np.isfinite(scale):
        raise ctx.error(bsdf.props["scale"].node, f"'scale' must be a finite number, got {scale:g}", bsdf)
    flip = bool(ctx.get(bsdf, "flip_invalid_normals", "boolean", True))
    shadowing = bool(ctx.get(bsdf, "use_shadowing_function", "boolean", True))
    ctx.finish(bsdf, ("normalmap", "scale", "flip_invalid_normals", "use_shadowing_function") if bsdf.type == "normalmap" else ("scale", "flip_invalid_normals", "use_shadowing_function"), ("bsdf", "texture"))
    spec = convert_bsdf(ctx, inner[0], outer=outer)
    sampling = ctx.texture_sampling.get(id(texture), DEFAULT)
    perturbation = NormalPerturbation(bsdf.type, torch.as_tensor(texels, dtype=torch.float32), None if sampling == DEFAULT else sampling, scale, False, flip, shadowing, where)
    return dataclasses.replace(spec, perturbation=perturbation)


def _transmits(cls) -> bool:
    """Does material class ``cls`` have a transmission lobe? (Read from its own lobe flags.)"""
    lobes = cls.lobes
    return bool(lobes & type(lobes).TRANSMISSION)


class BsdfReader(PluginReader):
    """One ``<bsdf>`` as a material class's ``from_mitsuba`` reads it: the getters of
    :class:`~.reader.PluginReader` and those only BSDFs need (indices of refraction, the Fresnel
    term of conductors)."""

    def nested_materials(self) -> list[Material]:
        """The BSDFs nested in this one (a blend's, a mask's), each converted as a top-level one
        (``twosided`` unwrapped), in the file's order."""
        return [convert_bsdf(self._ctx, b) for b in self._ctx.nested(self._obj, "bsdf")]

    def ior(self, name: str, default: str) -> float:
        """An index of refraction: a positive number or one of Mitsuba's named media
        (:data:`NAMED_IOR`); the medium ``default`` when absent."""
        prop = self._ctx.take(self._obj, name, ("float", "integer", "string"), "a <float> or a <string> naming a medium")
        if prop is None:
            return NAMED_IOR[default]
        if prop.tag == "string":
            key = prop.value.strip().lower()
            if key not in NAMED_IOR:
                raise self.error(name, f"unknown {name} {prop.value!r} (known: {', '.join(NAMED_IOR)})")
            return NAMED_IOR[key]
        value = float(prop.value)
        if value <= 0:
            raise self.error(name, f"'{name}' must be positive, got {value:g}")
        return value

    def conductor(self, metals: dict) -> dict:
        """A conductor's complex index of refraction as the constants ``eta``, ``k`` (RGB tuples):
        ``material`` (a name in ``metals``, name -> (eta, k), the material's table of named metals;
        absent or ``"none"``: eta 0, k 1, Fresnel 1, Mitsuba 3's default) or ``eta`` and ``k``
        (defaults 0 and 1, as Mitsuba's); empty for Fresnel 1."""
        prop = self._ctx.take(self._obj, "material", ("string",), "a <string>")
        name = "none" if prop is None else prop.value.strip()
        given = [key for key in ("eta", "k") if self.has(key)]
        if name != "none":
            if given:
                raise self.error(given[0], f"give either material {name!r} or '{given[0]}', not both (as Mitsuba)")
            if name not in metals:
                raise self.error("material", f"unknown conductor material {name!r} (known: none, {', '.join(metals)})")
            eta, k = metals[name]
            return {"eta": tuple(eta), "k": tuple(k)}
        if not given:
            return {}
        out = {}
        for key, default in (("eta", (0.0, 0.0, 0.0)), ("k", (1.0, 1.0, 1.0))):
            p = self._ctx.take(self._obj, key, ("rgb", "float", "spectrum"), "an <rgb>, a <float> or a constant <spectrum> (textures are not supported)")
            value = default if p is None else tuple(float(x) for x in np.broadcast_to(np.asarray(p.value, dtype=np.float64), (3,)))
            if min(value) < 0:
                raise self.error(key, f"'{key}' (the complex index of refraction's {'real' if key == 'eta' else 'imaginary'} part) must be >= 0, got {', '.join(f'{v:g}' for v in value)}")
            out[key] = value
        return out
