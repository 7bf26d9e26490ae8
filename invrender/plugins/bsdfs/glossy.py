"""Glossy conductors, two-sided: Mitsuba's ``roughconductor``, with the GGX distribution (type
``glossy``) or the Beckmann distribution (type ``glossy_beckmann``, Mitsuba's default).

Torrance-Sparrow microfacet BRDF of roughness alpha with a microfacet distribution (D, G1 and the
sampling of visible normals of :mod:`invrender.plugins.bsdfs.microfacet`; Walter et al., "Microfacet
Models for Refraction through Rough Surfaces", EGSR 2007):

    f(wo, wi) = k_s F(wo . h) D(h) G(wo, wi) / (4 cos_o cos_i),   h = normalize(wo + wi)
    G = G1(wo) G1(wi)   (separable Smith)

F is the conductor Fresnel term of the complex index ``eta + i k`` (RGB constants, a named metal
or given: :mod:`invrender.plugins.bsdfs.metals`); the default ``eta = 0, k = 1`` (Mitsuba's material
``none``) is F = 1 exactly, and where every material of the type has it no Fresnel term is computed
at all (a flag of the lane form).

Anisotropic (the constant ``alpha_v`` > 0, Mitsuba's ``alpha_u``/``alpha_v``): roughness alpha_u
(``roughness``) along the shading frame's tangent s and alpha_v along t, the frame Mitsuba builds
from the mesh's dp/du (docs/rendering.md#shading-frames-and-anisotropy), D and G1 in their anisotropic forms
(Mitsuba's). A type none of whose materials is anisotropic keeps the isotropic code (and its
random bits) in any frame.

Directions are sampled from the distribution of visible normals (Heitz, "Sampling the GGX
Distribution of Visible Normals", JCGT 7(4), 2018; Heitz and d'Eon 2014 for Beckmann): a normal
h is drawn with density ``G1(wo) max(0, wo.h) D(h) / cos_o`` and ``wo`` is reflected about it, so
``pdf(wi) = G1(wo) D(h) / (4 cos_o)`` and the weight ``f cos_i / pdf`` is ``k_s F G1(wi)``.

The roughness alpha is a differentiable parameter (``NAME.roughness``, kind ``roughness``):
``eval`` reads it attached, sampling and ``pdf`` read it detached (alpha_s), and the weight is
``f(alpha) cos_i / pdf(alpha_s) = k_s F G1(wi; alpha) D(h; alpha) G1(wo; alpha) / (D(h; alpha_s)
G1(wo; alpha_s))``, the ratio exactly 1 in value: every estimator stays unbiased in alpha
(docs/gradient_variance.md#roughness).
"""

from __future__ import annotations

import functools
from typing import ClassVar

import numpy as np

from invrender import registry
from invrender.plugins.bsdfs.metal_iors import METAL_IORS
from invrender.plugins.bsdfs.metals import CONDUCTOR_CONSTANTS, ConductorFresnel, fresnel_lanes
from invrender.plugins.bsdfs.microfacet import BECKMANN, GGX, Distribution, Microfacets
from invrender.scene.kinds import ROUGHNESS, SPECULAR_REFLECTANCE
from invrender.scene.plugins import Constant, Param
from invrender.scene.textures import SampledTexture, VertexAttribute
from invrender.core import lanes
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe
from invrender.core.lanes import scale


#: the range Mitsuba's ``alpha`` is read in (the roughness kind's (0, 1], its default 0.1)
ALPHA = Constant(0.1, 0.0, 1.0, True, False)
#: the roughness along the shading frame's tangent t (Mitsuba's ``alpha_v``; ``roughness`` is then
#: ``alpha_u``, along s): 0, the default, is the same as ``roughness`` (isotropic)
ALPHA_V = Constant(0.0, 0.0, 1.0, False, False)


def anisotropic(bsdf) -> bool:
    """Does some material of ``bsdf`` (a microfacet type with the constant ``alpha_v``) have a
    roughness along t of its own? Its lane form is then the anisotropic one, in the UV tangent
    frame (:attr:`~invrender.core.bsdf.LaneForm.tangent`); else the isotropic one, in any frame."""
    return any(c.get("alpha_v", 0.0) > 0.0 for c in bsdf.constants)


#: the smallest alpha Mitsuba's microfacet distributions use (``MicrofacetDistribution::configure``)
MIN_ALPHA = 1e-4


def at_least(value, low: float):
    """A value read from a scene file (an array, a :class:`SampledTexture`'s texels) with every
    number below ``low`` raised to it; a vertex attribute as it is (checked when the scene is built)."""
    if isinstance(value, SampledTexture):
        return SampledTexture(np.maximum(np.asarray(value.texels, dtype=np.float64), low), value.sampling)
    return value if isinstance(value, VertexAttribute) else np.maximum(value, low)


