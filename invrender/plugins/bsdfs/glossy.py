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

from typing import ClassVar

import torch

from invrender import registry
from invrender.plugins.bsdfs.metal_iors import METAL_IORS
from invrender.plugins.bsdfs.metals import CONDUCTOR_CONSTANTS, ConductorFresnel
from invrender.plugins.bsdfs.microfacet import BECKMANN, GGX, Distribution, roughness_at, visible_reweight
from invrender.scene.kinds import ROUGHNESS, SPECULAR_REFLECTANCE
from invrender.scene.plugins import Constant, Param
from invrender.core.bsdf import BSDF, BSDFSample, Lobe, ShadingPoint
from invrender.vec import dot, normalize


#: the range Mitsuba's ``alpha`` is read in (the roughness kind's (0, 1], its default 0.1)
ALPHA = Constant(0.1, 0.0, 1.0, True, False)


@registry.MATERIALS.register
class Glossy(ConductorFresnel, BSDF):
    type_name = "glossy"
    lobes = Lobe.GLOSSY
    params = {"specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0), "roughness": Param(ROUGHNESS, 0.1)}
    constants = dict(CONDUCTOR_CONSTANTS)
    doc = "GGX rough conductor (eta, k: a named metal or given; default Fresnel 1), two-sided"
    #: the microfacet distribution
    distribution: ClassVar[Distribution] = GGX

    def _local(self, sp: ShadingPoint, wi: torch.Tensor):
        return sp.frame, sp.wo_local, sp.frame.to_local(wi)

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``k_s F D G / (4 cos_o)`` (N, 3) (the cosine cos_i folded in; differentiable in alpha)."""
        _, wo, wl = self._local(sp, wi)
        alpha, _ = roughness_at(self, sp)
        d = self.distribution
        cos_o, cos_i = wo[:, 2], wl[:, 2]
        h = normalize(wo + wl)
        value = d.D(h[:, 2], alpha) * d.G1(cos_o, alpha) * d.G1(cos_i, alpha) / (4.0 * cos_o.clamp_min(1e-12))
        value = torch.where((cos_o > 0) & (cos_i > 0), value, 0.0)
        ks = self.param("specular_reflectance", sp)
        fresnel = self.fresnel(sp, dot(wo, h))
        return ks * value[:, None] if fresnel is None else ks * (fresnel * value[:, None])

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``G1(wo) D(h) / (4 cos_o)`` (N,) (visible-normal sampling, at the detached alpha_s)."""
        _, wo, wl = self._local(sp, wi)
        _, alpha = roughness_at(self, sp)
        d = self.distribution
        cos_o, cos_i = wo[:, 2], wl[:, 2]
        h = normalize(wo + wl)
        p = d.G1(cos_o, alpha) * d.D(h[:, 2], alpha) / (4.0 * cos_o.clamp_min(1e-12))
        return torch.where((cos_o > 0) & (cos_i > 0), p, 0.0)

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """A visible normal (of the detached alpha_s), ``wo`` reflected about it: weight
        ``k_s F G1(wi)`` (times the reweighting to the attached alpha, 1 in value)."""
        frame, wo = sp.frame, sp.wo_local
        d = self.distribution
        attached, alpha = roughness_at(self, sp)
        above = wo[:, 2] > 0
        wo_up = torch.where(above[:, None], wo, torch.tensor([0.0, 0.0, 1.0], device=wo.device))
        h = d.sample_visible(wo_up, alpha, u_dir)
        cos_d = dot(wo_up, h)
        wl = 2.0 * cos_d[:, None] * h - wo_up
        cos_i = wl[:, 2]
        ok = above & (cos_i > 0)
        pdf = torch.where(ok, d.G1(wo_up[:, 2], alpha) * d.D(h[:, 2], alpha) / (4.0 * wo_up[:, 2].clamp_min(1e-12)), 0.0)
        ratio = visible_reweight(d, h[:, 2], wo_up[:, 2], attached, alpha)
        g1 = d.G1(cos_i, alpha) if ratio is None else d.G1(cos_i, attached) * ratio
        weight = self.param("specular_reflectance", sp) * torch.where(ok, g1, 0.0)[:, None]
        fresnel = self.fresnel(sp, cos_d)
        if fresnel is not None:
            weight = weight * fresnel
        return BSDFSample(frame.to_world(wl), weight, pdf, torch.zeros_like(ok))

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
