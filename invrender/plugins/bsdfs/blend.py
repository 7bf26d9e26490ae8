"""A blend of two materials: Mitsuba 3's ``blendbsdf``, ``f = (1 - w) f_0 + w f_1``.

The two nested materials are any material types (composites too), held under the prefixes
``bsdf_0.`` and ``bsdf_1.`` (:mod:`invrender.plugins.bsdfs.composite`; the type of a blend of a
diffuse and a mirror is ``blendbsdf(diffuse,mirror)``); ``weight`` w (one number in [0, 1] or a grey
map) is differentiable.

- ``eval``: ``(1 - w) f_0 cos + w f_1 cos``; ``pdf``: ``(1 - w) pdf_0 + w pdf_1`` (w detached).
- ``sample``, as Mitsuba 3.9.1's: the second material with probability w (its lobe uniform
  stretched back to [0, 1)), else the first; a direction with a density is weighted by the whole
  blend, ``f / pdf`` with the mixture's ``f`` (the chosen material's own ``f cos`` as its sample
  gives it, weight times pdf, and the other's ``eval`` there) and pdf (the chosen's sample pdf and
  the other's ``pdf``): one-sample multiple importance sampling with the balance heuristic.
- A sample from a delta lobe (a blended mirror or glass) keeps the nested sample's weight: the
  blend's factor (1 - w or w) and the probability of choosing that material cancel, and the other
  material, which has a density, adds nothing on a set of directions of measure zero. Mitsuba
  3.9.1 instead mixes a delta sample's weight with the other material's density there (its
  sampled pdf taken for a density), which is biased: a blend (w = 0.5) of a perfect mirror and a
  diffuse of albedo 0.2 has directional albedo 0.6, invrender's mean sample weight, and Mitsuba's
  sampler returns 0.512 (10^6 samples at 0.5 rad); bench/blend_mask_compare.py renders both.

Lobes: both materials'. The constants ``one_sided_0`` and ``one_sided_1`` make a nested material
black from behind (Mitsuba's nested BSDFs that reflect only, not wrapped in ``twosided``; the
Mitsuba loader sets them, and clears them where a ``twosided`` wraps the blend): its ``f`` and pdf
are 0 there and a sample of it has weight 0, the other material unchanged.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from invrender import registry
from invrender.scene.kinds import BLEND_WEIGHT
from invrender.scene.plugins import Constant, Param
from invrender.core.bsdf import LaneForm, Lobe, ShadingPoint
from invrender.core.lanes import add, scale, select3
from invrender.plugins.bsdfs.composite import Composite, nested_pair, with_frame

#: the last uniform below 1 in float32 (a stretched lobe uniform stays in [0, 1))
BELOW_ONE = 1.0 - 2.0**-24


def _lit(xp, ps, front):
    """Per nested material, 1.0 where it is seen (0 from behind a one-sided one)."""
    return tuple(xp.select(front | (ps[f"one_sided_{k}"] < 0.5), 1.0, 0.0) for k in (0, 1))


def eval_lanes(xp, p, ps, wo, wi, front, *, evals, samples, worlds, prefixes):
    """``(1 - w) f_0 cos + w f_1 cos`` (w and ``f`` of ``p``) and ``(1 - w_s) pdf_0 + w_s pdf_1``
    (of ``ps``)."""
    w, w_s = p["weight"], ps["weight"]
    lit0, lit1 = _lit(xp, ps, front)
    (f0, pdf0), (f1, pdf1) = (e(xp, *nested_pair(p, ps, pre), wo, wi, front) for e, pre in zip(evals, prefixes))
    return add(scale(f0, (1.0 - w) * lit0), scale(f1, w * lit1)), (1.0 - w_s) * pdf0 * lit0 + w_s * pdf1 * lit1


def sample_lanes(xp, p, ps, wo, front, u_lobe, u0, u1, *, evals, samples, worlds, prefixes, frame=None):
    """The second material where ``u_lobe < w_s``, else the first, each sampled with its stretched
    lobe uniform; weight and pdf of the whole blend (module docstring), a delta sample's weight the
    nested one's (times ``w / w_s`` or ``(1 - w) / (1 - w_s)``: 1 in value, the weight's gradient)."""
    w, w_s = p["weight"], ps["weight"]
    second = u_lobe < w_s
    u_first = xp.minimum(xp.maximum((u_lobe - w_s) / xp.maximum(1.0 - w_s, 1e-30), 0.0), BELOW_ONE)
    u_second = xp.minimum(u_lobe / xp.maximum(w_s, 1e-30), BELOW_ONE)
    pairs = [nested_pair(p, ps, pre) for pre in prefixes]
    s0, s1 = (with_frame(s, world, frame)(xp, *pair, wo, front, u, u0, u1) for s, world, pair, u in zip(samples, worlds, pairs, (u_first, u_second)))
    wi = select3(xp, second, s1[0], s0[0])
    delta = xp.select(second, s1[3], s0[3])
    lit0, lit1 = _lit(xp, ps, front)
    s0 = (s0[0], scale(s0[1], lit0), s0[2] * lit0, s0[3])
    s1 = (s1[0], scale(s1[1], lit1), s1[2] * lit1, s1[3])
    # the mixture at wi: the chosen material's f cos from its sample (weight x pdf), the other's eval
    (e0, q0), (e1, q1) = (e(xp, *pair, wo, wi, front) for e, pair in zip(evals, pairs))
    e0, q0, e1, q1 = scale(e0, lit0), q0 * lit0, scale(e1, lit1), q1 * lit1
    f0 = select3(xp, second, e0, scale(s0[1], s0[2]))
    f1 = select3(xp, second, scale(s1[1], s1[2]), e1)
    pdf = (1.0 - w_s) * xp.select(second, q0, s0[2]) + w_s * xp.select(second, s1[2], q1)
    f = add(scale(f0, 1.0 - w), scale(f1, w))
    inv = xp.select(pdf > 0.0, 1.0 / xp.maximum(pdf, 1e-30), 0.0)
    # a delta sample: the nested weight, times the blend's factor over its choice probability
    ratio = xp.select(second, w / xp.maximum(w_s, 1e-30), (1.0 - w) / xp.maximum(1.0 - w_s, 1e-30))
    chosen = select3(xp, second, s1[1], s0[1])
    # a sample of a material seen from behind its one side: none (its weight and pdf are 0)
    seen = xp.select(second, lit1, lit0)
    weight = scale(select3(xp, delta, scale(chosen, ratio), scale(f, inv)), seen)
    return wi, weight, xp.select(delta, 0.0, pdf), delta


@registry.MATERIALS.register
class Blend(Composite):
    """Written once in lane form (:func:`eval_lanes`, :func:`sample_lanes`), the nested types' lane
    functions bound when the form is built."""

    type_name = "blendbsdf"
    doc = "blend of two materials, (1 - w) f_0 + w f_1 (Mitsuba's blendbsdf; type blendbsdf(TYPE0,TYPE1), plain blendbsdf = blendbsdf(diffuse,mirror))"
    slots = ("bsdf_0.", "bsdf_1.")
    own_params = {"weight": Param(BLEND_WEIGHT, 0.5)}
    own_constants = {f"one_sided_{k}": Constant(False, 0.0, 1.0, False, False, boolean=True) for k in (0, 1)}
    default_nested = ("diffuse", "mirror")
    _variants = {}

    def lane_form(self) -> LaneForm:
        forms = self.nested_forms()
        bound = self.bound(forms)
        keys = (("weight", 1), ("one_sided_0", 1), ("one_sided_1", 1)) + self.nested_keys(forms)
        return LaneForm(keys, functools.partial(eval_lanes, **bound), functools.partial(sample_lanes, **bound), world=any(f.world for f in forms))

    def _weight(self, sp: ShadingPoint) -> torch.Tensor:
        """(N, 1) the weight w at the points (differentiable)."""
        return self.param("weight", sp)[:, :1]

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Each nested material's delta lobes, scaled by its factor (1 - w or w)."""
        w = self._weight(sp)
        return [(wi, weight * k) for n, k in zip(self.nested, (1.0 - w, w)) for wi, weight in n.specular_lobes(sp)]

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor | None:
        """``(1 - w) k_d0 + w k_d1`` (as Mitsuba's ``eval_diffuse_reflectance``)."""
        parts = [n.diffuse_reflectance(sp) for n in self.nested]
        if all(x is None for x in parts):
            return None
        w = self._weight(sp)
        return sum((x if x is not None else torch.zeros_like(w.expand(-1, 3))) * k for x, k in zip(parts, (1.0 - w, w)))

    @classmethod
    def not_polynomial(cls, key: str, constants: dict) -> str | None:
        return "a blendbsdf's value sums its two materials, (1 - w) f_0 + w f_1, not one monomial"

    # ---- its aliases in the scene formats (read through the registry)

    mitsuba_plugins = ("blendbsdf",)

    @classmethod
    def from_mitsuba(cls, bsdf) -> dict:
        """Mitsuba's ``blendbsdf``: ``weight`` (a number, a colour or a bitmap read as one number as
        Mitsuba's ``eval_1`` does, default 0.5) and two nested BSDFs, in the file's order (any
        material type, ``twosided`` ones too)."""
        nested = bsdf.nested_materials()
        if len(nested) != 2:
            raise bsdf.error(None, f"a blendbsdf needs two nested BSDFs, got {len(nested)}")
        weight = bsdf.grey("weight", BLEND_WEIGHT, 0.5)
        bsdf.finish(("weight",), children=("bsdf",))
        sides = {f"one_sided_{k}": m.one_sided and not m.spec.has(Lobe.TRANSMISSION) for k, m in enumerate(nested)}
        type_name = f"blendbsdf({nested[0].type},{nested[1].type})"
        # the nested materials say which side each has (one_sided_k); the blend itself is two-sided
        return {"type": type_name, "weight": weight, **cls.nested_entries(zip(cls.slots, nested)), **sides, "one_sided": False}

    @classmethod
    def from_mitsuba_twosided(cls, entries: dict, error) -> dict:
        """Mitsuba's ``twosided`` around it: both nested materials shaded from behind as in front;
        refused where one transmits (Mitsuba's twosided rejects a BSDF with a transmission lobe)."""
        if registry.MATERIALS[entries["type"]].has(Lobe.TRANSMISSION):
            raise error(f"twosided cannot wrap a {entries['type']} BSDF (a transmission lobe)")
        return {**entries, "one_sided_0": False, "one_sided_1": False}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        w = np.asarray(values["weight"].detach().cpu() if torch.is_tensor(values["weight"]) else values["weight"], dtype=np.float64)
        b0, b1 = cls.nested_mitsuba(values, constants)
        return {"type": "blendbsdf", "weight": float(w.reshape(-1)[0]) if w.ndim <= 1 else w, "bsdf_0": b0, "bsdf_1": b1}


Blend.declare(tuple(registry.MATERIALS[t] for t in Blend.default_nested))
