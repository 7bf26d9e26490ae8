"""Plastics, two-sided: a diffuse base under a dielectric coating, Mitsuba 3's ``plastic`` (smooth
coating, type ``plastic``) and ``roughplastic`` (microfacet coating: Beckmann, Mitsuba's default,
type ``roughplastic``; GGX, type ``roughplastic_ggx``), with Mitsuba's model, defaults and sampling.

The coating has the relative index ``eta = int_ior / ext_ior`` (defaults polypropylene 1.49 over
air 1.000277; numbers or Mitsuba's named media). With ``rho`` the base's ``reflectance`` (Mitsuba's
``diffuse_reflectance``) and ``k_s`` the coating's ``specular_reflectance``, for ``wo`` (towards the
camera) and ``wi`` (towards the light) at cosines ``c_o``, ``c_i`` with the normal:

``plastic`` (lobes: delta reflection, diffuse)
    - specular: a delta reflection of weight ``k_s F(c_o)`` (F the dielectric Fresnel term,
      :func:`~invrender.plugins.bsdfs.dielectric.fresnel_dielectric`);
    - diffuse: ``f cos = rho' c_i / pi (1 - F(c_o)) (1 - F(c_i)) / eta^2``, light refracted in,
      scattered by the base, refracted out; ``rho' = rho / (1 - F_dr)`` sums the internal
      reflections (``nonlinear = false``, Mitsuba's default: the colour is kept) or
      ``rho / (1 - rho F_dr)`` (``nonlinear = true``: each internal bounce scatters off the base
      again, so colours darken and saturate). ``F_dr`` is the diffuse Fresnel reflectance seen from
      inside (index ``1 / eta``), by Mitsuba's fits (:func:`fresnel_diffuse_reflectance`).

``roughplastic`` (lobes: glossy, diffuse)
    - specular: the microfacet reflection ``k_s F(wo . h) D(h) G1(wo) G1(wi) / (4 c_o)`` of the
      distribution (:mod:`invrender.plugins.bsdfs.microfacet`) at ``roughness`` alpha (Mitsuba's
      ``alpha``);
    - diffuse: ``rho' c_i / pi T(c_o) T(c_i) / eta^2``, ``T(c)`` the rough interface's
      transmittance, ``rho'`` as above with the rough internal reflectance ``R_int`` for ``F_dr``.

    ``T`` and ``R_int`` are what Mitsuba precomputes (``roughplastic.cpp``, ``eval_transmittance``
    and ``eval_reflectance`` of ``microfacet.h``), computed here the same way for each material
    (:func:`rough_tables`): ``T(mu)`` at 64 cosines ``mu = max(1e-6, linspace(0, 1, 64))`` is the
    mean, over visible normals m from ``wi = (sqrt(1 - mu^2), 0, mu)``, of ``(1 - F(wi . m))
    G1(wt)`` (``wt`` the refracted direction), by a 32 x 32 Gauss-Legendre rule over the square
    of the visible-normal sampler's uniforms; ``R_int = 2 mean_mu(mu R(mu))`` over the same 64
    cosines, ``R(mu)`` the reflected ``F G1`` at index ``1 / eta`` (a 64 x 64 rule; Mitsuba's
    is 128 x 128). ``T`` is
    read by linear interpolation in ``c``. ``docs/rendering.md`` gives the approximation's
    measured size.

    The roughness is a differentiable parameter (``NAME.roughness``, kind ``roughness``, one number
    per material: the tables are a material's, so a map is refused). ``eval`` reads it attached in
    ``D`` and ``G1`` (as the glossy conductors do) and in the tables, attached to first order:
    ``T(alpha_0) + T'(alpha_0) (alpha - alpha_0)``, ``T'`` and ``R_int'`` by
    :func:`rough_table_slopes`, exact in value (renders are bit-identical to a constant
    roughness's). Sampling reads the detached roughness: the lobe choice (``T`` at alpha_s), the
    visible normal and ``pdf``; a sample's weight ``f(alpha) cos / pdf(alpha_s)`` carries the
    gradient, so every estimator stays unbiased (``docs/gradient_variance.md#roughness``).

Sampling (both): the specular lobe with probability ``P_s = a w / (a w + (1 - a)(1 - w))``, else
cosine-weighted directions, where ``a`` is ``F(c_o)`` (plastic) or ``1 - T(c_o)`` (roughplastic) and
``w = mean(k_s) / (mean(rho) + mean(k_s))`` is Mitsuba's specular sampling weight, computed from
the values a scene is built with and kept as the constant ``specular_sampling_weight`` (or given),
so sampling never depends on a differentiable parameter but through the detached roughness: finite
differences with common random numbers stay exact, and a fit only changes how well it samples,
never what it estimates. The rough lobe samples
visible normals; its ``pdf`` is ``P_s D G1(wo) / (4 c_o) + (1 - P_s) c_i / pi`` and a sample's
weight is ``f cos / pdf`` of the whole BSDF, as Mitsuba's.

Mitsuba's plastics are one-sided (black from behind); invrender's are two-sided, as its other
materials (Mitsuba's ``twosided`` of them).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import ClassVar

import numpy as np
import torch

from invrender import registry
from invrender.errors import ParameterError, SceneError
from invrender.plugins.bsdfs.dielectric import check_relative_ior, fresnel_dielectric, fresnel_dielectric_lanes
from invrender.plugins.bsdfs.glossy import ALPHA
from invrender.plugins.bsdfs.microfacet import BECKMANN, DISTRIBUTIONS, GGX, Distribution, fwAD_active
from invrender.plugins.bsdfs.mirror import reflect
from invrender.scene.formats.mitsuba.bsdfs import NAMED_IOR
from invrender.scene.kinds import REFLECTANCE, ROUGHNESS
from invrender.scene.kinds import SPECULAR_REFLECTANCE_RGB as SPECULAR_REFLECTANCE
from invrender.scene.plugins import Constant, Param
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe, ShadingPoint
from invrender.core import lanes
from invrender.core.lanes import scale, select3
from invrender.vec import dot

#: a rough plastic's roughness: the roughness kind, one number per material (its tables are a
#: material's, not a texel's: a map is refused as for any RGB-only parameter)
ROUGHNESS_RGB = dataclasses.replace(ROUGHNESS, texture=False)

#: Mitsuba's roughplastic transmittance table size (``MI_ROUGH_TRANSMITTANCE_RES``)
TABLE_SIZE = 64

#: the coating's indices of refraction and Mitsuba's ``nonlinear`` switch
COATING_CONSTANTS = {
    "int_ior": Constant(NAMED_IOR["polypropylene"], 0.0, math.inf, True, True, names=NAMED_IOR),
    "ext_ior": Constant(NAMED_IOR["air"], 0.0, math.inf, True, True, names=NAMED_IOR),
    "nonlinear": Constant(False, 0.0, 1.0, False, False, boolean=True),
    # Mitsuba's, for the defaults rho 0.5 and k_s 1; computed from the values unless given (resolve)
    "specular_sampling_weight": Constant(2.0 / 3.0, 0.0, 1.0, False, False),
}


#: the lane form's keys both plastics read (the rough one adds its roughness and tables)
COATING_KEYS = (("reflectance", 3), ("specular_reflectance", 3), ("eta", 1), ("internal", 1), ("nonlinear", 1), ("specular_sampling_weight", 1))


def fresnel_diffuse_reflectance(eta: float) -> float:
    """Mitsuba 3's diffuse Fresnel reflectance ``2 int_0^1 F(mu, eta) mu dmu`` of an interface of
    relative index ``eta``, by its fits: Egan and Hilgeman (1973) for ``eta < 1``, d'Eon and Irving
    (2011) otherwise (``docs/rendering.md`` compares them with the integral)."""
    if eta < 1.0:
        return 0.0636 / eta + eta * (eta * -1.4399 + 0.7099) + 0.6681
    x = 1.0 / eta
    return float(np.polyval([-1.36881, 4.98554, -7.80989, 6.75335, -3.4793, 0.919317], x))


def _mean(value) -> float:
    """The mean of a colour (a number, an RGB triple or a texture; arrays or tensors)."""
    return float(np.mean(np.asarray(value.detach().cpu() if torch.is_tensor(value) else value, dtype=np.float64)))


def coating_constants(where: str, values: dict, constants: dict, given: set, distinct: str | None) -> dict:
    """A coated material's constants (the plastics'): the indices must differ where Mitsuba's
    plugin ``distinct`` requires it and their ratio be one real media have; the specular sampling
    weight ``mean(k_s) / (mean(rho) + mean(k_s))`` (0.5 when both are 0) unless given."""
    if distinct is not None and constants["int_ior"] == constants["ext_ior"]:
        raise SceneError(f"{where}: 'int_ior' and 'ext_ior' must differ (both {constants['int_ior']:g}), as Mitsuba's {distinct} requires")
    check_relative_ior(where, constants["int_ior"], constants["ext_ior"])
    if "specular_sampling_weight" not in given:
        d, s = (_mean(values[k]) for k in ("reflectance", "specular_reflectance"))
        constants = {**constants, "specular_sampling_weight": s / (d + s) if d + s > 0 else 0.5}
    return constants


def _rough_quadrature(distribution: str, alpha: float, eta: float, nodes: tuple[int, int]) -> tuple[np.ndarray, float]:
    """``(T, R_int)`` of :func:`rough_tables`, in float64."""
    d = DISTRIBUTIONS[distribution]
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, TABLE_SIZE))
    wi_rows = torch.tensor(np.stack([np.sqrt(1.0 - mu * mu), np.zeros_like(mu), mu], 1), dtype=torch.float64)

    def integrate(n: int, integrand) -> np.ndarray:
        x, w = np.polynomial.legendre.leggauss(n)
        u = torch.tensor(np.stack(np.meshgrid(0.5 * x + 0.5, 0.5 * x + 0.5, indexing="ij"), -1).reshape(-1, 2), dtype=torch.float64)
        weight = torch.tensor(np.outer(w, w).reshape(-1) * 0.25, dtype=torch.float64)
        k = u.shape[0]
        wi = wi_rows.repeat_interleave(k, 0)  # every cosine with every node
        a = torch.full((wi.shape[0],), alpha, dtype=torch.float64)
        m = d.sample_visible(wi, a, u.repeat(TABLE_SIZE, 1)).double()
        return (integrand(wi, m, a).reshape(TABLE_SIZE, k) * weight).sum(1).numpy()

    def transmitted(wi, m, a):
        c = dot(wi, m)
        F, cos_t = fresnel_dielectric(c.clamp_min(0.0), torch.full_like(c, eta))
        wt = m * (c / eta - cos_t)[:, None] - wi / eta  # refracted below the interface
        g = d.G1(wt[:, 2].abs(), a) * (dot(wt, m) * wt[:, 2] > 0)
        return torch.where(wt[:, 2] * wi[:, 2] < 0, g * (1.0 - F), 0.0)

    def reflected(wi, m, a):  # from inside: index 1 / eta (total internal reflection: F = 1)
        c = dot(wi, m)
        F, _ = fresnel_dielectric(c.clamp_min(0.0), torch.full_like(c, 1.0 / eta))
        wr = 2.0 * c[:, None] * m - wi
        return torch.where(wr[:, 2] > 0, d.G1(wr[:, 2], a) * F, 0.0)

    with torch.no_grad():
        T = integrate(nodes[0], transmitted)
        R = integrate(nodes[1], reflected)
    return T, float(2.0 * np.mean(R * mu))


@functools.lru_cache(maxsize=64)
def rough_tables(distribution: str, alpha: float, eta: float, nodes: tuple[int, int] = (32, 64)) -> tuple[tuple[float, ...], float]:
    """``(T, R_int)`` of a rough interface (module docstring): the external transmittance at the
    :data:`TABLE_SIZE` cosines and the internal diffuse reflectance, for the named distribution at
    roughness ``alpha`` and relative index ``eta`` (float64). ``nodes``: the Gauss-Legendre
    rules' sizes per axis for the two; Mitsuba's are 32 and 128, the internal one is 64 here (four
    times cheaper; ``docs/rendering.md`` gives the difference)."""
    T, R = _rough_quadrature(distribution, alpha, eta, nodes)
    return tuple(float(t) for t in T), R


#: the step (in alpha) of the tables' central difference (:func:`rough_table_slopes`)
SLOPE_STEP = 1e-2


@functools.lru_cache(maxsize=64)
def rough_table_slopes(distribution: str, alpha: float, eta: float, nodes: tuple[int, int] = (32, 64)) -> tuple[tuple[float, ...], float]:
    """``(dT/dalpha, dR_int/dalpha)`` of :func:`rough_tables`, what a differentiable roughness
    attaches its tables by: the central difference of the same rules' values at ``alpha +- h``,
    ``h`` = :data:`SLOPE_STEP` (a quarter of alpha below 0.04). Not the rules' exact derivative:
    Fresnel's square-root edge at total internal reflection makes the internal rule's sum ripple
    in alpha (by about 3e-5, at scales below 2e-3), so its exact derivative wanders by 10% around
    the slope its values follow over 1e-2 (the scale a fit or a finite difference moves alpha
    by); the difference follows that slope. Two extra evaluations of the rules (each about 0.07 s
    on one quiet core)."""
    h = min(SLOPE_STEP, alpha / 4.0)
    (Tp, Rp), (Tm, Rm) = (_rough_quadrature(distribution, alpha + k * h, eta, nodes) for k in (1, -1))
    return tuple(float(t) for t in (Tp - Tm) / (2.0 * h)), (Rp - Rm) / (2.0 * h)


class Coated(LaneBSDF):
    """What both plastics share: a diffuse base under a dielectric coating of index ``eta``, the
    specular sampling weight, Mitsuba's properties and export. Subclasses give the coating."""

    params = {"reflectance": Param(REFLECTANCE, 0.5), "specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0)}
    #: the Mitsuba plugin it writes
    mitsuba_type: ClassVar[str]

    def _per_material(self, key: str, device, fn) -> torch.Tensor:
        """A (M,) float32 table of ``fn(index)`` over this BSDF's materials, built once per device."""
        token = (key, device)
        if token not in self._constant_tables:
            self._constant_tables[token] = torch.tensor([fn(i) for i in range(len(self.constants))], dtype=torch.float32, device=device)
        return self._constant_tables[token]

    def _eta(self, sp: ShadingPoint) -> torch.Tensor:
        """(N,) the relative index of the coating."""
        return self.constant("int_ior", sp) / self.constant("ext_ior", sp)

    def lane_rows(self, key: str, sampling: bool, device) -> torch.Tensor | None:
        """``eta``: the coating's relative index ``int_ior / ext_ior`` (M, 1)."""
        if key == "eta":
            return self._per_material("eta", device, lambda i: self.constants[i]["int_ior"] / self.constants[i]["ext_ior"])[:, None]
        return None

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor:
        return self.param("reflectance", sp)

    @classmethod
    def not_polynomial(cls, key: str, constants: dict) -> str | None:
        """Path records: the rough plastic's ``f`` sums its two lobes (no single monomial in
        ``k_s`` and ``rho``), and ``nonlinear`` makes ``rho / (1 - rho F_dr)``; the smooth one
        with ``nonlinear = false`` is linear in each, lobe by lobe."""
        if cls.has(Lobe.GLOSSY):
            return f"a {cls.type_name}'s value sums two lobes (k_s times the coating's, rho times the base's), not one monomial"
        if key == "reflectance" and constants.get("nonlinear"):
            return "with nonlinear = true the base's factor rho / (1 - rho F_dr) is not a polynomial in rho"
        return None

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        """Mitsuba's specular sampling weight ``mean(k_s) / (mean(rho) + mean(k_s))`` (over channels
        and texels; 0.5 when both are 0) from the values the scene is built with, unless given;
        the rough plastic's indices must differ (as Mitsuba's); the coating's ratio of indices must
        be one real media have (:func:`~invrender.plugins.bsdfs.dielectric.check_relative_ior`)."""
        return coating_constants(where, values, constants, given, "roughplastic" if cls.has(Lobe.GLOSSY) else None)

    # ---- its aliases in the scene formats (read through the registry)

    @classmethod
    def _read_coating(cls, bsdf) -> dict:
        """The properties both Mitsuba plastics share (``diffuse_reflectance``, a colour or bitmap;
        ``specular_reflectance``; ``int_ior``/``ext_ior``; ``nonlinear``)."""
        rho = bsdf.colour("diffuse_reflectance", REFLECTANCE, 0.5)
        ks = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0, texture=False)
        int_ior, ext_ior = bsdf.ior("int_ior", "polypropylene"), bsdf.ior("ext_ior", "air")
        nonlinear = bool(bsdf.boolean("nonlinear", False))
        return {"reflectance": rho, "specular_reflectance": ks, "int_ior": int_ior, "ext_ior": ext_ior, "nonlinear": nonlinear}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        inner = {
            "type": cls.mitsuba_type,
            "diffuse_reflectance": values["reflectance"],
            "specular_reflectance": values["specular_reflectance"],
            "int_ior": float(constants["int_ior"]),
            "ext_ior": float(constants["ext_ior"]),
            "nonlinear": bool(constants["nonlinear"]),
        }
        return {"type": "twosided", "bsdf": {**inner, **cls._mitsuba_extra(values, constants)}}

    @classmethod
    def _mitsuba_extra(cls, values: dict, constants: dict) -> dict:
        return {}


