"""Rough glass: Mitsuba 3's ``roughdielectric``, with the Beckmann distribution (type
``roughdielectric``, Mitsuba's default) or GGX (type ``roughdielectric_ggx``).

A rough interface of relative index ``int_ior / ext_ior`` (defaults bk7 1.5046 over air 1.000277,
numbers or Mitsuba's named media) between the outside (the triangles' front side) and the inside:
Walter et al., "Microfacet Models for Refraction through Rough Surfaces" (EGSR 2007), with the
distributions of :mod:`invrender.plugins.bsdfs.microfacet`. In the shading frame (normal ``n`` turned
to ``wo``, so ``c_o = wo.z > 0``), with ``eta`` the index ratio transmitted over incident
(``int_ior / ext_ior`` from outside, its inverse from inside) and ``F`` the dielectric Fresnel term
(:func:`~invrender.plugins.bsdfs.dielectric.fresnel_dielectric_lanes`):

- reflection (``wi`` on ``wo``'s side): ``h = normalize(wo + wi)``,
  ``f cos = k_r F(wo.h) D(h) G1(wo) G1(wi) / (4 c_o)``;
- transmission (``wi`` on the other side): the generalized half-vector ``h = normalize(wo + eta
  wi)`` turned up, ``f cos = k_t (1 - F(wo.h)) D(h) G1(wo) G1(wi) |wo.h| |wi.h| / (c_o (wo.h +
  eta wi.h)^2)``, both ``wo.h > 0`` and ``wi.h < 0`` (else 0). This is Walter's BTDF times
  ``1 / eta^2``: radiance is scaled across the interface as the smooth ``dielectric`` scales it
  (compressed into a smaller solid angle entering a denser medium; docs/closed_forms.md), and as
  Mitsuba's does in radiance mode.

G1 is Smith's masking of each direction at its angle with the normal (``|cos|``), ``k_r`` and
``k_t`` are ``specular_reflectance`` (a differentiable parameter, a colour or a texture) and
``specular_transmittance`` (an RGB constant), both default 1.

Sampling, as Mitsuba's with ``sample_visible``: a normal h visible from ``wo`` (density ``G1(wo)
wo.h D(h) / c_o``), reflection about it with probability ``F(wo.h)`` (1 under total internal
reflection), else refraction through it; ``pdf`` is that density times ``F`` or ``1 - F`` times the
Jacobian ``1 / (4 wi.h)`` (reflection) or ``eta^2 |wi.h| / (wo.h + eta wi.h)^2`` (refraction), and
the weights are ``k_r G1(wi)`` and ``k_t G1(wi) / eta^2``.

The roughness alpha (``NAME.roughness``, kind ``roughness``) is differentiable as the glossy
conductor's (:mod:`invrender.plugins.bsdfs.glossy`): ``eval`` reads it attached, sampling and ``pdf``
detached, and the weight carries ``D(h; alpha) G1(wo; alpha) / (D(h; alpha_s) G1(wo; alpha_s))``
(:meth:`~invrender.plugins.bsdfs.microfacet.Distribution.reweight_lanes`'s factor, exactly 1 in
value) and ``G1(wi; alpha)``, for both lobes: every estimator stays unbiased in alpha.

Anisotropic (the constant ``alpha_v`` > 0, Mitsuba's ``alpha_u``/``alpha_v``): as the glossy
conductors (:mod:`invrender.plugins.bsdfs.glossy`), in the UV tangent frame, D and G1 of the
half-vector in their anisotropic forms (from inside, the frame's z flipped and the half-vector
turned up: D and G1 are even in each coordinate, so the values are Mitsuba's).

Lobes: glossy reflection and glossy transmission, so next-event estimation gathers light from
either side (docs/integrators.md).
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar

import numpy as np

from invrender import registry
from invrender.errors import SceneError
from invrender.plugins.bsdfs.dielectric import check_relative_ior, fresnel_dielectric_lanes
from invrender.plugins.bsdfs.glossy import ALPHA_V, MIN_ALPHA, alpha_map, anisotropic, mitsuba_alphas, read_alphas
from invrender.plugins.bsdfs.microfacet import BECKMANN, GGX, Distribution, Microfacets
from invrender.scene.formats.mitsuba.bsdfs import NAMED_IOR
from invrender.scene.kinds import ROUGHNESS, SPECULAR_REFLECTANCE
from invrender.scene.plugins import Constant, Param
from invrender.core import lanes
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe
from invrender.core.lanes import scale, select3

#: the interface's indices of refraction (Mitsuba's defaults: bk7 inside, air outside)
INTERFACE_CONSTANTS = {
    "int_ior": Constant(NAMED_IOR["bk7"], 0.0, math.inf, True, True, names=NAMED_IOR),
    "ext_ior": Constant(NAMED_IOR["air"], 0.0, math.inf, True, True, names=NAMED_IOR),
    # RGB, a scene constant (not differentiable: parameter names are kinds, and none is a transmittance)
    "specular_transmittance": Constant((1.0, 1.0, 1.0), 0.0, 1.0, False, False, size=3),
}


def _eta(xp, p, front):
    """The index ratio transmitted over incident: ``int_ior / ext_ior`` from outside (``front``),
    its inverse from inside."""
    eta = p["int_ior"] / p["ext_ior"]
    return xp.select(front, eta, 1.0 / eta)


def _lobe_density(xp, reflected, F, eta, d_o, d_i, denom):
    """The lobe's choice probability times the Jacobian from h to ``wi``: ``F / (4 wo.h)``
    (reflection) or ``(1 - F) eta^2 |wi.h| / (wo.h + eta wi.h)^2`` (refraction), each times ``wo.h``
    (the visible density's, which :func:`eval_lanes` and :func:`sample_lanes` leave out)."""
    return xp.select(reflected, F * 0.25, (1.0 - F) * eta * eta * xp.abs(d_i) * d_o / denom)


def _g1_in(m: Microfacets, xp, wi, h):
    """Masking of ``wi`` (on either side) on ``h``: the isotropic form at ``|cos|``, the anisotropic
    one of ``wi`` itself (its sign is checked against ``h``'s side)."""
    return m.G1((wi[0], wi[1], xp.abs(wi[2])), h) if m.alpha_y is None else m.G1(wi, h)


def eval_lanes(xp, p, ps, wo, wi, front, *, distribution: Distribution, anisotropic: bool = False):
    """``f cos`` of the lobe ``wi``'s side takes (module docstring; roughness ``p``'s) and the pdf
    (``ps``'s): 0 unless ``wo`` lies above the normal, ``wo.h > 0`` and ``wi`` lies on h's side
    that its own side asks."""
    m_s = Microfacets.of(xp, distribution, ps, anisotropic)
    m = m_s if p["roughness"] is ps["roughness"] else Microfacets.of(xp, distribution, p, anisotropic)
    eta = _eta(xp, ps, front)
    c_o, c_i = wo[2], wi[2]
    reflected = c_i > 0.0
    # the (generalized) half-vector, turned up
    h = lanes.normalize(xp, lanes.add(wo, scale(wi, xp.select(reflected, 1.0, eta))))
    h = scale(h, xp.select(h[2] < 0.0, -1.0, 1.0))
    d_o, d_i = lanes.dot(wo, h), lanes.dot(wi, h)
    ok = (c_o > 0.0) & (c_i != 0.0) & (d_o > 0.0) & (d_i * c_i > 0.0)
    F, _ = fresnel_dielectric_lanes(xp, xp.minimum(xp.maximum(d_o, 0.0), 1.0), eta)
    s = d_o + eta * d_i
    denom = xp.maximum(s * s, 1e-12)
    inv_o = 1.0 / xp.maximum(c_o, 1e-12)
    D_s, g1_s = m_s.D(h), m_s.G1(wo, h)
    pdf = xp.select(ok, g1_s * D_s * inv_o * _lobe_density(xp, reflected, F, eta, d_o, d_i, denom), 0.0)
    D, g1_o = (D_s, g1_s) if m is m_s else (m.D(h), m.G1(wo, h))
    common = D * g1_o * _g1_in(m, xp, wi, h) * inv_o
    f_r = xp.select(ok & reflected, F * common * 0.25, 0.0)
    f_t = xp.select(ok & ~reflected, (1.0 - F) * common * d_o * xp.abs(d_i) / denom, 0.0)
    f = lanes.add(scale(p["specular_reflectance"], f_r), scale(p["specular_transmittance"], f_t))
    return f, pdf


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, distribution: Distribution, anisotropic: bool = False):
    """A visible normal h (roughness ``ps``'s); reflection about it with probability F (weight
    ``k_r G1(wi)``), else refraction through it (weight ``k_t G1(wi) / eta^2``), times ``D(h;
    alpha) G1(wo; alpha) / (D(h; alpha_s) G1(wo; alpha_s))`` (``p``'s roughness over ``ps``'s: 1
    in value, the roughness gradient of ``f``); 0 where ``wo`` lies below or ``wi`` on the wrong
    side."""
    m_s = Microfacets.of(xp, distribution, ps, anisotropic)
    m = m_s if p["roughness"] is ps["roughness"] else Microfacets.of(xp, distribution, p, anisotropic)
    eta = _eta(xp, ps, front)
    above = wo[2] > 0.0
    wo_up = (xp.select(above, wo[0], 0.0), xp.select(above, wo[1], 0.0), xp.select(above, wo[2], 1.0))
    h = m_s.sample(wo_up, u0, u1)
    d_o = xp.minimum(xp.maximum(lanes.dot(wo_up, h), 0.0), 1.0)
    F, cos_t = fresnel_dielectric_lanes(xp, d_o, eta)
    reflected = u_lobe < F
    inv = 1.0 / eta
    w_r = lanes.sub(scale(h, 2.0 * d_o), wo_up)
    w_t = lanes.sub(scale(h, d_o * inv - cos_t), scale(wo_up, inv))
    wi = select3(xp, reflected, w_r, w_t)
    c_i = wi[2]
    ok = above & (d_o > 0.0) & xp.select(reflected, c_i > 0.0, (c_i < 0.0) & (cos_t > 0.0))
    d_i = lanes.dot(wi, h)
    s = d_o + eta * d_i
    denom = xp.maximum(s * s, 1e-12)
    D_s, g1_s = m_s.D(h), m_s.G1(wo_up, h)
    pdf = g1_s * D_s / xp.maximum(wo_up[2], 1e-12) * _lobe_density(xp, reflected, F, eta, d_o, d_i, denom)
    g1 = _g1_in(m, xp, wi, h)
    if m is not m_s:  # the same lanes where p is ps (a ratio of exactly 1 otherwise)
        den = D_s * g1_s
        ratio = m.D(h) * m.G1(wo_up, h) / xp.select(den > 0.0, den, 1.0)
        g1 = g1 * xp.select(den > 0.0, ratio, 1.0)
    g1 = xp.select(ok, g1, 0.0)
    weight = select3(xp, reflected, scale(p["specular_reflectance"], g1), scale(p["specular_transmittance"], g1 * inv * inv))
    return wi, weight, xp.select(ok, pdf, 0.0), xp.full(False, u0)


