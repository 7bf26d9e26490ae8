"""A constant environment: Mitsuba's ``constant`` emitter, uniform radiance L from every direction.

Rays that leave the scene see L, whatever their direction; next-event estimation samples
directions uniformly over the sphere (pdf ``1 / (4 pi)``, as Mitsuba's), so a shadow ray towards
the sky has no end (``tmax = inf``). A convex diffuse object under it has radiance ``rho L``
exactly (it sees nothing but the sky): docs/closed_forms.md. Its power, for choosing between it
and the scene's other emitters, is that of L through the scene's bounding sphere,
``4 pi r^2 mean(L)`` (the same units as an area light's ``area x mean(eps)``).
"""

from __future__ import annotations

import math

import torch

from invrender import registry
from invrender.scene.kinds import EMISSION, EMISSION_RGB
from invrender.scene.plugins import Param
from invrender.scene.scene import scene_extent
from invrender.core import compiled, lanes
from invrender.core.lights import Light, LightLanes, LightSample

#: the density of a direction sampled uniformly over the sphere
UNIFORM_SPHERE_PDF = 1.0 / (4.0 * math.pi)


def constant_sample(xp, t, u0, u1, u2, x, nx, offset: float):
    """:class:`~invrender.core.lights.LightLanes`' ``sample``: directions uniform over the sphere
    (``z = 1 - 2 u1``, ``phi = 2 pi u2``, pdf ``1 / (4 pi)``), shadow rays without end, the radiance
    ``t[0]`` (L, padded to 4)."""
    z = 1.0 - 2.0 * u1
    r = xp.sqrt(xp.maximum(1.0 - z * z, 0.0))
    phi = (2.0 * math.pi) * u2
    wl = (r * xp.cos(phi), r * xp.sin(phi), z)
    zero = 0.0 * u0
    return lanes.add(x, lanes.scale(nx, offset)), wl, zero + math.inf, _radiance(xp, t[0], u0), zero + UNIFORM_SPHERE_PDF, lanes.dot(nx, wl) > 0.0


def constant_escaped(xp, t, d):
    """:class:`~invrender.core.lights.LightLanes`' ``escaped``: L and ``1 / (4 pi)`` for every ray."""
    return _radiance(xp, t[0], d[0]), 0.0 * d[0] + UNIFORM_SPHERE_PDF


def _radiance(xp, L, like):
    """L (a (4,) table) on every lane of ``like``."""
    return xp.gather_rows(L, xp.full(0, like), 4)[:3]


@registry.EMITTERS.register
class Constant(Light):
    type_name = "constant"
    params = {"emission": Param(EMISSION_RGB, 1.0)}
    doc = "a uniform environment: radiance L from every direction (RGB)"
    surface = False
    infinite = True

    def L(self, n: int) -> torch.Tensor:
        """(n, 3) the sum of the scene's constant environments' radiances (differentiable)."""
        total = self.values[0]["emission"]
        for v in self.values[1:]:
            total = total + v["emission"]
        return total.expand(n, 3)

    @property
    def power(self) -> float:
        radius = 0.5 * math.sqrt(3.0) * scene_extent(self.triangles)  # the bounding box's sphere
        return 4.0 * math.pi * radius * radius * sum(float(v["emission"].mean()) for v in self.sampling)

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """Directions uniform over the sphere from ``u[:, 1:3]`` (:func:`constant_sample`)."""
        zero = torch.zeros(4, device=x.device)
        o, wl, tmax, _, pdf, facing = compiled.run(constant_sample, x.device, (zero,), u[:, 0], u[:, 1], u[:, 2], x, nx, float(offset))
        return LightSample(o, wl, tmax, facing, pdf, self.L(x.shape[0]))

    def lanes(self) -> LightLanes | None:
        """The lane form (:func:`constant_sample`, :func:`constant_escaped`), when sampling reads
        the values the render evaluates."""
        if any(not torch.equal(v["emission"].detach(), s["emission"]) for v, s in zip(self.values, self.sampling)):
            return None
        L = torch.nn.functional.pad(self.L(1)[0].detach().float(), (0, 1))
        return LightLanes(constant_sample, (L,), escaped=constant_escaped)

    def escaped(self, d: torch.Tensor) -> torch.Tensor:
        return self.L(d.shape[0])

    def pdf_escaped(self, d: torch.Tensor) -> torch.Tensor:
        return torch.full((d.shape[0],), UNIFORM_SPHERE_PDF, device=d.device)

    # ---- the formats' aliases

    #: the Mitsuba emitter plugins it reads (a child of <scene>)
    mitsuba_plugins = ("constant",)

    @classmethod
    def from_mitsuba(cls, emitter) -> dict:
        """Mitsuba's ``constant``: ``radiance`` (RGB, float or constant spectrum; default 1)."""
        L = emitter.colour("radiance", EMISSION, 1.0, texture=False)
        emitter.finish(("radiance",))
        return {"emission": L}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        return {"type": "constant", "radiance": values["emission"]}
