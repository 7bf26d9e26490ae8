"""A spot light: Mitsuba's ``spot`` emitter, a point light whose intensity falls off with the angle
theta to its axis.

As Mitsuba's ``spot.cpp`` defines it: with the cutoff angle c and the beam width b (degrees; b
defaults to ``3/4 c``), the intensity towards a direction at angle theta from the axis is
``I falloff(theta)``, where ``falloff = 1`` for ``cos(theta) >= cos(b)``, ``(c - theta) / (c - b)``
(radians) between, and 0 for ``cos(theta) <= cos(c)``: full inside the beam, a linear ramp in
angle to the cutoff, black beyond. From a shading point at distance r, ``Le = I falloff / r^2``.
Its power is its flux over pi: ``I`` times the falloff's solid angle,
``2 pi (1 + (sin b - sin c) / (c - b))`` (``2 pi (1 - cos c)`` when b = c), over pi.

A projected texture (Mitsuba's ``texture``): the emission is then an image (h, w, 3), ``I x
texture`` texel by texel, read bilinearly (repeat wrapping) at Mitsuba's coordinates of the
direction leaving the light, in the light's frame (x = up x axis, y = up, z = the axis):
``u = 1/2 + x / (2 z tan c)``, ``v = 1/2 + y / (2 z tan c)`` with ``v = 0`` the image's top row, so
the image fills the square circumscribing the cutoff cone (its corners never lit), its first row
towards the light's local -y (``-up``) and its first column towards local -x: seen from behind the
light, it lands turned by 180 degrees (Mitsuba's convention; a ``projector``'s lands upright). ``Le = I(u, v) falloff /
r^2``, differentiable in the texels. The power (which chooses among lights) takes the image's mean
for I.

Scene files: the parameter ``emission`` is I (Mitsuba's ``intensity``: RGB, or an image for a
projected texture, Mitsuba's ``intensity`` times its ``texture``); the constants are ``position``
and ``direction`` (the axis, lists of three numbers; Mitsuba's ``to_world``, whose local +z is the
axis), ``up`` (the texture's up, local +y; made orthogonal to the axis; read only with a
texture), ``cutoff_angle`` and ``beam_width`` (degrees, ``beam_width <= cutoff_angle``).
"""

from __future__ import annotations

import math

import torch

from invrender import registry
from invrender.core import lanes
from invrender.core.compiled import TORCH
from invrender.plugins.emitters.delta import DIRECTION, OWN, POSITION, UP, DeltaLight, frame, frame_matrix, frame_of, projected_texture, towards_point, unit, up_of
from invrender.errors import SceneError
from invrender.scene.kinds import EMISSION
from invrender.scene.plugins import Constant, Param


def angles(cutoff_deg: float, beam_deg: float) -> list[float]:
    """The falloff's numbers as :func:`falloff_lanes` reads them: ``cos c, cos b, c, 1 / (c - b)``
    (radians; 0 for the last when b = c)."""
    c, b = math.radians(cutoff_deg), math.radians(beam_deg)
    return [math.cos(c), math.cos(b), c, 1.0 / (c - b) if c > b else 0.0]


def falloff_lanes(xp, cos_theta, cos_c, cos_b, c, inv_transition):
    """Mitsuba's ``falloff_curve`` against the array interface: 1 inside the beam, ``(c - theta) /
    (c - b)`` between the beam and the cutoff, 0 beyond (``cos_theta``: the cosine of the angle to
    the axis; the rest :func:`angles`, numbers or Floats)."""
    ramp = (c - xp.acos(xp.minimum(xp.maximum(cos_theta, -1.0), 1.0))) * inv_transition
    beam = xp.select(cos_theta >= cos_b, 1.0 + 0.0 * ramp, ramp)
    return xp.select(cos_theta > cos_c, beam, 0.0 * ramp)


def falloff(cos_theta: torch.Tensor, cutoff_deg: float, beam_deg: float) -> torch.Tensor:
    """:func:`falloff_lanes` of one spot (degrees) as eager torch."""
    return falloff_lanes(TORCH, cos_theta, *angles(cutoff_deg, beam_deg))


def falloff_solid_angle(cutoff_deg: float, beam_deg: float) -> float:
    """The integral of :func:`falloff` over the sphere of directions (sr)."""
    c, b = math.radians(cutoff_deg), math.radians(beam_deg)
    if c - b < 1e-9:
        return 2.0 * math.pi * (1.0 - math.cos(c))
    return 2.0 * math.pi * (1.0 + (math.sin(b) - math.sin(c)) / (c - b))


