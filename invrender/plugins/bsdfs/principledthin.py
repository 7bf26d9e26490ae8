"""The thin principled BSDF: Mitsuba 3's ``principledthin``, Burley 2015's thin-surface variant of
the principled BSDF (a sheet with no inside: leaves, paper, fabric), matched to Mitsuba's ``eval``
and ``pdf`` term by term (``docs/rendering.md#principled-materials``).

The sheet is symmetric: both directions are first mirrored to the side of ``a`` (the direction
towards the camera, ``c_a > 0``; ``b`` towards the light). ``h = normalize(a + b_r)`` with ``b_r``
``b`` reflected up. With ``st`` = spec_trans and ``dt`` = diff_trans / 2 (Mitsuba's diff_trans runs
from 0 to 2) and the helpers of :mod:`~invrender.plugins.bsdfs.principled`:

- specular reflection (``b`` above): ``st lerp(F, Schlick(c_tint R0(eta)), spec_tint) D G / (4 c_a)``,
  GGX of the principled alphas;
- specular transmission (``b`` below, the mirror image of a reflection): ``st base_color (1 - F) D' G'
  / (4 c_a)`` with the roughness scaled by ``0.65 eta - 0.35`` (Burley 2015, figure 15);
- diffuse with retro-reflection and flatness, and sheen, times ``(1 - st)(1 - dt)`` (``b`` above);
- diffuse transmission (``b`` below): ``(1 - st) dt base_color / pi |c_b|``.

spec_trans multiplies its lobes with no mask at 0 or 1 (Mitsuba masks them: the same values), so
its derivative there is the lobes'.

Sampling: the lobes with probabilities ``st r_sr / 2``, ``st r_st / 2``, ``(1 - st)(1 - dt) r_dr``,
``(1 - st) dt r_dt`` (normalized; the ``r`` are sampling rates, default 1), visible GGX normals for the
specular ones and the cosine for the diffuse ones; ``pdf`` is their mixture. ``eta`` (default 1.5)
and ``diff_trans`` are constants here (Mitsuba's are textures).
"""

from __future__ import annotations

import math

import numpy as np

from invrender import registry
from invrender.core import lanes
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe
from invrender.plugins.bsdfs.microfacet import ggx_D_aniso_lanes, ggx_G1_aniso_lanes, ggx_sample_visible_lanes, ggx_visible_pdf_aniso_lanes
from invrender.plugins.bsdfs.plastic import cosine_hemisphere_lanes
from invrender.plugins.bsdfs.principled import (
    ETA, WEIGHTS, PrincipledBase, alphas_lanes, compatible_lanes, diffuse_retro_lanes, fresnel_lanes, params_with, read_common, safe_lanes, schlick_lanes,
    schlick_weight_lanes, tint_lanes, _numpy,
)  # fmt: skip
from invrender.scene import kinds
from invrender.scene.plugins import Constant

#: the weights the thin sheet has (no metallic, no clearcoat)
THIN_WEIGHTS = {k: WEIGHTS[k] for k in ("spec_tint", "anisotropic", "sheen", "sheen_tint", "spec_trans", "flatness")}
#: its sampling rates (constants, default 1)
RATES = ("specular_reflectance_sampling_rate", "specular_transmittance_sampling_rate", "diffuse_reflectance_sampling_rate", "diffuse_transmittance_sampling_rate")


def _probabilities_lanes(xp, ps):
    """The lobe probabilities (specular reflection, specular transmission, diffuse reflection,
    diffuse transmission) at the detached spec_trans."""
    st = ps["spec_trans"]
    dt = 0.5 * ps["diff_trans"]
    r_sr, r_st, r_dr, r_dt = (ps[k] for k in RATES)
    p = (0.5 * st * r_sr, 0.5 * st * r_st, r_dr * (1.0 - st) * (1.0 - dt), r_dt * (1.0 - st) * dt)
    total = p[0] + p[1] + p[2] + p[3]
    inv = xp.select(total > 0.0, 1.0 / safe_lanes(xp, total), 0.0)
    return tuple(q * inv for q in p)


def _half_lanes(xp, a, b):
    """``normalize(a + b_r)``, ``b_r`` = ``b`` with ``|z|``."""
    return lanes.normalize(xp, (a[0] + b[0], a[1] + b[1], a[2] + xp.abs(b[2])))


