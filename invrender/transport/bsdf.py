"""The diffuse (Lambertian) BSDF, two-sided: ``f = rho / pi`` on whichever side the light arrives.

Exposes ``eval`` / ``sample`` / ``pdf`` as pbrt does, with the random numbers passed in. Directions
are world-space unit vectors; ``n`` is the shading normal already turned towards the outgoing
direction ``wo``, so both ``wo`` and a valid ``wi`` lie in the hemisphere around ``n``.
"""

from __future__ import annotations

import math

import torch


def eval(rho: torch.Tensor, n: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
    """``f(wi) * cos(theta_i)``: (N, 3) from rho (N, 3), normal (N, 3), incident direction (N, 3)."""
    cos_i = (n * wi).sum(-1, keepdim=True).clamp_min(0.0)
    return rho * (cos_i / math.pi)


def pdf(n: torch.Tensor, wi: torch.Tensor) -> torch.Tensor:
    """Solid-angle density (N,) of cosine-weighted sampling: ``cos(theta_i) / pi``."""
    return (n * wi).sum(-1).clamp_min(0.0) / math.pi


def sample(n: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """Cosine-weighted directions about ``n`` (N, 3) from uniforms ``u`` (N, 2): (N, 3) unit vectors.

    The sample weight ``f cos / pdf`` is exactly ``rho`` (REFERENCES.md, hemisphere integrals).
    Malley's method: a uniform point on the unit disk (concentric map) lifted to the hemisphere.
    """
    a = 2.0 * u[:, 0] - 1.0
    b = 2.0 * u[:, 1] - 1.0
    use_a = a.abs() > b.abs()
    r = torch.where(use_a, a, b)
    phi = torch.where(use_a, (math.pi / 4) * b / torch.where(a == 0, 1.0, a), math.pi / 2 - (math.pi / 4) * a / torch.where(b == 0, 1.0, b))
    x, y = r * torch.cos(phi), r * torch.sin(phi)
    z = (1.0 - x * x - y * y).clamp_min(0.0).sqrt()
    s, t = orthonormal_basis(n)
    return x[:, None] * s + y[:, None] * t + z[:, None] * n


def orthonormal_basis(n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit tangents ``(s, t)`` (N, 3) completing ``n`` to a right-handed frame (Duff et al. 2017)."""
    sign = torch.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = torch.stack([1.0 + sign * n[:, 0] * n[:, 0] * a, sign * b, -sign * n[:, 0]], dim=1)
    t = torch.stack([b, sign + n[:, 1] * n[:, 1] * a, -n[:, 1]], dim=1)
    return s, t
