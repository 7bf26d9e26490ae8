"""The principled BSDF: Mitsuba 3's ``principled`` (Burley, "Physically-Based Shading at Disney",
SIGGRAPH 2012 course; "Extending the Disney BRDF to a BSDF with Integrated Subsurface Scattering",
2015), matched to Mitsuba's ``eval`` and ``pdf`` term by term (``docs/rendering.md#principled-materials``).

Every quantity below is in the shading frame of the surface's *front* side (Mitsuba's: normal
along the triangle's front; ``a`` = the direction towards the camera, ``b`` = towards the light,
``c_a = a_z``, ``c_b = b_z``). The weights ``brdf = (1 - metallic)(1 - spec_trans)`` and ``bsdf =
(1 - metallic) spec_trans`` split the dielectric base between the opaque and the transmitting
part; alpha ``= max(0.001, roughness^2 / s)`` along x and ``max(0.001, roughness^2 s)`` along y,
``s = sqrt(1 - 0.9 anisotropic)``. With ``h`` the (generalized) half vector turned up and ``F`` the
exact dielectric Fresnel term at ``a . h`` for the relative index ``eta``:

- specular reflection (both sides): ``F_p D(h) G(a, b) / (4 |c_a|)``, anisotropic GGX ``D`` and
  Smith ``G`` (:mod:`~invrender.plugins.bsdfs.microfacet`), where on the front side ``F_p = (1 -
  m)(1 - spec_tint) F + m Schlick(base_color) + (1 - m) spec_tint Schlick(c_tint R0(eta))`` (Schlick's
  approximation with the index's branch, ``c_tint`` = base_color over its luminance) and on the back
  side ``F_p = bsdf F``;
- specular transmission: ``sqrt(base_color) bsdf (1 - F) D G |a.h| |b.h| / (|c_a| (a.h + eta' b.h)^2)``
  (Walter et al.'s BTDF in radiance units, ``eta'`` the index along the path);
- clearcoat (front only): ``clearcoat / 4 Schlick_0.04(a.h) D_GTR1(h) G_0.25(a) G_0.25(b) |c_b|``
  with the GTR1 distribution of alpha ``0.1 (1 - clearcoat_gloss) + 0.001 clearcoat_gloss`` and
  GGX masking of alpha 0.25 (Mitsuba's form, the cosine included as written);
- diffuse (front only): ``brdf base_color / pi |c_b| lerp(f_d + f_r, f_ss, flatness)``, Burley's
  ``f_d = (1 - F_i/2)(1 - F_o/2)`` with Schlick weights ``F = (1 - |c|)^5``, retro-reflection ``f_r
  = R (F_o + F_i + F_o F_i (R - 1))``, ``R = 2 roughness (b.h)^2``, and the Hanrahan-Krueger fake
  subsurface ``f_ss`` (flatness 0, the default, turns it off);
- sheen (front only): ``sheen (1 - m) (1 - |b.h|)^5 lerp(1, c_tint, sheen_tint) |c_b|``.

Each blend weight multiplies its lobe with no mask at 0 (Mitsuba masks a lobe whose weight is 0:
the same values), so the derivative in a weight at 0 is its lobe's and a fit can start there.

Sampling, as Mitsuba's: a GGX normal visible from ``a`` (turned up) gives ``F`` and so the lobe
probabilities ``P_diffuse ~ brdf r_d``, ``P_clearcoat ~ clearcoat / 4 r_c``, ``P_transmit ~ bsdf (1 -
F) r_s``, ``P_reflect ~ (1 - bsdf (1 - F)) r_s`` (front; from behind only ``F`` and ``1 - F``), the
``r`` being the sampling rates (constants, default 1); ``pdf`` is the mixture of the lobes' densities
with those probabilities at the half vector of ``b``. Where spec_trans > 0 and the surface is also
opaque in part, Mitsuba's lobe choice reads ``F`` at the sampled normal while its ``pdf`` reads it at
the direction's half vector, so sampling follows the ``pdf`` only approximately there (as in
Mitsuba; renders match Mitsuba's). Sampling reads the parameters detached
(:meth:`~invrender.core.bsdf.BSDF.sampling_param`), ``eval`` attached: the weight ``f cos / pdf`` carries
every gradient.

Back side: ``two_sided = true`` (the default, as invrender's other materials; Mitsuba's
``twosided`` wrapper, which the Blender exporter writes around every opaque principled material)
shades the back of an opaque material as its front; with ``two_sided = false`` (Mitsuba's
``principled`` unwrapped: the Mitsuba reader sets it) an opaque material is black from behind. A
material that transmits (spec_trans > 0 somewhere) reflects and refracts from behind as a
dielectric, whatever ``two_sided`` says.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from invrender import registry
from invrender.core import lanes
from invrender.core.bsdf import BSDF, LaneBSDF, LaneForm, Lobe, ShadingPoint
from invrender.plugins.bsdfs.dielectric import MAX_RELATIVE_IOR, fresnel_dielectric_lanes
from invrender.plugins.bsdfs.microfacet import ggx_D_aniso_lanes, ggx_G1_aniso_lanes, ggx_sample_visible_lanes, ggx_visible_pdf_aniso_lanes
from invrender.plugins.bsdfs.plastic import cosine_hemisphere_lanes
from invrender.scene import kinds
from invrender.scene.plugins import Constant, Param

#: Rec. 709 luminance weights (Mitsuba's ``luminance`` of an RGB colour)
LUMINANCE = (0.212671, 0.715160, 0.072169)

#: Mitsuba's ``specular`` (read as eta = 2 / (1 - sqrt(0.08 specular)) - 1: 0.5 is eta 1.5; 12 is eta 99,
#: about the largest relative index a material takes)
SPECULAR = Constant(0.5, 0.0, 12.0, False, False)

#: the blend weights every principled material has (key -> kind), all default 0
WEIGHTS = {
    "metallic": kinds.METALLIC,
    "spec_tint": kinds.SPEC_TINT,
    "anisotropic": kinds.ANISOTROPIC,
    "sheen": kinds.SHEEN,
    "sheen_tint": kinds.SHEEN_TINT,
    "clearcoat": kinds.CLEARCOAT,
    "clearcoat_gloss": kinds.CLEARCOAT_GLOSS,
    "spec_trans": kinds.SPEC_TRANS,
    "flatness": kinds.FLATNESS,
}


# ---------------------------------------------------------------- the helpers both principled materials use


def params_with(weights: dict) -> dict:
    """The parameters of a principled material with the blend ``weights`` (name -> kind, default 0):
    ``base_color`` and ``roughness`` (default 0.5) first, as Mitsuba declares them."""
    return {"base_color": Param(kinds.BASE_COLOR, 0.5), "roughness": Param(kinds.ROUGHNESS, 0.5), **{k: Param(kind, 0.0) for k, kind in weights.items()}}


#: the relative index of refraction both principled materials take (a constant)
ETA = Constant(1.5, 1.0 / MAX_RELATIVE_IOR, MAX_RELATIVE_IOR, False, False)


# ---------------------------------------------------------------- the lane functions both principled materials use


def _scale3(xp, v, s):
    """``v * s`` (a 3-tuple times a Float)."""
    return (v[0] * s, v[1] * s, v[2] * s)


def luminance_lanes(c):
    """The luminance of linear RGB colours ``c`` (a 3-tuple)."""
    return LUMINANCE[0] * c[0] + LUMINANCE[1] * c[1] + LUMINANCE[2] * c[2]


def tint_lanes(xp, base):
    """The base colour over its luminance (white where the luminance is 0), a 3-tuple."""
    lum = luminance_lanes(base)
    pos = lum > 0.0
    inv = 1.0 / xp.select(pos, lum, 1.0)
    return tuple(xp.select(pos, b * inv, 1.0) for b in base)


def schlick_weight_lanes(xp, cos):
    """``(1 - cos)^5``, ``1 - cos`` clamped to [0, 1]."""
    m = xp.minimum(xp.maximum(1.0 - cos, 0.0), 1.0)
    m2 = m * m
    return m2 * m2 * m


def fresnel_lanes(xp, cos_i, eta):
    """Exact dielectric Fresnel reflectance at signed cosines (the index inverted from inside)."""
    return fresnel_dielectric_lanes(xp, xp.abs(cos_i), xp.select(cos_i >= 0.0, eta, 1.0 / eta))[0]


def schlick_lanes(xp, r0, cos_i, eta):
    """Schlick's ``r0 + (1 - r0) (1 - cos)^5`` (``r0`` a Float or a 3-tuple) with Mitsuba's
    ``calc_schlick`` choice of cosine: the transmitted one where the incident side is the denser
    (index ratio ``eta`` inverted where ``cos_i < 0``)."""
    eta_it = xp.select(cos_i >= 0.0, eta, 1.0 / eta)
    cos2_t = 1.0 - (1.0 - cos_i * cos_i) / (eta_it * eta_it)
    w = xp.select(eta_it > 1.0, schlick_weight_lanes(xp, xp.abs(cos_i)), schlick_weight_lanes(xp, xp.sqrt(xp.maximum(cos2_t, 0.0))))
    if isinstance(r0, tuple):
        return tuple(w * (1.0 - r) + r for r in r0)
    return w * (1.0 - r0) + r0


def alphas_lanes(xp, anisotropic, roughness):
    """(alpha_x, alpha_y): ``max(0.001, r^2 / s)`` and ``max(0.001, r^2 s)``, ``s = sqrt(1 - 0.9
    anisotropic)`` (Burley 2012's mapping)."""
    r2 = roughness * roughness
    aspect = xp.sqrt(xp.maximum(1.0 - 0.9 * anisotropic, 0.0))
    return xp.maximum(r2 / xp.maximum(aspect, 1e-6), 0.001), xp.maximum(r2 * aspect, 0.001)


def diffuse_retro_lanes(xp, c_a, c_b, cos_d, roughness, flatness):
    """Burley's diffuse with retro-reflection, blended by ``flatness`` towards the fake subsurface
    lobe: ``lerp(f_d + f_r, f_ss, flatness)`` (times ``base_color / pi`` makes f)."""
    Fo, Fi = schlick_weight_lanes(xp, xp.abs(c_b)), schlick_weight_lanes(xp, xp.abs(c_a))
    f_diff = (1.0 - 0.5 * Fi) * (1.0 - 0.5 * Fo)
    Rr = 2.0 * roughness * (cos_d * cos_d)
    f_retro = Rr * (Fo + Fi + Fo * Fi * (Rr - 1.0))
    Fss90 = 0.5 * Rr
    Fss = (1.0 + (Fss90 - 1.0) * Fo) * (1.0 + (Fss90 - 1.0) * Fi)
    f_ss = 1.25 * (Fss * (1.0 / xp.maximum(xp.abs(c_b) + xp.abs(c_a), 1e-12) - 0.5) + 0.5)
    return (f_diff + f_retro) * (1.0 - flatness) + f_ss * flatness


def compatible_lanes(xp, h, a, b, c_a, reflection: bool):
    """Do the macro- and the microsurface agree on the sides of ``a`` and ``b`` (``b`` on ``a``'s
    side of ``h`` for a reflection, on the other for a transmission)? ``h`` is turned to ``a``'s
    side of the macrosurface (sign of ``c_a``) first."""
    s = xp.select(c_a >= 0.0, 1.0, -1.0)
    d_a, d_b = lanes.dot(a, h) * s, lanes.dot(b, h) * s
    return (d_a > 0.0) & ((d_b > 0.0) if reflection else (d_b < 0.0))


def gtr1_D_lanes(xp, cos_h, alpha):
    """Burley's GTR1 density ``(alpha^2 - 1) / (pi log(alpha^2) (1 + (alpha^2 - 1) cos^2))`` (0 where
    ``D cos <= 1e-20``)."""
    a2 = alpha * alpha
    d = (a2 - 1.0) / (math.pi * xp.log(a2) * (1.0 + (a2 - 1.0) * (cos_h * cos_h)))
    return xp.select(d * cos_h > 1e-20, d, 0.0)


def gtr1_sample_lanes(xp, alpha, u0, u1):
    """GTR1 normals (a 3-tuple; density ``D cos``) from uniforms ``u0``, ``u1``."""
    phi = (2.0 * math.pi) * u0
    a2 = alpha * alpha
    cos2 = (1.0 - xp.exp((1.0 - u1) * xp.log(a2))) / (1.0 - a2)
    sin_t, cos_t = xp.sqrt(xp.maximum(1.0 - cos2, 0.0)), xp.sqrt(xp.maximum(cos2, 0.0))
    return (xp.cos(phi) * sin_t, xp.sin(phi) * sin_t, cos_t)


def safe_lanes(xp, x):
    """``x`` with zeros replaced by 1 (a denominator whose zero lanes are masked out later, so that
    neither the value nor the gradient of the masked lanes is NaN)."""
    return xp.select(x == 0.0, 1.0, x)


# ---------------------------------------------------------------- the principled BSDF


def _sided(xp, p, front):
    """-1 where invrender's frame (normal towards ``wo``) is flipped to the front side's, else 1."""
    flip = ~front & ~((p["two_sided"] > 0.5) & ~(p["has_spec_trans"] > 0.5))
    return xp.select(flip, -1.0, 1.0)


def _half_lanes(xp, p, a, b):
    """The geometry of a direction pair in the front-side frame: ``(c_a, c_b, front, reflect,
    refract, eta, eta_path, h, a.h, b.h, F)``."""
    c_a, c_b = a[2], b[2]
    front = c_a > 0.0
    reflect, refract = c_a * c_b > 0.0, c_a * c_b < 0.0
    eta = p["eta"]
    eta_path = xp.select(front, eta, 1.0 / eta)
    h = lanes.normalize(xp, lanes.add(a, _scale3(xp, b, xp.select(reflect, 1.0, eta_path))))
    h = _scale3(xp, h, xp.select(h[2] < 0.0, -1.0, 1.0))
    d_a, d_b = lanes.dot(a, h), lanes.dot(b, h)
    return c_a, c_b, front, reflect, refract, eta, eta_path, h, d_a, d_b, fresnel_lanes(xp, d_a, eta)


def principled_value_lanes(xp, p, a, b, half):
    """``f |c_b|`` (a 3-tuple) in the front-side frame, parameters ``p`` (module docstring), ``half``
    the pair's geometry (:func:`_half_lanes`)."""
    c_a, c_b, front, reflect, refract, eta, eta_path, h, d_a, d_b, F = half
    active = c_a != 0.0
    base = p["base_color"]
    r, m, st = p["roughness"], p["metallic"], p["spec_trans"]
    brdf, bsdf = (1.0 - m) * (1.0 - st), (1.0 - m) * st
    ax, ay = alphas_lanes(xp, p["anisotropic"], r)
    D = ggx_D_aniso_lanes(xp, h, ax, ay)
    G = ggx_G1_aniso_lanes(xp, a, h, ax, ay) * ggx_G1_aniso_lanes(xp, b, h, ax, ay)
    compat_r, compat_t = compatible_lanes(xp, h, a, b, c_a, True), compatible_lanes(xp, h, a, b, c_a, False)
    abs_a = safe_lanes(xp, xp.abs(c_a))
    # main specular reflection: the principled Fresnel blend (front) or the dielectric's (back)
    eta_it = xp.select(d_a >= 0.0, eta, 1.0 / eta)
    tint = p["spec_tint"]
    r0 = (eta_it - 1.0) / (eta_it + 1.0)
    s_base = schlick_lanes(xp, base, d_a, eta)
    c_tint = tint_lanes(xp, base)
    s_tint = schlick_lanes(xp, _scale3(xp, c_tint, r0 * r0), d_a, eta)
    F_front = tuple((1.0 - m) * (1.0 - tint) * F + m * x + (1.0 - m) * tint * y for x, y in zip(s_base, s_tint))
    on = active & reflect & compat_r & (F > 0.0)
    spec = xp.select(on, D * G / (4.0 * abs_a), 0.0)
    value = tuple(xp.select(front, x, bsdf * F) * spec for x in F_front)
    # main specular transmission (radiance: 1 / eta_path^2 times Walter's eta_path^2)
    on = active & refract & compat_t & (F < 1.0)
    q = d_a + eta_path * d_b
    t = xp.abs((1.0 - F) * D * G * d_a * d_b / (abs_a * safe_lanes(xp, q * q)))
    t = xp.select(on, bsdf * t, 0.0)
    value = tuple(v + xp.sqrt(xp.maximum(c, 1e-12)) * t for v, c in zip(value, base))
    # clearcoat: GTR1, Schlick with R0 = 0.04, GGX masking of alpha 0.25
    on = active & reflect & compat_r & front
    alpha_cc = 0.1 + (0.001 - 0.1) * p["clearcoat_gloss"]
    quarter = 0.0 * c_a + 0.25
    G_cc = ggx_G1_aniso_lanes(xp, a, h, quarter, quarter) * ggx_G1_aniso_lanes(xp, b, h, quarter, quarter)
    cc = xp.select(on, 0.25 * p["clearcoat"] * schlick_lanes(xp, 0.0 * d_a + 0.04, d_a, eta) * gtr1_D_lanes(xp, h[2], alpha_cc) * G_cc * xp.abs(c_b), 0.0)
    # diffuse with retro-reflection (and the fake subsurface by flatness), and sheen
    on = active & reflect & front
    diff = xp.select(on, brdf * xp.abs(c_b) * (1.0 / math.pi) * diffuse_retro_lanes(xp, c_a, c_b, d_b, r, p["flatness"]), 0.0)
    sh = xp.select(on, p["sheen"] * (1.0 - m) * schlick_weight_lanes(xp, xp.abs(d_b)) * xp.abs(c_b), 0.0)
    sheen_tint = p["sheen_tint"]
    return tuple(v + cc + c * diff + (1.0 + sheen_tint * (k - 1.0)) * sh for v, c, k in zip(value, base, c_tint))


def _probabilities_lanes(xp, ps, front, F):
    """The lobe probabilities ``(diffuse, clearcoat, transmission, reflection)`` at the detached
    parameters ``ps`` for Fresnel reflectance ``F``."""
    m, st = ps["metallic"], ps["spec_trans"]
    has_st = ps["has_spec_trans"] > 0.5
    brdf, bsdf = (1.0 - m) * (1.0 - st), xp.select(has_st, (1.0 - m) * st, 0.0)
    r_spec = ps["main_specular_sampling_rate"]
    p_r = xp.select(front, r_spec * (1.0 - bsdf * (1.0 - F)), F)
    p_t = xp.select(has_st, xp.select(front, r_spec * bsdf * (1.0 - F), 1.0 - F), 0.0)
    p_c = xp.select(front, 0.25 * ps["clearcoat"] * ps["clearcoat_sampling_rate"], 0.0)
    p_d = xp.select(front, brdf * ps["diffuse_reflectance_sampling_rate"], 0.0)
    total = p_r + p_t + p_c + p_d
    inv = xp.select(total > 0.0, 1.0 / safe_lanes(xp, total), 0.0)
    return p_d * inv, p_c * inv, p_t * inv, p_r * inv


def principled_pdf_lanes(xp, ps, a, b, half):
    """The sampling density of ``b`` in the front-side frame (detached parameters ``ps``), ``half``
    the pair's geometry (:func:`_half_lanes`)."""
    c_a, c_b, front, reflect, refract, eta, eta_path, h, d_a, d_b, F = half
    p_d, p_c, p_t, p_r = _probabilities_lanes(xp, ps, front, F)
    ax, ay = alphas_lanes(xp, ps["anisotropic"], ps["roughness"])
    q = d_a + eta_path * d_b
    jacobian = xp.abs(xp.select(reflect, 1.0 / safe_lanes(xp, 4.0 * d_b), eta_path * eta_path * d_b / safe_lanes(xp, q * q)))
    up = _scale3(xp, a, xp.select(c_a < 0.0, -1.0, 1.0))
    visible = ggx_visible_pdf_aniso_lanes(xp, up, h, ax, ay) * jacobian
    mirror = compatible_lanes(xp, h, a, b, c_a, True) & reflect
    through = compatible_lanes(xp, h, a, b, c_a, False) & refract & (ps["has_spec_trans"] > 0.5)
    alpha_cc = 0.1 + (0.001 - 0.1) * ps["clearcoat_gloss"]
    coat = xp.select(h[2] < 0.0, 0.0, h[2] * gtr1_D_lanes(xp, h[2], alpha_cc)) * jacobian
    pdf = xp.select(mirror, p_r * visible + p_c * coat, 0.0) + xp.select(reflect, p_d * c_b * (1.0 / math.pi), 0.0) + xp.select(through, p_t * visible, 0.0)
    return xp.select(c_a != 0.0, pdf, 0.0)


def principled_eval_lanes(xp, p, ps, wo, wi, front):
    """``f |cos theta_i|`` of all lobes (``p``) and the lobes' densities mixed by their
    probabilities (``ps``), in the front side's frame (:func:`_sided`)."""
    s = _sided(xp, ps, front)
    a, b = (wo[0], wo[1], wo[2] * s), (wi[0], wi[1], wi[2] * s)
    half = _half_lanes(xp, ps, a, b)  # eta is a constant: the same geometry for f and the pdf
    return principled_value_lanes(xp, p, a, b, half), principled_pdf_lanes(xp, ps, a, b, half)


def principled_sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1):
    """Mitsuba's procedure: a visible GGX normal from ``u0, u1`` fixes ``F`` and so the lobe
    probabilities; ``u_lobe`` picks diffuse, clearcoat, transmission or reflection in that order;
    ``u0, u1`` draw the lobe's direction (cosine-weighted, a GTR1 normal, or the visible normal
    refracted or reflected). Weight ``f cos / pdf`` (``f`` at ``p``)."""
    s = _sided(xp, ps, front)
    a = (wo[0], wo[1], wo[2] * s)
    c_a = a[2]
    front_side = c_a > 0.0
    up = _scale3(xp, a, xp.select(c_a < 0.0, -1.0, 1.0))
    ax, ay = alphas_lanes(xp, ps["anisotropic"], ps["roughness"])
    one = 0.0 * c_a + 1.0
    h = ggx_sample_visible_lanes(xp, lanes.select3(xp, up[2] > 0.0, up, (0.0 * one, 0.0 * one, one)), ax, ay, u0, u1)
    eta = ps["eta"]
    d_a = lanes.dot(a, h)
    F = fresnel_lanes(xp, d_a, eta)
    p_d, p_c, p_t, _ = _probabilities_lanes(xp, ps, front_side, F)
    diffuse = u_lobe < p_d
    coat = ~diffuse & (u_lobe < p_d + p_c)
    transmit = ~diffuse & ~coat & (u_lobe < p_d + p_c + p_t)
    # reflection about the visible normal, or about a GTR1 normal for the clearcoat
    alpha_cc = 0.1 + (0.001 - 0.1) * ps["clearcoat_gloss"]
    h_r = lanes.select3(xp, coat, gtr1_sample_lanes(xp, alpha_cc, u0, u1), h)
    w_r = lanes.reflect(a, h_r)
    # refraction through the visible normal (Mitsuba's refract, its signed cosine)
    eta_ti = xp.select(d_a >= 0.0, 1.0 / eta, eta)
    cos2_t = 1.0 - eta_ti * eta_ti * (1.0 - d_a * d_a)
    cos_t = -xp.sqrt(xp.maximum(cos2_t, 0.0)) * xp.select(d_a >= 0.0, 1.0, -1.0)
    w_t = lanes.sub(_scale3(xp, h, d_a * eta_ti + cos_t), _scale3(xp, a, eta_ti))
    b = lanes.select3(xp, diffuse, cosine_hemisphere_lanes(xp, u0, u1), lanes.select3(xp, transmit, w_t, w_r))
    c_b = b[2]
    opaque_back = (ps["has_spec_trans"] > 0.5) & (ps["spec_trans"] * (1.0 - ps["metallic"]) > 0.0)
    ok = (c_a != 0.0) & (front_side | opaque_back)
    ok = ok & xp.select(transmit, compatible_lanes(xp, h, a, b, c_a, False) & (c_a * c_b < 0.0), c_a * c_b > 0.0)
    ok = ok & (diffuse | transmit | compatible_lanes(xp, h_r, a, b, c_a, True))
    half = _half_lanes(xp, ps, a, b)
    pdf = xp.select(ok, principled_pdf_lanes(xp, ps, a, b, half), 0.0)
    ok = ok & (pdf > 0.0)
    inv = 1.0 / safe_lanes(xp, pdf)
    weight = tuple(xp.select(ok, v * inv, 0.0) for v in principled_value_lanes(xp, p, a, b, half))
    return (b[0], b[1], b[2] * s), weight, xp.select(ok, pdf, 0.0), xp.full(False, u0)


