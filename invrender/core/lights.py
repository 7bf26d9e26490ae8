"""The light interface and the dispatch of emitter queries to the scene's emitters.

An emitter type is a plugin (:mod:`invrender.plugins.emitters`): a subclass of :class:`Light` that declares
its type name, parameters and constants, and answers the queries of the integrators:

- from a shading point, sample a direction towards it (next-event estimation): the shadow ray, the
  solid-angle pdf and the radiance arriving (:meth:`Light.sample_from`);
- for a ray that hit a surface it emits from (:attr:`Light.surface` types, e.g. ``area``): the
  radiance leaving back along the ray and the pdf with which :meth:`Light.sample_from` would have
  chosen that point (for multiple importance sampling);
- for a ray that leaves the scene (:attr:`Light.infinite` types, e.g. a sky): the radiance
  arriving along it and the pdf of having sampled its direction.

Delta emitters (a point light, a directional light) are neither: they are sampled and never hit,
their samples flagged ``delta`` (:class:`LightSample`).

Sampling is detached (docs/architecture.md#detached-sampling-differentiable-evaluation): whatever a
light picks by (power, luminance) is read without gradient when the render starts; only the
radiance it returns is differentiable in its parameters. One instance holds every emitter of its
type in a scene; :class:`Lights` picks among the instances by their detached power and sends hits to
the instance their emitter belongs to.
"""

from __future__ import annotations

from collections.abc import Callable

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import torch

from invrender.errors import ParameterError
from invrender.registry import EMITTERS
from invrender.scene.plugins import Declared
from invrender.scene.scene import Triangles
from invrender.core.surface import Surface


@dataclass(frozen=True)
class LightSample:
    """N emitter samples as seen from N surface points x: the shadow rays towards them.

    Attributes:
        o: (N, 3) shadow-ray origins, x offset off its surface along its geometric normal.
        wl: (N, 3) unit directions from ``o`` towards the sampled emitter points or directions.
        tmax: (N,) where the shadow ray stops: the distance to the point minus the offset
            (``inf`` for emitters infinitely far away).
        facing: (N,) bool: the sample lies in front of x's geometric normal and x on the emitting
            side of the emitter; only then can it light x.
        pdf: (N,) solid-angle density at ``o`` of having sampled ``wl`` (including the choice of
            the emitter).
        Le: (N, 3) radiance arriving at x along ``-wl`` from the sample if unoccluded
            (differentiable in the emitter's parameters); for a delta emitter (a point or a
            direction) the irradiance-like quantity whose ratio to ``pdf`` is the estimate.
        delta: (N,) bool where the sample came from a delta emitter (a point light, a
            directional light): ``pdf`` is then the discrete probability of the choice, no BSDF
            sample can hit the emitter, and multiple importance sampling gives it weight 1; None
            when no sample did.
    """

    o: torch.Tensor
    wl: torch.Tensor
    tmax: torch.Tensor
    facing: torch.Tensor
    pdf: torch.Tensor
    Le: torch.Tensor
    delta: torch.Tensor | None = None

    def scaled_pdf(self, p: float) -> "LightSample":
        """The same samples with their pdf multiplied by ``p`` (the probability of having chosen
        this emitter type)."""
        return dataclasses.replace(self, pdf=self.pdf * p)