def cosine_hemisphere_lanes(xp, u0, u1):
    """Cosine-distributed local directions about +z (a 3-tuple) from uniforms ``u0``, ``u1`` (N,):
    Malley's method (the unit disk's polar mapping, lifted to the hemisphere)."""
    r = xp.sqrt(u0)
    phi = (2.0 * math.pi) * u1
    return (r * xp.cos(phi), r * xp.sin(phi), xp.sqrt(xp.maximum(1.0 - u0, 0.0)))


def lobe_choice_lanes(xp, a, w):
    """The probability of the specular lobe, ``a w / (a w + (1 - a)(1 - w))`` (module docstring)."""
    s, d = a * w, (1.0 - a) * (1.0 - w)
    return xp.select(s + d > 0.0, s / xp.maximum(s + d, 1e-30), 0.0)


def base_lanes(xp, p):
    """``rho / (1 - F_dr)`` or, nonlinear, ``rho / (1 - rho F_dr)`` (a 3-tuple), with the internal
    reflectance ``p["internal"]``."""
    F = p["internal"]
    nonlinear = p["nonlinear"] > 0.5
    return tuple(r / xp.select(nonlinear, 1.0 - r * F, 1.0 - F) for r in p["reflectance"])


def _coating_fresnel(xp, cos, eta):
    return fresnel_dielectric_lanes(xp, xp.minimum(xp.maximum(cos, 0.0), 1.0), eta)[0]


