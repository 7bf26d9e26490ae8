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
from invrender.plugins.bsdfs.dielectric import MAX_RELATIVE_IOR, fresnel_dielectric_lanes
from invrender.plugins.bsdfs.mirror import eval_lanes as delta_eval_lanes  # no density: f cos and pdf 0
from invrender.scene.plugins import Constant
from invrender.core.lanes import select3
from invrender.core.bsdf import TORCH, LaneBSDF, LaneForm, Lobe, ShadingPoint


def pane_lanes(xp, ior, wo):
    """The pane of index ``ior`` seen from local ``wo`` (normal +z, either side): ``(R, reflected
    wi, transmitted wi)``, ``R = 2 F / (1 + F)`` with F one interface's reflectance at ``|cos|``."""
    F, _ = fresnel_dielectric_lanes(xp, xp.abs(wo[2]), ior)
    R = 2.0 * F / (1.0 + F)
    x, y = -wo[0], -wo[1]
    return R, (x, y, wo[2]), (x, y, -wo[2])


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1):
    """Reflection with probability R, else transmission straight through; both weight 1, delta."""
    R, wr, wt = pane_lanes(xp, ps["ior"], wo)
    one = xp.full(1.0, u_lobe)
    return select3(xp, u_lobe < R, wr, wt), (one, one, one), xp.full(0.0, u_lobe), xp.full(True, u_lobe)


@registry.MATERIALS.register
class ThinDielectric(LaneBSDF):
    """Written once in lane form (:func:`sample_lanes`; eval: the mirror's, no density);
    :meth:`specular_lobes` evaluates the same :func:`pane_lanes`."""

    type_name = "thindielectric"
    lobes = Lobe.DELTA_REFLECTION | Lobe.DELTA_TRANSMISSION
    constants = {"ior": Constant(1.5, 1.0 / MAX_RELATIVE_IOR, MAX_RELATIVE_IOR, False, False)}
    doc = "a thin pane of glass: reflection, and transmission straight through"

    def lane_form(self) -> LaneForm:
        return LaneForm((("ior", 1),), delta_eval_lanes, sample_lanes)

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Reflection with weight R, transmission straight through with weight 1 - R."""
        R, wr, wt = pane_lanes(TORCH, self.constant("ior", sp), tuple(sp.wo_local.unbind(1)))
        to_world = lambda w: sp.frame.to_world(torch.stack(w, dim=1))  # noqa: E731
        return [(to_world(wr), R[:, None].expand(-1, 3)), (to_world(wt), (1.0 - R)[:, None].expand(-1, 3))]

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
