"""Mitsuba 3's polarized plastic ``pplastic`` as its RGB variants render it (type ``pplastic``,
Beckmann, Mitsuba's default distribution; ``pplastic_ggx``, GGX).

Mitsuba's ``pplastic`` (Baek et al. 2018, "Simultaneous acquisition of polarimetric SVBRDF and
normals") tracks the polarization of light; its RGB variants (``llvm_ad_rgb``) drop the Mueller
matrices and evaluate the unpolarized model, which is what invrender renders. For ``wo`` (towards
the camera) and ``wi`` (towards the light) at cosines ``c_o``, ``c_i`` with the normal, both > 0
(else 0), ``h = normalize(wo + wi)``, F the dielectric Fresnel term of the relative index ``eta =
int_ior / ext_ior`` (defaults polypropylene 1.49 over air 1.000277):

    f cos = k_s F(wo . h) D(h) G1(wo) G1(wi) / (4 c_o)  +  rho (1 - F(c_o)) (1 - F(c_i)) c_i / pi

a rough specular reflection over a Lambertian base seen through two smooth refractions (no
``1 / eta^2``, no internal reflections: unlike ``roughplastic``, not energy conserving). ``rho``
is Mitsuba's ``diffuse_reflectance`` (``reflectance`` here), ``k_s`` its ``specular_reflectance``
(default 1), alpha its ``alpha`` (``roughness``; a number or a grey map, differentiable: ``eval``
reads it attached, sampling and ``pdf`` detached, as the glossy materials).

Sampling, Mitsuba's: the specular lobe with the constant probability ``P_s = mean(k_s) / (mean(rho)
+ mean(k_s))`` (the constant ``specular_sampling_weight``, computed from the values a scene is
built with unless given), a visible normal's reflection; else a cosine-weighted direction;
``pdf = P_s D(h) G1(wo) / (4 c_o) + (1 - P_s) c_i / pi`` and the weight ``f cos / pdf`` of the
whole BSDF.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar

import torch

from invrender import registry
from invrender.plugins.bsdfs.dielectric import fresnel_dielectric_lanes
from invrender.plugins.bsdfs.microfacet import BECKMANN, GGX, Distribution
from invrender.plugins.bsdfs.plastic import COATING_CONSTANTS, coating_constants, cosine_hemisphere_lanes
from invrender.plugins.bsdfs.glossy import MIN_ALPHA, at_least
from invrender.scene.kinds import REFLECTANCE, ROUGHNESS, SPECULAR_REFLECTANCE
from invrender.scene.plugins import Param
from invrender.core import lanes
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe, ShadingPoint
from invrender.core.lanes import scale, select3

KEYS = (("reflectance", 3), ("specular_reflectance", 3), ("roughness", 1), ("eta", 1), ("specular_sampling_weight", 1))


def _fresnel(xp, cos, eta):
    return fresnel_dielectric_lanes(xp, xp.minimum(xp.maximum(cos, 0.0), 1.0), eta)[0]


def eval_lanes(xp, p, ps, wo, wi, front, *, distribution: Distribution):
    """``f cos`` (the module docstring's; roughness ``p``'s) and the pdf (``ps``'s)."""
    d = distribution
    c_o, c_i = wo[2], wi[2]
    h = lanes.normalize(xp, lanes.add(wo, wi))
    d_o, d_i = lanes.dot(wo, h), lanes.dot(wi, h)
    ok = (c_o > 0.0) & (c_i > 0.0)
    visible = ok & (d_o > 0.0) & (d_i > 0.0)
    inv_4co = 1.0 / (4.0 * xp.maximum(c_o, 1e-12))
    alpha, alpha_s = p["roughness"], ps["roughness"]
    D_s, g_o_s = d.D_lanes(xp, h[2], alpha_s), d.G1_lanes(xp, c_o, alpha_s)
    p_s = ps["specular_sampling_weight"]
    pdf = xp.select(ok, p_s * xp.select(visible, D_s * g_o_s * inv_4co, 0.0) + (1.0 - p_s) * c_i * (1.0 / math.pi), 0.0)
    D, g_o = (D_s, g_o_s) if alpha is alpha_s else (d.D_lanes(xp, h[2], alpha), d.G1_lanes(xp, c_o, alpha))
    eta = p["eta"]
    spec = xp.select(visible, _fresnel(xp, d_o, eta) * D * g_o * d.G1_lanes(xp, c_i, alpha) * inv_4co, 0.0)
    diff = xp.select(ok, (1.0 - _fresnel(xp, c_o, eta)) * (1.0 - _fresnel(xp, c_i, eta)) * c_i * (1.0 / math.pi), 0.0)
    return lanes.add(scale(p["specular_reflectance"], spec), scale(p["reflectance"], diff)), pdf


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, distribution: Distribution):
    """A visible normal's reflection with probability P_s, else a cosine-weighted direction
    (detached roughness); weight ``f cos / pdf`` of the whole BSDF, 0 where ``wo`` lies below."""
    above = wo[2] > 0.0
    one = xp.full(1.0, u0)
    wo_up = select3(xp, above, wo, (0.0 * one, 0.0 * one, one))
    h = distribution.sample_visible_lanes(xp, wo_up, ps["roughness"], u0, u1)
    wi = select3(xp, u_lobe < ps["specular_sampling_weight"], lanes.reflect(wo_up, h), cosine_hemisphere_lanes(xp, u0, u1))
    f, pdf = eval_lanes(xp, p, ps, wo, wi, front, distribution=distribution)
    ok = above & (pdf > 0.0)
    weight = tuple(xp.select(ok, x / xp.maximum(pdf, 1e-30), 0.0) for x in f)
    return wi, weight, xp.select(ok, pdf, 0.0), xp.full(False, u0)


