"""A smooth conductor, two-sided: Mitsuba's ``conductor`` (a perfect mirror for its default
``material = "none"``, Fresnel 1).

All light arriving from the mirror direction ``wi = 2 (wo . n) n - wo`` is reflected, scaled by
``specular_reflectance`` k_s and the conductor Fresnel term F(wo . n) of the complex index
``eta + i k`` (:mod:`invrender.plugins.bsdfs.metals`): a delta lobe of weight ``k_s F``. The default
``eta = 0, k = 1`` is F = 1 (no Fresnel term computed: the weight is k_s exactly).
"""

from __future__ import annotations

import torch

from invrender import registry
from invrender.plugins.bsdfs.metal_iors import METAL_IORS
from invrender.plugins.bsdfs.metals import CONDUCTOR_CONSTANTS, ConductorFresnel, conductor_lanes
from invrender.scene.kinds import SPECULAR_REFLECTANCE_RGB as SPECULAR_REFLECTANCE
from invrender.scene.plugins import Param
from invrender.core import lanes
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe, ShadingPoint
from invrender.vec import dot


def reflect(wo: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """Mirror directions (N, 3) of ``wo`` about ``n``."""
    return 2.0 * dot(wo, n)[:, None] * n - wo


def eval_lanes(xp, p, ps, wo, wi, front):
    """A delta lobe: no value, no density."""
    zero = 0.0 * wo[2]
    return (zero, zero, zero), zero


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1):
    """The reflection ``(-wo_x, -wo_y, wo_z)``, weight ``k_s F(cos_o)`` (zero where ``wo`` lies
    below the shading normal), flagged delta."""
    above = xp.select(wo[2] > 0.0, 1.0, 0.0)
    weight = lanes.scale(lanes.scale(p["specular_reflectance"], conductor_lanes(xp, wo[2], p["eta"], p["k"])), above)
    return (-wo[0], -wo[1], wo[2]), weight, 0.0 * wo[2], xp.full(True, u0)


@registry.MATERIALS.register
class Mirror(ConductorFresnel, LaneBSDF):
    type_name = "mirror"
    lobes = Lobe.DELTA_REFLECTION
    params = {"specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0)}
    constants = dict(CONDUCTOR_CONSTANTS)
    doc = "perfect specular reflector (eta, k: a named metal or given; default Fresnel 1), two-sided"

    def lane_form(self) -> LaneForm:
        return LaneForm((("specular_reflectance", 3), ("eta", 3), ("k", 3)), eval_lanes, sample_lanes)

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The reflection, weight k_s F (the lane form's one sample)."""
        bs = self.sample(sp, sp.wo.new_zeros(sp.count), sp.wo.new_zeros(sp.count, 2))
        return [(bs.wi, bs.weight)]

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("conductor",)
    gltf_priority = 20

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``conductor``: ``material`` (a named metal, default none: Fresnel 1) or
        ``eta``/``k``, ``specular_reflectance`` (default 1)."""
        ior = bsdf.conductor(METAL_IORS)
        ks = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0, texture=False)
        bsdf.finish(("material", "eta", "k", "specular_reflectance"))
        return {"specular_reflectance": ks, **ior}

    @classmethod
    def from_gltf(cls, material) -> dict | None:
        """A metal with GGX alpha below 1e-3 (an MTL ``illum 3`` with Ks): k_s = its colour."""
        if material.metal and material.alpha < 1e-3:
            return {"specular_reflectance": material.metal_colour}
        return None

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        inner = {"type": "conductor", **cls.mitsuba_ior(constants), "specular_reflectance": values["specular_reflectance"]}
        return {"type": "twosided", "bsdf": inner}
