"""A directional light: Mitsuba's ``directional`` emitter, irradiance E (W/m^2 on a surface
facing it) arriving from infinitely far along one direction.

The light travels along ``direction`` (Mitsuba's: the emitter's local +z); from a shading point it
arrives along ``wl = -direction`` with ``Le = E`` and no end to the shadow ray (``tmax = inf``), so a
diffuse surface of albedo rho at angle theta to it has radiance ``rho / pi * E cos(theta)``
exactly. No ray ever sees it. Its power is the flux through the scene's bounding disc
(``pi r^2 E``, r the radius of the sphere around the bounding box, as the ``constant`` emitter's)
over pi: ``r^2 mean(E)`` (the units of an area light's ``area x mean(eps)``).

Scene files: the parameter ``emission`` is E (RGB only; Mitsuba's ``irradiance``); the constant
``direction`` is a list of three numbers (normalized; Mitsuba's ``direction``, or the local +z of
its ``to_world``, never both).
"""

from __future__ import annotations

import math

from invrender import registry
from invrender.core import lanes
from invrender.plugins.emitters.delta import DIRECTION, OWN, DeltaLight, unit
from invrender.scene.kinds import EMISSION, EMISSION_RGB
from invrender.scene.plugins import Param
from invrender.scene.scene import scene_extent


@registry.EMITTERS.register
class Directional(DeltaLight):
    type_name = "directional"
    params = {"emission": Param(EMISSION_RGB, 1.0)}
    constants = {"direction": DIRECTION}
    doc = "a directional light: irradiance E (RGB) travelling along `direction` from infinitely far"

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        return dict(constants, direction=unit(where, "direction", constants["direction"]))

    def member_power(self, i: int) -> float:
        radius = 0.5 * math.sqrt(3.0) * scene_extent(self.triangles)
        return radius * radius * float(self.sampling[i]["emission"].mean())

    def member_row(self, i: int) -> list[float]:
        return list(self.constants[i]["direction"])

    @staticmethod
    def arrive(xp, row, o, nx, offset: float):
        """Against the direction of travel (row columns 4-6), no end to the ray: ``Le = E``."""
        wl = (-row[OWN], -row[OWN + 1], -row[OWN + 2])
        return wl, xp.full(math.inf, o[0]), xp.full(1.0, o[0]), lanes.dot(nx, wl) > 0.0

    # ---- the formats' aliases

    #: the Mitsuba emitter plugins it reads (a child of <scene>)
    mitsuba_plugins = ("directional",)

    @classmethod
    def from_mitsuba(cls, emitter) -> dict:
        """Mitsuba's ``directional``: ``irradiance`` (RGB, default 1), ``direction`` (a <vector>)
        or the local +z of ``to_world`` (not both)."""
        E = emitter.colour("irradiance", EMISSION, 1.0, texture=False)
        if emitter.has("direction") and emitter.has("to_world"):
            raise emitter.error("direction", "give one of 'direction' and 'to_world', not both")
        if emitter.has("direction"):
            direction = emitter.vector("direction")
        else:
            m = emitter.transform("to_world")
            direction = m[:3, :3] @ [0.0, 0.0, 1.0]
        emitter.finish(("irradiance", "direction", "to_world"))
        return {"emission": E, "direction": [float(v) for v in direction]}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        return {"type": "directional", "irradiance": values["emission"], "direction": [float(v) for v in constants["direction"]]}