@registry.MATERIALS.register
class PolarizedPlastic(LaneBSDF):
    """Written once in lane form (:func:`eval_lanes`, :func:`sample_lanes`), its distribution bound
    when the form is built."""

    type_name = "pplastic"
    lobes = Lobe.GLOSSY | Lobe.DIFFUSE
    params = {"reflectance": Param(REFLECTANCE, 0.5), "specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0), "roughness": Param(ROUGHNESS, 0.1)}
    constants = {k: v for k, v in COATING_CONSTANTS.items() if k != "nonlinear"}
    doc = "Mitsuba's polarized plastic (pplastic) as its RGB variants render it: Beckmann specular over a diffuse base seen through two refractions, two-sided"
    #: the microfacet distribution
    distribution: ClassVar[Distribution] = BECKMANN

    def lane_form(self) -> LaneForm:
        bound = {"distribution": self.distribution}
        return LaneForm(KEYS, functools.partial(eval_lanes, **bound), functools.partial(sample_lanes, **bound))

    def lane_rows(self, key: str, sampling: bool, device) -> torch.Tensor | None:
        """``eta``: the relative index ``int_ior / ext_ior`` (M, 1)."""
        if key == "eta":
            return torch.tensor([[c["int_ior"] / c["ext_ior"]] for c in self.constants], dtype=torch.float32, device=device)
        return None

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor:
        return self.param("reflectance", sp)

    @classmethod
    def not_polynomial(cls, key: str, constants: dict) -> str | None:
        return f"a {cls.type_name}'s value sums two lobes (k_s times the specular one, rho times the diffuse one), not one monomial"

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        """The indices must differ (as Mitsuba's); the sampling weight from the values unless given."""
        return coating_constants(where, values, constants, given, "pplastic")

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("pplastic",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``pplastic``: ``diffuse_reflectance`` and ``specular_reflectance`` (colours or
        bitmaps, defaults 0.5 and 1), ``int_ior``/``ext_ior`` (numbers or named media, default
        polypropylene / air) or ``eta`` (a number: their ratio, not both), ``distribution``
        beckmann (its default: type pplastic) or ggx (type pplastic_ggx), isotropic ``alpha`` (a
        number or a bitmap read as one number, as Mitsuba's ``eval_1``: its luminance; default
        0.1; below 1e-4 read as 1e-4, as Mitsuba clamps it), ``sample_visible`` (read; invrender always samples visible normals)."""
        name = (bsdf.string("distribution", allowed=("beckmann", "ggx")) or "beckmann").lower()
        target = PolarizedPlastic if name == "beckmann" else PolarizedPlasticGGX
        for key in ("alpha_u", "alpha_v"):
            if bsdf.has(key):
                raise bsdf.error(key, f"'{key}' (anisotropic roughness) is not supported: give one 'alpha'")
        rho = bsdf.colour("diffuse_reflectance", REFLECTANCE, 0.5)
        ks = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0)
        if bsdf.has("eta"):
            if bsdf.has("int_ior") or bsdf.has("ext_ior"):
                raise bsdf.error("eta", "give either 'eta' or 'int_ior'/'ext_ior', not both (as Mitsuba)")
            int_ior, ext_ior = bsdf.ior("eta", "polypropylene"), 1.0
        else:
            int_ior, ext_ior = bsdf.ior("int_ior", "polypropylene"), bsdf.ior("ext_ior", "air")
        alpha = at_least(bsdf.grey("alpha", ROUGHNESS, 0.1), MIN_ALPHA)  # as Mitsuba's microfacet clamps it
        bsdf.boolean("sample_visible")
        bsdf.finish(("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "eta", "distribution", "alpha", "sample_visible"))
        return {"type": target.type_name, "reflectance": rho, "specular_reflectance": ks, "roughness": alpha, "int_ior": int_ior, "ext_ior": ext_ior}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        alpha = values["roughness"]
        alpha = alpha.detach().cpu().numpy() if torch.is_tensor(alpha) else alpha
        return {
            "type": "pplastic", "distribution": cls.distribution.name, "diffuse_reflectance": values["reflectance"], "specular_reflectance": values["specular_reflectance"],
            "alpha": float(alpha.reshape(-1)[0]) if alpha.ndim <= 1 else alpha, "int_ior": float(constants["int_ior"]), "ext_ior": float(constants["ext_ior"]),
        }  # fmt: skip


@registry.MATERIALS.register
class PolarizedPlasticGGX(PolarizedPlastic):
    type_name = "pplastic_ggx"
    doc = "Mitsuba's pplastic with the GGX distribution, as its RGB variants render it, two-sided"
    distribution = GGX
    # the same Mitsuba plugin (its distribution picks the type: PolarizedPlastic.from_mitsuba, inherited)
    mitsuba_plugins = ("pplastic",)
