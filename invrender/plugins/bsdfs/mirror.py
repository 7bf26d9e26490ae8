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
from invrender.plugins.bsdfs.metals import CONDUCTOR_CONSTANTS, ConductorFresnel
from invrender.scene.kinds import SPECULAR_REFLECTANCE_RGB as SPECULAR_REFLECTANCE
from invrender.scene.plugins import Param
from invrender.core.bsdf import BSDFSample, DeltaBSDF, Lobe, ShadingPoint
from invrender.vec import dot


def reflect(wo: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """Mirror directions (N, 3) of ``wo`` about ``n``."""
    return 2.0 * dot(wo, n)[:, None] * n - wo


@registry.MATERIALS.register
class Mirror(ConductorFresnel, DeltaBSDF):
    type_name = "mirror"
    lobes = Lobe.DELTA_REFLECTION
    params = {"specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0)}
    constants = dict(CONDUCTOR_CONSTANTS)
    doc = "perfect specular reflector (eta, k: a named metal or given; default Fresnel 1), two-sided"

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The reflection, weight k_s F (zero where ``wo`` lies below the shading normal)."""
        cos_o = dot(sp.n, sp.wo)
        above = (cos_o > 0)[:, None].to(sp.wo.dtype)
        weight = self.param("specular_reflectance", sp) * above
        fresnel = self.fresnel(sp, cos_o)
        return [(reflect(sp.wo, sp.n), weight if fresnel is None else weight * fresnel)]

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        ((wi, weight),) = self.specular_lobes(sp)
        return self.delta_sample(wi, weight)

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