@dataclass(frozen=True)
class LightLanes:
    """An emitter type written once against the array interface (:mod:`invrender.core.lanes`): the
    form in which the compiled bounce samples it and reads its radiance, lane by lane with masks.
    Its torch methods evaluate the same functions for what they detach (directions, pdfs, shadow
    rays; ``compiled.run``), so the sampling maths is written once.

    The functions take the namespace ``xp``, then ``t``: :attr:`tables` as arrays, then per lane
    3-tuples of Floats (points, normals, directions) and Floats (uniforms):

    - ``sample(xp, t, u0, u1, u2, x, nx, offset) -> (origin, wl, tmax, Le, pdf, facing)``: what
      :meth:`Light.sample_from` returns from uniforms ``(u0, u1, u2)`` at points ``x`` with
      geometric normals ``nx`` (detached: ``Le`` a 3-tuple of the radiance arriving, or for delta
      emitters the quantity whose ratio to ``pdf`` is the estimate; ``pdf`` this type's own, the
      choice among types is the caller's; ``tmax`` ``inf`` for emitters infinitely far away);
      surface types return a seventh, the scene emitter sampled (UInt);
    - ``escaped(xp, t, d) -> (Le, pdf)`` (types with :attr:`Light.infinite`; else None): what
      :meth:`Light.escaped` and :meth:`Light.pdf_escaped` return for rays of directions ``d``
      leaving the scene;
    - ``hit(xp, t, tri, front, dist, cos) -> (Le, pdf, seen, emitter)`` (types with
      :attr:`Light.surface`; else None): the radiance leaving hits back along their rays, the
      density with which ``sample`` from the ray's origin would have picked them, a Bool where the
      hit is on an emitting side, and the scene emitter hit (UInt); ``tri`` the hit triangles' rows (:class:`invrender.core.lanes.Triangle`),
      ``dist`` the ray's length, ``cos`` the cosine at the hit (> 0).

    Attributes:
        sample, escaped, hit: the functions.
        tables: the flat float32 tensors they read (detached values, on the render's device).
        delta: every sample is a delta one (a point, a direction): MIS gives it weight 1.
    """

    sample: Callable
    tables: tuple
    escaped: Callable | None = None
    hit: Callable | None = None
    delta: bool = False


