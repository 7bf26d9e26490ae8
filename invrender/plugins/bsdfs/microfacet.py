"""Microfacet distributions shared by the microfacet materials: GGX and Beckmann, each with its
normal density D, its Smith masking G1 and the sampling of visible normals, in the forms Mitsuba 3
uses (``include/mitsuba/render/microfacet.h``), so that renders can be compared.

A material holds one :class:`Distribution` (:data:`GGX` or :data:`BECKMANN`, by name in
:data:`DISTRIBUTIONS`) and calls the same four methods whichever it is:

- :meth:`Distribution.D` (the normal density, per unit projected area: ``int D cos_h dw = 1``);
- :meth:`Distribution.G1` (separable Smith masking, 0 below the surface);
- :meth:`Distribution.sample_visible` (a normal h drawn from the distribution of normals visible
  from ``wo``, density ``G1(wo) max(0, wo.h) D(h) / cos_o``);
- :meth:`Distribution.visible_pdf` (that density, as the material's ``pdf`` needs it).

GGX (Trowbridge-Reitz; Walter et al., "Microfacet Models for Refraction through Rough Surfaces",
EGSR 2007):

- ``D(h) = alpha^2 / (pi (cos_h^2 (alpha^2 - 1) + 1)^2)``;
- ``G1(v) = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta_v))`` (exact for GGX);
- visible normals by Heitz, "Sampling the GGX Distribution of Visible Normals", JCGT 7(4), 2018.

Beckmann (Gaussian random surfaces; alpha is the RMS slope):

- ``D(h) = exp(-tan^2 theta_h / alpha^2) / (pi alpha^2 cos^4 theta_h)``;
- ``G1`` is Walter et al.'s rational approximation of the exact Smith term
  ``2 / (1 + erf(a) + exp(-a^2) / (a sqrt(pi)))``, ``a = 1 / (alpha tan theta_v)``: 1 for
  ``a >= 1.6``, else ``(3.535 a + 2.181 a^2) / (1 + 2.276 a + 2.577 a^2)`` (below 0.35% relative
  error), as Mitsuba 3's ``smith_g1`` does: renders match Mitsuba's at grazing angles;
- visible normals by Heitz and d'Eon ("Importance Sampling Microfacet-Based BSDFs using the
  Distribution of Visible Normals", EGSR 2014): ``wo`` stretched by alpha, slopes of the alpha = 1
  distribution drawn by Jakob's numerical inversion ("An Improved Visible Normal Sampling Routine
  for the Beckmann Distribution", 2014: an analytic first guess, three Newton steps in the erf
  domain; in float32, as Mitsuba's single-precision variants), rotated and unstretched.

Each is written once against the array interface (``*_lanes``: :mod:`invrender.core.lanes`); the
torch functions below evaluate them as eager torch, and the compiled bounce compiles them. The samples follow the exact Smith normalization; ``pdf`` uses
  the rational G1 (as Mitsuba's does), so the two differ by that approximation's error at most.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import torch
import torch.autograd.forward_ad as fwAD

from invrender.core.compiled import TORCH
from invrender.vec import dot, normalize


# ---------------------------------------------------------------- GGX, as functions (the GGX material's originals)


def ggx_D_lanes(xp, cos_h, alpha):
    """GGX normal distribution D(h) for cosines of h with the normal ``cos_h`` (the array
    interface: :mod:`invrender.core.lanes`; arrays or (N,) tensors with ``TORCH``)."""
    a2 = alpha * alpha
    c2 = cos_h * cos_h
    d = c2 * (a2 - 1.0) + 1.0
    return xp.select(cos_h > 0.0, a2 / xp.maximum(math.pi * d * d, 1e-30), 0.0)


def ggx_G1_lanes(xp, cos_v, alpha):
    """GGX's Smith masking G1 of a direction with cosine ``cos_v`` to the normal (0 below)."""
    c2 = xp.maximum(cos_v * cos_v, 1e-12)
    tan2 = xp.maximum(1.0 - c2, 0.0) / c2
    return xp.select(cos_v > 0.0, 2.0 / (1.0 + xp.sqrt(1.0 + alpha * alpha * tan2)), 0.0)


