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

Written once (:class:`~invrender.core.lights.LightLanes`): the choice and the shadow rays are lane
functions (:func:`delta_geometry`, each type's ``arrive``) reading a table of the type's emitters
(:attr:`DeltaLight.lane_tables`); :meth:`DeltaLight.sample_from` evaluates them
(:func:`invrender.core.compiled.run`) and keeps only ``Le = I x factor`` in torch, differentiable in I.
"""

from __future__ import annotations

import functools
from abc import abstractmethod
from collections.abc import Callable
from typing import ClassVar

import math

import numpy as np
import torch

from invrender.errors import SceneError
from invrender.scene.plugins import Constant
from invrender.core import compiled, lanes
from invrender.core.lights import Light, LightLanes, LightSample

#: a position anywhere (three numbers)
POSITION = Constant((0.0, 0.0, 0.0), -math.inf, math.inf, True, True, size=3)
#: a direction (three numbers, normalized when read; not zero)
DIRECTION = Constant((0.0, 0.0, 1.0), -math.inf, math.inf, True, True, size=3)
#: floats per emitter in a delta light type's table (:attr:`DeltaLight.lane_tables`): the probability
#: of choosing it, its intensity (RGB, detached), then the type's own (:meth:`DeltaLight.member_row`)
ROW = 16
#: where the type's own numbers start in a row
OWN = 4


def unit(where: str, key: str, v) -> tuple:
    """``v`` (3 numbers) normalized; a one-line error for a zero vector."""
    a = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if not n > 0:
        raise SceneError(f"{where}: '{key}' must be a non-zero direction, got {tuple(float(x) for x in a)}")
    return tuple(float(x) for x in a / n)


class DeltaLight(Light):
    """Base of the delta lights: picks one of the type's emitters by power.

    Subclasses give :meth:`member_power` (detached, per emitter, in the units above),
    :meth:`member_row` (the numbers their shadow rays read: a position, a direction, angles) and
    :attr:`arrive`, the lane function of the shadow rays towards the chosen emitters.
    """

    surface = False
    infinite = False

    #: ``arrive(xp, row, o, nx, offset) -> (wl, tmax, factor, facing)``: from shadow-ray origins
    #: ``o`` (3-tuple) with geometric normals ``nx`` towards the emitters of table rows ``row``
    #: (:data:`ROW` Floats), the unit directions, where the rays stop, the factor of the intensity
    #: that arrives (``Le = I factor``) and whether it can light x (a staticmethod of the type)
    arrive: ClassVar[Callable]

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

    @abstractmethod
    def member_row(self, i: int) -> list[float]:
        """The type's own numbers of its emitter ``i`` (at most ``ROW - OWN``), from column
        :data:`OWN` of its table row."""

    @property
    def power(self) -> float:
        return self.total

    def stacked(self, key: str) -> torch.Tensor:
        """(E, 3) parameter ``key`` of the type's emitters (differentiable)."""
        return torch.stack([v[key].reshape(3) for v in self.values])

    @functools.cached_property
    def lane_tables(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(choice (E * 2,), rows (E * 16,))`` float32 on the render device, made once: the
        choice's cdf as a light table (:func:`invrender.core.lanes.light_rows`, the emitter's index
        in place of a triangle's) and per emitter a row: its probability, its intensity
        (detached ``values``), then :meth:`member_row`."""
        n = len(self.emitters)
        choice = lanes.light_rows(self._cdf, torch.arange(n, device=self.device))
        intensity = self.stacked("emission").detach().float().cpu()
        rows = torch.zeros(n, ROW, dtype=torch.float32)
        for i in range(n):
            own = [float(v) for v in self.member_row(i)]
            rows[i, 0] = float(self.choice[i])
            rows[i, 1:OWN] = intensity[i]
            rows[i, OWN : OWN + len(own)] = torch.tensor(own, dtype=torch.float32)
        return choice, rows.reshape(-1).to(self.device)

    def lanes(self) -> LightLanes | None:
        """The type in lane form: :func:`delta_sample` on :attr:`lane_tables`, every sample a delta
        one. It applies to every render, one that holds sampling fixed included (the table holds
        the choice made from the sampling values and the intensities of the values); None for a
        subclass that answers ``sample_from`` by other means than the lane functions."""
        if type(self).sample_from is not DeltaLight.sample_from:
            return None
        return LightLanes(functools.partial(delta_sample, size=len(self.emitters), arrive=type(self).arrive), self.lane_tables, delta=True)

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """:func:`delta_geometry` (compiled where Dr.Jit runs); ``Le = I_k factor`` in torch."""
        k, o, wl, tmax, factor, pdf, facing = compiled.run(delta_geometry, x.device, *self.lane_tables, u[:, 0].detach().float(), x.detach().float(), nx.detach().float(), float(offset), size=len(self.emitters), arrive=type(self).arrive)
        Le = self.stacked("emission").index_select(0, k.long()) * factor[:, None]
        return LightSample(o, wl, tmax, facing, pdf, Le, torch.ones_like(facing))


def delta_geometry(xp, choice, rows, u0, x, nx, offset: float, *, size: int, arrive: Callable):
    """The detached part of a delta light type's samples, written once against the array interface:
    the emitter picked by ``u0`` through the cdf of ``choice`` (``size`` emitters, masked halvings:
    :func:`invrender.core.lanes.pick_light`), the shadow ray from ``x`` (3-tuples) offset along its
    geometric normal ``nx``, by the type's ``arrive``. Returns (emitter index (UInt), origin, unit
    direction, tmax, factor (``Le = I factor``), pdf (the choice's probability), facing)."""
    k, row, o, wl, tmax, factor, pdf, facing = _delta(xp, choice, rows, u0, x, nx, offset, size, arrive)
    return k, o, wl, tmax, factor, pdf, facing


def delta_sample(xp, t, u0, u1, u2, x, nx, offset: float, *, size: int, arrive: Callable):
    """:attr:`LightLanes.sample <invrender.core.lights.LightLanes>` of a delta light type: ``t`` its
    :attr:`~DeltaLight.lane_tables`; ``u1``, ``u2`` unused. Returns (origin, wl, tmax, Le, pdf, facing)."""
    k, row, o, wl, tmax, factor, pdf, facing = _delta(xp, t[0], t[1], u0, x, nx, offset, size, arrive)
    return o, wl, tmax, lanes.scale(row[1:OWN], factor), pdf, facing


def _delta(xp, choice, rows, u0, x, nx, offset, size, arrive):
    k = lanes.pick_light(xp, choice, size, u0)
    row = xp.gather_rows(rows, k, ROW)
    o = lanes.add(x, lanes.scale(nx, offset))
    wl, tmax, factor, facing = arrive(xp, row, o, nx, offset)
    pdf = row[0]
    return k, row, o, wl, tmax, factor, pdf, facing & (pdf > 0.0)


def towards_point(xp, p, o, nx, offset: float):
    """``(wl, r, tmax, facing)`` from shadow-ray origins ``o`` to points ``p`` (3-tuples): the unit
    direction, the distance, where the shadow ray stops (the distance minus the offset) and
    whether the point lies in front of x's geometric normal."""
    d = lanes.sub(p, o)
    r = xp.maximum(xp.sqrt(lanes.dot(d, d)), 1e-12)
    wl = (d[0] / r, d[1] / r, d[2] / r)
    return wl, r, xp.maximum(r - offset, 0.0), lanes.dot(nx, wl) > 0.0


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
