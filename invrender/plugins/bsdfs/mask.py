"""An opacity mask over a material: Mitsuba 3's ``mask``.

With probability ``opacity`` light meets the nested material (any material type, held under the
prefix ``bsdf.``: :mod:`invrender.plugins.bsdfs.composite`; the type of a mask over a diffuse is
``mask(diffuse)``), else it passes straight through (a leaf's cut-out, a fence):

- ``eval``: ``opacity f_nested cos``; ``pdf``: ``opacity pdf_nested``;
- ``sample``: the nested material's sample where ``u_lobe < opacity`` (its lobe uniform stretched
  back to [0, 1)), weight the nested one's (the opacity and its choice cancel), pdf times the
  opacity; else the direction ``-wo`` with weight 1, a delta transmission (pdf 0, flagged delta),
  as Mitsuba's null lobe (probability ``1 - opacity``, weight 1).

The opacity (one number in [0, 1] or a grey map: a bitmap's luminance, as Mitsuba's ``eval_1``
reads it; Mitsuba's bitmaps drop an alpha channel) decides what is seen, and invrender never
differentiates visibility: the material reads it detached (its derivative is zero), it is not a
parameter to fit. Shadow rays, as Mitsuba's ``path`` integrator casts them, are blocked by a
masked surface whatever its opacity: light behind one is found by the paths that pass through it
(a delta event, so the emission they reach counts fully).

``nested_one_sided`` (true for Mitsuba's nested BSDFs not wrapped in ``twosided``, set by the
Mitsuba loader) makes the nested material black from behind, while the mask still lets light
through there. A mask is always two-sided: it transmits.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from invrender import registry
from invrender.scene.kinds import OPACITY
from invrender.scene.plugins import Constant, Param
from invrender.core.bsdf import LaneForm, Lobe, ShadingPoint
from invrender.core.lanes import scale, select3
from invrender.plugins.bsdfs.blend import BELOW_ONE
from invrender.plugins.bsdfs.composite import Composite, nested_pair, with_frame


def _opacity(xp, ps, front):
    """The detached opacity of the nested material's side: 0 from behind a one-sided one."""
    return xp.select(front | (ps["nested_one_sided"] < 0.5), ps["opacity"], 0.0)


def eval_lanes(xp, p, ps, wo, wi, front, *, evals, samples, worlds, prefixes):
    """``opacity f cos`` and ``opacity pdf`` of the nested material (opacity detached)."""
    o = _opacity(xp, ps, front)
    f, pdf = evals[0](xp, *nested_pair(p, ps, prefixes[0]), wo, wi, front)
    return scale(f, o), pdf * o


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, evals, samples, worlds, prefixes, frame=None):
    """The nested material's sample where ``u_lobe < opacity``, else straight through (module
    docstring)."""
    o = ps["opacity"]
    through = u_lobe >= o
    u = xp.minimum(u_lobe / xp.maximum(o, 1e-30), BELOW_ONE)
    wi, weight, pdf, delta = with_frame(samples[0], worlds[0], frame)(xp, *nested_pair(p, ps, prefixes[0]), wo, front, u, u0, u1)
    lit = _opacity(xp, ps, front) > 0.0
    one = xp.full(1.0, u0)
    weight = select3(xp, through, (one, one, one), select3(xp, lit, weight, (0.0 * one, 0.0 * one, 0.0 * one)))
    wi = select3(xp, through, scale(wo, -1.0), wi)
    return wi, weight, xp.select(through, 0.0, pdf * o), through | delta


@registry.MATERIALS.register
class Mask(Composite):
    """Written once in lane form (:func:`eval_lanes`, :func:`sample_lanes`), the nested type's lane
    functions bound when the form is built."""

    type_name = "mask"
    doc = "opacity mask over a material: passes light straight through with probability 1 - opacity (Mitsuba's mask; type mask(TYPE), plain mask = mask(diffuse))"
    slots = ("bsdf.",)
    own_params = {"opacity": Param(OPACITY, 0.5)}
    own_constants = {"nested_one_sided": Constant(False, 0.0, 1.0, False, False, boolean=True)}
    default_nested = ("diffuse",)
    _variants = {}

    @classmethod
    def own_lobes(cls, nested) -> Lobe:
        return super().own_lobes(nested) | Lobe.DELTA_TRANSMISSION

    def lane_form(self) -> LaneForm:
        forms = self.nested_forms()
        bound = self.bound(forms)
        keys = (("opacity", 1), ("nested_one_sided", 1)) + self.nested_keys(forms)
        return LaneForm(keys, functools.partial(eval_lanes, **bound), functools.partial(sample_lanes, **bound), world=forms[0].world)

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Straight through, weight 1 - opacity, and the nested material's delta lobes times the opacity."""
        o = self.sampling_param("opacity", sp)[:, :1]
        seen = o * (sp.front | (self.constant("nested_one_sided", sp) < 0.5))[:, None]
        return [(-sp.wo, (1.0 - o).expand(-1, 3))] + [(wi, weight * seen) for wi, weight in self.nested[0].specular_lobes(sp)]

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor | None:
        """The nested material's (as Mitsuba's ``eval_diffuse_reflectance``)."""
        return self.nested[0].diffuse_reflectance(sp)

    @classmethod
    def not_polynomial(cls, key: str, constants: dict) -> str | None:
        """The nested material's answer: the opacity is a constant factor."""
        if key.startswith(cls.slots[0]):
            n = len(cls.slots[0])
            return cls.nested_types[0].not_polynomial(key[n:], {k[n:]: v for k, v in constants.items() if k.startswith(cls.slots[0])})
        return None

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("mask",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``mask``: ``opacity`` (a number, a colour or a bitmap read as one number as
        Mitsuba's ``eval_1`` does: a bitmap's luminance; default 0.5) and one nested BSDF (any
        material type; not wrapped in ``twosided``, it is black from behind)."""
        nested = bsdf.nested_materials()
        if len(nested) != 1:
            raise bsdf.error(None, f"a mask needs one nested BSDF, got {len(nested)}")
        opacity = bsdf.grey("opacity", OPACITY, 0.5)
        bsdf.finish(("opacity",), children=("bsdf",))
        inner = nested[0]
        one_sided = inner.one_sided and not inner.spec.has(Lobe.TRANSMISSION)
        return {"type": f"mask({inner.type})", "opacity": opacity, "nested_one_sided": one_sided, **cls.nested_entries(zip(cls.slots, nested))}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        o = np.asarray(values["opacity"].detach().cpu() if torch.is_tensor(values["opacity"]) else values["opacity"], dtype=np.float64)
        (inner,) = cls.nested_mitsuba(values, constants)
        if constants.get("nested_one_sided") and inner.get("type") == "twosided":
            inner = inner["bsdf"]
        return {"type": "mask", "opacity": float(o.reshape(-1)[0]) if o.ndim <= 1 else o, "bsdf": inner}


Mask.declare(tuple(registry.MATERIALS[t] for t in Mask.default_nested))