def thin_value_lanes(xp, p, a, b, h):
    """``f |c_b|`` (a 3-tuple; module docstring) at parameters ``p``; ``c_a >= 0``, ``h`` the half
    vector (:func:`_half_lanes`)."""
    c_a, c_b = a[2], b[2]
    active = c_a != 0.0
    reflect, refract = c_b > 0.0, c_b < 0.0
    base = p["base_color"]
    r, st, dt, eta = p["roughness"], p["spec_trans"], 0.5 * p["diff_trans"], p["eta"]
    d_a = lanes.dot(a, h)
    F = fresnel_lanes(xp, d_a, eta)
    inv_4ca = 1.0 / safe_lanes(xp, 4.0 * c_a)
    # specular reflection, its Fresnel term tinted by spec_tint
    ax, ay = alphas_lanes(xp, p["anisotropic"], r)
    on = active & reflect & compatible_lanes(xp, h, a, b, c_a, True)
    r0 = (eta - 1.0) / (eta + 1.0)
    c_tint = tint_lanes(xp, base)
    s_tint = schlick_lanes(xp, tuple(c * (r0 * r0) for c in c_tint), d_a, eta)
    g = ggx_D_aniso_lanes(xp, h, ax, ay) * ggx_G1_aniso_lanes(xp, a, h, ax, ay) * ggx_G1_aniso_lanes(xp, b, h, ax, ay) * inv_4ca
    spec = xp.select(on, st * g, 0.0)
    value = tuple((F + p["spec_tint"] * (s - F)) * spec for s in s_tint)
    # specular transmission: the roughness scaled by the index
    ax_t, ay_t = alphas_lanes(xp, p["anisotropic"], (0.65 * eta - 0.35) * r)
    on = active & refract & compatible_lanes(xp, h, a, b, c_a, False)
    g = ggx_D_aniso_lanes(xp, h, ax_t, ay_t) * ggx_G1_aniso_lanes(xp, a, h, ax_t, ay_t) * ggx_G1_aniso_lanes(xp, b, h, ax_t, ay_t) * inv_4ca
    trans = xp.select(on, st * (1.0 - F) * g, 0.0)
    # diffuse with retro-reflection and flatness, and sheen; diffuse transmission
    on = active & reflect & (dt < 1.0)
    cos_d = lanes.dot(h, b)
    diff = xp.select(on, (1.0 - st) * c_b * (1.0 / math.pi) * (1.0 - dt) * diffuse_retro_lanes(xp, c_a, c_b, cos_d, r, p["flatness"]), 0.0)
    sh = xp.select(on, p["sheen"] * (1.0 - st) * schlick_weight_lanes(xp, xp.abs(cos_d)) * (1.0 - dt) * xp.abs(c_b), 0.0)
    on = active & refract & (dt > 0.0)
    diff_t = xp.select(on, (1.0 - st) * dt * (1.0 / math.pi) * xp.abs(c_b), 0.0)
    sheen_tint = p["sheen_tint"]
    return tuple(v + c * (trans + diff + diff_t) + (1.0 + sheen_tint * (k - 1.0)) * sh for v, c, k in zip(value, base, c_tint))


def thin_pdf_lanes(xp, ps, a, b, h):
    """The sampling density of ``b`` (``c_a >= 0``) at the detached parameters ``ps``."""
    c_a, c_b = a[2], b[2]
    reflect, refract = c_b > 0.0, c_b < 0.0
    p_sr, p_st, p_dr, p_dt = _probabilities_lanes(xp, ps)
    r, aniso, eta = ps["roughness"], ps["anisotropic"], ps["eta"]
    jacobian = xp.abs(1.0 / safe_lanes(xp, 4.0 * lanes.dot((b[0], b[1], xp.abs(c_b)), h)))
    ax, ay = alphas_lanes(xp, aniso, r)
    ax_t, ay_t = alphas_lanes(xp, aniso, (0.65 * eta - 0.35) * r)
    mirror = compatible_lanes(xp, h, a, b, c_a, True) & reflect
    through = compatible_lanes(xp, h, a, b, c_a, False) & refract
    pdf = xp.select(mirror, p_sr * ggx_visible_pdf_aniso_lanes(xp, a, h, ax, ay) * jacobian, 0.0)
    pdf = pdf + xp.select(through, p_st * ggx_visible_pdf_aniso_lanes(xp, a, h, ax_t, ay_t) * jacobian, 0.0)
    pdf = pdf + xp.select(reflect, p_dr * c_b * (1.0 / math.pi), 0.0) + xp.select(refract, p_dt * -c_b * (1.0 / math.pi), 0.0)
    return xp.select(c_a != 0.0, pdf, 0.0)


def _mirrored(xp, wo, wi):
    """``(a, b, s)``: the local directions mirrored through the origin where ``wo`` lies below (the
    sheet is symmetric), so that ``c_a >= 0``; ``s`` the sign."""
    s = xp.select(wo[2] < 0.0, -1.0, 1.0)
    return lanes.scale(wo, s), lanes.scale(wi, s), s


def thin_eval_lanes(xp, p, ps, wo, wi, front):
    """``f |cos theta_i|`` of all lobes (``p``) and their densities mixed by their probabilities (``ps``)."""
    a, b, _ = _mirrored(xp, wo, wi)
    h = _half_lanes(xp, a, b)
    return thin_value_lanes(xp, p, a, b, h), thin_pdf_lanes(xp, ps, a, b, h)


