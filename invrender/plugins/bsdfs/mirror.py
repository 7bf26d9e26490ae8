"""A smooth conductor, two-sided: Mitsuba's ``conductor`` (a perfect mirror for its default
``material = "none"``, Fresnel 1).

All light arriving from the mirror direction ``wi = 2 (wo . n) n - wo`` is reflected, scaled by
``specular_reflectance`` k_s and the conductor Fresnel term F(wo . n) of the complex index
``eta + i k`` (:mod:`invrender.plugins.bsdfs.metals`): a delta lobe of weight ``k_s F``. The default
``eta = 0, k = 1`` is F = 1 (where every material of the type has it no Fresnel term is computed:
the weight is k_s exactly).
"""

from __future__ import annotations

import functools

import torch

from invrender import registry
from invrender.plugins.bsdfs.metal_iors import METAL_IORS
from invrender.plugins.bsdfs.metals import CONDUCTOR_CONSTANTS, ConductorFresnel, fresnel_lanes
from invrender.scene.kinds import SPECULAR_REFLECTANCE_RGB as SPECULAR_REFLECTANCE
from invrender.scene.plugins import Param
from invrender.core.bsdf import LaneBSDF, LaneForm, Lobe, ShadingPoint
from invrender.core.lanes import scale
from invrender.vec import dot


def reflect(wo: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """Mirror directions (N, 3) of ``wo`` about ``n``."""
    return 2.0 * dot(wo, n)[:, None] * n - wo


def eval_lanes(xp, p, ps, wo, wi, front):
    """A delta lobe has no density: ``f cos`` and the pdf are 0."""
    zero = 0.0 * wi[2]
    return (zero, zero, zero), zero


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, fresnel: bool):
    """The mirror direction ``(-wo_x, -wo_y, wo_z)``, weight ``k_s F(cos_o)`` (0 where ``wo`` lies
    below the normal), pdf 0, flagged delta."""
    cos_o = wo[2]
    weight = scale(p["specular_reflectance"], xp.select(cos_o > 0.0, 1.0, 0.0))
    return (-wo[0], -wo[1], cos_o), fresnel_lanes(xp, p, cos_o, weight, fresnel=fresnel), 0.0 * cos_o, xp.full(True, u0)


@registry.MATERIALS.register
class Mirror(ConductorFresnel, LaneBSDF):
    """Written once in lane form (:func:`eval_lanes`, :func:`sample_lanes`, whether any material
    has a Fresnel term other than 1 bound when the form is built); :meth:`specular_lobes` is its
    sample."""

    type_name = "mirror"
    lobes = Lobe.DELTA_REFLECTION
    params = {"specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0)}
    constants = dict(CONDUCTOR_CONSTANTS)
    doc = "perfect specular reflector (eta, k: a named metal or given; default Fresnel 1), two-sided"

    def lane_form(self) -> LaneForm:
        fresnel = not self.fresnel_one
        keys = (("specular_reflectance", 3),) + self.fresnel_keys
        return LaneForm(keys, eval_lanes, functools.partial(sample_lanes, fresnel=fresnel))

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The reflection, weight k_s F (zero where ``wo`` lies below the shading normal)."""
        zero = sp.wo.new_zeros(sp.count)
        bs = self.sample(sp, zero, sp.wo.new_zeros(sp.count, 2))
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
        """A metal with GGX alpha below 1e-3 everywhere (an MTL ``illum 3`` with Ks): k_s = its colour."""
        if material.metal and material.smooth:
            return {"specular_reflectance": material.metal_colour}
        return None

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        inner = {"type": "conductor", **cls.mitsuba_ior(constants), "specular_reflectance": values["specular_reflectance"]}
        return {"type": "twosided", "bsdf": inner}
