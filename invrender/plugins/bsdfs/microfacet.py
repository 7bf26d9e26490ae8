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

Each is written once as a lane function (``*_lanes``, against the array interface of
:mod:`invrender.core.lanes`: the materials' lane forms call them, eager or compiled); the torch
methods and helpers are the same functions evaluated with ``TORCH``. The anisotropic terms of both
(``*_aniso_lanes``: roughness ``alpha_u`` along the shading frame's tangent s, ``alpha_v`` along t,
Mitsuba's forms; the anisotropic conductors and dielectrics and the principled materials read them)
likewise.

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
  domain), rotated and unstretched. The samples follow the exact Smith normalization; ``pdf`` uses
  the rational G1 (as Mitsuba's does), so the two differ by that approximation's error at most.
"""

from __future__ import annotations

import math
from abc import ABC
from collections.abc import Callable

import torch
import torch.autograd.forward_ad as fwAD

from invrender.core.bsdf import TORCH, grey_channel
from invrender.core.lanes import add, dot, normalize, scale

# Lane functions take ``xp`` first (eager torch or Dr.Jit) and arrays of one shape (3-vectors as
# tuples); evaluated with TORCH they keep the input's dtype.


# ---------------------------------------------------------------- GGX


def ggx_D_lanes(xp, cos_h, alpha):
    """GGX normal density D(h) at cosines ``cos_h`` of h with the normal (0 below)."""
    a2 = alpha * alpha
    d = cos_h * cos_h * (a2 - 1.0) + 1.0
    return xp.select(cos_h > 0.0, a2 / xp.maximum(math.pi * d * d, 1e-30), 0.0)


def ggx_G1_lanes(xp, cos_v, alpha):
    """GGX's Smith masking G1 of a direction at cosine ``cos_v`` to the normal (0 below)."""
    c2 = xp.maximum(cos_v * cos_v, 1e-12)
    tan2 = xp.maximum(1.0 - c2, 0.0) / c2
    return xp.select(cos_v > 0.0, 2.0 / (1.0 + xp.sqrt(1.0 + alpha * alpha * tan2)), 0.0)


def ggx_sample_visible_lanes(xp, wo, alpha_x, alpha_y, u0, u1):
    """Heitz (2018): a GGX normal (a 3-tuple, local frame) visible from ``wo`` (z > 0), roughness
    ``alpha_x`` along x and ``alpha_y`` along y (the same array for an isotropic one), from
    uniforms ``u0``, ``u1``."""
    vh = normalize(xp, (alpha_x * wo[0], alpha_y * wo[1], wo[2]))
    lensq = vh[0] * vh[0] + vh[1] * vh[1]
    tilted = lensq > 0.0
    inv = xp.select(tilted, 1.0 / xp.sqrt(xp.maximum(lensq, 1e-30)), 0.0)
    t1 = (xp.select(tilted, -vh[1] * inv, 1.0), vh[0] * inv, 0.0 * inv)  # (1, 0, 0) at normal incidence
    t2 = (-vh[2] * t1[1], vh[2] * t1[0], vh[0] * t1[1] - vh[1] * t1[0])  # vh x t1 (t1 has no z)
    r = xp.sqrt(u0)
    phi = (2.0 * math.pi) * u1
    p1, p2 = r * xp.cos(phi), r * xp.sin(phi)
    s = 0.5 * (1.0 + vh[2])
    p2 = (1.0 - s) * xp.sqrt(xp.maximum(1.0 - p1 * p1, 0.0)) + s * p2
    p3 = xp.sqrt(xp.maximum(1.0 - p1 * p1 - p2 * p2, 0.0))
    nh = add(add(scale(t1, p1), scale(t2, p2)), scale(vh, p3))
    return normalize(xp, (alpha_x * nh[0], alpha_y * nh[1], xp.maximum(nh[2], 1e-6)))


def ggx_D_aniso_lanes(xp, m, alpha_x, alpha_y):
    """Anisotropic GGX density D(m) of local normals ``m`` (a 3-tuple), roughness ``alpha_x``
    along x and ``alpha_y`` along y: ``1 / (pi ax ay ((mx/ax)^2 + (my/ay)^2 + mz^2)^2)``, 0 where
    ``D cos_m <= 1e-20`` (as Mitsuba's, which is also where m points below)."""
    x, y = m[0] / alpha_x, m[1] / alpha_y
    q = x * x + y * y + m[2] * m[2]
    d = 1.0 / xp.maximum(math.pi * alpha_x * alpha_y * (q * q), 1e-30)
    return xp.select(d * m[2] > 1e-20, d, 0.0)


def ggx_G1_aniso_lanes(xp, v, m, alpha_x, alpha_y):
    """Anisotropic GGX Smith masking G1 of directions ``v`` on microfacets ``m`` (3-tuples):
    ``2 / (1 + sqrt(1 + (ax^2 vx^2 + ay^2 vy^2) / vz^2))``, 1 at normal incidence, 0 where ``v``
    sees the microfacet's back (``(v.m) vz <= 0``), Mitsuba's ``smith_g1``."""
    x, y = alpha_x * v[0], alpha_y * v[1]
    xy = x * x + y * y
    g = 2.0 / (1.0 + xp.sqrt(1.0 + xy / xp.maximum(v[2] * v[2], 1e-30)))
    g = xp.select(xy == 0.0, 1.0, g)
    return xp.select(dot(v, m) * v[2] <= 0.0, 0.0, g)


def ggx_visible_pdf_aniso_lanes(xp, v, m, alpha_x, alpha_y):
    """Density of :func:`ggx_sample_visible_lanes` drawing ``m`` seen from ``v`` (``vz > 0``):
    ``D(m) G1(v, m) |v.m| / vz``."""
    return ggx_D_aniso_lanes(xp, m, alpha_x, alpha_y) * ggx_G1_aniso_lanes(xp, v, m, alpha_x, alpha_y) * xp.abs(dot(v, m)) / v[2]


# ---------------------------------------------------------------- Beckmann


def beckmann_D_lanes(xp, cos_h, alpha):
    """Beckmann normal density D(h) at cosines ``cos_h`` (0 where Mitsuba's is: ``D cos_h <= 1e-20``)."""
    c2 = xp.maximum(cos_h * cos_h, 1e-18)  # c2^2 stays a normal float32 (D is 0 long before)
    a2 = alpha * alpha
    d = xp.exp(-(xp.maximum(1.0 - c2, 0.0) / c2) / a2) / (math.pi * a2 * c2 * c2)
    return xp.select((cos_h > 0.0) & (d * cos_h > 1e-20), d, 0.0)


def beckmann_G1_lanes(xp, cos_v, alpha):
    """Beckmann's Smith masking G1, Walter et al.'s rational approximation (Mitsuba 3's form), for
    cosines ``cos_v`` (1 at normal incidence, 0 below)."""
    c2 = xp.maximum(cos_v * cos_v, 1e-30)
    s2 = xp.maximum(1.0 - c2, 0.0)
    a = xp.sqrt(c2 / xp.maximum(alpha * alpha * s2, 1e-30))  # 1 / (alpha tan theta)
    b = xp.minimum(a, 1.6)  # the rational where it is used (no overflow where it is not)
    g = xp.select(a >= 1.6, 1.0, (3.535 * b + 2.181 * b * b) / (1.0 + 2.276 * b + 2.577 * b * b))
    return xp.select(cos_v > 0.0, xp.select(s2 > 0.0, g, 1.0), 0.0)


#: the largest float32 below 1: where Beckmann sampling clamps its erf-domain values
_ERF_EDGE = 1.0 - 2.0**-24


def beckmann_slopes_11_lanes(xp, cos_theta, u0, u1):
    """Slopes (a 2-tuple) of Beckmann normals of roughness 1 visible from a direction at
    ``cos_theta`` in the xz plane (x towards it), from uniforms ``u0``, ``u1``: Jakob's inversion
    (module docstring)."""
    c = xp.minimum(xp.maximum(cos_theta, 1e-12), 1.0)
    u0 = xp.minimum(xp.maximum(u0, 1e-6), 1.0 - 1e-6)
    u1 = xp.minimum(xp.maximum(u1, 1e-6), 1.0 - 1e-6)
    tan_t = xp.sqrt(xp.maximum(1.0 - c * c, 0.0)) / c
    cot_t = 1.0 / xp.maximum(tan_t, 1e-30)
    inv_sqrt_pi = 1.0 / math.sqrt(math.pi)
    maxval = xp.erf(cot_t)
    x = maxval - (maxval + 1.0) * xp.erf(xp.sqrt(-xp.log(u0)))
    target = u0 * (1.0 + maxval + inv_sqrt_pi * tan_t * xp.exp(-(cot_t * cot_t)))
    for _ in range(3):  # Newton steps in the erf domain
        slope = xp.erfinv(xp.minimum(xp.maximum(x, -_ERF_EDGE), _ERF_EDGE))
        value = 1.0 + x + inv_sqrt_pi * tan_t * xp.exp(-(slope * slope)) - target
        x = x - value / (1.0 - slope * tan_t)
    edge = lambda v: xp.minimum(xp.maximum(v, -_ERF_EDGE), _ERF_EDGE)  # noqa: E731
    return xp.erfinv(edge(x)), xp.erfinv(edge(2.0 * u1 - 1.0))


def beckmann_D_aniso_lanes(xp, m, alpha_x, alpha_y):
    """Anisotropic Beckmann density D(m) of local normals ``m`` (a 3-tuple), roughness ``alpha_x``
    along x and ``alpha_y`` along y: ``exp(-((mx/ax)^2 + (my/ay)^2) / mz^2) / (pi ax ay mz^4)``, 0
    where ``D mz <= 1e-20`` (Mitsuba's mask, also where m points below)."""
    c2 = xp.maximum(m[2] * m[2], 1e-18)
    x, y = m[0] / alpha_x, m[1] / alpha_y
    d = xp.exp(-(x * x + y * y) / c2) / (math.pi * alpha_x * alpha_y * c2 * c2)
    return xp.select((m[2] > 0.0) & (d * m[2] > 1e-20), d, 0.0)


def beckmann_G1_aniso_lanes(xp, v, m, alpha_x, alpha_y):
    """Anisotropic Beckmann Smith masking G1 of directions ``v`` on microfacets ``m`` (3-tuples):
    the rational approximation of :func:`beckmann_G1_lanes` at ``a = vz / sqrt(ax^2 vx^2 + ay^2
    vy^2)``, 1 at normal incidence, 0 where ``v`` sees the microfacet's back (Mitsuba's ``smith_g1``)."""
    x, y = alpha_x * v[0], alpha_y * v[1]
    xy = x * x + y * y
    a = xp.sqrt(v[2] * v[2] / xp.maximum(xy, 1e-30))
    b = xp.minimum(a, 1.6)
    g = xp.select(a >= 1.6, 1.0, (3.535 * b + 2.181 * b * b) / (1.0 + 2.276 * b + 2.577 * b * b))
    g = xp.select(xy == 0.0, 1.0, g)
    return xp.select(dot(v, m) * v[2] <= 0.0, 0.0, g)


def beckmann_sample_visible_lanes(xp, wo, alpha, u0, u1):
    """Heitz and d'Eon (2014) with Jakob's slopes: a Beckmann normal (a 3-tuple, local frame)
    visible from ``wo`` (z > 0)."""
    return beckmann_sample_visible_aniso_lanes(xp, wo, alpha, alpha, u0, u1)


def beckmann_sample_visible_aniso_lanes(xp, wo, alpha_x, alpha_y, u0, u1):
    """:func:`beckmann_sample_visible_lanes` of roughness ``alpha_x`` along x and ``alpha_y`` along
    y: ``wo`` stretched by them, the slopes rotated and unstretched."""
    wp = normalize(xp, (alpha_x * wo[0], alpha_y * wo[1], wo[2]))
    sin2 = wp[0] * wp[0] + wp[1] * wp[1]
    tilted = sin2 > 1e-14
    inv = xp.select(tilted, 1.0 / xp.sqrt(xp.maximum(sin2, 1e-30)), 0.0)
    cos_phi = xp.select(tilted, xp.minimum(xp.maximum(wp[0] * inv, -1.0), 1.0), 1.0)
    sin_phi = xp.select(tilted, xp.minimum(xp.maximum(wp[1] * inv, -1.0), 1.0), 0.0)
    s0, s1 = beckmann_slopes_11_lanes(xp, wp[2], u0, u1)
    sx = (cos_phi * s0 - sin_phi * s1) * alpha_x
    sy = (sin_phi * s0 + cos_phi * s1) * alpha_y
    return normalize(xp, (-sx, -sy, 0.0 * sx + 1.0))


# ---------------------------------------------------------------- torch helpers (the same functions with TORCH)


def _lanes(v: torch.Tensor) -> tuple:
    return tuple(v.unbind(-1))


def sample_visible_normal(wo_local: torch.Tensor, alpha: torch.Tensor, u: torch.Tensor, alpha_y: torch.Tensor | None = None) -> torch.Tensor:
    """:func:`ggx_sample_visible_lanes` on torch: normals (N, 3) visible from ``wo_local`` (N, 3)
    (z > 0) from uniforms ``u`` (N, 2); anisotropic where ``alpha_y`` (N,) is given."""
    h = ggx_sample_visible_lanes(TORCH, _lanes(wo_local), alpha, alpha if alpha_y is None else alpha_y, u[:, 0], u[:, 1])
    return torch.stack(h, dim=-1)


def ggx_D_aniso(m: torch.Tensor, alpha_x: torch.Tensor, alpha_y: torch.Tensor) -> torch.Tensor:
    """:func:`ggx_D_aniso_lanes` (N,) of local normals ``m`` (N, 3), roughness ``alpha_x``, ``alpha_y`` (N,)."""
    return ggx_D_aniso_lanes(TORCH, _lanes(m), alpha_x, alpha_y)


def ggx_G1_aniso(v: torch.Tensor, m: torch.Tensor, alpha_x: torch.Tensor, alpha_y: torch.Tensor) -> torch.Tensor:
    """:func:`ggx_G1_aniso_lanes` (N,) of directions ``v`` (N, 3) on microfacets ``m`` (N, 3)."""
    return ggx_G1_aniso_lanes(TORCH, _lanes(v), _lanes(m), alpha_x, alpha_y)


def ggx_visible_pdf_aniso(v: torch.Tensor, m: torch.Tensor, alpha_x: torch.Tensor, alpha_y: torch.Tensor) -> torch.Tensor:
    """:func:`ggx_visible_pdf_aniso_lanes` (N,) of ``m`` (N, 3) seen from ``v`` (N, 3), ``vz > 0``."""
    return ggx_visible_pdf_aniso_lanes(TORCH, _lanes(v), _lanes(m), alpha_x, alpha_y)


# ---------------------------------------------------------------- the interface materials use


class Distribution(ABC):
    """A microfacet normal distribution of roughness alpha (isotropic), in a material's local
    frame (normal +z): its lane functions (``*_lanes``, ``xp`` first, on arrays and 3-tuples) and
    the same as torch methods (tensors (N,) or (N, 3); alpha (N,) per point)."""

    #: the name scene files give it (Mitsuba's ``distribution``), and how messages spell it
    name: str
    label: str

    #: ``(xp, cos_h, alpha)``: the normal density D(h) at cosines ``cos_h`` of h with the normal
    D_lanes: Callable
    #: ``(xp, cos_v, alpha)``: Smith's masking of directions at cosines ``cos_v`` (0 below)
    G1_lanes: Callable

    #: ``(xp, wo, alpha, u0, u1)``: a normal (a 3-tuple) visible from ``wo`` (z > 0) from uniforms ``u0``, ``u1``
    sample_visible_lanes: Callable

    #: the anisotropic forms, roughness ``alpha_x`` along the tangent s (x) and ``alpha_y`` along t
    #: (y), as Mitsuba's ``alpha_u``, ``alpha_v``: ``(xp, m, alpha_x, alpha_y)`` the density D(m) of
    #: a local normal ``m`` (a 3-tuple); ``(xp, v, m, alpha_x, alpha_y)`` the masking of direction
    #: ``v`` on microfacet ``m`` (0 where ``v`` sees its back: Mitsuba's ``smith_g1``);
    #: ``(xp, wo, alpha_x, alpha_y, u0, u1)`` a visible normal
    D_aniso_lanes: Callable
    G1_aniso_lanes: Callable
    sample_visible_aniso_lanes: Callable

    def visible_pdf_lanes(self, xp, cos_o, cos_h, wo_dot_h, alpha):
        """Density of :meth:`sample_visible_lanes` drawing a normal at ``cos_h`` with ``wo . h =
        wo_dot_h`` for ``wo`` at ``cos_o``: ``G1(wo) max(0, wo.h) D(h) / cos_o``."""
        return self.G1_lanes(xp, cos_o, alpha) * xp.maximum(wo_dot_h, 0.0) * self.D_lanes(xp, cos_h, alpha) / xp.maximum(cos_o, 1e-12)

    def reweight_lanes(self, xp, cos_h, cos_o, alpha, alpha_s):
        """The factor that turns a visible-normal sample weight of roughness ``alpha_s`` into the
        weight ``f(alpha) cos_i / pdf(alpha_s)`` (:func:`visible_reweight`): ``D(h; alpha)
        G1(wo; alpha) / (D(h; alpha_s) G1(wo; alpha_s))``, 1 where the sampling density vanishes;
        exactly 1 in value where ``alpha`` equals ``alpha_s`` (``alpha_s`` is read as a constant)."""
        num = self.D_lanes(xp, cos_h, alpha) * self.G1_lanes(xp, cos_o, alpha)
        den = self.D_lanes(xp, cos_h, alpha_s) * self.G1_lanes(xp, cos_o, alpha_s)
        return xp.select(den > 0.0, num / xp.select(den > 0.0, den, 1.0), 1.0)

    def D(self, cos_h: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """The normal density D(h) (N,) at cosines ``cos_h`` (N,) of h with the normal."""
        return self.D_lanes(TORCH, cos_h, alpha)

    def G1(self, cos_v: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """Smith's masking (N,) of directions at cosines ``cos_v`` (N,) (0 below the surface)."""
        return self.G1_lanes(TORCH, cos_v, alpha)

    def sample_visible(self, wo_local: torch.Tensor, alpha: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """A normal (N, 3) visible from ``wo_local`` (N, 3) (z > 0), from uniforms ``u`` (N, 2)."""
        return torch.stack(self.sample_visible_lanes(TORCH, _lanes(wo_local), alpha, u[:, 0], u[:, 1]), dim=-1)

    def visible_pdf(self, cos_o: torch.Tensor, cos_h: torch.Tensor, wo_dot_h: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
        """:meth:`visible_pdf_lanes` (N,) on torch."""
        return self.visible_pdf_lanes(TORCH, cos_o, cos_h, wo_dot_h, alpha)

    def __repr__(self) -> str:
        return f"<{self.name} microfacet distribution>"


class _GGX(Distribution):
    name, label = "ggx", "GGX"
    D_lanes = staticmethod(ggx_D_lanes)
    G1_lanes = staticmethod(ggx_G1_lanes)

    D_aniso_lanes = staticmethod(ggx_D_aniso_lanes)
    G1_aniso_lanes = staticmethod(ggx_G1_aniso_lanes)
    sample_visible_aniso_lanes = staticmethod(ggx_sample_visible_lanes)

    @staticmethod
    def sample_visible_lanes(xp, wo, alpha, u0, u1):
        return ggx_sample_visible_lanes(xp, wo, alpha, alpha, u0, u1)


class _Beckmann(Distribution):
    name, label = "beckmann", "Beckmann"
    D_lanes = staticmethod(beckmann_D_lanes)
    G1_lanes = staticmethod(beckmann_G1_lanes)
    sample_visible_lanes = staticmethod(beckmann_sample_visible_lanes)
    D_aniso_lanes = staticmethod(beckmann_D_aniso_lanes)
    G1_aniso_lanes = staticmethod(beckmann_G1_aniso_lanes)
    sample_visible_aniso_lanes = staticmethod(beckmann_sample_visible_aniso_lanes)

    def sample_visible(self, wo_local: torch.Tensor, alpha: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """As :meth:`Distribution.sample_visible`, computed in float64 (the torch materials'
        sampling and the plastics' tables), returned in ``wo_local``'s dtype."""
        return super().sample_visible(wo_local.double(), alpha.double(), u.double()).to(wo_local.dtype)


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
    return grey_channel(bsdf.param(key, sp)), bsdf.sampling_param(key, sp)[:, 0]


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
    return d.reweight_lanes(TORCH, cos_h, cos_o, alpha, alpha_s.detach())


# ---------------------------------------------------------------- a roughness as lane functions read it


class Microfacets:
    """A distribution at one roughness per lane, isotropic or anisotropic, as the microfacet
    materials' lane functions read it: :meth:`D` of a local normal, :meth:`G1` of a direction on
    a microfacet and :meth:`sample` of a visible normal. Isotropic (``alpha_y`` None): the
    distribution's isotropic lane functions of the cosines alone (the same operations as they
    were called before anisotropy existed, so isotropic renders keep their bits); anisotropic:
    ``alpha_x`` along the shading frame's tangent s, ``alpha_y`` along t (Mitsuba's ``alpha_u``,
    ``alpha_v``)."""

    __slots__ = ("xp", "d", "alpha_x", "alpha_y")

    def __init__(self, xp, d: Distribution, alpha_x, alpha_y=None):
        self.xp, self.d, self.alpha_x, self.alpha_y = xp, d, alpha_x, alpha_y

    @staticmethod
    def of(xp, d: Distribution, p: dict, anisotropic: bool) -> "Microfacets":
        """The roughness of a material's values ``p``: ``roughness`` (alpha_u), and where the form
        is ``anisotropic``, ``alpha_v`` (0: the same as alpha_u)."""
        ax = p["roughness"]
        return Microfacets(xp, d, ax, xp.select(p["alpha_v"] > 0.0, p["alpha_v"], ax) if anisotropic else None)

    def D(self, m):
        if self.alpha_y is None:
            return self.d.D_lanes(self.xp, m[2], self.alpha_x)
        return self.d.D_aniso_lanes(self.xp, m, self.alpha_x, self.alpha_y)

    def G1(self, v, m):
        """Masking of ``v`` on ``m``; the isotropic form reads ``|v_z|``'s cosine only (``v`` is
        given as seen from its own side)."""
        if self.alpha_y is None:
            return self.d.G1_lanes(self.xp, v[2], self.alpha_x)
        return self.d.G1_aniso_lanes(self.xp, v, m, self.alpha_x, self.alpha_y)

    def sample(self, wo, u0, u1):
        if self.alpha_y is None:
            return self.d.sample_visible_lanes(self.xp, wo, self.alpha_x, u0, u1)
        return self.d.sample_visible_aniso_lanes(self.xp, wo, self.alpha_x, self.alpha_y, u0, u1)
