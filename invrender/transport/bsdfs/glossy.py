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

import math

import torch

from invrender.transport.bsdfs.base import BSDF, BSDFSample, ShadingPoint
from invrender.transport.frame import Frame
from invrender.vec import dot, normalize


def ggx_D(cos_h: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """GGX normal distribution D(h) (N,) for cosines of h with the normal ``cos_h`` (N,)."""
    a2 = alpha * alpha
    c2 = cos_h * cos_h
    d = c2 * (a2 - 1.0) + 1.0
    return torch.where(cos_h > 0, a2 / (math.pi * d * d).clamp_min(1e-30), 0.0)


def smith_G1(cos_v: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Smith's masking G1 (N,) of a direction with cosine ``cos_v`` (N,) to the normal (0 below)."""
    c2 = (cos_v * cos_v).clamp_min(1e-12)
    tan2 = (1.0 - c2).clamp_min(0.0) / c2
    return torch.where(cos_v > 0, 2.0 / (1.0 + (1.0 + alpha * alpha * tan2).sqrt()), 0.0)


def sample_visible_normal(wo_local: torch.Tensor, alpha: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Heitz (2018): a GGX normal (N, 3), local frame, visible from ``wo_local`` (N, 3) (z > 0)."""
    vh = normalize(torch.stack([alpha * wo_local[:, 0], alpha * wo_local[:, 1], wo_local[:, 2]], dim=1))
    lensq = vh[:, 0] ** 2 + vh[:, 1] ** 2
    inv = torch.where(lensq > 0, lensq.clamp_min(1e-30).rsqrt(), 0.0)
    t1 = torch.where((lensq > 0)[:, None], torch.stack([-vh[:, 1] * inv, vh[:, 0] * inv, torch.zeros_like(inv)], dim=1), torch.tensor([1.0, 0.0, 0.0], device=u.device))
    t2 = torch.linalg.cross(vh, t1)
    r = u[:, 0].sqrt()
    phi = (2.0 * math.pi) * u[:, 1]
    p1, p2 = r * torch.cos(phi), r * torch.sin(phi)
    s = 0.5 * (1.0 + vh[:, 2])
    p2 = (1.0 - s) * (1.0 - p1 * p1).clamp_min(0.0).sqrt() + s * p2
    p3 = (1.0 - p1 * p1 - p2 * p2).clamp_min(0.0).sqrt()
    nh = p1[:, None] * t1 + p2[:, None] * t2 + p3[:, None] * vh
    return normalize(torch.stack([alpha * nh[:, 0], alpha * nh[:, 1], nh[:, 2].clamp_min(1e-6)], dim=1))


class Glossy(BSDF):
    type_name = "glossy"
    lobe = "glossy"

    def _local(self, sp: ShadingPoint, wi: torch.Tensor):
        frame = Frame.from_normal(sp.n)
        return frame, frame.to_local(sp.wo), frame.to_local(wi), self.constant("roughness", sp)

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
        frame = Frame.from_normal(sp.n)
        wo = frame.to_local(sp.wo)
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
