"""A thin pane of glass: Mitsuba's ``thindielectric``. Light meets two parallel interfaces of
relative index ``ior`` so close together that it leaves where it entered: reflected about the
normal or passing straight through, undeviated (``wi = -wo``).

With F the unpolarized Fresnel reflectance of one interface at the incident angle (from either
side: the pane is symmetric), the light bouncing between the two faces sums to the reflectance

    R = F + (1 - F)^2 F / (1 - F^2) = 2 F / (1 + F),        T = 1 - R

(a geometric series of internal reflections, absorption-free: R + T = 1; Mitsuba's
``thindielectric.cpp`` computes the same). Sampling picks reflection with probability R, so both
weights are 1. Entering and leaving cancel, so transmission carries no ``1 / eta^2``. No parameter
is differentiable (``ior`` is a scene constant).
"""

from __future__ import annotations


import torch

from invrender import registry
from invrender.plugins.bsdfs.dielectric import MAX_RELATIVE_IOR, fresnel_dielectric
from invrender.plugins.bsdfs.mirror import reflect
from invrender.scene.plugins import Constant
from invrender.core.bsdf import BSDFSample, DeltaBSDF, Lobe, ShadingPoint
from invrender.vec import dot


@registry.MATERIALS.register
class ThinDielectric(DeltaBSDF):
    type_name = "thindielectric"
    lobes = Lobe.DELTA_REFLECTION | Lobe.DELTA_TRANSMISSION
    constants = {"ior": Constant(1.5, 1.0 / MAX_RELATIVE_IOR, MAX_RELATIVE_IOR, False, False)}
    doc = "a thin pane of glass: reflection, and transmission straight through"

    def _pane(self, sp: ShadingPoint) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(R (N,), reflected wi (N, 3), transmitted wi (N, 3)) at each point."""
        ior = self.constant("ior", sp)
        cos_i = dot(sp.n, sp.wo).abs()
        F, _ = fresnel_dielectric(cos_i, torch.broadcast_to(ior, cos_i.shape))
        R = 2.0 * F / (1.0 + F)
        return R, reflect(sp.wo, sp.n), -sp.wo

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Reflection with weight R, transmission straight through with weight 1 - R."""
        R, wr, wt = self._pane(sp)
        return [(wr, R[:, None].expand(-1, 3)), (wt, (1.0 - R)[:, None].expand(-1, 3))]

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """Reflection with probability R, else transmission; both weight 1."""
        R, wr, wt = self._pane(sp)
        wi = torch.where((u_lobe < R)[:, None], wr, wt)
        return self.delta_sample(wi, torch.ones_like(wi))

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("thindielectric",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``thindielectric``: ``ior = int_ior / ext_ior`` (numbers or named media,
        default bk7 / air); ``specular_reflectance`` and ``specular_transmittance`` at their default 1 only."""
        ior = bsdf.ior("int_ior", "bk7") / bsdf.ior("ext_ior", "air")
        bsdf.finish(("int_ior", "ext_ior"))
        return {"ior": ior}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        return {"type": "thindielectric", "int_ior": float(constants["ior"]), "ext_ior": 1.0}