def alpha_map(bsdf):
    """Mitsuba's isotropic ``alpha`` where a texture gives it (bitmap, checkerboard; a colour too):
    one number per texel as Mitsuba's ``eval_1`` reads it (a bitmap's luminance), each in [0, 1], a
    roughness map (h, w, 3) of grey texels, values below 1e-4 read as 1e-4 as Mitsuba's microfacet
    distributions clamp them (a checkerboard of 0 and 0.4 is half smooth); None where ``alpha`` is
    a number or absent."""
    if not bsdf.has("alpha") or bsdf.tag("alpha") in ("float", "integer"):
        return None
    return at_least(bsdf.grey("alpha", ROUGHNESS, 0.1), MIN_ALPHA)


def read_alphas(bsdf, label: str) -> dict:
    """Mitsuba's ``alpha`` (isotropic) or ``alpha_u`` and ``alpha_v`` (anisotropic: along the
    tangent s from dp/du and along t; not beside ``alpha``) as invrender's ``roughness`` (alpha_u)
    and ``alpha_v`` constants."""
    given = [k for k in ("alpha_u", "alpha_v") if bsdf.has(k)]
    if not given:
        return {"roughness": bsdf.number("alpha", ALPHA, f"{label} roughness", "a <float> or a texture")}
    if bsdf.has("alpha"):
        raise bsdf.error("alpha", "give either 'alpha' or 'alpha_u' and 'alpha_v', not both (as Mitsuba)")
    if len(given) == 1:
        missing = ({"alpha_u", "alpha_v"} - set(given)).pop()
        raise bsdf.error(given[0], f"'{given[0]}' needs '{missing}' too (as Mitsuba)")
    alpha_u = bsdf.number("alpha_u", ALPHA, f"{label} roughness along the tangent", "a <float> (a texture only for the isotropic alpha)")
    alpha_v = bsdf.number("alpha_v", ALPHA, f"{label} roughness along the bitangent", "a <float> (a texture only for the isotropic alpha)")
    return {"roughness": alpha_u, "alpha_v": alpha_v}


def mitsuba_alphas(alpha: float, constants: dict) -> dict:
    """Mitsuba's ``alpha``, or ``alpha_u``/``alpha_v`` where the material is anisotropic."""
    alpha_v = float(constants.get("alpha_v", 0.0))
    return {"alpha_u": alpha, "alpha_v": alpha_v} if alpha_v > 0.0 else {"alpha": alpha}


def eval_lanes(xp, p, ps, wo, wi, front, *, distribution: Distribution, fresnel: bool, anisotropic: bool = False):
    """``k_s F D G / (4 cos_o)`` (the cosine cos_i folded in; roughness ``p``'s) and the pdf
    ``G1(wo) D(h) / (4 cos_o)`` (``ps``'s), both 0 unless ``wo`` and ``wi`` lie above the normal;
    ``anisotropic``: roughness ``alpha_u`` along the frame's tangent s, ``alpha_v`` along t."""
    m_s = Microfacets.of(xp, distribution, ps, anisotropic)
    m = m_s if p["roughness"] is ps["roughness"] else Microfacets.of(xp, distribution, p, anisotropic)
    cos_o, cos_i = wo[2], wi[2]
    h = lanes.normalize(xp, lanes.add(wo, wi))
    D_s, g1_s = m_s.D(h), m_s.G1(wo, h)
    pdf = g1_s * D_s / (4.0 * xp.maximum(cos_o, 1e-12))
    D, g1_o = (D_s, g1_s) if m is m_s else (m.D(h), m.G1(wo, h))
    on = (cos_o > 0.0) & (cos_i > 0.0)
    value = xp.select(on, D * g1_o * m.G1(wi, h) / (4.0 * xp.maximum(cos_o, 1e-12)), 0.0)
    f = fresnel_lanes(xp, p, lanes.dot(wo, h), scale(p["specular_reflectance"], value), fresnel=fresnel)
    return f, xp.select(on, pdf, 0.0)


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, distribution: Distribution, fresnel: bool, anisotropic: bool = False):
    """A visible normal h (roughness ``ps``'s), ``wo`` reflected about it: weight ``k_s F G1(wi)``
    times ``D(h; alpha) G1(wo; alpha) / (D(h; alpha_s) G1(wo; alpha_s))`` (``p``'s roughness over
    ``ps``'s: 1 in value, the roughness gradient of ``f``), 0 where ``wo`` or ``wi`` lies below."""
    m_s = Microfacets.of(xp, distribution, ps, anisotropic)
    m = m_s if p["roughness"] is ps["roughness"] else Microfacets.of(xp, distribution, p, anisotropic)
    above = wo[2] > 0.0
    wo_up = (xp.select(above, wo[0], 0.0), xp.select(above, wo[1], 0.0), xp.select(above, wo[2], 1.0))
    h = m_s.sample(wo_up, u0, u1)
    cos_d = lanes.dot(wo_up, h)
    wi = lanes.sub(scale(h, 2.0 * cos_d), wo_up)
    ok = above & (wi[2] > 0.0)
    D_s, g1_s = m_s.D(h), m_s.G1(wo_up, h)
    pdf = g1_s * D_s / (4.0 * xp.maximum(wo_up[2], 1e-12))
    g1 = m.G1(wi, h)
    if m is not m_s:  # the same lanes where p is ps (a ratio of exactly 1 otherwise)
        ratio = m.D(h) * m.G1(wo_up, h) / xp.select(D_s * g1_s > 0.0, D_s * g1_s, 1.0)
        g1 = g1 * xp.select(D_s * g1_s > 0.0, ratio, 1.0)
    weight = fresnel_lanes(xp, p, cos_d, scale(p["specular_reflectance"], xp.select(ok, g1, 0.0)), fresnel=fresnel)
    return wi, weight, xp.select(ok, pdf, 0.0), xp.full(False, u0)


