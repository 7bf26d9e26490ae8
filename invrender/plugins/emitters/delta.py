"""What the delta lights (:mod:`~invrender.plugins.emitters.point`, :mod:`~invrender.plugins.emitters.spot`,
:mod:`~invrender.plugins.emitters.directional`) share: a choice among the type's emitters, the Mitsuba
frame readers, and the one-line errors for their vector constants.

A delta light is a point or a direction: next-event estimation picks one of the type's emitters
with probability proportional to its detached power (the sample's ``pdf`` is that discrete
probability, its ``delta`` flag set), no BSDF sample can hit it, and multiple importance sampling
gives it weight 1. :func:`~invrender.plugins.integrators.vertex.add_direct` weighs a sample
``1 / pdf`` and multiplies by ``f cos Le``, so ``Le`` is what arrives at x: ``I / r^2`` for a
point, ``E`` for a direction.

Power (for choosing among emitter types) is in the units of the area light's ``area x mean(eps)``,
which is its flux divided by pi: a point light's flux ``4 pi I`` gives ``4 mean(I)``.
"""

from __future__ import annotations

from abc import abstractmethod

import math

import numpy as np
import torch

from invrender.errors import SceneError
from invrender.scene.plugins import Constant
from invrender.core.lights import Light, LightSample

#: a position anywhere (three numbers)
POSITION = Constant((0.0, 0.0, 0.0), -math.inf, math.inf, True, True, size=3)
#: a direction (three numbers, normalized when read; not zero)
DIRECTION = Constant((0.0, 0.0, 1.0), -math.inf, math.inf, True, True, size=3)


def unit(where: str, key: str, v) -> tuple:
    """``v`` (3 numbers) normalized; a one-line error for a zero vector."""
    a = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if not n > 0:
        raise SceneError(f"{where}: '{key}' must be a non-zero direction, got {tuple(float(x) for x in a)}")
    return tuple(float(x) for x in a / n)


class DeltaLight(Light):
    """Base of the delta lights: picks one of the type's emitters by power.

    Subclasses give :meth:`member_power` (detached, per emitter, in the units above) and
    :meth:`arrive` (the shadow rays and ``Le`` of the chosen emitters).
    """

    surface = False
    infinite = False

    def __init__(self, emitters, values, constants, triangles, sampling=None):
        super().__init__(emitters, values, constants, triangles, sampling)
        device = triangles.p0.device
        self.device = device
        power = [max(self.member_power(i), 0.0) for i in range(len(emitters))]
        self.total = float(sum(power))
        #: per emitter of this type, the probability of choosing it
        self.choice = torch.tensor([p / self.total if self.total > 0 else 0.0 for p in power], dtype=torch.float32, device=device)
        self._cdf = torch.tensor(power, dtype=torch.float64).cumsum(0).div(max(self.total, 1e-300)).float().to(device)

    @abstractmethod
    def member_power(self, i: int) -> float:
        """The power of the type's emitter ``i`` (detached; flux / pi, the area light's units)."""

    @property
    def power(self) -> float:
        return self.total

    def stacked(self, key: str) -> torch.Tensor:
        """(E, 3) parameter ``key`` of the type's emitters (differentiable)."""
        return torch.stack([v[key].reshape(3) for v in self.values])

    def vectors(self, key: str) -> torch.Tensor:
        """(E, 3) vector constant ``key`` of the type's emitters."""
        return torch.tensor([c[key] for c in self.constants], dtype=torch.float32, device=self.device)

    def pick(self, u: torch.Tensor) -> torch.Tensor:
        """(N,) int64 emitter (index among the type's) chosen by ``u`` (N,), by power."""
        if len(self.emitters) == 1:
            return torch.zeros(u.shape[0], dtype=torch.int64, device=u.device)
        return torch.searchsorted(self._cdf, u.contiguous(), right=True).clamp_max(len(self.emitters) - 1)

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        k = self.pick(u[:, 0])
        o = x + offset * nx
        wl, tmax, facing, Le = self.arrive(k, o, nx, offset)
        pdf = self.choice.index_select(0, k)
        return LightSample(o, wl, tmax, facing & (pdf > 0), pdf, Le, torch.ones_like(facing))

    @abstractmethod
    def arrive(self, k: torch.Tensor, o: torch.Tensor, nx: torch.Tensor, offset: float):
        """``(wl, tmax, facing, Le)`` of the shadow rays from ``o`` (N, 3) towards emitters ``k``."""


def towards_point(p: torch.Tensor, o: torch.Tensor, nx: torch.Tensor, offset: float):
    """``(wl, r, tmax, facing)`` from shadow-ray origins ``o`` to points ``p`` (both (N, 3)): the
    unit direction, the distance, where the shadow ray stops (the distance minus the offset) and
    whether the point lies in front of x's geometric normal."""
    d = p - o
    r = d.norm(dim=1).clamp_min(1e-12)
    wl = d / r[:, None]
    facing = (nx * wl).sum(dim=1) > 0
    return wl, r, (r - offset).clamp_min(0.0), facing


def frame_z(reader, where_key: str = "to_world") -> tuple[np.ndarray, np.ndarray, float]:
    """``(translation (3,), unit local +z in the world (3,), scale)`` of the reader's ``to_world``;
    an error unless its linear part is a rotation times a uniform scale (lookat, rotate, translate,
    scale by one number): only then is a direction's angle to the axis the one Mitsuba measures in
    the local frame."""
    m = reader.transform(where_key)
    a = m[:3, :3]
    gram = a.T @ a
    s2 = float(np.trace(gram)) / 3.0
    if not s2 > 0 or not np.allclose(gram, s2 * np.eye(3), rtol=1e-5, atol=1e-8 * max(s2, 1.0)):
        raise reader.error(where_key, f"'{where_key}' of a {reader.type} emitter must be a rotation, translation and uniform scale (lookat, rotate, translate), not a shear or non-uniform scale")
    z = a @ np.array([0.0, 0.0, 1.0])
    return m[:3, 3].copy(), z / np.linalg.norm(z), math.sqrt(s2)


def look_at_matrix(position, direction) -> np.ndarray:
    """A (4, 4) ``to_world`` placing the local origin at ``position`` and local +z along
    ``direction`` (the other axes any orthonormal completion)."""
    z = np.asarray(direction, dtype=np.float64)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, np.asarray(position, dtype=np.float64)
    return m
