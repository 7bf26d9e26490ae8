"""Rough glass: Mitsuba 3's ``roughdielectric``, with the Beckmann distribution (type
``roughdielectric``, Mitsuba's default) or GGX (type ``roughdielectric_ggx``).

A rough interface of relative index ``int_ior / ext_ior`` (defaults bk7 1.5046 over air 1.000277,
numbers or Mitsuba's named media) between the outside (the triangles' front side) and the inside:
Walter et al., "Microfacet Models for Refraction through Rough Surfaces" (EGSR 2007), with the
distributions of :mod:`invrender.plugins.bsdfs.microfacet`. In the shading frame (normal ``n`` turned
to ``wo``, so ``c_o = wo.z > 0``), with ``eta`` the index ratio transmitted over incident
(``int_ior / ext_ior`` from outside, its inverse from inside) and ``F`` the dielectric Fresnel term
(:func:`~invrender.plugins.bsdfs.dielectric.fresnel_dielectric`):

- reflection (``wi`` on ``wo``'s side): ``h = normalize(wo + wi)``,
  ``f cos = k_r F(wo.h) D(h) G1(wo) G1(wi) / (4 c_o)``;
- transmission (``wi`` on the other side): the generalized half-vector ``h = normalize(wo + eta
  wi)`` turned up, ``f cos = k_t (1 - F(wo.h)) D(h) G1(wo) G1(wi) |wo.h| |wi.h| / (c_o (wo.h +
  eta wi.h)^2)``, both ``wo.h > 0`` and ``wi.h < 0`` (else 0). This is Walter's BTDF times
  ``1 / eta^2``: radiance is scaled across the interface as the smooth ``dielectric`` scales it
  (compressed into a smaller solid angle entering a denser medium; docs/closed_forms.md), and as
  Mitsuba's does in radiance mode.

G1 is Smith's masking of each direction at its angle with the normal (``|cos|``), ``k_r`` and
``k_t`` are ``specular_reflectance`` (a differentiable parameter, a colour or a texture) and
``specular_transmittance`` (an RGB constant), both default 1.

Sampling, as Mitsuba's with ``sample_visible``: a normal h visible from ``wo`` (density ``G1(wo)
wo.h D(h) / c_o``), reflection about it with probability ``F(wo.h)`` (1 under total internal
reflection), else refraction through it; ``pdf`` is that density times ``F`` or ``1 - F`` times the
Jacobian ``1 / (4 wi.h)`` (reflection) or ``eta^2 |wi.h| / (wo.h + eta wi.h)^2`` (refraction), and
the weights are ``k_r G1(wi)`` and ``k_t G1(wi) / eta^2``.

The roughness alpha (``NAME.roughness``, kind ``roughness``) is differentiable as the glossy
conductor's (:mod:`invrender.plugins.bsdfs.glossy`): ``eval`` reads it attached, sampling and ``pdf``
detached, and the weight carries ``D(h; alpha) G1(wo; alpha) / (D(h; alpha_s) G1(wo; alpha_s))``
(:func:`~invrender.plugins.bsdfs.microfacet.visible_reweight`, exactly 1 in value) and ``G1(wi;
alpha)``, for both lobes: every estimator stays unbiased in alpha.

Lobes: glossy reflection and glossy transmission, so next-event estimation gathers light from
either side (docs/integrators.md).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import torch

from invrender import registry
from invrender.errors import SceneError
from invrender.plugins.bsdfs.dielectric import check_relative_ior, fresnel_dielectric
from invrender.plugins.bsdfs.glossy import ALPHA
from invrender.plugins.bsdfs.microfacet import BECKMANN, GGX, Distribution, roughness_at, visible_reweight
from invrender.scene.formats.mitsuba.bsdfs import NAMED_IOR
from invrender.scene.kinds import ROUGHNESS, SPECULAR_REFLECTANCE
from invrender.scene.plugins import Constant, Param
from invrender.core.bsdf import BSDF, BSDFSample, Lobe, ShadingPoint
from invrender.vec import dot, normalize

#: the interface's indices of refraction (Mitsuba's defaults: bk7 inside, air outside)
INTERFACE_CONSTANTS = {
    "int_ior": Constant(NAMED_IOR["bk7"], 0.0, math.inf, True, True, names=NAMED_IOR),
    "ext_ior": Constant(NAMED_IOR["air"], 0.0, math.inf, True, True, names=NAMED_IOR),
    # RGB, a scene constant (not differentiable: parameter names are kinds, and none is a transmittance)
    "specular_transmittance": Constant((1.0, 1.0, 1.0), 0.0, 1.0, False, False, size=3),
}


@registry.MATERIALS.register
class RoughDielectric(BSDF):
    type_name = "roughdielectric"
    lobes = Lobe.GLOSSY | Lobe.GLOSSY_TRANSMISSION
    params = {
        "specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0),
        "roughness": Param(ROUGHNESS, 0.1),
    }
    constants = dict(INTERFACE_CONSTANTS)
    doc = "rough glass: Beckmann microfacet reflection and refraction (Mitsuba's roughdielectric, its default distribution)"
    #: the microfacet distribution
    distribution: ClassVar[Distribution] = BECKMANN

    def _eta(self, sp: ShadingPoint) -> torch.Tensor:
        """(N,) the index ratio transmitted over incident (``int_ior / ext_ior`` from outside)."""
        eta = self.constant("int_ior", sp) / self.constant("ext_ior", sp)
        return torch.where(sp.front, eta, 1.0 / eta)

    def _terms(self, sp: ShadingPoint, wl: torch.Tensor, alpha: torch.Tensor, value: bool):
        """``(f cos (N, 3) or None, pdf (N,))`` at local directions ``wl`` (N, 3); ``f`` at roughness
        ``alpha`` (N,), the pdf at the detached sampling roughness."""
        wo = sp.wo_local
        eta = self._eta(sp)
        c_o, c_i = wo[:, 2], wl[:, 2]
        reflected = c_i > 0
        h = normalize(wo + wl * torch.where(reflected, 1.0, eta)[:, None])
        h = h * torch.where(h[:, 2] < 0, -1.0, 1.0)[:, None]
        d_o, d_i = dot(wo, h), dot(wl, h)
        ok = (c_o > 0) & (c_i != 0) & (d_o > 0) & (d_i * c_i > 0)
        F = fresnel_dielectric(d_o.clamp(0.0, 1.0), eta)[0]
        denom = (d_o + eta * d_i).square().clamp_min(1e-12)
        d = self.distribution
        alpha_s = roughness_at(self, sp)[1]
        visible = d.G1(c_o, alpha_s) * d.D(h[:, 2], alpha_s) / c_o.clamp_min(1e-12)  # / wo.h, times the Jacobian's wo.h
        pdf = visible * torch.where(reflected, F / 4.0, (1.0 - F) * eta * eta * d_i.abs() * d_o / denom)
        pdf = torch.where(ok, pdf, 0.0)
        if not value:
            return None, pdf
        common = d.D(h[:, 2], alpha) * d.G1(c_o, alpha) * d.G1(c_i.abs(), alpha) / c_o.clamp_min(1e-12)
        f_r = torch.where(ok & reflected, F * common / 4.0, 0.0)
        f_t = torch.where(ok & ~reflected, (1.0 - F) * common * d_o * d_i.abs() / denom, 0.0)
        f = self.param("specular_reflectance", sp) * f_r[:, None] + self.constant("specular_transmittance", sp) * f_t[:, None]
        return f, pdf

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``f cos`` (N, 3) of the lobe ``wi``'s side takes (differentiable in alpha)."""
        return self._terms(sp, sp.frame.to_local(wi), roughness_at(self, sp)[0], value=True)[0]

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """The visible normal's density times ``F`` or ``1 - F`` times the Jacobian (N,), at the
        detached alpha_s."""
        wl = sp.frame.to_local(wi)
        return self._terms(sp, wl, wl.new_zeros(wl.shape[0]), value=False)[1]

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """A visible normal (of the detached alpha_s); reflection about it with probability F
        (weight ``k_r G1(wi)``), else refraction (weight ``k_t G1(wi) / eta^2``), times the
        reweighting to the attached alpha (1 in value)."""
        wo = sp.wo_local
        d = self.distribution
        attached, alpha = roughness_at(self, sp)
        eta = self._eta(sp)
        above = wo[:, 2] > 0
        wo_up = torch.where(above[:, None], wo, torch.tensor([0.0, 0.0, 1.0], device=wo.device))
        h = d.sample_visible(wo_up, alpha, u_dir)
        d_o = dot(wo_up, h).clamp(0.0, 1.0)
        F, cos_t = fresnel_dielectric(d_o, eta)
        reflected = u_lobe < F
        w_r = 2.0 * d_o[:, None] * h - wo_up
        w_t = -wo_up / eta[:, None] + (d_o / eta - cos_t)[:, None] * h
        wl = torch.where(reflected[:, None], w_r, w_t)
        c_i = wl[:, 2]
        ok = above & (d_o > 0) & torch.where(reflected, c_i > 0, (c_i < 0) & (cos_t > 0))
        d_i = dot(wl, h)
        denom = (d_o + eta * d_i).square().clamp_min(1e-12)
        visible = d.G1(wo_up[:, 2], alpha) * d.D(h[:, 2], alpha) / wo_up[:, 2].clamp_min(1e-12)
        pdf = visible * torch.where(reflected, F / 4.0, (1.0 - F) * eta * eta * d_i.abs() * d_o / denom)
        ratio = visible_reweight(d, h[:, 2], wo_up[:, 2], attached, alpha)
        g1 = d.G1(c_i.abs(), alpha) if ratio is None else d.G1(c_i.abs(), attached) * ratio
        g1 = torch.where(ok, g1, 0.0)
        k_r, k_t = self.param("specular_reflectance", sp), self.constant("specular_transmittance", sp)
        weight = torch.where(reflected[:, None], k_r, k_t / (eta * eta)[:, None]) * g1[:, None]
        return BSDFSample(sp.frame.to_world(wl), weight, torch.where(ok, pdf, 0.0), torch.zeros_like(ok))

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        """The indices must differ (an index-matched interface has no half-vector to refract about), and
        their ratio be one real media have (:func:`~invrender.plugins.bsdfs.dielectric.check_relative_ior`)."""
        if constants["int_ior"] == constants["ext_ior"]:
            raise SceneError(f"{where}: 'int_ior' and 'ext_ior' must differ (both {constants['int_ior']:g}): an index-matched interface is not a {cls.type_name}")
        check_relative_ior(where, constants["int_ior"], constants["ext_ior"])
        return constants

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("roughdielectric",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``roughdielectric``: ``distribution`` beckmann (its default: type
        roughdielectric) or ggx (type roughdielectric_ggx), isotropic ``alpha`` (the roughness,
        default 0.1), ``int_ior``/``ext_ior`` (numbers or named media, default bk7 / air),
        ``specular_reflectance`` (a colour or a bitmap texture) and ``specular_transmittance``
        (a colour), default 1, ``sample_visible`` (read; invrender always samples visible normals)."""
        name = (bsdf.string("distribution", allowed=("beckmann", "ggx")) or "beckmann").lower()
        target = RoughDielectric if name == "beckmann" else RoughDielectricGGX
        for key in ("alpha_u", "alpha_v"):
            if bsdf.has(key):
                raise bsdf.error(key, f"'{key}' (anisotropic roughness) is not supported: give one 'alpha'")
        alpha = bsdf.number("alpha", ALPHA, f"{target.distribution.label} roughness", "a <float> (textured roughness is not supported)")
        int_ior, ext_ior = bsdf.ior("int_ior", "bk7"), bsdf.ior("ext_ior", "air")
        kr = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0)
        kt = bsdf.colour("specular_transmittance", SPECULAR_REFLECTANCE, 1.0, texture=False)
        bsdf.boolean("sample_visible")
        bsdf.finish(("distribution", "alpha", "int_ior", "ext_ior", "specular_reflectance", "specular_transmittance", "sample_visible"))
        return {"type": target.type_name, "roughness": alpha, "int_ior": int_ior, "ext_ior": ext_ior, "specular_reflectance": kr, "specular_transmittance": kt}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        alpha = values["roughness"]
        if alpha.ndim != 1:
            raise ValueError("a roughness map has no Mitsuba counterpart here (alpha is written as one number)")
        return {
            "type": "roughdielectric",
            "distribution": cls.distribution.name,
            "alpha": float(alpha[0]),
            "int_ior": float(constants["int_ior"]),
            "ext_ior": float(constants["ext_ior"]),
            "specular_reflectance": values["specular_reflectance"],
            "specular_transmittance": np.asarray(constants.get("specular_transmittance", (1.0, 1.0, 1.0)), dtype=np.float64),
            "sample_visible": True,
        }


@registry.MATERIALS.register
class RoughDielectricGGX(RoughDielectric):
    type_name = "roughdielectric_ggx"
    doc = "rough glass with the GGX distribution (Mitsuba's roughdielectric, distribution ggx)"
    distribution = GGX
    # the same Mitsuba plugin (its distribution picks the type: RoughDielectric.from_mitsuba, inherited)
    mitsuba_plugins = ("roughdielectric",)
