"""A perfect mirror, two-sided: Mitsuba's ``conductor`` with ``material = "none"`` (Fresnel 1).

All light arriving from the mirror direction ``wi = 2 (wo . n) n - wo`` is reflected, scaled by
``specular_reflectance`` k_s: a delta lobe of weight k_s.
"""

from __future__ import annotations

import torch

from invrender import registry
from invrender.scene.kinds import SPECULAR_REFLECTANCE
from invrender.scene.plugins import Param
from invrender.transport.bsdfs.base import BSDFSample, DeltaBSDF, Lobe, ShadingPoint
from invrender.vec import dot


def reflect(wo: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """Mirror directions (N, 3) of ``wo`` about ``n``."""
    return 2.0 * dot(wo, n)[:, None] * n - wo


@registry.MATERIALS.register
class Mirror(DeltaBSDF):
    type_name = "mirror"
    lobes = Lobe.DELTA_REFLECTION
    params = {"specular_reflectance": Param(SPECULAR_REFLECTANCE, 1.0)}
    doc = "perfect specular reflector, two-sided"

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The reflection, weight k_s (zero where ``wo`` lies below the shading normal)."""
        above = (dot(sp.n, sp.wo) > 0)[:, None].to(sp.wo.dtype)
        return [(reflect(sp.wo, sp.n), self.param("specular_reflectance", sp) * above)]

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        ((wi, weight),) = self.specular_lobes(sp)
        return self.delta_sample(wi, weight)

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("conductor",)
    gltf_priority = 20

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``conductor`` with material none (Fresnel 1): ``specular_reflectance`` (default 1)."""
        bsdf.fresnel_one()
        ks = bsdf.colour("specular_reflectance", SPECULAR_REFLECTANCE, 1.0, texture=False)
        bsdf.finish(("material", "specular_reflectance"))
        return {"specular_reflectance": ks}

    @classmethod
    def from_gltf(cls, material) -> dict | None:
        """A metal with GGX alpha below 1e-3 (an MTL ``illum 3`` with Ks): k_s = its colour."""
        if material.metal and material.alpha < 1e-3:
            return {"specular_reflectance": material.metal_colour}
        return None

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        inner = {"type": "conductor", "material": "none", "specular_reflectance": values["specular_reflectance"]}
        return {"type": "twosided", "bsdf": inner}