class Light(Declared, ABC):
    """Base class of the emitter types: one instance holds every emitter of one type in a scene.

    A subclass is the whole description of an emitter type: it declares ``type_name``, ``params``
    (at least the ones its radiance reads), ``constants``, ``doc`` and :attr:`surface`, implements
    the queries below, and is registered with ``@EMITTERS.register``
    (:data:`invrender.registry.EMITTERS`).

    Args:
        emitters: (E,) the scene emitter indices this instance holds (``triangles.emitter`` values).
        values: per emitter, parameter key -> tensor (differentiable).
        constants: per emitter, constant key -> float.
        triangles: the scene geometry on the render device.
        sampling: per emitter, the (detached) values its sampling decisions are built from: the
            choice by power, an environment map's density (:attr:`sampling`). None = ``values``.
            Finite differences with common random numbers give both renders the unperturbed values,
            so that both draw the same paths (``render(..., sampling_params=...)``).
    """

    #: does it emit from scene surfaces (the shapes naming it)?
    surface: ClassVar[bool] = True
    #: do rays that leave the scene see it (emitters infinitely far away: skies, environment maps)?
    infinite: ClassVar[bool] = False

    def __init__(self, emitters: list[int], values: list[dict[str, torch.Tensor]], constants: list[dict[str, float]], triangles: Triangles, sampling: list[dict[str, torch.Tensor]] | None = None):
        self.emitters, self.values, self.constants, self.triangles = emitters, values, constants, triangles
        #: per emitter, parameter key -> detached tensor: what sampling (never evaluation) reads
        self.sampling = [{k: v.detach() for k, v in d.items()} for d in (values if sampling is None else sampling)]

    @property
    @abstractmethod
    def power(self) -> float:
        """A detached measure of the power it sends into the scene (W, up to a common factor),
        by which :class:`Lights` chooses among emitter types; 0 = never sampled."""

    @abstractmethod
    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """Samples from uniforms ``u`` (N, 3) as seen from points ``x`` (N, 3) with geometric
        normals ``nx`` (N, 3); shadow rays start ``offset`` off x's surface."""

    def emits(self, s: Surface) -> torch.Tensor:
        """(N,) bool: is each hit on an emitting side (surface types only)?"""
        return torch.zeros(s.tri.shape[0], dtype=torch.bool, device=s.tri.device)

    def emitted(self, s: Surface) -> torch.Tensor:
        """Radiance (N, 3) leaving hits ``s`` back along their rays (surface types only)."""
        return s.p.new_zeros(s.p.shape[0], 3)

    def pdf_hit(self, s: Surface) -> torch.Tensor:
        """Solid-angle density (N,) with which :meth:`sample_from`, from the ray's origin, would
        have sampled the hit points ``s`` (surface types only)."""
        return s.t.new_zeros(s.t.shape[0])

    def escaped(self, d: torch.Tensor) -> torch.Tensor:
        """Radiance (N, 3) arriving along rays with directions ``d`` (N, 3) that leave the scene
        (types that emit from infinitely far only)."""
        return d.new_zeros(d.shape[0], 3)

    def pdf_escaped(self, d: torch.Tensor) -> torch.Tensor:
        """Solid-angle density (N,) with which :meth:`sample_from` would have sampled directions
        ``d`` (N, 3) (types that emit from infinitely far only)."""
        return d.new_zeros(d.shape[0])

    def lanes(self) -> LightLanes | None:
        """This type in lane form (:class:`LightLanes`), which puts its scenes on the compiled
        bounce; None (the default, or where a render's emitters of this type cannot be: a
        texture, a sampling held fixed): the torch bounce answers by its methods."""
        return None

    #: does :meth:`texels` answer (a textured emission read through a linear filter by direction)?
    texel_lookup: ClassVar[bool] = False

    def texels(self, k: int, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """For types with :attr:`texel_lookup`: which texels of emitter ``k``'s (of this instance)
        textured emission the radiance along world directions ``d`` (N, 3) reads, as (indices
        (N, J) into its flattened texels, filter weights (N, J)); the radiance must be a constant
        times ``sum_j weight_j texel_j``. Path records use it to keep such a map per texel."""
        raise ParameterError(f"emitter type {self.type_name!r} reads no texture by direction: path records cannot keep its emission per texel")


class Lights:
    """The scene's emitters on one device, and the dispatch of queries to them.

    Args:
        types: per scene emitter, its type name.
        values: per scene emitter, parameter key -> tensor (differentiable).
        constants: per scene emitter, constant key -> float.
        triangles: the scene geometry on the render device.
        sampling: per scene emitter, the values sampling is built from (:class:`Light`); None =
            ``values``.
    """

    def __init__(self, types: list[str], values: list[dict[str, torch.Tensor]], constants: list[dict[str, float]], triangles: Triangles, sampling: list[dict[str, torch.Tensor]] | None = None):
        device = triangles.p0.device
        self.triangles = triangles
        present = list(dict.fromkeys(types))  # first-seen order
        self.lights: list[Light] = []
        for t in present:
            members = [i for i, ti in enumerate(types) if ti == t]
            args = (members, [values[i] for i in members], [constants[i] for i in members], triangles)
            # only when asked: a plugin's own __init__ may not take ``sampling``
            self.lights.append(EMITTERS[t](*args) if sampling is None else EMITTERS[t](*args, sampling=[sampling[i] for i in members]))
        power = [max(light.power, 0.0) for light in self.lights]
        total = sum(power)
        #: per instance, the probability of being chosen for an emitter sample
        self.choice = [p / total if total > 0 else 0.0 for p in power]
        self.sampled = [light for light, p in zip(self.lights, self.choice) if p > 0]
        #: cumulative choice probabilities of ``sampled``
        cdf = torch.tensor([p for p in self.choice if p > 0], dtype=torch.float64).cumsum(0).float()
        self._cdf = cdf.to(device)
        self._cdf_host = cdf.tolist()  # the same float32 values, read without a device round trip
        self.surfaces = [light for light in self.lights if light.surface]
        self.infinite = [light for light in self.lights if light.infinite]
        #: (E + 1,) int64, which of ``surfaces`` each scene emitter belongs to (last: no emitter)
        slot = [-1] * (len(types) + 1)
        for k, light in enumerate(self.surfaces):
            for e in light.emitters:
                slot[e] = k
        self._surface_slot = torch.tensor(slot, dtype=torch.int64, device=device)

    @property
    def count(self) -> int:
        """How many emitter types can be sampled (0: next-event estimation finds nothing)."""
        return len(self.sampled)

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """One emitter sample per point ``x`` (N, 3) with geometric normal ``nx`` (N, 3), from
        uniforms ``u`` (N, 3): ``u[:, 0]`` chooses the emitter type by power (and is stretched back
        to [0, 1) for the type's own choice), the rest is the type's."""
        if len(self.sampled) == 1:
            return self.sampled[0].sample_from(u, x, nx, offset)  # one type: its own pdf, u as is
        k = torch.searchsorted(self._cdf, u[:, 0].contiguous(), right=True).clamp_max(len(self.sampled) - 1)
        out = None
        for i, light in enumerate(self.sampled):
            index = (k == i).nonzero()[:, 0]
            if not index.numel():
                continue
            lo = self._cdf_host[i - 1] if i else 0.0
            p = self._cdf_host[i] - lo
            ui = u.index_select(0, index).clone()
            ui[:, 0] = ((ui[:, 0] - lo) / p).clamp(0.0, 1.0 - 2**-24)
            part = light.sample_from(ui, x.index_select(0, index), nx.index_select(0, index), offset).scaled_pdf(p)
            if part.delta is None:
                part = dataclasses.replace(part, delta=torch.zeros_like(part.facing))
            if out is None:
                out = {f: getattr(part, f).new_zeros((x.shape[0], *getattr(part, f).shape[1:])) for f in part.__dataclass_fields__}
            out = {f: out[f].index_put((index,), getattr(part, f)) for f in out}
        return LightSample(**out)

    def probability(self, light: Light) -> float:
        """The probability that an emitter sample picks ``light``'s type."""
        return self.choice[self.lights.index(light)]

    def share(self, light: Light) -> tuple[float, float]:
        """``(lo, p)``: the interval ``[lo, lo + p)`` of the uniform that picks ``light``'s type in
        :meth:`sample_from` (``p`` 0: never sampled)."""
        if light not in self.sampled:
            return 0.0, 0.0
        k = self.sampled.index(light)
        lo = self._cdf_host[k - 1] if k else 0.0
        return lo, self._cdf_host[k] - lo

    def emits(self, s: Surface) -> torch.Tensor:
        """(N,) bool: is each hit on an emitting side of an emitter?"""
        if len(self.surfaces) == 1:
            return self.surfaces[0].emits(s)
        out = torch.zeros(s.tri.shape[0], dtype=torch.bool, device=s.tri.device)
        for light in self.surfaces:
            out = out | light.emits(s)
        return out

    def emitted(self, s: Surface) -> torch.Tensor:
        """Radiance (N, 3) leaving emitting hits ``s`` back along their rays."""
        return self._per_surface(s, lambda light, t: light.emitted(t))

    def pdf_hit(self, s: Surface) -> torch.Tensor:
        """Solid-angle density (N,) of next-event estimation having sampled the emitting hits ``s``."""
        return self._per_surface(s, lambda light, t: light.pdf_hit(t) * self.probability(light))

    def _per_surface(self, s: Surface, call):
        if len(self.surfaces) == 1:
            return call(self.surfaces[0], s)
        e = self.triangles.emitter.index_select(0, s.tri)
        slot = self._surface_slot.index_select(0, torch.where(e >= 0, e, len(self._surface_slot) - 1))
        out = None
        for k, light in enumerate(self.surfaces):
            index = (slot == k).nonzero()[:, 0]
            part = call(light, s.select(index))
            if out is None:
                out = part.new_zeros((s.tri.shape[0], *part.shape[1:]))
            out = out.index_put((index,), part)
        return out

    def escaped(self, d: torch.Tensor) -> torch.Tensor:
        """Radiance (N, 3) arriving along rays ``d`` (N, 3) that leave the scene (summed over the
        emitters infinitely far away)."""
        out = self.infinite[0].escaped(d)
        for light in self.infinite[1:]:
            out = out + light.escaped(d)
        return out

    def pdf_escaped(self, d: torch.Tensor) -> torch.Tensor:
        """Solid-angle density (N,) of next-event estimation having sampled directions ``d``."""
        out = self.infinite[0].pdf_escaped(d) * self.probability(self.infinite[0])
        for light in self.infinite[1:]:
            out = out + light.pdf_escaped(d) * self.probability(light)
        return out
