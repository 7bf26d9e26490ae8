"""The GGX (Trowbridge-Reitz) microfacet distribution: its normal density, Smith masking and the
sampling of visible normals, shared by the microfacet materials.

- D(h) = alpha^2 / (pi (cos_h^2 (alpha^2 - 1) + 1)^2) (Walter et al., "Microfacet Models for
  Refraction through Rough Surfaces", EGSR 2007);
- separable Smith masking G1(v) = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta_v));
- visible normals (Heitz, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4), 2018),
  drawn with density ``G1(wo) max(0, wo.h) D(h) / cos_o``.
"""

from __future__ import annotations

import math

import torch

from invrender.vec import normalize


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
