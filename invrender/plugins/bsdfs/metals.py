"""Conductors as scene files describe them: the complex index of refraction ``eta + i k`` (RGB)
of a named metal or given explicitly, and the exact unpolarized Fresnel reflectance of a conductor.

Named metals (:data:`NAMES`) are Mitsuba 3's ``material`` presets (``"Au"``, ``"Cu"``, ``"Al"``,
``"Ag"``, ``"Cr"``, ...: every table of its ``data/ior``), converted to RGB as Mitsuba's RGB
variants convert them; the numbers live in :mod:`invrender.plugins.bsdfs.metal_iors`, written by
``bench/metal_iors.py`` (which says where they come from and how they are converted). ``"none"``
is Mitsuba's default: ``eta = 0, k = 1``, a Fresnel term of exactly 1 (a perfect reflector, then
scaled by ``specular_reflectance``).

:func:`fresnel_conductor` is Mitsuba 3's ``fresnel_conductor`` (after Moeller, "Optics", 1988): with
``a^2 + b^2 = sqrt((eta^2 - k^2 - sin^2)^2 + 4 eta^2 k^2)`` and ``a = sqrt((a^2 + b^2 + eta^2 - k^2
- sin^2) / 2)``,

    R_s = (a^2 + b^2 + cos^2 - 2 a cos) / (a^2 + b^2 + cos^2 + 2 a cos)
    R_p = R_s ((a^2 + b^2) cos^2 + sin^4 - 2 a cos sin^2) / ((a^2 + b^2) cos^2 + sin^4 + 2 a cos sin^2)
    F = (R_s + R_p) / 2,

which at normal incidence is ``((eta - 1)^2 + k^2) / ((eta + 1)^2 + k^2)``.
"""

from __future__ import annotations

import numpy as np
import torch

from invrender.errors import SceneError
from invrender.plugins.bsdfs.metal_iors import METAL_IORS
from invrender.scene.plugins import Constant
from invrender.core.bsdf import TORCH, ShadingPoint

#: the conductor with a Fresnel term of 1 (Mitsuba's default ``material``): eta = 0, k = 1
NONE = "none"
NONE_ETA, NONE_K = (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)

#: Mitsuba's named conductors, in its data's order (case-insensitive sort)
NAMES: tuple[str, ...] = tuple(METAL_IORS)