def thin_sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1):
    """``u_lobe`` picks specular reflection, specular transmission, diffuse reflection or diffuse
    transmission (in that order); ``u0, u1`` draw a visible GGX normal (reflected about, and for
    transmission mirrored below) or a cosine-weighted direction (below for transmission). Weight
    ``f cos / pdf`` (``f`` at ``p``)."""
    a, _, s = _mirrored(xp, wo, wo)
    p_sr, p_st, p_dr, _ = _probabilities_lanes(xp, ps)
    spec_r = u_lobe < p_sr
    spec_t = ~spec_r & (u_lobe < p_sr + p_st)
    diff_r = ~spec_r & ~spec_t & (u_lobe < p_sr + p_st + p_dr)
    diff_t = ~spec_r & ~spec_t & ~diff_r & (0.5 * ps["diff_trans"] > 0.0)
    k = xp.select(spec_t, 0.65 * ps["eta"] - 0.35, 1.0)
    ax, ay = alphas_lanes(xp, ps["anisotropic"], k * ps["roughness"])
    one = 0.0 * a[2] + 1.0
    h = ggx_sample_visible_lanes(xp, lanes.select3(xp, a[2] > 0.0, a, (0.0 * one, 0.0 * one, one)), ax, ay, u0, u1)
    w_r = lanes.reflect(a, h)
    cos = cosine_hemisphere_lanes(xp, u0, u1)
    b = lanes.select3(xp, spec_r, w_r, lanes.select3(xp, spec_t, (w_r[0], w_r[1], -w_r[2]), lanes.select3(xp, diff_r, cos, lanes.scale(cos, -1.0))))
    ok = (a[2] != 0.0) & (spec_r | spec_t | diff_r | diff_t)
    ok = ok & (~spec_r | (compatible_lanes(xp, h, a, b, a[2], True) & (b[2] > 0.0)))
    ok = ok & (~spec_t | (compatible_lanes(xp, h, a, b, a[2], False) & (b[2] < 0.0)))
    hb = _half_lanes(xp, a, b)
    pdf = xp.select(ok, thin_pdf_lanes(xp, ps, a, b, hb), 0.0)
    ok = ok & (pdf > 0.0)
    inv = 1.0 / safe_lanes(xp, pdf)
    weight = tuple(xp.select(ok, v * inv, 0.0) for v in thin_value_lanes(xp, p, a, b, hb))
    return lanes.scale(b, s), weight, xp.select(ok, pdf, 0.0), xp.full(False, u0)


#: the lane form's keys of the thin sheet
THIN_KEYS = (("base_color", 3), ("roughness", 1), *((k, 1) for k in THIN_WEIGHTS), ("eta", 1), ("diff_trans", 1), *((k, 1) for k in RATES))


@registry.MATERIALS.register
class PrincipledThin(PrincipledBase, LaneBSDF):
    type_name = "principledthin"
    lobes = Lobe.DIFFUSE | Lobe.GLOSSY | Lobe.GLOSSY_TRANSMISSION
    params = params_with(THIN_WEIGHTS)
    constants = {
        "eta": ETA,
        "diff_trans": Constant(0.0, 0.0, 2.0, False, False),
        **{k: Constant(1.0, 0.0, math.inf, False, True) for k in RATES},
    }
    doc = "Disney's thin principled BSDF (Mitsuba's principledthin): a two-sided sheet with diffuse, sheen, GGX specular reflection and transmission, diffuse transmission"

    def lane_form(self) -> LaneForm:
        # an anisotropic lobe turns with the UV tangent frame (Mitsuba's dp/du); an isotropic one keeps any frame
        anisotropic = any(bool((v["anisotropic"] != 0).any()) for v in self.sampling_values)
        return LaneForm(THIN_KEYS, thin_eval_lanes, thin_sample_lanes, tangent=anisotropic)

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("principledthin",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``principledthin``: ``base_color`` (colour or bitmap, default 0.5),
        ``roughness`` (default 0.5; 0 read as 1e-4), the weights ``spec_tint``, ``anisotropic``,
        ``sheen``, ``sheen_tint``, ``spec_trans``, ``flatness`` (numbers, colours or bitmaps, default
        0), ``eta`` (a number, default 1.5), ``diff_trans`` (a number in [0, 2], default 0) and the
        four sampling rates."""
        entries = {"base_color": bsdf.colour("base_color", kinds.BASE_COLOR, 0.5)}
        entries.update(read_common(cls, bsdf))
        entries["eta"] = bsdf.number("eta", cls.constants["eta"], "relative index of refraction of the sheet", "a <float> (a texture is not supported)")
        entries["diff_trans"] = bsdf.number("diff_trans", cls.constants["diff_trans"], "diffuse transmission, 0 to 2", "a <float> (a texture is not supported)")
        for key in RATES:
            entries[key] = bsdf.number(key, cls.constants[key], "a lobe's sampling rate")
        bsdf.finish(("base_color", "roughness", *THIN_WEIGHTS, "eta", "diff_trans", *RATES))
        return entries

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        out = {"type": cls.type_name, "base_color": values["base_color"]}
        for key in ("roughness", *THIN_WEIGHTS):
            v = np.asarray(_numpy(values[key]), dtype=np.float64)
            if v.ndim != 1:
                raise ValueError(f"a {key} map has no export here (written as one number)")
            out[key] = float(v[0])
        for key in ("eta", "diff_trans", *RATES):
            out[key] = float(constants[key])
        return out
