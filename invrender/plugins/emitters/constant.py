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
from invrender.core.lights import Light, LightSample
from invrender.vec import dot

#: the density of a direction sampled uniformly over the sphere
UNIFORM_SPHERE_PDF = 1.0 / (4.0 * math.pi)


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
        """Directions uniform over the sphere from ``u[:, 1:3]`` (``z = 1 - 2 u_1``, ``phi = 2 pi u_2``)."""
        z = 1.0 - 2.0 * u[:, 1]
        r = (1.0 - z * z).clamp_min(0.0).sqrt()
        phi = (2.0 * math.pi) * u[:, 2]
        wl = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=1)
        n = x.shape[0]
        pdf = torch.full((n,), UNIFORM_SPHERE_PDF, device=x.device)
        return LightSample(x + offset * nx, wl, torch.full((n,), math.inf, device=x.device), dot(nx, wl) > 0, pdf, self.L(n))

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
