"""A projector: Mitsuba's ``projector`` emitter, a pinhole that projects an image into the scene, the
light counterpart of a perspective camera.

As Mitsuba's ``projector.cpp`` defines it (v3.9): in the light's frame (x = up x axis, y = up,
z = the axis, the camera frame of Mitsuba's lookat) a point q = x - position with depth
``z = q . axis > 0`` lies on the image at

    u = 1/2 - (q . x) / (2 z tan(fov / 2)),   v = 1/2 - a (q . y) / (2 z tan(fov / 2))

(``v = 0`` the image's first row, ``a = w / h`` the image's aspect ratio, ``fov`` the horizontal
field of view), so seen from behind the light the image lands upright: its first row towards
``up``, its first column towards local +x (the left, seen from the light). Points with u or v
outside [0, 1] (or behind the light) get nothing. The image E, read bilinearly with repeat
wrapping (Mitsuba's bitmap defaults), is the irradiance on the plane z = 1 in units of pi: from
the point at distance r along a direction at angle theta to the axis,

    Le = pi scale E(u, v) / (z^2 cos theta) = pi scale E(u, v) / (r^2 cos^3 theta),

so a plane facing the light at depth z is lit with the irradiance ``pi scale E / z^2``, constant
for a constant image. ``Le`` is differentiable in the image's texels. Its power (which chooses
among lights) is its flux over pi: ``scale x mean(E) x`` the image's area at z = 1,
``4 tan^2(fov / 2) / a``.

Scene files: the parameter ``emission`` is E (RGB or an image; Mitsuba's ``irradiance``), the
constants ``scale`` (> 0), ``fov`` (horizontal, degrees, in (0, 180)), ``position``,
``direction`` and ``up`` (the image's up, made orthogonal to the axis; Mitsuba's ``to_world``).
An RGB E is a 1 x 1 image (aspect 1).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from invrender import registry
from invrender.core import lanes
from invrender.plugins.emitters.delta import DIRECTION, OWN, POSITION, UP, DeltaLight, frame, frame_matrix, frame_of, projected_texture, towards_point, unit, up_of
from invrender.scene.kinds import EMISSION
from invrender.scene.plugins import Constant, Param


def aspect_of(emission) -> float:
    """The aspect ratio w / h of an image (h, w, 3); 1 for an RGB value."""
    shape = tuple(getattr(emission, "shape", np.shape(emission)))
    return shape[1] / shape[0] if len(shape) == 3 else 1.0


def image_lanes(xp, row, e):
    """Mitsuba's image coordinates ``(u, v, z)`` (``v = 0`` the first row; ``z = e . axis``) of the
    unit directions ``e`` (3-tuple) leaving the projectors of rows ``row`` (columns 7-9 the axis,
    10-12 x, 13-15 y, 16 ``1 / tan(fov / 2)``, 17 the aspect ratio)."""
    z = lanes.dot(e, row[OWN + 3 : OWN + 6])
    s = 0.5 * row[OWN + 12] / z
    u = 0.5 - s * lanes.dot(e, row[OWN + 6 : OWN + 9])
    v = 0.5 - s * row[OWN + 13] * lanes.dot(e, row[OWN + 9 : OWN + 12])
    return u, v, z


@registry.EMITTERS.register
class Projector(DeltaLight):
    type_name = "projector"
    params = {"emission": Param(EMISSION, 1.0)}
    constants = {
        "position": POSITION,
        "direction": DIRECTION,
        "up": UP,
        "fov": Constant(60.0, 0.0, 180.0, low_open=True, high_open=True),
        "scale": Constant(1.0, 0.0, math.inf, low_open=True, high_open=True),
    }
    doc = "a projector: an image E (irradiance / pi on the plane at depth 1, RGB or texture) projected from `position` along `direction` through a pinhole of horizontal `fov`, its top towards `up`, times `scale` (Mitsuba's projector)"

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        out = dict(constants, direction=unit(where, "direction", constants["direction"]))
        out["up"] = up_of(where, out["direction"], constants["up"], required=True)
        return out

    def member_power(self, i: int) -> float:
        c = self.constants[i]
        e = self.sampling[i]["emission"]
        t = math.tan(math.radians(c["fov"]) / 2.0)
        return c["scale"] * float(e.mean()) * 4.0 * t * t / aspect_of(e)

    def member_intensity(self, i: int) -> torch.Tensor:
        e = self.values[i]["emission"]
        scale = self.constants[i]["scale"]
        return e.new_full((3,), scale) if e.ndim == 3 else e.reshape(3) * scale

    def member_texture(self, i: int) -> torch.Tensor | None:
        e = self.values[i]["emission"]
        return e if e.ndim == 3 else None

    def member_row(self, i: int) -> list[float]:
        """Position (row columns 4-6), the frame's z, x, y (7-15), ``1 / tan(fov / 2)`` (16), the
        aspect ratio (17)."""
        c = self.constants[i]
        x, y, z = frame(c["direction"], c["up"])
        return [*c["position"], *z, *x, *y, 1.0 / math.tan(math.radians(c["fov"]) / 2.0), aspect_of(self.values[i]["emission"])]

    @staticmethod
    def arrive(xp, row, o, nx, offset: float):
        """Towards the position: ``Le = pi E / (r^2 cos^3 theta)`` (the factor without E) inside
        the image, 0 outside."""
        wl, r, tmax, facing = towards_point(xp, row[OWN : OWN + 3], o, nx, offset)
        u, v, z = image_lanes(xp, row, (-wl[0], -wl[1], -wl[2]))
        inside = (z > 0.0) & (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (v <= 1.0)
        c = xp.maximum(z, 1e-12)
        factor = xp.select(inside, math.pi / (r * r * c * c * c), 0.0 * r)
        return wl, tmax, factor, facing & inside

    @staticmethod
    def project(xp, row, wl):
        """The image coordinates of the directions ``-wl``, in invrender's convention (``v`` up)."""
        u, v, _ = image_lanes(xp, row, (-wl[0], -wl[1], -wl[2]))
        return u, 1.0 - v

    # ---- the formats' aliases

    #: the Mitsuba emitter plugins it reads (a child of <scene>)
    mitsuba_plugins = ("projector",)

    @classmethod
    def from_mitsuba(cls, emitter) -> dict:
        """Mitsuba's ``projector``: ``irradiance`` (RGB or a bitmap, default 1; bilinear, repeat
        wrapping, no ``to_uv``), ``scale`` (default 1), ``fov`` with ``fov_axis`` (x, y, smaller,
        larger) or ``focal_length`` (default 50 mm, as the perspective sensor reads them, the film
        the image), ``to_world`` (a rotation, translation and uniform scale s, which scales the
        light by s as in Mitsuba; no mirror)."""
        E = projected_texture(emitter, "irradiance", colour=True)
        aspect = aspect_of(E)
        fov, axis = emitter.field_of_view((np.shape(E)[1], np.shape(E)[0]) if np.ndim(E) == 3 else (1, 1))
        if axis == "smaller":
            axis = "y" if aspect > 1 else "x"
        elif axis == "larger":
            axis = "x" if aspect > 1 else "y"
        if axis == "y":  # the horizontal field of view of a vertical one
            fov = math.degrees(2.0 * math.atan(math.tan(math.radians(fov) / 2.0) * aspect))
        scale = emitter.number("scale", cls.constants["scale"], "the irradiance's scale factor")
        position, axis_z, up, s = frame_of(emitter, mirror=False)
        emitter.finish(("irradiance", "scale", "fov", "fov_axis", "focal_length", "to_world"))
        return {"emission": E, "scale": scale * s, "fov": fov, "position": [float(v) for v in position], "direction": [float(v) for v in axis_z], "up": [float(v) for v in up]}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        return {
            "type": "projector",
            "irradiance": values["emission"],
            "scale": float(constants["scale"]),
            "fov": float(constants["fov"]),
            "to_world": frame_matrix(constants["position"], constants["direction"], constants["up"]),  # (4, 4)
        }