def transmittance_lanes(xp, table, cos):
    """The rough interface's transmittance T at cosines ``cos``, linear in its table (a
    :class:`~invrender.core.lanes.Row` of :data:`TABLE_SIZE` entries; Mitsuba's ``lerp_gather``)."""
    x = xp.minimum(xp.maximum(cos, 0.0), 1.0) * float(TABLE_SIZE - 1)
    i = xp.minimum(xp.floor(x), float(TABLE_SIZE - 2))
    j = xp.uint(i)
    t0 = lanes.row_at(xp, table, j)
    return t0 + (lanes.row_at(xp, table, j + 1) - t0) * (x - i)


def rough_eval_lanes(xp, p, ps, wo, wi, front, *, distribution: Distribution):
    """The rough plastic's ``f cos``, the coating's microfacet reflection plus the diffuse base (at
    the attached roughness and tables), and its pdf ``P_s D G1(wo) / (4 c_o) + (1 - P_s) c_i / pi``
    (at the detached ones)."""
    d = distribution
    c_o, c_i = wo[2], wi[2]
    ok = (c_o > 0.0) & (c_i > 0.0)
    h = lanes.normalize(xp, lanes.add(wo, wi))
    inv_4co = 1.0 / (4.0 * xp.maximum(c_o, 1e-12))
    p_s = lobe_choice_lanes(xp, 1.0 - transmittance_lanes(xp, ps["transmittance"], c_o), ps["specular_sampling_weight"])
    D, g_o = d.D_lanes(xp, h[2], ps["roughness"]), d.G1_lanes(xp, c_o, ps["roughness"])
    pdf = xp.select(ok, p_s * D * g_o * inv_4co + (1.0 - p_s) * c_i * (1.0 / math.pi), 0.0)
    alpha = p["roughness"]
    if p is not ps:  # f at its own roughness (the same values where the pdf's are passed for both)
        D, g_o = d.D_lanes(xp, h[2], alpha), d.G1_lanes(xp, c_o, alpha)
    F = _coating_fresnel(xp, lanes.dot(wo, h), p["eta"])
    spec = xp.select(ok, F * D * g_o * d.G1_lanes(xp, c_i, alpha) * inv_4co, 0.0)
    T_o, T_i = transmittance_lanes(xp, p["transmittance"], c_o), transmittance_lanes(xp, p["transmittance"], c_i)
    diff = xp.select(ok, c_i * T_o * T_i / (math.pi * p["eta"] * p["eta"]), 0.0)
    return lanes.add(scale(p["specular_reflectance"], spec), scale(base_lanes(xp, p), diff)), pdf


