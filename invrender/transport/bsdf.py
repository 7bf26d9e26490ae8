"""The diffuse (Lambertian) BSDF, two-sided: ``f = rho / pi`` on whichever side the light arrives.

Exposes ``eval`` / ``sample`` / ``pdf`` as pbrt does, with the random numbers passed in. Directions
are world-space unit vectors; ``n`` is the shading normal already turned towards the outgoing
direction ``wo``, so both ``wo`` and a valid ``wi`` lie in the hemisphere around ``n``.
"""

from __future__ import annotations

import math

import torch

from invrender.transport.vec import dot, normalize


def eval(rho: torch.Tensor, n: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
    """``f(wi) * cos(theta_i)``: (N, 3) from rho (N, 3), normal (N, 3), incident direction (N, 3)."""
    return rho * (dot(n, wi).clamp_min(0.0) / math.pi)[:, None]


def pdf(n: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
    """Solid-angle density (N,) of cosine-weighted sampling: ``cos(theta_i) / pi``."""
    return dot(n, wi).clamp_min(0.0) / math.pi


def sample(n: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Cosine-weighted directions about ``n`` (N, 3) from uniforms ``u`` (N, 2): (N, 3) unit vectors.

    The sample weight ``f cos / pdf`` is exactly ``rho`` (REFERENCES.md, hemisphere integrals).
    ``normalize(n + s)`` with ``s`` uniform on the unit sphere is cosine-distributed about ``n``
    (the tangent-sphere construction), which needs no tangent frame.
    """
    z = 1.0 - 2.0 * u[:, 0]
    r = (1.0 - z * z).clamp_min(0.0).sqrt()
    phi = (2.0 * math.pi) * u[:, 1]
    s = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=1)
    wi = n + s
    return normalize(wi)