def ggx_visible_lanes(xp, wo, alpha, u0, u1, alpha_y=None):
    """Heitz (2018): a GGX normal (a 3-tuple, local frame) visible from ``wo`` (z > 0), from
    uniforms ``u0``, ``u1``; anisotropic with roughness ``alpha`` along x and ``alpha_y`` along y
    where ``alpha_y`` is given."""
    ay = alpha if alpha_y is None else alpha_y
    vh = normalized(xp, (alpha * wo[0], ay * wo[1], wo[2]))
    lensq = vh[0] * vh[0] + vh[1] * vh[1]
    inv = xp.select(lensq > 0.0, 1.0 / xp.sqrt(xp.maximum(lensq, 1e-30)), 0.0)
    flat = lensq > 0.0
    t1 = (xp.select(flat, -vh[1] * inv, 1.0), xp.select(flat, vh[0] * inv, 0.0), 0.0 * inv)
    t2 = (vh[1] * t1[2] - vh[2] * t1[1], vh[2] * t1[0] - vh[0] * t1[2], vh[0] * t1[1] - vh[1] * t1[0])
    r = xp.sqrt(u0)
    phi = (2.0 * math.pi) * u1
    p1, p2 = r * xp.cos(phi), r * xp.sin(phi)
    s = 0.5 * (1.0 + vh[2])
    p2 = (1.0 - s) * xp.sqrt(xp.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    p3 = xp.sqrt(xp.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))
    nh = tuple(p1 * a + p2 * b + p3 * c for a, b, c in zip(t1, t2, vh))
    return normalized(xp, (alpha * nh[0], ay * nh[1], xp.maximum(nh[2], 1e-6)))


def normalized(xp, v):
    """``v / |v|`` (a 3-tuple; 0 stays 0)."""
    length = xp.maximum(xp.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]), 1e-30)
    return (v[0] / length, v[1] / length, v[2] / length)