def rough_sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, distribution: Distribution):
    """A visible normal's reflection with probability P_s, else a cosine-weighted direction (both
    at the detached roughness); weight ``f cos / pdf`` of both lobes (``f`` attached)."""
    above = wo[2] > 0.0
    one = xp.full(1.0, u0)
    wo_up = select3(xp, above, wo, (0.0 * one, 0.0 * one, one))
    p_s = lobe_choice_lanes(xp, 1.0 - transmittance_lanes(xp, ps["transmittance"], wo_up[2]), ps["specular_sampling_weight"])
    h = distribution.sample_visible_lanes(xp, wo_up, ps["roughness"], u0, u1)
    wi = select3(xp, u_lobe < p_s, lanes.reflect(wo_up, h), cosine_hemisphere_lanes(xp, u0, u1))
    f, pdf = rough_eval_lanes(xp, p, ps, wo, wi, front, distribution=distribution)
    ok = above & (pdf > 0.0)
    weight = tuple(xp.select(ok, x / xp.maximum(pdf, 1e-30), 0.0) for x in f)
    return wi, weight, xp.select(ok, pdf, 0.0), xp.full(False, u0)


def _smooth_diffuse(xp, p, c_o, c_i, F_o):
    """``f cos / (c_i / pi)`` of the smooth plastic's diffuse lobe, ``rho' (1 - F_o)(1 - F_i) /
    eta^2`` (a 3-tuple; 0 unless both directions lie above the normal), ``F_o`` the Fresnel term at
    ``c_o``."""
    eta = p["eta"]
    t = (1.0 - F_o) * (1.0 - _coating_fresnel(xp, c_i, eta)) / (eta * eta)
    return scale(base_lanes(xp, p), xp.select((c_o > 0.0) & (c_i > 0.0), t, 0.0))


