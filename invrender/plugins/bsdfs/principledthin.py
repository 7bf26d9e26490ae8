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
import torch

from invrender import registry
from invrender.core.bsdf import BSDFSample, Lobe, ShadingPoint
from invrender.plugins.bsdfs.microfacet import ggx_D_aniso, ggx_G1_aniso, ggx_visible_pdf_aniso, sample_visible_normal
from invrender.plugins.bsdfs.plastic import cosine_hemisphere
from invrender.plugins.bsdfs.principled import (
    ETA, WEIGHTS, PrincipledBase, compatible, params_with, diffuse_retro, distribution_alphas, fresnel, read_common, safe, schlick, schlick_r0, schlick_weight, sheen_colour,
    tint_colour, _numpy,
)  # fmt: skip
from invrender.scene import kinds
from invrender.scene.plugins import Constant
from invrender.vec import dot, normalize

#: the weights the thin sheet has (no metallic, no clearcoat)
THIN_WEIGHTS = {k: WEIGHTS[k] for k in ("spec_tint", "anisotropic", "sheen", "sheen_tint", "spec_trans", "flatness")}
#: its sampling rates (constants, default 1)
RATES = ("specular_reflectance_sampling_rate", "specular_transmittance_sampling_rate", "diffuse_reflectance_sampling_rate", "diffuse_transmittance_sampling_rate")