def ggx_D(cos_h: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """GGX normal distribution D(h) (N,) for cosines of h with the normal ``cos_h`` (N,)."""
    return ggx_D_lanes(TORCH, cos_h, alpha)


def smith_G1(cos_v: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """GGX's Smith masking G1 (N,) of a direction with cosine ``cos_v`` (N,) to the normal (0 below)."""
    return ggx_G1_lanes(TORCH, cos_v, alpha)


def sample_visible_normal(wo_local: torch.Tensor, alpha: torch.Tensor, u: torch.Tensor, alpha_y: torch.Tensor | None = None) -> torch.Tensor:
    """Heitz (2018): a GGX normal (N, 3), local frame, visible from ``wo_local`` (N, 3) (z > 0):
    :func:`ggx_visible_lanes` as eager torch."""
    return torch.stack(ggx_visible_lanes(TORCH, tuple(wo_local.unbind(1)), alpha, u[:, 0], u[:, 1], alpha_y), dim=1)


# ---------------------------------------------------------------- anisotropic GGX, on whole vectors


def ggx_D_aniso(m: torch.Tensor, alpha_x: torch.Tensor, alpha_y: torch.Tensor) -> torch.Tensor:
    """Anisotropic GGX density D(m) (N,) of local normals ``m`` (N, 3) with roughness ``alpha_x``
    (N,) along x and ``alpha_y`` (N,) along y: ``1 / (pi ax ay ((mx/ax)^2 + (my/ay)^2 + mz^2)^2)``,
    0 where ``D cos_m <= 1e-20`` (as Mitsuba's, which is also where m points below)."""
    q = (m[:, 0] / alpha_x).square() + (m[:, 1] / alpha_y).square() + m[:, 2].square()
    d = 1.0 / (math.pi * alpha_x * alpha_y * q.square()).clamp_min(1e-30)
    return torch.where(d * m[:, 2] > 1e-20, d, 0.0)


def ggx_G1_aniso(v: torch.Tensor, m: torch.Tensor, alpha_x: torch.Tensor, alpha_y: torch.Tensor) -> torch.Tensor:
    """Anisotropic GGX Smith masking G1 (N,) of directions ``v`` (N, 3) on microfacets ``m`` (N, 3):
    ``2 / (1 + sqrt(1 + (ax^2 vx^2 + ay^2 vy^2) / vz^2))``, 1 at normal incidence, 0 where ``v``
    sees the microfacet's back (``(v.m) vz <= 0``), Mitsuba's ``smith_g1``."""
    xy = (alpha_x * v[:, 0]).square() + (alpha_y * v[:, 1]).square()
    g = 2.0 / (1.0 + (1.0 + xy / v[:, 2].square().clamp_min(1e-30)).sqrt())
    g = torch.where(xy == 0, 1.0, g)
    return torch.where(dot(v, m) * v[:, 2] <= 0, 0.0, g)


def ggx_visible_pdf_aniso(v: torch.Tensor, m: torch.Tensor, alpha_x: torch.Tensor, alpha_y: torch.Tensor) -> torch.Tensor:
    """Density (N,) of :func:`sample_visible_normal` drawing ``m`` (N, 3) seen from ``v`` (N, 3),
    ``vz > 0``: ``D(m) G1(v, m) |v.m| / vz``."""
    return ggx_D_aniso(m, alpha_x, alpha_y) * ggx_G1_aniso(v, m, alpha_x, alpha_y) * dot(v, m).abs() / v[:, 2]


# ---------------------------------------------------------------- Beckmann, as functions


def beckmann_D_lanes(xp, cos_h, alpha):
    """Beckmann normal distribution D(h) for cosines ``cos_h`` (0 where Mitsuba's is: ``D cos_h <=
    1e-20``), written against the array interface."""
    c2 = xp.maximum(cos_h * cos_h, 1e-30)
    a2 = alpha * alpha
    d = xp.exp(-(xp.maximum(1.0 - c2, 0.0) / c2) / a2) / (math.pi * a2 * c2 * c2)
    return xp.select((cos_h > 0.0) & (d * cos_h > 1e-20), d, 0.0)


def beckmann_G1_lanes(xp, cos_v, alpha):
    """Beckmann's Smith masking G1, Walter et al.'s rational approximation (Mitsuba 3's form), for
    cosines ``cos_v`` (1 at normal incidence, 0 below)."""
    c2 = xp.maximum(cos_v * cos_v, 1e-30)
    s2 = xp.maximum(1.0 - c2, 0.0)
    a = xp.sqrt(c2 / xp.maximum(alpha * alpha * s2, 1e-30))  # 1 / (alpha tan theta)
    g = xp.select(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a))
    return xp.select(cos_v > 0.0, xp.select(s2 > 0.0, g, 1.0), 0.0)


#: the largest |erf| argument the slope inversion hands ``erfinv`` (float32's last value below 1)
_ERF_EDGE = 1.0 - 2.0**-24


def beckmann_slopes_lanes(xp, cos_theta, u0, u1):
    """Slopes (a 2-tuple) of Beckmann normals of roughness 1 visible from a direction at
    ``cos_theta`` in the xz plane (x towards it), from uniforms ``u0``, ``u1``: Jakob's inversion
    (module docstring) in float32, as Mitsuba 3's single-precision variants compute it."""
    c = xp.minimum(xp.maximum(cos_theta, 1e-7), 1.0)
    v0, v1 = (xp.minimum(xp.maximum(u, 1e-6), 1.0 - 1e-6) for u in (u0, u1))
    tan_t = xp.sqrt(xp.maximum(1.0 - c * c, 0.0)) / c
    cot_t = 1.0 / xp.maximum(tan_t, 1e-30)
    inv_sqrt_pi = 1.0 / math.sqrt(math.pi)
    maxval = xp.erf(cot_t)
    x = maxval - (maxval + 1.0) * xp.erf(xp.sqrt(-xp.log(v0)))
    target = v0 * (1.0 + maxval + inv_sqrt_pi * tan_t * xp.exp(-cot_t * cot_t))
    for _ in range(3):  # Newton steps in the erf domain
        slope = xp.erfinv(xp.minimum(xp.maximum(x, -_ERF_EDGE), _ERF_EDGE))
        value = 1.0 + x + inv_sqrt_pi * tan_t * xp.exp(-slope * slope) - target
        x = x - value / (1.0 - slope * tan_t)
    clamp = lambda y: xp.minimum(xp.maximum(y, -_ERF_EDGE), _ERF_EDGE)  # noqa: E731
    return xp.erfinv(clamp(x)), xp.erfinv(clamp(2.0 * v1 - 1.0))


def beckmann_visible_lanes(xp, wo, alpha, u0, u1):
    """Heitz and d'Eon (2014) with Jakob's slopes: a Beckmann normal (a 3-tuple, local frame)
    visible from ``wo`` (z > 0)."""
    wp = normalized(xp, (alpha * wo[0], alpha * wo[1], wo[2]))
    sin2 = wp[0] * wp[0] + wp[1] * wp[1]
    tilted = sin2 > 1e-14
    inv = 1.0 / xp.sqrt(xp.maximum(sin2, 1e-30))
    cos_phi = xp.select(tilted, xp.minimum(xp.maximum(wp[0] * inv, -1.0), 1.0), 1.0)
    sin_phi = xp.select(tilted, xp.minimum(xp.maximum(wp[1] * inv, -1.0), 1.0), 0.0)
    s0, s1 = beckmann_slopes_lanes(xp, wp[2], u0, u1)
    sx = (cos_phi * s0 - sin_phi * s1) * alpha
    sy = (sin_phi * s0 + cos_phi * s1) * alpha
    return normalized(xp, (-sx, -sy, 1.0 + 0.0 * sx))


def beckmann_D(cos_h: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Beckmann normal distribution D(h) (N,) for cosines ``cos_h`` (N,)."""
    return beckmann_D_lanes(TORCH, cos_h, alpha)


def beckmann_G1(cos_v: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Beckmann's Smith masking G1 (N,) for cosines ``cos_v`` (N,)."""
    return beckmann_G1_lanes(TORCH, cos_v, alpha)


def beckmann_sample_visible(wo_local: torch.Tensor, alpha: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """A Beckmann normal (N, 3) visible from ``wo_local`` (N, 3): :func:`beckmann_visible_lanes` as
    eager torch."""
    return torch.stack(beckmann_visible_lanes(TORCH, tuple(wo_local.unbind(1)), alpha, u[:, 0], u[:, 1]), dim=1)


# ---------------------------------------------------------------- the interface materials use


class Distribution(ABC):
    """A microfacet normal distribution of roughness alpha (isotropic), in a material's local
    frame (normal +z). Every tensor argument is (N,) or (N, 3); alpha (N,) per point."""

    #: the name scene files give it (Mitsuba's ``distribution``), and how messages spell it
    name: str
    label: str
    #: its D, G1 and visible-normal sampling written against the array interface (``(xp, cos_h,
    #: alpha)``, ``(xp, cos_v, alpha)``, ``(xp, wo, alpha, u0, u1)``): the torch methods evaluate them
    D_lanes: staticmethod
    G1_lanes: staticmethod
    visible_lanes: staticmethod

    @abstractmethod
    def D(self, cos_h: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """The normal density D(h) (N,) at cosines ``cos_h`` of h with the normal."""

    @abstractmethod
    def G1(self, cos_v: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """Smith's masking (N,) of directions at cosines ``cos_v`` (0 below the surface)."""

    @abstractmethod
    def sample_visible(self, wo_local: torch.Tensor, alpha: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """A normal (N, 3) visible from ``wo_local`` (N, 3) (z > 0), from uniforms ``u`` (N, 2)."""

    def visible_pdf(self, cos_o: torch.Tensor, cos_h: torch.Tensor, wo_dot_h: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """Density (N,) of :meth:`sample_visible` drawing a normal at ``cos_h`` with ``wo . h =
        wo_dot_h`` for ``wo`` at ``cos_o``: ``G1(wo) max(0, wo.h) D(h) / cos_o``."""
        return self.G1(cos_o, alpha) * wo_dot_h.clamp_min(0.0) * self.D(cos_h, alpha) / cos_o.clamp_min(1e-12)

    def __repr__(self) -> str:
        return f"<{self.name} microfacet distribution>"


class _GGX(Distribution):
    name, label = "ggx", "GGX"
    D_lanes, G1_lanes, visible_lanes = staticmethod(ggx_D_lanes), staticmethod(ggx_G1_lanes), staticmethod(ggx_visible_lanes)

    def D(self, cos_h, alpha):
        return ggx_D(cos_h, alpha)

    def G1(self, cos_v, alpha):
        return smith_G1(cos_v, alpha)

    def sample_visible(self, wo_local, alpha, u):
        return sample_visible_normal(wo_local, alpha, u)


class _Beckmann(Distribution):
    name, label = "beckmann", "Beckmann"
    D_lanes, G1_lanes, visible_lanes = staticmethod(beckmann_D_lanes), staticmethod(beckmann_G1_lanes), staticmethod(beckmann_visible_lanes)

    def D(self, cos_h, alpha):
        return beckmann_D(cos_h, alpha)

    def G1(self, cos_v, alpha):
        return beckmann_G1(cos_v, alpha)

    def sample_visible(self, wo_local, alpha, u):
        return beckmann_sample_visible(wo_local, alpha, u)


GGX: Distribution = _GGX()
BECKMANN: Distribution = _Beckmann()

#: the distributions by name (Mitsuba's ``distribution`` values)
DISTRIBUTIONS: dict[str, Distribution] = {d.name: d for d in (GGX, BECKMANN)}


# ---------------------------------------------------------------- a differentiable roughness


def roughness_at(bsdf, sp, key: str = "roughness") -> tuple[torch.Tensor, torch.Tensor]:
    """The roughness of a material's parameter ``key`` (kind ``roughness``: three equal channels)
    at the points ``sp``: ``(alpha, alpha_s)``, both (N,).

    ``alpha`` is what ``eval`` and the sample weight read: differentiable (the gradient of the
    channels' mean, its value channel 0's exactly, so a render is bit-identical to one with the
    same roughness as a constant). ``alpha_s`` is what sampling and ``pdf`` read: detached, and
    held at the unperturbed value where a render freezes sampling (``sampling_params``)."""
    v = bsdf.param(key, sp)
    alpha = v[:, 0]
    if v.requires_grad or fwAD_active(v):
        m = v.mean(dim=1)
        alpha = alpha.detach() + (m - m.detach())
    return alpha, bsdf.sampling_param(key, sp)[:, 0]


def fwAD_active(v: torch.Tensor) -> bool:
    """Does ``v`` carry a forward-mode tangent (a record's trace)?"""
    return fwAD.unpack_dual(v).tangent is not None


def visible_reweight(d: Distribution, cos_h: torch.Tensor, cos_o: torch.Tensor, alpha: torch.Tensor, alpha_s: torch.Tensor) -> torch.Tensor | None:
    """The factor (N,) that turns a visible-normal sample weight of roughness ``alpha_s`` into the
    weight ``f(alpha) cos_i / pdf(alpha_s)`` of a BRDF of roughness ``alpha``:
    ``D(h; alpha) G1(wo; alpha) / (D(h; alpha_s) G1(wo; alpha_s))`` (1 where the sampling density
    vanishes). Its value is exactly 1 where ``alpha == alpha_s``; its derivative in ``alpha`` is what
    the weight's roughness gradient needs. None where nothing differs (no gradient, no frozen
    sampling): the weight needs no factor."""
    if not alpha.requires_grad and not fwAD_active(alpha) and torch.equal(alpha, alpha_s):
        return None
    num = d.D(cos_h, alpha) * d.G1(cos_o, alpha)
    den = (d.D(cos_h, alpha_s) * d.G1(cos_o, alpha_s)).detach()
    return torch.where(den > 0, num / torch.where(den > 0, den, 1.0), 1.0)