def named(name: str, where: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``(eta, k)`` RGB triples of the conductor ``name`` (``"none"`` or one of :data:`NAMES`,
    spelt as Mitsuba spells it); a :class:`SceneError` naming ``where`` for an unknown name."""
    if name == NONE:
        return NONE_ETA, NONE_K
    if name not in METAL_IORS:
        raise SceneError(f"{where}: unknown conductor material {name!r} (known: none, {', '.join(NAMES)})")
    return METAL_IORS[name]


def is_fresnel_one(eta, k) -> bool:
    """Is ``(eta, k)`` the ``none`` conductor (Fresnel exactly 1)?"""
    return tuple(float(x) for x in eta) == NONE_ETA and tuple(float(x) for x in k) == NONE_K


def fresnel_conductor_lanes(xp, cos_i, eta, k):
    """Unpolarized Fresnel reflectance of a conductor of index ``eta + i k`` for cosines of
    incidence ``cos_i`` in [0, 1] (module docstring; Mitsuba 3's ``fresnel_conductor``), written
    against the array interface (:mod:`invrender.core.lanes`): ``eta``, ``k`` 3-tuples (RGB) give
    a 3-tuple, arrays (broadcasting against ``cos_i``) an array."""
    if isinstance(eta, tuple):
        return tuple(fresnel_conductor_lanes(xp, cos_i, e, kk) for e, kk in zip(eta, k))
    c2 = cos_i * cos_i
    s2 = 1.0 - c2
    t1 = eta * eta - k * k - s2
    a2b2 = xp.sqrt(xp.maximum(t1 * t1 + 4.0 * k * k * eta * eta, 0.0))
    a = xp.sqrt(xp.maximum(0.5 * (a2b2 + t1), 0.0))
    term1 = a2b2 + c2
    term2 = 2.0 * cos_i * a
    rs = (term1 - term2) / (term1 + term2)
    term3 = a2b2 * c2 + s2 * s2
    term4 = term2 * s2
    rp = rs * (term3 - term4) / (term3 + term4)
    return 0.5 * (rs + rp)


def fresnel_conductor(cos_i: torch.Tensor, eta: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """:func:`fresnel_conductor_lanes` on torch: reflectance (N, 3) of indices ``eta + i k`` (N, 3)
    each for cosines ``cos_i`` (N,)."""
    return fresnel_conductor_lanes(TORCH, cos_i[:, None], eta, k)


def fresnel_lanes(xp, p, cos_d, weight, *, fresnel: bool):
    """``weight`` (a 3-tuple) times the conductor Fresnel term of ``p["eta"]``, ``p["k"]`` at
    cosines ``cos_d`` (clamped to [0, 1]) in lane form; ``weight`` itself without ``fresnel`` (every
    material eta 0, k 1: :attr:`ConductorFresnel.fresnel_one`, nothing computed or multiplied)."""
    if not fresnel:
        return weight
    F = fresnel_conductor_lanes(xp, xp.minimum(xp.maximum(cos_d, 0.0), 1.0), p["eta"], p["k"])
    return (weight[0] * F[0], weight[1] * F[1], weight[2] * F[2])


#: the constants of a conductor's complex index of refraction, RGB (``none``: eta 0, k 1)
CONDUCTOR_CONSTANTS = {
    "eta": Constant(NONE_ETA, 0.0, float("inf"), False, True, size=3),
    "k": Constant(NONE_K, 0.0, float("inf"), False, True, size=3),
}


class ConductorFresnel:
    """Mixin of the conductors: the Fresnel term of their ``eta``/``k`` constants, and how the
    scene formats name them (TOML ``material = "Au"``, Mitsuba's ``material``/``eta``/``k``)."""

    #: the TOML key naming a preset of constants (:meth:`from_name`)
    toml_named = "material"

    @property
    def fresnel_one(self) -> bool:
        """Does every material of this instance have eta 0, k 1 (F = 1: nothing to compute or
        multiply; the lane forms bind it)?"""
        return all(is_fresnel_one(c.get("eta", NONE_ETA), c.get("k", NONE_K)) for c in self.constants)

    @property
    def fresnel_keys(self) -> tuple[tuple[str, int], ...]:
        """The lane form's keys of the Fresnel term (:func:`fresnel_lanes`): none where
        :attr:`fresnel_one`."""
        return () if self.fresnel_one else (("eta", 3), ("k", 3))

    def fresnel(self, sp: ShadingPoint, cos_d: torch.Tensor) -> torch.Tensor | None:
        """F (N, 3) at cosines ``cos_d`` (N,) of ``wo`` with the microfacet normal; None where
        :attr:`fresnel_one`."""
        if self.fresnel_one:
            return None
        eta, k = self.constant("eta", sp), self.constant("k", sp)
        one = ((eta == 0.0) & (k == 1.0)).all(1)
        return torch.where(one[:, None], 1.0, fresnel_conductor(cos_d.clamp(0.0, 1.0), eta, k))

    @classmethod
    def from_name(cls, name, where: str, given) -> dict:
        """The constants of TOML's ``material = NAME`` (a named metal or ``"none"``); ``given``: the
        table's keys (``eta``/``k`` beside a named metal are an error, as in Mitsuba)."""
        if not isinstance(name, str):
            raise SceneError(f"{where}: 'material' must be a string naming a conductor (none, Au, Cu, ...), got {name!r}")
        both = sorted({"eta", "k"} & set(given))
        if both and name != NONE:
            raise SceneError(f"{where}: give either material = {name!r} or '{both[0]}', not both")
        if name == NONE:
            return {}
        eta, k = named(name, where)
        return {"eta": eta, "k": k}

    @staticmethod
    def mitsuba_ior(constants: dict) -> dict:
        """Mitsuba's ``eta``/``k`` entries of the constants (``material none`` when they are the default)."""
        eta, k = constants.get("eta", NONE_ETA), constants.get("k", NONE_K)
        if is_fresnel_one(eta, k):
            return {"material": "none"}
        return {"eta": np.asarray(eta, dtype=np.float64), "k": np.asarray(k, dtype=np.float64)}