def _smooth_choice(xp, ps, c_o):
    """``(P_s, F_o)``: the specular lobe's probability and the Fresnel term at ``c_o`` (``eta`` is a
    constant: ``f`` and sampling read the same one)."""
    F_o = _coating_fresnel(xp, c_o, ps["eta"])
    return lobe_choice_lanes(xp, F_o, ps["specular_sampling_weight"]), F_o


def smooth_eval_lanes(xp, p, ps, wo, wi, front):
    """The smooth plastic's diffuse lobe ``f cos`` and its pdf ``(1 - P_s) c_i / pi`` (the delta
    lobe has no density)."""
    c_o, c_i = wo[2], wi[2]
    cos = xp.maximum(c_i, 0.0) * (1.0 / math.pi)
    p_s, F_o = _smooth_choice(xp, ps, c_o)
    pdf = xp.select(c_o > 0.0, (1.0 - p_s) * cos, 0.0)
    return scale(_smooth_diffuse(xp, p, c_o, c_i, F_o), cos), pdf


def smooth_sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1):
    """The coating's reflection with probability P_s (weight ``k_s F / P_s``, delta), else a
    cosine-weighted direction (weight ``rho' (1 - F_o)(1 - F_i) / (eta^2 (1 - P_s))``)."""
    c_o = wo[2]
    p_s, F_o = _smooth_choice(xp, ps, c_o)
    spec = (u_lobe < p_s) & (c_o > 0.0)
    wi = select3(xp, spec, (-wo[0], -wo[1], wo[2]), cosine_hemisphere_lanes(xp, u0, u1))
    c_i = wi[2]
    w_spec = scale(p["specular_reflectance"], F_o / xp.maximum(p_s, 1e-30))
    w_diff = scale(_smooth_diffuse(xp, p, c_o, c_i, F_o), 1.0 / xp.maximum(1.0 - p_s, 1e-30))
    pdf = xp.select(spec | (c_o <= 0.0), 0.0, (1.0 - p_s) * xp.maximum(c_i, 0.0) * (1.0 / math.pi))
    return wi, select3(xp, spec, w_spec, w_diff), pdf, spec


