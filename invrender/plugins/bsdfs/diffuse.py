"""The diffuse (Lambertian) BSDF, two-sided: ``f = rho / pi`` on ``wo``'s side of the surface.

Sampling is cosine-weighted by default, so a sample's weight ``f cos / pdf`` is exactly rho
(``docs/closed_forms.md``, hemisphere integrals); with ``BSDFSampling(hemisphere="uniform")`` it is
uniform over the hemisphere, pdf ``1/(2 pi)`` and weight ``2 rho cos(theta)`` (docs/sampling.md).
With a shading normal, light arriving below it (or a ``wo`` below it, at silhouettes) is not
reflected, as in Mitsuba's ``diffuse``.
"""

from __future__ import annotations

import math

import torch

from invrender import registry
from invrender.scene.kinds import REFLECTANCE
from invrender.scene.plugins import Param
from invrender.backends import kernels
from invrender.core import lanes
from invrender.core.bsdf import BSDF, BSDFSample, Lobe, ShadingPoint
from invrender.vec import dot, normalize


def cosine_lanes(xp, n, u0, u1):
    """Cosine-weighted directions about unit normals ``n`` (a 3-tuple of (N,) arrays) from uniforms
    ``u0``, ``u1`` (N,), written against the array interface (:mod:`invrender.core.lanes`):
    ``normalize(n + s)`` with ``s`` uniform on the unit sphere (the tangent-sphere construction,
    which needs no tangent frame). Returns (directions, their pdf ``max(n . w, 0) / pi``)."""
    z = 1.0 - 2.0 * u0
    r = xp.sqrt(xp.maximum(1.0 - z * z, 0.0))
    phi = (2.0 * math.pi) * u1
    a = (n[0] + r * xp.cos(phi), n[1] + r * xp.sin(phi), n[2] + z)
    length = xp.maximum(xp.sqrt(lanes.dot(a, a)), 1e-30)
    w = (a[0] / length, a[1] / length, a[2] / length)
    return w, xp.maximum(lanes.dot(n, w), 0.0) * (1.0 / math.pi)


@registry.MATERIALS.register
class Diffuse(BSDF):
    """Frame-free: every quantity is a cosine with ``n``, so it never builds the shading frame
    (except for uniform hemisphere sampling)."""

    type_name = "diffuse"
    lobes = Lobe.DIFFUSE
    params = {"reflectance": Param(REFLECTANCE, 0.5)}
    doc = "Lambertian, two-sided: f = rho / pi"

    def _rho(self, sp: ShadingPoint) -> torch.Tensor:
        """rho (N, 3), zero where ``wo`` lies below the shading normal (never without shading normals)."""
        rho = self.param("reflectance", sp)
        return rho if self.flat else rho * (dot(sp.n, sp.wo) > 0)[:, None].to(rho.dtype)

    sample_lanes = staticmethod(cosine_lanes)

    def fused_albedo(self) -> torch.Tensor | None:
        """(M, 3) rho of each material, when none is textured, sampling is cosine-weighted and the
        scene has no shading normals (the fused bounce's Lambertian lobe); else None. Not for a
        subclass that changes what the BSDF does (a plugin built on this one)."""
        rho = [v["reflectance"] for v in self.values]
        changed = any(getattr(type(self), m) is not getattr(Diffuse, m) for m in ("eval", "pdf", "sample", "_rho", "lobes", "params"))
        if changed or not self.flat or self.sampling.hemisphere != "cosine" or any(r.ndim != 1 for r in rho):
            return None
        return torch.stack(rho)

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``rho cos(theta_i) / pi`` (N, 3)."""
        cos_i = dot(sp.n, wi).clamp_min(0.0)
        return self._rho(sp) * (cos_i * (1.0 / math.pi))[:, None]

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """(N,): ``cos(theta_i) / pi`` (cosine sampling) or ``1 / (2 pi)`` above the shading normal
        (uniform sampling); 0 below it."""
        cos_i = dot(sp.n, wi)
        if self.sampling.hemisphere == "uniform":
            return (cos_i > 0).to(cos_i.dtype) * (0.5 / math.pi)
        return cos_i.clamp_min(0.0) * (1.0 / math.pi)

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """Directions about ``n`` from ``u_dir`` (N, 2), cosine-weighted (weight rho) or uniform
        (weight ``2 rho cos(theta_i)``)."""
        if self.sampling.hemisphere == "uniform":
            return self._sample_uniform(sp, u_dir)
        return self._sample_cosine(sp, u_dir)

    def _sample_cosine(self, sp: ShadingPoint, u_dir: torch.Tensor) -> BSDFSample:
        """Cosine-weighted directions: weight rho.

        ``normalize(n + s)`` with ``s`` uniform on the unit sphere is cosine-distributed about ``n``
        (the tangent-sphere construction), which needs no tangent frame; one fused kernel where
        :mod:`~invrender.backends.kernels` runs.
        """
        if kernels.enabled(sp.n.device):
            wi, pdf = kernels.cosine_directions(sp.n, u_dir)
        else:
            z = 1.0 - 2.0 * u_dir[:, 0]
            r = (1.0 - z * z).clamp_min(0.0).sqrt()
            phi = (2.0 * math.pi) * u_dir[:, 1]
            wi = normalize(sp.n + torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=1))
            pdf = self.pdf(sp, wi)
        return BSDFSample(wi, self._rho(sp), pdf, torch.zeros(wi.shape[0], dtype=torch.bool, device=wi.device))

    def _sample_uniform(self, sp: ShadingPoint, u_dir: torch.Tensor) -> BSDFSample:
        """Directions uniform over the hemisphere of ``n``: ``cos(theta) = u_0`` (the solid angle is
        uniform in cos theta), ``phi = 2 pi u_1``; weight ``(rho cos / pi) / (1 / (2 pi)) = 2 rho cos``."""
        cos_t = u_dir[:, 0]
        sin_t = (1.0 - cos_t * cos_t).clamp_min(0.0).sqrt()
        phi = (2.0 * math.pi) * u_dir[:, 1]
        local = torch.stack([sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t], dim=1)
        wi = sp.frame.to_world(local)
        pdf = self.pdf(sp, wi)
        weight = self._rho(sp) * torch.where(pdf > 0, 2.0 * cos_t, 0.0)[:, None]
        return BSDFSample(wi, weight, pdf, torch.zeros_like(cos_t, dtype=torch.bool))

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor:
        return self.param("reflectance", sp)

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("diffuse",)
    gltf_priority = 100  # the fallback: every other glTF/OBJ material

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``diffuse``: ``reflectance`` (colour or bitmap texture, default 0.5)."""
        rho = bsdf.colour("reflectance", REFLECTANCE, 0.5)
        bsdf.finish(("reflectance",))
        return {"reflectance": rho}

    @classmethod
    def from_gltf(cls, material) -> dict:
        """Any glTF/OBJ material the others do not take: rho = its base colour (or Kd x map_Kd)."""
        return {"reflectance": material.base_colour}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": values["reflectance"]}}