@registry.EMITTERS.register
class Spot(DeltaLight):
    type_name = "spot"
    params = {"emission": Param(EMISSION, 1.0)}
    constants = {
        "position": POSITION,
        "direction": DIRECTION,
        "up": UP,
        "cutoff_angle": Constant(20.0, 0.0, 180.0, low_open=True, high_open=True),
        "beam_width": Constant(15.0, 0.0, 180.0, low_open=False, high_open=True),
    }
    doc = "a spot light: intensity I (W/sr, RGB, or an image projected over the cone, oriented by `up`) from `position` along `direction`, Mitsuba's falloff (beam_width default: 3/4 of cutoff_angle)"

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        out = dict(constants, direction=unit(where, "direction", constants["direction"]))
        e = values.get("emission")
        out["up"] = up_of(where, out["direction"], constants["up"], required=e is not None and getattr(e, "ndim", 1) == 3)
        if "beam_width" not in given:
            out["beam_width"] = 0.75 * out["cutoff_angle"]  # Mitsuba's default
        if out["beam_width"] > out["cutoff_angle"]:
            raise SceneError(f"{where}: 'beam_width' ({out['beam_width']:g} degrees) must not exceed 'cutoff_angle' ({out['cutoff_angle']:g} degrees)")
        return out

    def member_power(self, i: int) -> float:
        c = self.constants[i]
        return float(self.sampling[i]["emission"].mean()) * falloff_solid_angle(c["cutoff_angle"], c["beam_width"]) / math.pi

    def member_intensity(self, i: int) -> torch.Tensor:
        e = self.values[i]["emission"]
        return e.new_ones(3) if e.ndim == 3 else e.reshape(3)

    def member_texture(self, i: int) -> torch.Tensor | None:
        e = self.values[i]["emission"]
        return e if e.ndim == 3 else None

    def member_row(self, i: int) -> list[float]:
        """Position (row columns 4-6), axis (7-9), :func:`angles` (10-13); for a textured instance
        then the frame's x and y (14-19) and tan c (20)."""
        c = self.constants[i]
        row = [*c["position"], *c["direction"], *angles(c["cutoff_angle"], c["beam_width"])]
        if self.textured:
            x, y, _ = frame(c["direction"], c["up"])
            row += [*x, *y, math.tan(math.radians(c["cutoff_angle"]))]
        return row

    @staticmethod
    def arrive(xp, row, o, nx, offset: float):
        """Towards the position (row columns 4-6), the axis 7-9, the falloff's :func:`angles`
        10-13: ``Le = I falloff / r^2``."""
        wl, r, tmax, facing = towards_point(xp, row[OWN : OWN + 3], o, nx, offset)
        cos_theta = -lanes.dot(wl, row[OWN + 3 : OWN + 6])  # the direction from the light to x, against the axis
        f = falloff_lanes(xp, cos_theta, *row[OWN + 6 : OWN + 10])
        return wl, tmax, f / (r * r), facing & (f > 0.0)

    @staticmethod
    def project(xp, row, wl):
        """Mitsuba's texture coordinates of the directions ``-wl`` leaving the light (module
        docstring), in invrender's convention (``v`` up)."""
        e = (-wl[0], -wl[1], -wl[2])
        z = lanes.dot(e, row[OWN + 3 : OWN + 6]) * row[OWN + 16]
        u = 0.5 + 0.5 * lanes.dot(e, row[OWN + 10 : OWN + 13]) / z
        v = 0.5 + 0.5 * lanes.dot(e, row[OWN + 13 : OWN + 16]) / z
        return u, 1.0 - v

    # ---- the formats' aliases

    #: the Mitsuba emitter plugins it reads (a child of <scene>)
    mitsuba_plugins = ("spot",)

    @classmethod
    def from_mitsuba(cls, emitter) -> dict:
        """Mitsuba's ``spot``: ``intensity`` (RGB, default 1), ``cutoff_angle`` (degrees, default
        20), ``beam_width`` (degrees, default 3/4 of the cutoff), ``to_world`` (a rotation, translation
        and uniform scale; the light looks along its local +z), ``texture``
        (a bitmap projected over the cone: the emission is then ``intensity x texture``; bilinear,
        repeat wrapping, and no ``to_uv``, as Mitsuba's defaults)."""
        I = emitter.colour("intensity", EMISSION, 1.0, texture=False)
        entries = {"emission": I, "cutoff_angle": emitter.number("cutoff_angle", cls.constants["cutoff_angle"], "the cone's half-angle, degrees")}
        if emitter.has("texture"):
            entries["emission"] = I * projected_texture(emitter, "texture")
        if emitter.has("beam_width"):
            entries["beam_width"] = emitter.number("beam_width", cls.constants["beam_width"], "the full beam's half-angle, degrees")
        position, axis, up, _ = frame_of(emitter, mirror=not emitter.has("texture"))
        emitter.finish(("intensity", "cutoff_angle", "beam_width", "texture", "to_world"))
        return {**entries, "position": [float(v) for v in position], "direction": [float(v) for v in axis], "up": [float(v) for v in up]}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        e = values["emission"]
        out = {
            "type": "spot",
            "intensity": e if e.ndim == 1 else torch.ones(3),
            "cutoff_angle": float(constants["cutoff_angle"]),
            "beam_width": float(constants["beam_width"]),
            "to_world": frame_matrix(constants["position"], constants["direction"], constants["up"]),  # (4, 4)
        }
        if e.ndim == 3:
            out["texture"] = e
        return out
