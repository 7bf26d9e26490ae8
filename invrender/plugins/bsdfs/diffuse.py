"""The diffuse (Lambertian) BSDF, two-sided: ``f = rho / pi`` on ``wo``'s side of the surface.

Sampling is cosine-weighted by default, so a sample's weight ``f cos / pdf`` is exactly rho
(``docs/closed_forms.md``, hemisphere integrals); with ``BSDFSampling(hemisphere="uniform")`` it is
uniform over the hemisphere, pdf ``1/(2 pi)`` and weight ``2 rho cos(theta)`` (docs/sampling.md).
With a shading normal, light arriving below it (or a ``wo`` below it, at silhouettes) is not
reflected, as in Mitsuba's ``diffuse``.
"""

from __future__ import annotations

import functools
import math

import torch

from invrender import registry
from invrender.scene.kinds import REFLECTANCE
from invrender.scene.plugins import Param
from invrender.core import lanes
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe, ShadingPoint
from invrender.core.lanes import scale


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


def _lambert(xp, p, wo, cos_i):
    """``rho`` where ``wo`` and ``wi`` (``cos_i``) lie above the shading normal, else 0 (3-tuple)."""
    lit = xp.select((wo[2] > 0.0) & (cos_i > 0.0), 1.0, 0.0)
    return scale(p["reflectance"], lit)


def eval_lanes(xp, p, ps, wo, wi, front, *, uniform: bool):
    """``rho cos(theta_i) / pi`` and the pdf: ``cos(theta_i) / pi`` (cosine sampling) or ``1 / (2 pi)``
    (uniform) above the shading normal, 0 below."""
    cos_i = wi[2]
    f = scale(_lambert(xp, p, wo, cos_i), xp.maximum(cos_i, 0.0) * (1.0 / math.pi))
    pdf = xp.select(cos_i > 0.0, 0.5 / math.pi, 0.0) if uniform else xp.maximum(cos_i, 0.0) * (1.0 / math.pi)
    return f, pdf


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, uniform: bool, frame):
    """Cosine-weighted directions (weight rho) or uniform over the hemisphere (``cos(theta) = u0``,
    ``phi = 2 pi u1``: weight ``2 rho cos(theta)``).

    The cosine-weighted directions are :func:`cosine_lanes` about the shading normal in world
    axes (the sphere's point ``s`` drawn in world coordinates, then the direction brought into the
    shading ``frame``), not about the frame's z: the two are the same distribution, but measured on
    the joint lighting and materials fit (``tests/inverse/test_joint_fit.py``, five seeds) the
    world-axes construction left the fitted albedos 4.9% off on average, the frame's 6.8%."""
    if uniform:
        sin_t = xp.sqrt(xp.maximum(1.0 - u0 * u0, 0.0))
        phi = (2.0 * math.pi) * u1
        wi = (sin_t * xp.cos(phi), sin_t * xp.sin(phi), u0)
        _, pdf = eval_lanes(xp, ps, ps, wo, wi, front, uniform=True)
        weight = scale(_lambert(xp, p, wo, wi[2]), xp.select(pdf > 0.0, 2.0 * u0, 0.0))
    else:
        w, pdf = cosine_lanes(xp, frame[2], u0, u1)
        wi = lanes.to_local(frame, w)
        weight = _lambert(xp, p, wo, wi[2])
    return wi, weight, pdf, xp.full(False, u0)


@registry.MATERIALS.register
class Diffuse(LaneBSDF):
    """Frame-free in the fused Lambertian bounce (every quantity is a cosine with ``n``); written
    once in lane form (:func:`eval_lanes`, :func:`sample_lanes`) for everything else."""

    type_name = "diffuse"
    lobes = Lobe.DIFFUSE
    params = {"reflectance": Param(REFLECTANCE, 0.5)}
    doc = "Lambertian, two-sided: f = rho / pi"

    def lane_form(self) -> LaneForm:
        uniform = self.sampling.hemisphere == "uniform"
        return LaneForm((("reflectance", 3),), functools.partial(eval_lanes, uniform=uniform), functools.partial(sample_lanes, uniform=uniform), world=True)

    def fused_albedo(self) -> torch.Tensor | None:
        """(M, 3) rho of each material, zeros for a textured one (its factors are constants of
        the paths, not parameters the fused bounce differentiates), when sampling is
        cosine-weighted (every sample weight and ``eval`` value is then rho times a factor of the
        geometry, shading normals or not); else None. Not for a subclass that changes what the
        BSDF does (a plugin built on this one)."""
        rho = [v["reflectance"] for v in self.values]
        changed = any(getattr(type(self), m) is not getattr(Diffuse, m) for m in ("eval", "pdf", "sample", "lane_form", "lobes", "params"))
        if changed or self.sampling.hemisphere != "cosine":
            return None
        return torch.stack([r if r.ndim == 1 else r.new_zeros(3) for r in rho])

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

