"""Glossy conductors, two-sided: Mitsuba's ``roughconductor``, with the GGX distribution (type
``glossy``) or the Beckmann distribution (type ``glossy_beckmann``, Mitsuba's default).

Torrance-Sparrow microfacet BRDF of roughness alpha with a microfacet distribution (D, G1 and the
sampling of visible normals of :mod:`invrender.plugins.bsdfs.microfacet`; Walter et al., "Microfacet
Models for Refraction through Rough Surfaces", EGSR 2007):

    f(wo, wi) = k_s F(wo . h) D(h) G(wo, wi) / (4 cos_o cos_i),   h = normalize(wo + wi)
    G = G1(wo) G1(wi)   (separable Smith)

F is the conductor Fresnel term of the complex index ``eta + i k`` (RGB constants, a named metal
or given: :mod:`invrender.plugins.bsdfs.metals`); the default ``eta = 0, k = 1`` (Mitsuba's material
``none``) is F = 1 exactly, and then no Fresnel term is computed at all.

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

import torch

from invrender import registry
from invrender.plugins.bsdfs.metal_iors import METAL_IORS
from invrender.plugins.bsdfs.metals import CONDUCTOR_CONSTANTS, ConductorFresnel, conductor_lanes
from invrender.plugins.bsdfs.microfacet import BECKMANN, GGX, Distribution, normalized
from invrender.scene.kinds import ROUGHNESS, SPECULAR_REFLECTANCE
from invrender.scene.plugins import Constant, Param
from invrender.core import lanes
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe


#: the range Mitsuba's ``alpha`` is read in (the roughness kind's (0, 1], its default 0.1)
ALPHA = Constant(0.1, 0.0, 1.0, True, False)


def eval_lanes(xp, p, ps, wo, wi, front, *, distribution: Distribution):
    """``k_s F D G / (4 cos_o)`` (``f cos_i``; D and G at p's roughness) and the pdf
    ``G1(wo) D(h) / (4 cos_o)`` (at ps's), 0 unless both directions lie above the normal."""
    d = distribution
    cos_o, cos_i = wo[2], wi[2]
    h = normalized(xp, lanes.add(wo, wi))
    both = (cos_o > 0.0) & (cos_i > 0.0)
    quarter = 1.0 / (4.0 * xp.maximum(cos_o, 1e-12))
    a, a_s = p["roughness"], ps["roughness"]
    value = xp.select(both, d.D_lanes(xp, h[2], a) * d.G1_lanes(xp, cos_o, a) * d.G1_lanes(xp, cos_i, a) * quarter, 0.0)
    F = conductor_lanes(xp, lanes.dot(wo, h), p["eta"], p["k"])
    f = lanes.scale(lanes.scale(p["specular_reflectance"], F), value)
    pdf = xp.select(both, d.G1_lanes(xp, cos_o, a_s) * d.D_lanes(xp, h[2], a_s) * quarter, 0.0)
    return f, pdf


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, distribution: Distribution):
    """A visible normal (of ps's roughness alpha_s), ``wo`` reflected about it: weight
    ``k_s F G1(wi)`` times ``D(h; alpha) G1(wo; alpha) / (D(h; alpha_s) G1(wo; alpha_s))``, which is
    1 in value (p and ps hold the same numbers) and carries the weight's derivative in alpha."""
    d = distribution
    above = wo[2] > 0.0
    up = (xp.select(above, wo[0], 0.0), xp.select(above, wo[1], 0.0), xp.select(above, wo[2], 1.0))
    a, a_s = p["roughness"], ps["roughness"]
    h = d.visible_lanes(xp, up, a_s, u0, u1)
    cos_d = lanes.dot(up, h)
    wi = lanes.sub(lanes.scale(h, 2.0 * cos_d), up)
    ok = above & (wi[2] > 0.0)
    sampling = d.D_lanes(xp, h[2], a_s) * d.G1_lanes(xp, up[2], a_s)
    pdf = xp.select(ok, sampling / (4.0 * xp.maximum(up[2], 1e-12)), 0.0)
    ratio = xp.select(sampling > 0.0, d.D_lanes(xp, h[2], a) * d.G1_lanes(xp, up[2], a) / xp.select(sampling > 0.0, sampling, 1.0), 1.0)
    g1 = xp.select(ok, d.G1_lanes(xp, wi[2], a) * ratio, 0.0)
    weight = lanes.scale(lanes.scale(p["specular_reflectance"], conductor_lanes(xp, cos_d, p["eta"], p["k"])), g1)
    return wi, weight, pdf, xp.full(False, u0)


@registry.MATERIALS.register
class Glossy(ConductorFresnel, LaneBSDF):
    type_name = "glossy"
    lobes = Lobe.GLOSSY
    params = {"specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0), "roughness": Param(ROUGHNESS, 0.1)}
    constants = dict(CONDUCTOR_CONSTANTS)
    doc = "GGX rough conductor (eta, k: a named metal or given; default Fresnel 1), two-sided"
    #: the microfacet distribution
    distribution: ClassVar[Distribution] = GGX

    def lane_form(self) -> LaneForm:
        keys = (("specular_reflectance", 3), ("roughness", 1), ("eta", 3), ("k", 3))
        bind = dict(distribution=self.distribution)
        return LaneForm(keys, functools.partial(eval_lanes, **bind), functools.partial(sample_lanes, **bind))

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("roughconductor",)
    gltf_priority = 30

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``roughconductor``: ``distribution`` beckmann (Mitsuba's default: type
        glossy_beckmann) or ggx (type glossy), isotropic ``alpha`` (the roughness, default 0.1),
        ``material`` (a named metal, default none) or ``eta``/``k``, ``specular_reflectance`` (a
        colour or a bitmap texture),
        ``sample_visible`` (read; invrender always samples visible normals)."""
        ior = bsdf.conductor(METAL_IORS)
        ks = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0)
        name = (bsdf.string("distribution", allowed=("beckmann", "ggx")) or "beckmann").lower()
        target = GlossyBeckmann if name == "beckmann" else Glossy
        for key in ("alpha_u", "alpha_v"):
            if bsdf.has(key):
                raise bsdf.error(key, f"'{key}' (anisotropic roughness) is not supported: give one 'alpha'")
        alpha = bsdf.number("alpha", ALPHA, f"{target.distribution.label} roughness", "a <float> (textured roughness is not supported)")
        bsdf.boolean("sample_visible")  # either way the same BRDF (invrender always samples visible normals)
        bsdf.finish(("material", "eta", "k", "specular_reflectance", "distribution", "alpha", "sample_visible"))
        return {"type": target.type_name, "specular_reflectance": ks, "roughness": alpha, **ior}

    @classmethod
    def from_gltf(cls, material) -> dict | None:
        """A metal (the smoothest are mirrors first): k_s = its colour, roughness = GGX alpha (``roughnessFactor``^2)."""
        return {"specular_reflectance": material.metal_colour, "roughness": min(material.alpha, 1.0)} if material.metal else None

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        alpha = values["roughness"]
        if alpha.ndim != 1:
            raise ValueError("a roughness map has no Mitsuba counterpart here (alpha is written as one number)")
        inner = {"type": "roughconductor", **cls.mitsuba_ior(constants), "distribution": cls.distribution.name, "alpha": float(alpha[0])}
        return {"type": "twosided", "bsdf": {**inner, "sample_visible": True, "specular_reflectance": values["specular_reflectance"]}}


@registry.MATERIALS.register
class GlossyBeckmann(Glossy):
    type_name = "glossy_beckmann"
    doc = "Beckmann rough conductor (Mitsuba's default roughconductor; eta, k as glossy), two-sided"
    distribution = BECKMANN
    # the same Mitsuba plugin (its distribution picks the type: Glossy.from_mitsuba, inherited)
    mitsuba_plugins = ("roughconductor",)
