"""A point light: Mitsuba's ``point`` emitter, radiant intensity I (W/sr) from one point, equally
in every direction.

From a shading point x at distance r the light arrives along one direction with ``Le = I / r^2``
(the sample's pdf is the discrete probability of having chosen this light; Mitsuba's
``sample_direction``), so a diffuse surface of albedo rho facing it at angle theta has radiance
``rho / pi * I cos(theta) / r^2`` exactly, with no variance. No ray ever hits it. Its power, for
choosing between it and other emitters, is its flux ``4 pi I`` over pi: ``4 mean(I)`` (the units of
an area light's ``area x mean(eps)``, :mod:`invrender.plugins.emitters.delta`).

Scene files: the parameter ``emission`` is I (RGB only; Mitsuba's ``intensity``); the constant
``position`` is a list of three numbers (TOML ``position = [x, y, z]``; Mitsuba's ``position``, or
the translation of its ``to_world``, never both).
"""

from __future__ import annotations


from invrender import registry
from invrender.plugins.emitters.delta import OWN, POSITION, DeltaLight, towards_point
from invrender.scene.kinds import EMISSION, EMISSION_RGB
from invrender.scene.plugins import Param


@registry.EMITTERS.register
class Point(DeltaLight):
    type_name = "point"
    params = {"emission": Param(EMISSION_RGB, 1.0)}
    constants = {"position": POSITION}
    doc = "a point light: radiant intensity I (W/sr, RGB) from `position`, equally in all directions"

    def member_power(self, i: int) -> float:
        return 4.0 * float(self.sampling[i]["emission"].mean())

    def member_row(self, i: int) -> list[float]:
        return list(self.constants[i]["position"])

    @staticmethod
    def arrive(xp, row, o, nx, offset: float):
        """Towards the position (row columns 4-6): ``Le = I / r^2``."""
        wl, r, tmax, facing = towards_point(xp, row[OWN : OWN + 3], o, nx, offset)
        return wl, tmax, 1.0 / (r * r), facing

    # ---- the formats' aliases

    #: the Mitsuba emitter plugins it reads (a child of <scene>)
    mitsuba_plugins = ("point",)

    @classmethod
    def from_mitsuba(cls, emitter) -> dict:
        """Mitsuba's ``point``: ``intensity`` (RGB, default 1), ``position`` (a <point>) or the
        translation of ``to_world`` (not both)."""
        I = emitter.colour("intensity", EMISSION, 1.0, texture=False)
        if emitter.has("position") and emitter.has("to_world"):
            raise emitter.error("position", "give one of 'position' and 'to_world', not both")
        if emitter.has("position"):
            position = emitter.vector("position")
        else:
            position = emitter.transform("to_world")[:3, 3]
        emitter.finish(("intensity", "position", "to_world"))
        return {"emission": I, "position": [float(v) for v in position]}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        return {"type": "point", "intensity": values["emission"], "position": [float(v) for v in constants["position"]]}
