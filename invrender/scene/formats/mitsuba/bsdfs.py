"""Mitsuba BSDFs onto invrender's materials.

BSDFs (``<bsdf type=...>``), mapped to invrender's materials (:mod:`invrender.scene.materials`)
    - ``diffuse`` -> ``diffuse``: ``reflectance`` (rgb, float, constant spectrum, or
      ``<texture type="bitmap">``; default 0.5).
    - ``conductor`` -> ``mirror`` and ``roughconductor`` -> ``glossy`` (GGX): only Fresnel 1,
      i.e. ``<string name="material" value="none"/>``, which is Mitsuba 3's default when
      ``material`` is absent; any other material and ``eta``/``k`` are errors.
      ``specular_reflectance`` (rgb, float or constant spectrum; default 1). roughconductor:
      ``distribution`` must be given as ``ggx`` (Mitsuba's default is ``beckmann``, which invrender
      does not have), ``alpha`` a float in (0, 1] (default 0.1) is invrender's ``roughness``;
      ``alpha_u``/``alpha_v`` (anisotropy) are errors; ``sample_visible`` is accepted and ignored.
    - ``dielectric`` -> ``dielectric``: ``int_ior`` and ``ext_ior`` as positive numbers or
      Mitsuba's named media (:data:`NAMED_IOR`; defaults ``bk7`` and ``air``). invrender's
      dielectric has one relative index ``ior = int_ior / ext_ior`` (its exterior is 1.0), which
      is exactly what a smooth dielectric interface depends on.
    - ``twosided`` wrapping one BSDF (or two references to the same one): accepted, the material
      is the nested one (a dielectric cannot be nested).

Deviations from Mitsuba
    - invrender's diffuse, mirror and glossy materials are two-sided: one-sided Mitsuba materials
      (diffuse, conductor, roughconductor without ``twosided``) are rendered two-sided (Mitsuba
      renders their back side black).
"""

from __future__ import annotations

from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj
from invrender.scene.formats.mitsuba.textures import colour
from invrender.scene.kinds import REFLECTANCE, SPECULAR_REFLECTANCE
from invrender.scene.materials import Material

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

BSDF_TYPES = ("diffuse", "conductor", "roughconductor", "dielectric", "twosided")


def material(ctx: Context, bsdf: Obj, owner: str | None) -> int:
    """The key of ``bsdf``'s material (converting it once; references share it)."""
    key = id(bsdf)
    if key not in ctx.materials:
        ctx.materials[key] = (bsdf, convert_bsdf(ctx, bsdf), owner)
    return key


def convert_bsdf(ctx: Context, bsdf: Obj) -> Material:
    where = f"{ctx.where}:{bsdf.node.line}: {bsdf.describe()}"
    t = bsdf.type
    if t == "twosided":
        inner = ctx.nested(bsdf, "bsdf")
        if not inner or len(inner) > 2 or (len(inner) == 2 and inner[0] is not inner[1]):
            raise ctx.error(bsdf.node, "twosided must wrap one BSDF (two different sides are not supported: invrender's materials are two-sided)", bsdf)
        if inner[0].type in ("dielectric", "twosided"):
            raise ctx.error(inner[0].node, f"twosided cannot wrap a {inner[0].type} BSDF", bsdf)
        ctx.finish(bsdf, (), ("bsdf",))
        return convert_bsdf(ctx, inner[0])
    if t == "diffuse":
        rho = colour(ctx, bsdf, "reflectance", REFLECTANCE, 0.5)
        ctx.finish(bsdf, ("reflectance",))
        return Material.of("diffuse", where, reflectance=rho)
    if t in ("conductor", "roughconductor"):
        material = ctx.take(bsdf, "material", ("string",), "a <string>")
        if material is not None and material.value != "none":
            raise ctx.error(material.node, f"conductor material {material.value!r} is not supported: only 'none' (Fresnel 1, a perfect reflector) is", bsdf)
        for key in ("eta", "k"):
            if key in bsdf.props:
                raise ctx.error(bsdf.props[key].node, f"'{key}' is not supported: only material 'none' (Fresnel 1) is", bsdf)
        ks = colour(ctx, bsdf, "specular_reflectance", SPECULAR_REFLECTANCE, 1.0, texture=False)
        if t == "conductor":
            ctx.finish(bsdf, ("material", "specular_reflectance"))
            return Material.of("mirror", where, specular_reflectance=ks)
        distribution = ctx.take(bsdf, "distribution", ("string",), "a <string>")
        if distribution is None:
            raise ctx.error(bsdf.node, "give <string name=\"distribution\" value=\"ggx\"/>: Mitsuba's default distribution is beckmann, and invrender has GGX only", bsdf)
        if distribution.value.lower() != "ggx":
            raise ctx.error(distribution.node, f"distribution {distribution.value!r} is not supported (supported: ggx)", bsdf)
        for key in ("alpha_u", "alpha_v"):
            if key in bsdf.props:
                raise ctx.error(bsdf.props[key].node, f"'{key}' (anisotropic roughness) is not supported: give one 'alpha'", bsdf)
        alpha = ctx.take(bsdf, "alpha", ("float", "integer"), "a <float> (textured roughness is not supported)")
        value = 0.1 if alpha is None else float(alpha.value)
        if not 0.0 < value <= 1.0:
            raise ctx.error(alpha.node, f"'alpha' (GGX roughness) must lie in (0, 1], got {value:g}", bsdf)
        ctx.get(bsdf, "sample_visible", "boolean")
        ctx.finish(bsdf, ("material", "specular_reflectance", "distribution", "alpha", "sample_visible"))
        return Material.of("glossy", where, specular_reflectance=ks, roughness=value)
    if t == "dielectric":
        int_ior = ior(ctx, bsdf, "int_ior", "bk7")
        ext_ior = ior(ctx, bsdf, "ext_ior", "air")
        ctx.finish(bsdf, ("int_ior", "ext_ior"))
        return Material.of("dielectric", where, ior=int_ior / ext_ior)
    raise ctx.error(bsdf.node, f"unsupported bsdf type {t!r} (supported: {', '.join(BSDF_TYPES)})", bsdf)


def ior(ctx: Context, bsdf: Obj, name: str, default: str) -> float:
    prop = ctx.take(bsdf, name, ("float", "integer", "string"), "a <float> or a <string> naming a medium")
    if prop is None:
        return NAMED_IOR[default]
    if prop.tag == "string":
        key = prop.value.strip().lower()
        if key not in NAMED_IOR:
            raise ctx.error(prop.node, f"unknown {name} {prop.value!r} (known: {', '.join(NAMED_IOR)})", bsdf)
        return NAMED_IOR[key]
    value = float(prop.value)
    if value <= 0:
        raise ctx.error(prop.node, f"'{name}' must be positive, got {value:g}", bsdf)
    return value