#: the lane form's keys of the principled BSDF
PRINCIPLED_KEYS = (("base_color", 3), ("roughness", 1), *((k, 1) for k in WEIGHTS), ("eta", 1), ("main_specular_sampling_rate", 1),
                   ("clearcoat_sampling_rate", 1), ("diffuse_reflectance_sampling_rate", 1), ("two_sided", 1), ("has_spec_trans", 1))  # fmt: skip


class PrincipledBase(BSDF):
    """What both principled materials share: the diffuse albedo, path records' refusal and the
    Mitsuba reading (each is written once as lane functions: :class:`~invrender.core.bsdf.LaneBSDF`)."""

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor:
        return self.param("base_color", sp)

    @classmethod
    def not_polynomial(cls, key: str, constants: dict) -> str | None:
        return f"a {cls.type_name}'s value sums several lobes, each non-linear in its parameters"

    @staticmethod
    def read_weight(bsdf, key: str, kind, default: float) -> np.ndarray:
        """A blend weight of a Mitsuba file: a number, or a colour or bitmap reduced to one number
        as Mitsuba's ``eval_1`` does (a constant colour's channel mean, a bitmap's luminance; the
        reader's :meth:`~invrender.scene.formats.mitsuba.reader.PluginReader.grey`)."""
        return bsdf.grey(key, kind, default)