@registry.MATERIALS.register
class Glossy(ConductorFresnel, LaneBSDF):
    """Written once in lane form (:func:`eval_lanes`, :func:`sample_lanes`), its distribution and
    whether any material has a Fresnel term other than 1 bound when the form is built."""

    type_name = "glossy"
    lobes = Lobe.GLOSSY
    params = {"specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0), "roughness": Param(ROUGHNESS, 0.1)}
    constants = {**CONDUCTOR_CONSTANTS, "alpha_v": ALPHA_V}
    doc = "GGX rough conductor (eta, k: a named metal or given; default Fresnel 1; alpha_v: anisotropic), two-sided"
    #: the microfacet distribution
    distribution: ClassVar[Distribution] = GGX

    def lane_form(self) -> LaneForm:
        aniso = anisotropic(self)
        keys = (("specular_reflectance", 3), ("roughness", 1)) + self.fresnel_keys + ((("alpha_v", 1),) if aniso else ())
        bound = {"distribution": self.distribution, "fresnel": not self.fresnel_one, "anisotropic": aniso}
        return LaneForm(keys, functools.partial(eval_lanes, **bound), functools.partial(sample_lanes, **bound), tangent=aniso)

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("roughconductor",)
    gltf_priority = 30

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``roughconductor``: ``distribution`` beckmann (Mitsuba's default: type
        glossy_beckmann) or ggx (type glossy), ``alpha`` (the roughness, default 0.1; a number,
        or a texture: a roughness map, :func:`alpha_map`) or ``alpha_u`` and ``alpha_v``
        (anisotropic, numbers: the roughness and the constant ``alpha_v``),
        ``material`` (a named metal, default none) or ``eta``/``k``, ``specular_reflectance`` (a
        colour or a bitmap texture),
        ``sample_visible`` (read; invrender always samples visible normals)."""
        ior = bsdf.conductor(METAL_IORS)
        ks = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0)
        name = (bsdf.string("distribution", allowed=("beckmann", "ggx")) or "beckmann").lower()
        target = GlossyBeckmann if name == "beckmann" else Glossy
        textured = None if bsdf.has("alpha_u") or bsdf.has("alpha_v") else alpha_map(bsdf)
        alphas = read_alphas(bsdf, target.distribution.label) if textured is None else {"roughness": textured}
        bsdf.boolean("sample_visible")  # either way the same BRDF (invrender always samples visible normals)
        bsdf.finish(("material", "eta", "k", "specular_reflectance", "distribution", "alpha", "alpha_u", "alpha_v", "sample_visible"))
        return {"type": target.type_name, "specular_reflectance": ks, **alphas, **ior}

    @classmethod
    def from_gltf(cls, material) -> dict | None:
        """A metal (the smoothest are mirrors first): k_s = its colour, roughness = GGX alpha (glTF's
        perceptual roughness squared; a map where ``metallicRoughnessTexture`` varies it)."""
        return {"specular_reflectance": material.metal_colour, "roughness": material.alpha} if material.metal else None

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        alpha = values["roughness"]
        alphas = mitsuba_alphas(float(alpha[0]), constants) if alpha.ndim == 1 else {"alpha": alpha}  # a map: a (grey) bitmap
        inner = {"type": "roughconductor", **cls.mitsuba_ior(constants), "distribution": cls.distribution.name, **alphas}
        return {"type": "twosided", "bsdf": {**inner, "sample_visible": True, "specular_reflectance": values["specular_reflectance"]}}


@registry.MATERIALS.register
class GlossyBeckmann(Glossy):
    type_name = "glossy_beckmann"
    doc = "Beckmann rough conductor (Mitsuba's default roughconductor; eta, k as glossy), two-sided"
    distribution = BECKMANN
    # the same Mitsuba plugin (its distribution picks the type: Glossy.from_mitsuba, inherited)
    mitsuba_plugins = ("roughconductor",)
