"""The diffuse (Lambertian) BSDF, two-sided: ``f = rho / pi`` on ``wo``'s side of the surface.

Sampling is cosine-weighted, so a sample's weight ``f cos / pdf`` is exactly rho
(``docs/closed_forms.md``, hemisphere integrals). With a shading normal, light arriving below it
(or a ``wo`` below it, at silhouettes) is not reflected, as in Mitsuba's ``diffuse``.
"""

from __future__ import annotations

import math

import torch

from invrender.transport.bsdfs.base import BSDF, BSDFSample, ShadingPoint
from invrender.transport.vec import dot, normalize


class Diffuse(BSDF):
    type_name = "diffuse"
    lobe = "diffuse"

    def _rho(self, sp: ShadingPoint) -> torch.Tensor:
        """rho (N, 3), zero where ``wo`` lies below the shading normal (never without shading normals)."""
        rho = self.param("reflectance", sp)
        return rho if self.flat else rho * (dot(sp.n, sp.wo) > 0)[:, None].to(rho.dtype)

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``rho cos(theta_i) / pi`` (N, 3)."""
        cos_i = dot(sp.n, wi).clamp_min(0.0)
        return self._rho(sp) * (cos_i * (1.0 / math.pi))[:, None]

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``cos(theta_i) / pi`` (N,)."""
        return dot(sp.n, wi).clamp_min(0.0) * (1.0 / math.pi)

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """Cosine-weighted directions about ``n``: weight rho.

        ``normalize(n + s)`` with ``s`` uniform on the unit sphere is cosine-distributed about ``n``
        (the tangent-sphere construction), which needs no tangent frame.
        """
        z = 1.0 - 2.0 * u_dir[:, 0]
        r = (1.0 - z * z).clamp_min(0.0).sqrt()
        phi = (2.0 * math.pi) * u_dir[:, 1]
        s = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=1)
        wi = normalize(sp.n + s)
        return BSDFSample(wi, self._rho(sp), self.pdf(sp, wi), torch.zeros_like(z, dtype=torch.bool))

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor:
        return self.param("reflectance", sp)
