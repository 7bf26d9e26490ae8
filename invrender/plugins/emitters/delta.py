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

Projected textures (a ``projector``, a ``spot`` with an image): a type with a ``project`` lane
function gives the texture coordinates of the direction leaving the light, and ``Le = I x factor x
T(uv)`` with T the emitter's texture (:meth:`DeltaLight.member_texture`) read through
:func:`invrender.core.textures.filter_lanes` (bilinear, repeat: Mitsuba's bitmap defaults). The
lanes read the textures from a :class:`~invrender.core.lanes.TextureTable` (its rows and texels
after the type's own tables, :func:`~invrender.core.lanes.texture_lookup`); the torch method reads
the same texels by :func:`invrender.core.textures.lookup`, differentiable in them.
"""

from __future__ import annotations

import functools
from abc import abstractmethod
from collections.abc import Callable
from typing import ClassVar

import math

import numpy as np
import torch

from invrender.errors import ParameterError, SceneError
from invrender.scene.plugins import Constant
from invrender.core import compiled, lanes, textures
from invrender.core.lights import Light, LightLanes, LightSample

#: a position anywhere (three numbers)
POSITION = Constant((0.0, 0.0, 0.0), -math.inf, math.inf, True, True, size=3)
#: a direction (three numbers, normalized when read; not zero)
DIRECTION = Constant((0.0, 0.0, 1.0), -math.inf, math.inf, True, True, size=3)
#: the up of a light's projected image (three numbers, made orthogonal to its direction when read)
UP = Constant((0.0, 1.0, 0.0), -math.inf, math.inf, True, True, size=3)
#: floats per emitter in a delta light type's table (:attr:`DeltaLight.lane_tables`): the probability
#: of choosing it, its intensity (RGB, detached), then the type's own (:meth:`DeltaLight.member_row`)
ROW = 16
#: where the type's own numbers start in a row
OWN = 4
#: floats per emitter in the table of an instance whose emitters project textures: two rows of
#: :data:`ROW`, the texture's id in the instance's texture table (-1: none) in the last column
TEXTURED_ROW = 2 * ROW
#: the column of a textured row holding its texture's id
TEXTURE = TEXTURED_ROW - 1


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
    #: (:attr:`width` Floats), the unit directions, where the rays stop, the factor of the intensity
    #: that arrives (``Le = I factor``) and whether it can light x (a staticmethod of the type)
    arrive: ClassVar[Callable]
    #: ``project(xp, row, wl) -> (u, v)``: for types that can project a texture, the texture
    #: coordinates (invrender's convention, ``v`` up) of the directions ``-wl`` leaving the
    #: emitters of rows ``row`` (:data:`TEXTURED_ROW` Floats); None: the type reads no texture
    project: ClassVar[Callable | None] = None

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
        """The type's own numbers of its emitter ``i`` (at most ``ROW - OWN``, or ``TEXTURE - OWN``
        where the instance is :attr:`textured`), from column :data:`OWN` of its table row."""

    def member_intensity(self, i: int) -> torch.Tensor:
        """(3,) the factor I of emitter ``i``'s ``Le = I factor`` (differentiable): its
        ``emission`` (a type whose emission is a texture says otherwise)."""
        return self.values[i]["emission"].reshape(3)

    def member_texture(self, i: int) -> torch.Tensor | None:
        """(h, w, 3) the texture emitter ``i`` projects (differentiable), read at ``project``'s
        coordinates; None: none (types with a ``project`` say)."""
        return None

    @functools.cached_property
    def textures(self) -> list:
        """Per emitter, :meth:`member_texture` (all None for a type without ``project``)."""
        return [self.member_texture(i) if type(self).project is not None else None for i in range(len(self.emitters))]

    @property
    def textured(self) -> bool:
        """Does one of the instance's emitters project a texture (its rows :data:`TEXTURED_ROW`
        wide, its lane functions reading textures)?"""
        return any(t is not None for t in self.textures)

    @functools.cached_property
    def width(self) -> int:
        """Floats per emitter in :attr:`lane_tables`' rows: :data:`TEXTURED_ROW` where the instance
        is :attr:`textured` or an emitter's :meth:`member_row` needs more than :data:`ROW` holds,
        else :data:`ROW`."""
        wide = self.textured or any(len(self.member_row(i)) > ROW - OWN for i in range(len(self.emitters)))
        return TEXTURED_ROW if wide else ROW

    @property
    def _static(self) -> dict:
        """The lane functions' static arguments."""
        return {"size": len(self.emitters), "arrive": type(self).arrive, "width": self.width, "project": type(self).project if self.textured else None}

    @property
    def power(self) -> float:
        return self.total

    def stacked(self, key: str) -> torch.Tensor:
        """(E, 3) parameter ``key`` of the type's emitters (differentiable)."""
        return torch.stack([v[key].reshape(3) for v in self.values])

    def intensities(self) -> torch.Tensor:
        """(E, 3) :meth:`member_intensity` of the type's emitters (differentiable)."""
        return torch.stack([self.member_intensity(i) for i in range(len(self.emitters))])

    @functools.cached_property
    def lane_tables(self) -> tuple[torch.Tensor, ...]:
        """``(choice (E * 2,), rows (E * W,))`` float32 on the render device, made once: the
        choice's cdf as a light table (:func:`invrender.core.lanes.light_rows`, the emitter's index
        in place of a triangle's) and per emitter a row of W floats (:attr:`width`): its probability, its
        intensity (detached :meth:`member_intensity`), then :meth:`member_row`. A textured
        instance's tables go on with its textures' (:meth:`invrender.core.lanes.TextureTable.tables`:
        rows, texels), each emitter's texture id in column :data:`TEXTURE` of its row."""
        n = len(self.emitters)
        textured = self.textured
        choice = lanes.light_rows(self._cdf, torch.arange(n, device=self.device))
        intensity = self.intensities().detach().float().cpu()
        rows = torch.zeros(n, self.width, dtype=torch.float32)
        table = lanes.TextureTable()
        for i in range(n):
            own = [float(v) for v in self.member_row(i)]
            rows[i, 0] = float(self.choice[i])
            rows[i, 1:OWN] = intensity[i]
            rows[i, OWN : OWN + len(own)] = torch.tensor(own, dtype=torch.float32)
            if textured:
                t = self.textures[i]
                k = -1 if t is None else table.add(t, None)
                if k is None:
                    raise ParameterError(f"the textures of a scene's {self.type_name} lights hold more than {lanes.TextureTable.LIMIT} texels")
                rows[i, TEXTURE] = float(k)
        out = (choice, rows.reshape(-1).to(self.device))
        return out + table.tables(self.device) if textured else out

    def lanes(self) -> LightLanes | None:
        """The type in lane form: :func:`delta_sample` on :attr:`lane_tables`, every sample a delta
        one. It applies to every render, one that holds sampling fixed included (the table holds
        the choice made from the sampling values and the intensities of the values); None for a
        subclass that answers ``sample_from`` by other means than the lane functions."""
        if type(self).sample_from is not DeltaLight.sample_from:
            return None
        return LightLanes(functools.partial(delta_sample, **self._static), self.lane_tables, delta=True)

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """:func:`delta_geometry` (compiled where Dr.Jit runs); ``Le = I_k factor`` (times the
        texture at the lanes' coordinates, :meth:`projected`) in torch."""
        k, o, wl, tmax, factor, pdf, facing, *uv = compiled.run(delta_geometry, x.device, *self.lane_tables[:2], u[:, 0].detach().float(), x.detach().float(), nx.detach().float(), float(offset), **self._static)
        Le = self.intensities().index_select(0, k.long()) * factor[:, None]
        if uv:
            Le = Le * self.projected(k.long(), torch.stack(uv, dim=1))
        return LightSample(o, wl, tmax, facing, pdf, Le, torch.ones_like(facing))

    def projected(self, k: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """(N, 3) the textures of emitters ``k`` (N,) at coordinates ``uv`` (N, 2) (1 for an
        emitter without one), differentiable in the textures."""
        out = uv.new_ones(uv.shape[0], 3)
        for i, t in enumerate(self.textures):
            at = (k == i).nonzero()[:, 0] if t is not None else None
            if at is not None and at.numel():
                out = out.index_put((at,), textures.lookup(t, uv.index_select(0, at)).to(out.dtype))
        return out


def delta_geometry(xp, choice, rows, u0, x, nx, offset: float, *, size: int, arrive: Callable, width: int = ROW, project: Callable | None = None):
    """The detached part of a delta light type's samples, written once against the array interface:
    the emitter picked by ``u0`` through the cdf of ``choice`` (``size`` emitters, masked halvings:
    :func:`invrender.core.lanes.pick_light`), the shadow ray from ``x`` (3-tuples) offset along its
    geometric normal ``nx``, by the type's ``arrive`` (rows of ``width`` floats). Returns (emitter
    index (UInt), origin, unit direction, tmax, factor (``Le = I factor``), pdf (the choice's
    probability), facing), then with ``project`` the texture coordinates u, v."""
    k, row, o, wl, tmax, factor, pdf, facing, uv = _delta(xp, choice, rows, u0, x, nx, offset, size, arrive, width, project)
    return (k, o, wl, tmax, factor, pdf, facing) + (uv if project is not None else ())


def delta_sample(xp, t, u0, u1, u2, x, nx, offset: float, *, size: int, arrive: Callable, width: int = ROW, project: Callable | None = None):
    """:attr:`LightLanes.sample <invrender.core.lights.LightLanes>` of a delta light type: ``t`` its
    :attr:`~DeltaLight.lane_tables`; ``u1``, ``u2`` unused. Returns (origin, wl, tmax, Le, pdf, facing)."""
    k, row, o, wl, tmax, factor, pdf, facing, uv = _delta(xp, t[0], t[1], u0, x, nx, offset, size, arrive, width, project)
    Le = lanes.scale(row[1:OWN], factor)
    if project is not None:  # times the texture (1 for an emitter without one: id -1)
        one = 0.0 * factor + 1.0
        T = lanes.texture_lookup(xp, t[2], t[3], uv)(row[TEXTURE], (one, one, one))
        Le = (Le[0] * T[0], Le[1] * T[1], Le[2] * T[2])
    return o, wl, tmax, Le, pdf, facing


def _delta(xp, choice, rows, u0, x, nx, offset, size, arrive, width, project):
    k = lanes.pick_light(xp, choice, size, u0)
    if width == ROW:
        row = xp.gather_rows(rows, k, ROW)
    else:  # rows of several packets of ROW floats
        row = sum((xp.gather_rows(rows, k * (width // ROW) + j, ROW) for j in range(width // ROW)), ())
    o = lanes.add(x, lanes.scale(nx, offset))
    wl, tmax, factor, facing = arrive(xp, row, o, nx, offset)
    pdf = row[0]
    uv = None
    if project is not None:  # where nothing arrives the coordinates may be infinite: the image's centre there
        lit = factor > 0.0
        centre = 0.0 * factor + 0.5
        uv = tuple(xp.select(lit, xp.minimum(xp.maximum(c, -1e6), 1e6), centre) for c in project(xp, row, wl))
    return k, row, o, wl, tmax, factor, pdf, facing & (pdf > 0.0), uv


def towards_point(xp, p, o, nx, offset: float):
    """``(wl, r, tmax, facing)`` from shadow-ray origins ``o`` to points ``p`` (3-tuples): the unit
    direction, the distance, where the shadow ray stops (the distance minus the offset) and
    whether the point lies in front of x's geometric normal."""
    d = lanes.sub(p, o)
    r = xp.maximum(xp.sqrt(lanes.dot(d, d)), 1e-12)
    wl = (d[0] / r, d[1] / r, d[2] / r)
    return wl, r, xp.maximum(r - offset, 0.0), lanes.dot(nx, wl) > 0.0


def frame(direction, up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The light's frame ``(x, y, z)`` (unit (3,) float64 each) from its axis ``direction`` and its
    ``up`` (made orthogonal to the axis): ``x = up x z`` as Mitsuba's lookat makes it (the image's
    left, seen from the light), ``y = z x x``."""
    z = np.asarray(direction, dtype=np.float64)
    z = z / np.linalg.norm(z)
    x = np.cross(np.asarray(up, dtype=np.float64), z)
    x = x / np.linalg.norm(x)
    return x, np.cross(z, x), z


def up_of(where: str, direction, up, required: bool) -> tuple:
    """``up`` made orthogonal to the unit ``direction`` and normalized; a one-line error naming
    ``where`` when it is parallel to it and the light reads it (``required``: a texture), else
    (it is read by nothing) an orthogonal completion."""
    d = np.asarray(direction, dtype=np.float64)
    a = np.asarray(up, dtype=np.float64)
    a = a - float(a @ d) * d
    n = float(np.linalg.norm(a))
    if not n > 1e-6:
        if required:
            raise SceneError(f"{where}: 'up' {tuple(float(v) for v in up)} must not be parallel to 'direction' {tuple(round(float(v), 6) for v in d)} (it orients the projected image)")
        helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        a = helper - float(helper @ d) * d
        n = float(np.linalg.norm(a))
    return tuple(float(v) for v in a / n)


def frame_of(reader, mirror: bool = True, where_key: str = "to_world") -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``(translation (3,), unit local +z (3,), unit local +y (3,), scale)`` in the world of the
    reader's ``to_world``; an error unless its linear part is a rotation times a uniform scale
    (lookat, rotate, translate, scale by one number): only then is a direction's angle to the axis
    the one Mitsuba measures in the local frame. Without ``mirror``, also an error for a
    reflection (a negative determinant), which would flip a projected image."""
    m = reader.transform(where_key)
    a = m[:3, :3]
    gram = a.T @ a
    s2 = float(np.trace(gram)) / 3.0
    if not s2 > 0 or not np.allclose(gram, s2 * np.eye(3), rtol=1e-5, atol=1e-8 * max(s2, 1.0)):
        raise reader.error(where_key, f"'{where_key}' of a {reader.type} emitter must be a rotation, translation and uniform scale (lookat, rotate, translate), not a shear or non-uniform scale")
    if not mirror and np.linalg.det(a) < 0:
        raise reader.error(where_key, f"'{where_key}' of a {reader.type} emitter with an image must not mirror (negative determinant): it would flip the image")
    z, y = a[:, 2], a[:, 1]
    return m[:3, 3].copy(), z / np.linalg.norm(z), y / np.linalg.norm(y), math.sqrt(s2)


def frame_matrix(position, direction, up) -> np.ndarray:
    """A (4, 4) ``to_world`` placing the local origin at ``position``, local +z along
    ``direction`` and +y along ``up`` (:func:`frame`; Mitsuba's lookat)."""
    x, y, z = frame(direction, up)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, np.asarray(position, dtype=np.float64)
    return m


def projected_texture(reader, name: str, colour: bool = False) -> np.ndarray:
    """The image (h, w, 3) of a light's ``<texture type="bitmap">`` property ``name`` (with
    ``colour``, an RGB (3,) is also taken; 1 when absent); a one-line error for a colour otherwise
    (Mitsuba asks for a spatially varying texture) and for bitmap options other than Mitsuba's
    defaults (bilinear, repeat wrapping, no ``to_uv``)."""
    from invrender.scene.kinds import EMISSION
    from invrender.scene.textures import SampledTexture

    t = reader.colour(name, EMISSION, 1.0)
    if isinstance(t, SampledTexture):
        raise reader.error(name, f"a {reader.type} light's '{name}' reads bilinearly with repeat wrapping (Mitsuba's defaults): filter_type, wrap_mode and to_uv are not supported")
    if np.ndim(t) != 3 and not colour:
        raise reader.error(name, f"a {reader.type} light's '{name}' must be an image (a bitmap texture), got a colour")
    return np.asarray(t, dtype=np.float64)