def read_alpha(bsdf, distribution: Distribution):
    """A Mitsuba ``alpha``: a ``<float>`` in [0, 1] (default 0.1, at least 1e-4), or a texture read
    as a roughness map (:func:`~invrender.plugins.bsdfs.glossy.alpha_map`)."""
    textured = alpha_map(bsdf)
    if textured is not None:
        return textured
    return max(bsdf.number("alpha", Constant(0.1, 0.0, 1.0, False, False), f"{distribution.label} roughness", "a <float> or a texture"), MIN_ALPHA)


@registry.MATERIALS.register
class RoughDielectric(LaneBSDF):
    """Written once in lane form (:func:`eval_lanes`, :func:`sample_lanes`), its distribution bound
    when the form is built."""

    type_name = "roughdielectric"
    lobes = Lobe.GLOSSY | Lobe.GLOSSY_TRANSMISSION
    params = {
        "specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0),
        "roughness": Param(ROUGHNESS, 0.1),
    }
    constants = {**INTERFACE_CONSTANTS, "alpha_v": ALPHA_V}
    doc = "rough glass: Beckmann microfacet reflection and refraction (Mitsuba's roughdielectric, its default distribution)"
    #: the microfacet distribution
    distribution: ClassVar[Distribution] = BECKMANN

    def lane_form(self) -> LaneForm:
        aniso = anisotropic(self)
        keys = (("specular_reflectance", 3), ("roughness", 1), ("int_ior", 1), ("ext_ior", 1), ("specular_transmittance", 3)) + ((("alpha_v", 1),) if aniso else ())
        bound = {"distribution": self.distribution, "anisotropic": aniso}
        return LaneForm(keys, functools.partial(eval_lanes, **bound), functools.partial(sample_lanes, **bound), tangent=aniso)

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        """The indices must differ (an index-matched interface has no half-vector to refract about), and
        their ratio be one real media have (:func:`~invrender.plugins.bsdfs.dielectric.check_relative_ior`)."""
        if constants["int_ior"] == constants["ext_ior"]:
            raise SceneError(f"{where}: 'int_ior' and 'ext_ior' must differ (both {constants['int_ior']:g}): an index-matched interface is not a {cls.type_name}")
        check_relative_ior(where, constants["int_ior"], constants["ext_ior"])
        return constants

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("roughdielectric",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``roughdielectric``: ``distribution`` beckmann (its default: type
        roughdielectric) or ggx (type roughdielectric_ggx), ``alpha`` (the roughness,
        default 0.1) or ``alpha_u`` and ``alpha_v`` (anisotropic: the roughness and the constant
        ``alpha_v``, as the glossy conductors read them), ``int_ior``/``ext_ior`` (numbers or named media, default bk7 / air),
        ``specular_reflectance`` (a colour or a bitmap texture) and ``specular_transmittance``
        (a colour), default 1, ``sample_visible`` (read; invrender always samples visible normals).
        ``alpha`` may be a texture (a bitmap or checkerboard), read as one number per texel as
        Mitsuba's ``eval_1`` reads it (:func:`read_alpha`)."""
        name = (bsdf.string("distribution", allowed=("beckmann", "ggx")) or "beckmann").lower()
        target = RoughDielectric if name == "beckmann" else RoughDielectricGGX
        if bsdf.has("alpha_u") or bsdf.has("alpha_v"):  # anisotropic: numbers
            alphas = read_alphas(bsdf, target.distribution.label)
        else:  # a number or a roughness map
            alphas = {"roughness": read_alpha(bsdf, target.distribution)}
        int_ior, ext_ior = bsdf.ior("int_ior", "bk7"), bsdf.ior("ext_ior", "air")
        kr = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0)
        kt = bsdf.colour("specular_transmittance", SPECULAR_REFLECTANCE, 1.0, texture=False)
        bsdf.boolean("sample_visible")
        bsdf.finish(("distribution", "alpha", "alpha_u", "alpha_v", "int_ior", "ext_ior", "specular_reflectance", "specular_transmittance", "sample_visible"))
        return {"type": target.type_name, **alphas, "int_ior": int_ior, "ext_ior": ext_ior, "specular_reflectance": kr, "specular_transmittance": kt}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        alpha = values["roughness"]
        return {
            "type": "roughdielectric",
            "distribution": cls.distribution.name,
            **(mitsuba_alphas(float(alpha[0]), constants) if alpha.ndim == 1 else {"alpha": alpha}),  # a map: a (grey) bitmap
            "int_ior": float(constants["int_ior"]),
            "ext_ior": float(constants["ext_ior"]),
            "specular_reflectance": values["specular_reflectance"],
            "specular_transmittance": np.asarray(constants.get("specular_transmittance", (1.0, 1.0, 1.0)), dtype=np.float64),
            "sample_visible": True,
        }


@registry.MATERIALS.register
class RoughDielectricGGX(RoughDielectric):
    type_name = "roughdielectric_ggx"
    doc = "rough glass with the GGX distribution (Mitsuba's roughdielectric, distribution ggx)"
    distribution = GGX
    # the same Mitsuba plugin (its distribution picks the type: RoughDielectric.from_mitsuba, inherited)
    mitsuba_plugins = ("roughdielectric",)