@registry.MATERIALS.register
class Plastic(Coated):
    type_name = "plastic"
    lobes = Lobe.DELTA_REFLECTION | Lobe.DIFFUSE
    constants = dict(COATING_CONSTANTS)
    doc = "smooth plastic: a diffuse base under a smooth dielectric coating (Mitsuba's plastic), two-sided"
    mitsuba_type = "plastic"

    def lane_form(self) -> LaneForm:
        return LaneForm(COATING_KEYS, smooth_eval_lanes, smooth_sample_lanes)

    def lane_rows(self, key: str, sampling: bool, device) -> torch.Tensor | None:
        """``eta`` and ``internal``: the diffuse Fresnel reflectance F_dr seen from inside (index
        ``1 / eta``) by Mitsuba's fits (:func:`fresnel_diffuse_reflectance`)."""
        if key == "internal":
            return self._per_material("fdr_int", device, lambda i: fresnel_diffuse_reflectance(self.constants[i]["ext_ior"] / self.constants[i]["int_ior"]))[:, None]
        return super().lane_rows(key, sampling, device)

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The coating's reflection, weight ``k_s F(c_o)``."""
        c_o = dot(sp.n, sp.wo)
        F = torch.where(c_o > 0, fresnel_dielectric(c_o.clamp(0.0, 1.0), self._eta(sp))[0], 0.0)
        return [(reflect(sp.wo, sp.n), self.param("specular_reflectance", sp) * F[:, None])]

    mitsuba_plugins = ("plastic",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``plastic``: ``diffuse_reflectance`` (colour or bitmap, default 0.5; invrender's
        ``reflectance``), ``specular_reflectance`` (default 1), ``int_ior``/``ext_ior`` (numbers or
        named media, default polypropylene / air), ``nonlinear`` (default false)."""
        entries = cls._read_coating(bsdf)
        bsdf.finish(("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "nonlinear"))
        return entries


@registry.MATERIALS.register
class RoughPlastic(Coated):
    type_name = "roughplastic"
    lobes = Lobe.GLOSSY | Lobe.DIFFUSE
    params = {**Coated.params, "roughness": Param(ROUGHNESS_RGB, 0.1)}
    constants = dict(COATING_CONSTANTS)
    doc = "rough plastic: a diffuse base under a Beckmann rough dielectric coating (Mitsuba's roughplastic, its default distribution), two-sided"
    mitsuba_type = "roughplastic"
    #: the coating's microfacet distribution
    distribution: ClassVar[Distribution] = BECKMANN

    def _alphas(self, values: list[dict]) -> list[torch.Tensor]:
        """Each material's roughness (a (3,) grey tensor) in ``values``."""
        alphas = [v["roughness"] for v in values]
        if any(a.ndim != 1 for a in alphas):
            raise ParameterError(f"a {self.type_name} material's roughness must be an RGB triple, not a texture (its coating's tables are one per material)")
        return alphas

    def _table_rows(self, alphas: list[torch.Tensor], device, fn) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, 64) and (M,) float32 of ``fn(distribution, alpha, eta)`` over the materials."""
        rows = [fn(self.distribution.name, float(a.detach().reshape(-1)[0]), float(c["int_ior"] / c["ext_ior"])) for a, c in zip(alphas, self.constants)]
        T = torch.tensor([r[0] for r in rows], dtype=torch.float32, device=device)
        R = torch.tensor([r[1] for r in rows], dtype=torch.float32, device=device)
        return T, R

    def lane_form(self) -> LaneForm:
        d = self.distribution
        keys = COATING_KEYS + (("roughness", 1), ("transmittance", TABLE_SIZE))
        return LaneForm(keys, functools.partial(rough_eval_lanes, distribution=d), functools.partial(rough_sample_lanes, distribution=d))

    def lane_rows(self, key: str, sampling: bool, device) -> torch.Tensor | None:
        """``transmittance`` (M, 64) and ``internal`` (M, 1): :meth:`tables`."""
        if key in ("transmittance", "internal"):
            T, R = self.tables(device, sampling)
            return T if key == "transmittance" else R[:, None]
        return super().lane_rows(key, sampling, device)

    def tables(self, device, sampling: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """(M, 64) transmittance tables and (M,) internal reflectances of this BSDF's materials, at
        the roughness ``eval`` reads (attached: to first order in alpha, by the tables' slopes) or,
        ``sampling``, at the detached one sampling and ``pdf`` read."""
        token = ("rough_tables", device, sampling)
        alphas = self._alphas(self.sampling_values if sampling else self.values)
        if token not in self._constant_tables:
            self._constant_tables[token] = self._table_rows(alphas, device, rough_tables)
        T, R = self._constant_tables[token]
        if sampling or not any(a.requires_grad or fwAD_active(a) for a in alphas):
            return T, R
        slopes = ("rough_table_slopes", device)
        if slopes not in self._constant_tables:
            self._constant_tables[slopes] = self._table_rows(alphas, device, rough_table_slopes)
        dT, dR = self._constant_tables[slopes]
        delta = torch.stack([a.mean() - a.mean().detach() for a in alphas]).to(device, torch.float32)  # 0 in value
        return T + dT * delta[:, None], R + dR * delta

    mitsuba_plugins = ("roughplastic",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``roughplastic``: the properties of ``plastic`` and ``distribution`` beckmann
        (Mitsuba's default: type roughplastic) or ggx (type roughplastic_ggx), isotropic ``alpha``
        (invrender's ``roughness``, default 0.1), ``sample_visible`` (read; invrender always
        samples visible normals)."""
        entries = cls._read_coating(bsdf)
        name = (bsdf.string("distribution", allowed=("beckmann", "ggx")) or "beckmann").lower()
        target = RoughPlastic if name == "beckmann" else RoughPlasticGGX
        for key in ("alpha_u", "alpha_v"):
            if bsdf.has(key):
                raise bsdf.error(key, f"'{key}' (anisotropic roughness) is not supported: give one 'alpha' (Mitsuba's roughplastic is isotropic)")
        alpha = bsdf.number("alpha", ALPHA, f"{target.distribution.label} roughness", "a <float> (Mitsuba's roughplastic takes no texture)")
        bsdf.boolean("sample_visible")
        bsdf.finish(("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "nonlinear", "distribution", "alpha", "sample_visible"))
        return {"type": target.type_name, **entries, "roughness": alpha}

    @classmethod
    def _mitsuba_extra(cls, values: dict, constants: dict) -> dict:
        return {"distribution": cls.distribution.name, "alpha": float(np.asarray(values["roughness"]).reshape(-1)[0]), "sample_visible": True}


@registry.MATERIALS.register
class RoughPlasticGGX(RoughPlastic):
    type_name = "roughplastic_ggx"
    doc = "rough plastic with a GGX coating (Mitsuba's roughplastic, distribution ggx), two-sided"
    distribution = GGX