@registry.MATERIALS.register
class PrincipledThin(PrincipledBase):
    type_name = "principledthin"
    lobes = Lobe.DIFFUSE | Lobe.GLOSSY | Lobe.GLOSSY_TRANSMISSION
    params = params_with(THIN_WEIGHTS)
    constants = {
        "eta": ETA,
        "diff_trans": Constant(0.0, 0.0, 2.0, False, False),
        **{k: Constant(1.0, 0.0, math.inf, False, True) for k in RATES},
    }
    doc = "Disney's thin principled BSDF (Mitsuba's principledthin): a two-sided sheet with diffuse, sheen, GGX specular reflection and transmission, diffuse transmission"

    def _mirror(self, sp: ShadingPoint, wl: torch.Tensor):
        """``(a, b)``: the local directions mirrored through the origin where ``a`` lies below
        (the sheet is symmetric), so that ``c_a >= 0``."""
        a = sp.wo_local
        s = torch.where(a[:, 2] < 0, -1.0, 1.0)[:, None]
        return a * s, wl * s, s

    def _probabilities(self, sp: ShadingPoint):
        """The lobe probabilities (specular reflection, specular transmission, diffuse reflection,
        diffuse transmission), (N,) each, at the detached spec_trans."""
        st = self.grey("spec_trans", sp)[1]
        dt = 0.5 * self.constant("diff_trans", sp)
        r_sr, r_st, r_dr, r_dt = (self.constant(k, sp) for k in RATES)
        p = (0.5 * st * r_sr, 0.5 * st * r_st, r_dr * (1.0 - st) * (1.0 - dt), r_dt * (1.0 - st) * dt)
        total = p[0] + p[1] + p[2] + p[3]
        inv = torch.where(total > 0, 1.0 / safe(total), 0.0)
        return tuple(q * inv for q in p)

    def _half(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(N, 3) ``normalize(a + b_r)``, ``b_r`` = ``b`` with ``|z|``."""
        b_r = torch.stack([b[:, 0], b[:, 1], b[:, 2].abs()], dim=1)
        return normalize(a + b_r)

    def _value(self, sp: ShadingPoint, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """``f |c_b|`` (N, 3) (module docstring), parameters attached; ``c_a >= 0``."""
        c_a, c_b = a[:, 2], b[:, 2]
        active = c_a != 0
        reflect, refract = c_b > 0, c_b < 0
        base = self.param("base_color", sp)
        w = {k: self.grey(k, sp)[0] for k in THIN_WEIGHTS}
        r = self.grey("roughness", sp)[0]
        st, dt = w["spec_trans"], 0.5 * self.constant("diff_trans", sp)
        eta = self.constant("eta", sp)
        h = self._half(a, b)
        d_a = dot(a, h)
        F = fresnel(d_a, eta)
        inv_4ca = 1.0 / safe(4.0 * c_a)
        # specular reflection, its Fresnel term tinted by spec_tint
        ax, ay = distribution_alphas(w["anisotropic"], r)
        on = active & reflect & compatible(h, a, b, c_a, True)
        F_thin = F[:, None] + w["spec_tint"][:, None] * (schlick(tint_colour(base) * schlick_r0(eta)[:, None], d_a, eta) - F[:, None])
        g = ggx_D_aniso(h, ax, ay) * ggx_G1_aniso(a, h, ax, ay) * ggx_G1_aniso(b, h, ax, ay) * inv_4ca
        value = F_thin * torch.where(on, st * g, 0.0)[:, None]
        # specular transmission: the roughness scaled by the index
        ax_t, ay_t = distribution_alphas(w["anisotropic"], (0.65 * eta - 0.35) * r)
        on = active & refract & compatible(h, a, b, c_a, False)
        g = ggx_D_aniso(h, ax_t, ay_t) * ggx_G1_aniso(a, h, ax_t, ay_t) * ggx_G1_aniso(b, h, ax_t, ay_t) * inv_4ca
        value = value + base * torch.where(on, st * (1.0 - F) * g, 0.0)[:, None]
        # diffuse with retro-reflection and flatness, and sheen
        on = active & reflect & (dt < 1)
        cos_d = dot(h, b)
        lobe = diffuse_retro(c_a, c_b, cos_d, r, w["flatness"])
        value = value + base * torch.where(on, (1.0 - st) * c_b / math.pi * (1.0 - dt) * lobe, 0.0)[:, None]
        sheen = sheen_colour(base, w["sheen_tint"]) * torch.where(on, w["sheen"] * (1.0 - st) * schlick_weight(cos_d.abs()) * (1.0 - dt) * c_b.abs(), 0.0)[:, None]
        value = value + sheen
        # diffuse transmission
        on = active & refract & (dt > 0)
        return value + base * torch.where(on, (1.0 - st) * dt / math.pi * c_b.abs(), 0.0)[:, None]

    def _pdf(self, sp: ShadingPoint, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """(N,) the sampling density of ``b`` (``c_a >= 0``), detached parameters."""
        c_a, c_b = a[:, 2], b[:, 2]
        reflect, refract = c_b > 0, c_b < 0
        p_sr, p_st, p_dr, p_dt = self._probabilities(sp)
        r, aniso = self.grey("roughness", sp)[1], self.grey("anisotropic", sp)[1]
        eta = self.constant("eta", sp)
        h = self._half(a, b)
        b_r = torch.stack([b[:, 0], b[:, 1], c_b.abs()], dim=1)
        jacobian = (1.0 / safe(4.0 * dot(b_r, h))).abs()
        ax, ay = distribution_alphas(aniso, r)
        ax_t, ay_t = distribution_alphas(aniso, (0.65 * eta - 0.35) * r)
        mirror = compatible(h, a, b, c_a, True) & reflect
        through = compatible(h, a, b, c_a, False) & refract
        pdf = torch.where(mirror, p_sr * ggx_visible_pdf_aniso(a, h, ax, ay) * jacobian, 0.0)
        pdf = pdf + torch.where(through, p_st * ggx_visible_pdf_aniso(a, h, ax_t, ay_t) * jacobian, 0.0)
        pdf = pdf + torch.where(reflect, p_dr * c_b / math.pi, 0.0) + torch.where(refract, p_dt * -c_b / math.pi, 0.0)
        return torch.where(c_a != 0, pdf, 0.0)

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``f |cos theta_i|`` (N, 3) of all lobes (differentiable in every parameter)."""
        a, b, _ = self._mirror(sp, sp.frame.to_local(wi))
        return self._value(sp, a, b)

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """(N,) the lobes' densities mixed by their (detached) probabilities."""
        a, b, _ = self._mirror(sp, sp.frame.to_local(wi))
        return self._pdf(sp, a, b)

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """``u_lobe`` picks specular reflection, specular transmission, diffuse reflection or
        diffuse transmission (in that order); ``u_dir`` draws a visible GGX normal (reflected
        about, and for transmission mirrored below) or a cosine-weighted direction (below for
        transmission). Weight ``f cos / pdf`` (``f`` attached)."""
        a, _, s = self._mirror(sp, sp.wo_local)
        p_sr, p_st, p_dr, _ = self._probabilities(sp)
        r, aniso = self.grey("roughness", sp)[1], self.grey("anisotropic", sp)[1]
        eta = self.constant("eta", sp)
        spec_r = u_lobe < p_sr
        spec_t = ~spec_r & (u_lobe < p_sr + p_st)
        diff_r = ~spec_r & ~spec_t & (u_lobe < p_sr + p_st + p_dr)
        diff_t = ~spec_r & ~spec_t & ~diff_r & (0.5 * self.constant("diff_trans", sp) > 0)
        scale = torch.where(spec_t, 0.65 * eta - 0.35, 1.0)
        ax, ay = distribution_alphas(aniso, scale * r)
        up = torch.where((a[:, 2] > 0)[:, None], a, torch.tensor([0.0, 0.0, 1.0], device=a.device))
        h = sample_visible_normal(up, ax, u_dir, ay)
        w_r = 2.0 * dot(a, h)[:, None] * h - a
        w_t = w_r * torch.tensor([1.0, 1.0, -1.0], device=a.device)
        cos = cosine_hemisphere(u_dir)
        b = torch.where(spec_r[:, None], w_r, torch.where(spec_t[:, None], w_t, torch.where(diff_r[:, None], cos, -cos)))
        ok = (a[:, 2] != 0) & (spec_r | spec_t | diff_r | diff_t)
        ok = ok & torch.where(spec_r, compatible(h, a, b, a[:, 2], True) & (b[:, 2] > 0), True)
        ok = ok & torch.where(spec_t, compatible(h, a, b, a[:, 2], False) & (b[:, 2] < 0), True)
        pdf = torch.where(ok, self._pdf(sp, a, b), 0.0)
        ok = ok & (pdf > 0)
        weight = torch.where(ok[:, None], self._value(sp, a, b) / safe(pdf)[:, None], 0.0)
        return BSDFSample(sp.frame.to_world(b * s), weight, torch.where(ok, pdf, 0.0), torch.zeros_like(ok))

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
