"""Smooth glass: Mitsuba's ``dielectric``. Fresnel reflection and refraction at an interface with
relative index ``ior`` (interior over exterior; the exterior is vacuum, 1.0).

With ``eta`` the index ratio transmitted over incident (``ior`` entering, ``1 / ior`` leaving) and
``cos_t^2 = 1 - (1 - cos_i^2) / eta^2``, unpolarized Fresnel reflectance is the mean of

    r_s = (cos_i - eta cos_t) / (cos_i + eta cos_t),   r_p = (eta cos_i - cos_t) / (eta cos_i + cos_t)

squared (Born and Wolf, Principles of Optics, 1.5.2), ``((n - 1)/(n + 1))^2`` at normal incidence
and 1 beyond the critical angle (total internal reflection). Sampling picks reflection with
probability F, so the reflection's weight is 1 and the refraction's ``1 / eta^2``: radiance is
compressed into a smaller solid angle on entering a denser medium (Veach's thesis, 5.2); entering and
leaving a closed object cancel. No parameter is differentiable (``ior`` is a scene constant).
"""

from __future__ import annotations


import torch

from invrender import registry
from invrender.errors import SceneError
from invrender.plugins.bsdfs.mirror import eval_lanes as delta_eval_lanes  # no density: f cos and pdf 0
from invrender.scene.plugins import Constant
from invrender.core.lanes import select3
from invrender.core.bsdf import TORCH, LaneBSDF, LaneForm, Lobe, ShadingPoint


#: the widest relative index of refraction (interior over exterior) a material accepts, and its
#: inverse the narrowest: real media lie between 1 (vacuum) and about 4 (germanium, in the
#: infrared), so a ratio beyond it is a slip, and far beyond it the Fresnel terms' ``eta^2``
#: leaves float32's range (a render of NaN)
MAX_RELATIVE_IOR = 100.0


def check_relative_ior(where: str, int_ior: float, ext_ior: float) -> None:
    """A :class:`SceneError` naming ``where`` and both indices unless ``int_ior / ext_ior`` lies in
    ``[1 / MAX_RELATIVE_IOR, MAX_RELATIVE_IOR]``."""
    eta = int_ior / ext_ior
    if not 1.0 / MAX_RELATIVE_IOR <= eta <= MAX_RELATIVE_IOR:
        raise SceneError(f"{where}: 'int_ior' / 'ext_ior' = {int_ior:g} / {ext_ior:g} = {eta:g}; expected a relative index of refraction in "
                         f"[{1.0 / MAX_RELATIVE_IOR:g}, {MAX_RELATIVE_IOR:g}] (real media lie between 1 and about 4)")


def fresnel_dielectric_lanes(xp, cos_i, eta):
    """Unpolarized Fresnel reflectance F and the transmitted cosine cos_t (0 under total internal
    reflection), for incident cosines ``cos_i`` >= 0 and index ratios ``eta`` (transmitted over
    incident), lane by lane against the array interface (:mod:`invrender.core.lanes`)."""
    cos2_t = 1.0 - (1.0 - cos_i * cos_i) / (eta * eta)
    tir = cos2_t <= 0.0
    cos_t = xp.sqrt(xp.maximum(cos2_t, 0.0))
    r_s = (cos_i - eta * cos_t) / xp.maximum(cos_i + eta * cos_t, 1e-12)
    r_p = (eta * cos_i - cos_t) / xp.maximum(eta * cos_i + cos_t, 1e-12)
    F = xp.select(tir, 1.0, 0.5 * (r_s * r_s + r_p * r_p))
    return F, cos_t


def fresnel_dielectric(cos_i: torch.Tensor, eta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`fresnel_dielectric_lanes` on torch tensors: F (N,) and cos_t (N,) for ``cos_i`` (N,)
    >= 0 and ``eta`` (N,) (any float dtype; differentiable)."""
    return fresnel_dielectric_lanes(TORCH, cos_i, eta)


def interface_lanes(xp, ior, wo, front):
    """The smooth interface of relative index ``ior`` seen from local ``wo`` (normal +z): ``(F,
    reflected wi, refracted wi, eta)``, ``eta`` the index ratio transmitted over incident (``ior``
    from the front side, ``1 / ior`` from inside); under total internal reflection F is 1 and the
    refracted direction is never taken."""
    eta = xp.select(front, ior, 1.0 / ior)
    cos_i = xp.maximum(wo[2], 0.0)
    F, cos_t = fresnel_dielectric_lanes(xp, cos_i, eta)
    x, y, inv = -wo[0], -wo[1], 1.0 / eta
    # reflection mirrors wo about +z; refraction scales its tangential part by 1 / eta (Snell)
    # and goes down by cos_t (``-wo / eta + (cos_i / eta - cos_t) n`` where wo is above)
    return F, (x, y, wo[2]), (x * inv, y * inv, -cos_t), eta


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1):
    """Reflection with probability F (weight 1), else refraction (weight ``1 / eta^2``); delta."""
    F, wr, wt, eta = interface_lanes(xp, ps["ior"], wo, front)
    reflected = u_lobe < F
    inv = 1.0 / eta
    w = xp.select(reflected, 1.0, inv * inv)
    return select3(xp, reflected, wr, wt), (w, w, w), xp.full(0.0, u_lobe), xp.full(True, u_lobe)


@registry.MATERIALS.register
class Dielectric(LaneBSDF):
    """Written once in lane form (:func:`sample_lanes`; eval: the mirror's, no density);
    :meth:`specular_lobes` evaluates the same :func:`interface_lanes`."""

    type_name = "dielectric"
    lobes = Lobe.DELTA_REFLECTION | Lobe.DELTA_TRANSMISSION
    constants = {"ior": Constant(1.5, 1.0 / MAX_RELATIVE_IOR, MAX_RELATIVE_IOR, False, False)}
    doc = "smooth glass: Fresnel reflection and refraction"

    def lane_form(self) -> LaneForm:
        return LaneForm((("ior", 1),), delta_eval_lanes, sample_lanes)

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Reflection with weight F, refraction with weight ``(1 - F) / eta^2``."""
        F, wr, wt, eta = interface_lanes(TORCH, self.constant("ior", sp), tuple(sp.wo_local.unbind(1)), sp.front)
        to_world = lambda w: sp.frame.to_world(torch.stack(w, dim=1))  # noqa: E731
        return [(to_world(wr), F[:, None].expand(-1, 3)), (to_world(wt), ((1.0 - F) / (eta * eta))[:, None].expand(-1, 3))]

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("dielectric",)
    gltf_priority = 10

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``dielectric``: ``ior = int_ior / ext_ior`` (numbers or named media, default bk7 / air)."""
        ior = bsdf.ior("int_ior", "bk7") / bsdf.ior("ext_ior", "air")
        bsdf.finish(("int_ior", "ext_ior"))
        return {"ior": ior}

    @classmethod
    def from_gltf(cls, material) -> dict | None:
        """Clear glass: full transmission (``transmissionFactor`` 1), not metallic, smooth (GGX alpha
        below 1e-3): of the material's ``ior`` (its base colour is not read). Any other
        transmission is a principled material's ``spec_trans``."""
        clear = material.transmission >= 1.0 and not material.partial_metal and not material.metal and material.smooth  # metallic 0
        return {"ior": material.ior} if clear else None

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        return {"type": "dielectric", "int_ior": float(constants["ior"]), "ext_ior": 1.0}
