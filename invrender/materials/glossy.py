"""A glossy conductor, two-sided: Mitsuba's ``roughconductor`` with ``material = "none"`` (Fresnel 1).

Torrance-Sparrow microfacet BRDF with the GGX (Trowbridge-Reitz) distribution of roughness alpha
(Walter et al., "Microfacet Models for Refraction through Rough Surfaces", EGSR 2007):

    f(wo, wi) = k_s D(h) G(wo, wi) / (4 cos_o cos_i),   h = normalize(wo + wi)
    D(h) = alpha^2 / (pi (cos_h^2 (alpha^2 - 1) + 1)^2)
    G = G1(wo) G1(wi),   G1(v) = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta_v))   (separable Smith)

Directions are sampled from the distribution of visible normals (Heitz, "Sampling the GGX
Distribution of Visible Normals", JCGT 7(4), 2018): a normal h is drawn with density
``G1(wo) max(0, wo.h) D(h) / cos_o`` and ``wo`` is reflected about it, so
``pdf(wi) = G1(wo) D(h) / (4 cos_o)`` and the weight ``f cos_i / pdf`` is ``k_s G1(wi)``.
"""

from __future__ import annotations

import torch

from invrender import registry
from invrender.materials.microfacet import ggx_D, sample_visible_normal, smith_G1
from invrender.scene.kinds import SPECULAR_REFLECTANCE
from invrender.scene.plugins import Constant, Param
from invrender.transport.bsdfs.base import BSDF, BSDFSample, Lobe, ShadingPoint
from invrender.vec import dot, normalize


@registry.MATERIALS.register
class Glossy(BSDF):
    type_name = "glossy"
    lobes = Lobe.GLOSSY
    params = {"specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0)}
    constants = {"roughness": Constant(0.1, 0.0, 1.0, True, False)}
    doc = "GGX rough conductor, Fresnel 1, two-sided"

    def _local(self, sp: ShadingPoint, wi: torch.Tensor):
        return sp.frame, sp.wo_local, sp.frame.to_local(wi), self.constant("roughness", sp)

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``k_s D G / (4 cos_o)`` (N, 3) (the cosine cos_i folded in)."""
        _, wo, wl, alpha = self._local(sp, wi)
        cos_o, cos_i = wo[:, 2], wl[:, 2]
        h = normalize(wo + wl)
        value = ggx_D(h[:, 2], alpha) * smith_G1(cos_o, alpha) * smith_G1(cos_i, alpha) / (4.0 * cos_o.clamp_min(1e-12))
        value = torch.where((cos_o > 0) & (cos_i > 0), value, 0.0)
        return self.param("specular_reflectance", sp) * value[:, None]

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``G1(wo) D(h) / (4 cos_o)`` (N,) (visible-normal sampling)."""
        _, wo, wl, alpha = self._local(sp, wi)
        cos_o, cos_i = wo[:, 2], wl[:, 2]
        h = normalize(wo + wl)
        p = smith_G1(cos_o, alpha) * ggx_D(h[:, 2], alpha) / (4.0 * cos_o.clamp_min(1e-12))
        return torch.where((cos_o > 0) & (cos_i > 0), p, 0.0)

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """A visible normal, ``wo`` reflected about it: weight ``k_s G1(wi)``."""
        frame, wo = sp.frame, sp.wo_local
        alpha = self.constant("roughness", sp)
        above = wo[:, 2] > 0
        wo_up = torch.where(above[:, None], wo, torch.tensor([0.0, 0.0, 1.0], device=wo.device))
        h = sample_visible_normal(wo_up, alpha, u_dir)
        wl = 2.0 * dot(wo_up, h)[:, None] * h - wo_up
        cos_i = wl[:, 2]
        ok = above & (cos_i > 0)
        pdf = torch.where(ok, smith_G1(wo_up[:, 2], alpha) * ggx_D(h[:, 2], alpha) / (4.0 * wo_up[:, 2].clamp_min(1e-12)), 0.0)
        weight = self.param("specular_reflectance", sp) * torch.where(ok, smith_G1(cos_i, alpha), 0.0)[:, None]
        return BSDFSample(frame.to_world(wl), weight, pdf, torch.zeros_like(ok))

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("roughconductor",)
    gltf_priority = 30

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``roughconductor``, material none (Fresnel 1), ``distribution`` ggx (required:
        Mitsuba's default is beckmann), isotropic ``alpha`` (the roughness), ``specular_reflectance``."""
        bsdf.fresnel_one()
        ks = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0, texture=False)
        if bsdf.string("distribution", allowed=("ggx",)) is None:
            message = "give <string name=\"distribution\" value=\"ggx\"/>: Mitsuba's default distribution is beckmann, and invrender has GGX only"
            raise bsdf.error(None, message)
        for key in ("alpha_u", "alpha_v"):
            if bsdf.has(key):
                raise bsdf.error(key, f"'{key}' (anisotropic roughness) is not supported: give one 'alpha'")
        alpha = bsdf.number("alpha", cls.constants["roughness"], "GGX roughness", "a <float> (textured roughness is not supported)")
        bsdf.boolean("sample_visible")
        bsdf.finish(("material", "specular_reflectance", "distribution", "alpha", "sample_visible"))
        return {"specular_reflectance": ks, "roughness": alpha}

    @classmethod
    def from_gltf(cls, material) -> dict | None:
        """A metal (the smoothest are mirrors first): k_s = its colour, roughness = GGX alpha (``roughnessFactor``^2)."""
        return {"specular_reflectance": material.metal_colour, "roughness": min(material.alpha, 1.0)} if material.metal else None

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        inner = {"type": "roughconductor", "material": "none", "distribution": "ggx", "alpha": float(constants["roughness"])}
        return {"type": "twosided", "bsdf": {**inner, "sample_visible": True, "specular_reflectance": values["specular_reflectance"]}}