@registry.MATERIALS.register
class Principled(PrincipledBase, LaneBSDF):
    type_name = "principled"
    lobes = Lobe.DIFFUSE | Lobe.GLOSSY | Lobe.GLOSSY_TRANSMISSION
    params = params_with(WEIGHTS)
    constants = {
        "eta": ETA,
        "main_specular_sampling_rate": Constant(1.0, 0.0, math.inf, False, True),
        "clearcoat_sampling_rate": Constant(1.0, 0.0, math.inf, False, True),
        "diffuse_reflectance_sampling_rate": Constant(1.0, 0.0, math.inf, False, True),
        "two_sided": Constant(True, 0.0, 1.0, False, False, boolean=True),
    }
    doc = "Disney's principled BSDF (Mitsuba's principled): diffuse with retro-reflection, sheen, GGX specular with metallic and tint, GTR1 clearcoat, rough transmission"

    def lane_form(self) -> LaneForm:
        # an anisotropic lobe turns with the UV tangent frame (Mitsuba's dp/du); an isotropic one keeps any frame
        anisotropic = any(bool((v["anisotropic"] != 0).any()) for v in self.sampling_values)
        return LaneForm(PRINCIPLED_KEYS, principled_eval_lanes, principled_sample_lanes, tangent=anisotropic)

    def lane_rows(self, key: str, sampling: bool, device) -> torch.Tensor | None:
        """``has_spec_trans`` (M, 1): 1 where the material transmits (:meth:`_transmits`)."""
        if key == "has_spec_trans":
            token = ("has_spec_trans_rows", device)
            if token not in self._constant_tables:
                flags = [float(bool((v["spec_trans"] != 0).any())) for v in self.sampling_values]
                self._constant_tables[token] = torch.tensor(flags, dtype=torch.float32, device=device)[:, None]
            return self._constant_tables[token]
        return None

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        """``eta = 1`` (no interface to refract at) becomes 1.001 where the material transmits, as
        Mitsuba's does."""
        if constants["eta"] == 1.0 and bool(np.any(np.asarray(_numpy(values["spec_trans"])) != 0)):
            constants = {**constants, "eta": 1.001}
        return constants

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("principled",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``principled``: ``base_color`` (colour or bitmap, default 0.5), ``roughness``
        (default 0.5; 0 is read as 1e-4, the smallest roughness invrender's kind holds, which gives
        the same alpha 0.001), the blend weights (``metallic``, ``spec_tint``, ``anisotropic``,
        ``sheen``, ``sheen_tint``, ``clearcoat``, ``clearcoat_gloss``, ``spec_trans``, ``flatness``;
        numbers, colours or bitmaps, default 0), ``eta`` or ``specular`` (not both; ``eta = 2 / (1 -
        sqrt(0.08 specular)) - 1``, default specular 0.5: eta 1.5) and the three sampling rates."""
        entries = {"base_color": bsdf.colour("base_color", kinds.BASE_COLOR, 0.5)}
        entries.update(read_common(cls, bsdf))
        if bsdf.has("eta") and bsdf.has("specular"):
            raise bsdf.error("specular", "give either 'eta' or 'specular', not both (as Mitsuba)")
        transmits = bool(np.any(entries["spec_trans"] != 0))
        if bsdf.has("eta"):
            eta = bsdf.number("eta", cls.constants["eta"], "relative index of refraction")
            eta = 1.001 if transmits and eta == 1.0 else eta
        else:
            specular = bsdf.number("specular", SPECULAR, "specular level, Mitsuba's eta = 2 / (1 - sqrt(0.08 specular)) - 1")
            specular = 1e-3 if transmits and specular == 0.0 else specular
            eta = 2.0 / (1.0 - math.sqrt(0.08 * specular)) - 1.0
        entries["eta"] = eta
        entries["two_sided"] = False  # Mitsuba's principled is one-sided unless wrapped in twosided
        for key in ("main_specular_sampling_rate", "clearcoat_sampling_rate", "diffuse_reflectance_sampling_rate"):
            entries[key] = bsdf.number(key, cls.constants[key], "a lobe's sampling rate")
        bsdf.finish(("base_color", "roughness", *WEIGHTS, "eta", "specular", "main_specular_sampling_rate", "clearcoat_sampling_rate", "diffuse_reflectance_sampling_rate"))
        return entries

    gltf_priority = 25  # after the mirrors (a polished partial metal stays a mirror), before the glossy metals

    @classmethod
    def from_gltf(cls, material) -> dict | None:
        """A glTF material whose metallic value lies strictly between 0 and 1 or varies (a
        ``metallicRoughnessTexture``), or that transmits and is not a metal (and not clear glass,
        which the dielectric takes): base_color = its base colour (a texture too), metallic (a
        map too), roughness = glTF's perceptual roughness (a map too; at least 1e-4), spec_trans =
        ``transmissionFactor``, eta = its ``ior`` (1.5 by default: F0 = 0.04, glTF's), two-sided
        as invrender's other glTF materials."""
        if not (material.partial_metal or (material.transmission > 0 and not material.metal)):
            return None
        entries = {"base_color": material.base_colour, "metallic": material.metallic, "roughness": material.roughness, "eta": material.ior, "two_sided": True}
        return entries | ({"spec_trans": material.transmission} if material.transmission > 0 else {})

    @classmethod
    def from_mitsuba_twosided(cls, entries: dict, error) -> dict:
        """Mitsuba's ``twosided`` around it: the back shaded as the front; refused where it
        transmits (Mitsuba's twosided rejects a BSDF with a transmission lobe)."""
        if bool(np.any(np.asarray(_numpy(entries.get("spec_trans", 0.0))) != 0)):
            raise error(f"twosided cannot wrap a {cls.type_name} BSDF with spec_trans > 0 (a transmission lobe)")
        return {**entries, "two_sided": True}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        out = {"type": cls.type_name, "base_color": values["base_color"]}
        for key in ("roughness", *WEIGHTS):
            v = np.asarray(_numpy(values[key]), dtype=np.float64)
            if v.ndim != 1:
                raise ValueError(f"a {key} map has no export here (written as one number)")
            out[key] = float(v[0])
        out["eta"] = float(constants["eta"])
        for key in ("main_specular_sampling_rate", "clearcoat_sampling_rate", "diffuse_reflectance_sampling_rate"):
            out[key] = float(constants[key])
        return {"type": "twosided", "bsdf": out} if constants.get("two_sided") else out


def _numpy(value):
    return value.detach().cpu().numpy() if torch.is_tensor(value) else np.asarray(value)


def read_common(cls, bsdf) -> dict:
    """The parameters both principled materials read alike: ``roughness`` and the blend weights the
    class ``cls`` has."""
    r = np.asarray(cls.read_weight(bsdf, "roughness", kinds.ROUGHNESS, 0.5), dtype=np.float64)
    entries = {"roughness": np.maximum(r, 1e-4)}
    for key, kind in WEIGHTS.items():
        if key in cls.params:
            entries[key] = cls.read_weight(bsdf, key, kind, 0.0)
    return entries
