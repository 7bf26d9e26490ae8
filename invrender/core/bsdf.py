"""The BSDF interface (pbrt-v4's ``BSDF`` / ``BSDFSample``, batched): ``eval``, ``sample``, ``pdf``.

Conventions, shared by every material:

- Directions are world-space unit vectors. ``wo`` points back along the ray that arrived (towards
  the camera side of the path), ``wi`` towards where light comes from (the next vertex).
- ``eval`` returns ``f(wo, wi) |cos theta_i|`` (the cosine folded in, as Mitsuba does), ``pdf`` the
  solid-angle density with which ``sample`` would have produced ``wi``, and ``sample`` a direction
  with its *weight* ``f |cos theta_i| / pdf``. Random numbers are arguments: ``u_lobe`` (N,) picks a
  lobe (reflection or refraction), ``u_dir`` (N, 2) the direction within it.
- Delta lobes (a mirror, smooth glass) have no density: ``eval`` and ``pdf`` return 0 for them and
  ``sample`` flags them, and integrators never sample emitters towards them.
- Sampling never depends on a differentiable parameter: pdfs read constants (ior) or detached
  values (:meth:`BSDF.sampling_param`: a roughness), so the derivative of a weight is the
  derivative of its ``f`` alone (``f(alpha) cos / pdf(detached alpha)``). Weights are
  differentiable in the material's parameters; that is what path replay's vertex adjoint
  differentiates.
- ``n`` is the shading normal turned to ``wo``'s geometric side; ``front`` says whether that side
  is the triangle's front (for glass: outside). :attr:`ShadingPoint.frame` is the shading frame,
  built once per vertex and shared by every BSDF call there; BSDFs that are not rotationally
  trivial (microfacets, refraction) work in it, where ``cos(theta) = z``.
- A BSDF says what kinds of lobe it has with :class:`Lobe` flags (several per material: a plastic
  is a diffuse base under a delta or glossy coating). Integrators branch on these flags, never on a
  material's type, so a new material needs no integrator change.

A material is a plugin (:mod:`invrender.plugins.bsdfs`): one module holding a subclass of :class:`BSDF`
that declares its type name, parameters, constants, lobes and format aliases beside ``eval`` /
``pdf`` / ``sample``, registered in :data:`invrender.registry.MATERIALS`. Written as lane functions
(:class:`LaneForm`, subclassing :class:`LaneBSDF`), those three methods are derived from them and
the material is on the compiled bounce too: written once.
"""

from __future__ import annotations

import enum
import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from collections.abc import Callable
from typing import ClassVar

import torch
import torch.autograd.forward_ad as fwAD

from invrender.errors import ParameterError, did_you_mean
from invrender.scene.plugins import Declared
from invrender.backends.arrays import TORCH
from invrender.core import lanes
from invrender.core.frame import Frame
from invrender.core.textures import gather_rgb
from invrender.scene.textures import TextureSampling


class Lobe(enum.IntFlag):
    """Kinds of lobe a BSDF has (a bitset, as pbrt-v4's ``BxDFFlags``).

    ``DIFFUSE``, ``GLOSSY`` (reflection) and ``GLOSSY_TRANSMISSION`` lobes have a density:
    emitters can be sampled towards them and ``eval`` / ``pdf`` see them; a glossy transmission
    lobe gathers emitter samples from behind the surface too. ``DELTA_REFLECTION`` and
    ``DELTA_TRANSMISSION`` scatter into discrete directions only: ``eval`` and ``pdf`` are zero
    for them, ``sample`` flags them and :meth:`BSDF.specular_lobes` lists them.
    """

    DIFFUSE = 1
    GLOSSY = 2
    DELTA_REFLECTION = 4
    DELTA_TRANSMISSION = 8
    GLOSSY_TRANSMISSION = 16
    #: lobes with a density (next-event estimation and MIS apply)
    SMOOTH = DIFFUSE | GLOSSY | GLOSSY_TRANSMISSION
    #: lobes without one
    DELTA = DELTA_REFLECTION | DELTA_TRANSMISSION
    #: lobes that cross the surface
    TRANSMISSION = DELTA_TRANSMISSION | GLOSSY_TRANSMISSION
    ALL = SMOOTH | DELTA

    def describe(self) -> str:
        """The lobes in words (``"diffuse, delta reflection"``)."""
        single = (Lobe.DIFFUSE, Lobe.GLOSSY, Lobe.GLOSSY_TRANSMISSION, Lobe.DELTA_REFLECTION, Lobe.DELTA_TRANSMISSION)
        return ", ".join(f.name.lower().replace("_", " ") for f in single if f & self)

#: how diffuse lobes draw directions (:attr:`BSDFSampling.hemisphere`)
HEMISPHERES = ("cosine", "uniform")


@dataclass(frozen=True)
class BSDFSampling:
    """How BSDFs draw directions, never what they evaluate: ``eval`` is the same whatever the choice,
    and ``pdf`` always returns the density of the chosen ``sample`` (so MIS weights stay right).

    Attributes:
        hemisphere: diffuse lobes: ``"cosine"`` (pdf ``cos(theta)/pi``, weight rho; the default)
            or ``"uniform"`` over the hemisphere (pdf ``1/(2 pi)``, weight ``2 rho cos(theta)``).
    """

    hemisphere: str = "cosine"

    def __post_init__(self):
        if self.hemisphere not in HEMISPHERES:
            raise ParameterError(f"unknown hemisphere sampling {self.hemisphere!r}{did_you_mean(self.hemisphere, HEMISPHERES)} (known: {', '.join(HEMISPHERES)})")


@dataclass(frozen=True)
class ShadingPoint:
    """N surface points as a BSDF sees them.

    Attributes:
        wo: (N, 3) unit direction back along the arriving ray.
        n: (N, 3) unit shading normal on ``wo``'s geometric side.
        ng: (N, 3) unit geometric normal on ``wo``'s side.
        front: (N,) bool, True where ``wo`` lies on the triangle's front (outside) side.
        uv: (N, 2) texture coordinates.
        material: (N,) int64 index of each point's material among its BSDF's materials.
        slot: (N,) int64 which of the render's BSDF instances takes each point (for dispatch).
        cache: parameter values already looked up at these points (a vertex's ``eval`` for its
            emitter sample and its ``sample`` share one lookup); not carried by :meth:`select`.
        corners: (N, 3) int64 rows of the hit triangles' corners in per-vertex parameters, or
            None (the scene has none).
        bary: (N, 3) barycentric weights of those corners, or None.
        bend: where some material's normal is perturbed (a normal or bump map), what its value
            and pdf are masked and weighted by (:func:`invrender.core.lanes.bend_lanes`: the base
            normal (N, 3), the perturbed one (N, 3), alpha^2 (N,), perturbed (N,) bool); else None.
        sampling: the same points as sampling sees them, where their shading frame can differ
            from this one (differentiated normals: this frame carries a derivative, or a render
            holds sampling at other normals): detached, in the frame of the normals sampling is
            held at; None where sampling reads this frame.
    """

    wo: torch.Tensor
    n: torch.Tensor
    ng: torch.Tensor
    front: torch.Tensor
    uv: torch.Tensor
    material: torch.Tensor
    slot: torch.Tensor
    cache: dict = field(default_factory=dict, compare=False, repr=False)
    corners: torch.Tensor | None = None
    bary: torch.Tensor | None = None
    bend: tuple | None = None
    sampling: "ShadingPoint | None" = None

    def select(self, index: torch.Tensor) -> "ShadingPoint":
        """The points at ``index`` (M,) int64 (with their frames, where already built)."""
        vertex = {} if self.corners is None else {"corners": self.corners.index_select(0, index), "bary": self.bary.index_select(0, index)}
        if self.bend is not None:
            vertex["bend"] = tuple(v.index_select(0, index) for v in self.bend)
        if self.sampling is not None:
            vertex["sampling"] = self.sampling.select(index)
        out = ShadingPoint(*(getattr(self, f).index_select(0, index) for f in _POINT_FIELDS), **vertex)
        if "frame" in self.__dict__:
            out.__dict__["frame"] = Frame(*(v.index_select(0, index) for v in (self.frame.s, self.frame.t, self.frame.n)))
        return out

    @property
    def count(self) -> int:
        return int(self.wo.shape[0])

    @functools.cached_property
    def frame(self) -> Frame:
        """The shading frames (z = ``n``), built on first use and shared by every BSDF call at
        these points (given where a material needs the UV tangent frame or a perturbed normal:
        :meth:`invrender.core.context.TransportContext.shading_point`)."""
        return Frame.from_normal(self.n)

    @functools.cached_property
    def wo_local(self) -> torch.Tensor:
        """``wo`` in :attr:`frame` (N, 3)."""
        return self.frame.to_local(self.wo)


_POINT_FIELDS = ("wo", "n", "ng", "front", "uv", "material", "slot")


@dataclass(frozen=True)
class BSDFSample:
    """N sampled directions.

    Attributes:
        wi: (N, 3) unit direction towards the next vertex.
        weight: (N, 3) ``f |cos theta_i| / pdf`` (differentiable in the material's parameters);
            zero where no valid direction was drawn.
        pdf: (N,) solid-angle density (0 for a delta lobe).
        delta: (N,) bool, True where ``wi`` came from a delta lobe.
    """

    wi: torch.Tensor
    weight: torch.Tensor
    pdf: torch.Tensor
    delta: torch.Tensor


@dataclass(frozen=True)
class LaneForm:
    """A material type's BSDF written once against the array interface (:mod:`invrender.core.lanes`),
    lane by lane with masks: evaluated as eager torch it *is* the type's differentiable
    :meth:`~BSDF.eval`, :meth:`~BSDF.pdf` and :meth:`~BSDF.sample` (:class:`LaneBSDF`), compiled it is
    the material's part of the compiled bounce.

    Both functions work in the shading frame (:func:`invrender.core.lanes.frame`: z is the shading
    normal turned to ``wo``'s geometric side, as :attr:`ShadingPoint.frame`) on 3-tuples of (N,)
    Float lanes:

    - ``eval(xp, p, ps, wo, wi, front) -> (f_cos, pdf)``: ``f(wo, wi) |cos theta_i|`` (a 3-tuple)
      and the density (a Float) with which ``sample`` draws ``wi``; 0 for delta lobes;
    - ``sample(xp, p, ps, wo, front, u_lobe, u0, u1) -> (wi, weight, pdf, delta)``: one direction
      from uniforms ``u_lobe`` (the lobe) and ``u0, u1`` (the direction within it), its weight
      ``f |cos| / pdf`` (a 3-tuple; zero where no valid direction was drawn), its pdf and a Bool,
      True for a delta lobe.

    ``p`` and ``ps`` hold each lane's material values, ``p[key]`` a 3-tuple of Floats (size 3), a
    Float (size 1) or, for a table of more floats a material derives (:meth:`LaneBSDF.lane_rows`: a
    rough interface's transmittance), a :class:`~invrender.core.lanes.Row` the functions read at
    positions they compute (:func:`~invrender.core.lanes.row_at`), for every ``(key, size)`` of
    :attr:`keys`: ``p`` the values ``f`` and the weight
    are differentiated in, ``ps`` the detached ones sampling and pdfs read
    (:meth:`BSDF.sampling_param`; the same arrays in the compiled bounce). ``front`` (Bool) is True
    where ``wo`` lies on the triangle's front (outside) side. Python values the code depends on (a
    sampling choice, a distribution) are bound when :meth:`BSDF.lane_form` builds the form.

    Attributes:
        keys: ``((key, size), ...)`` the parameters, constants and derived values the functions
            read, in order (size 1 of an RGB parameter: its first channel).
        eval, sample: the two functions.
        world: ``sample`` also takes the shading frame, ``frame=(s, t, n)`` (world 3-vectors), for
            a construction tied to world axes (the diffuse lobe's tangent sphere).
        tangent: the functions depend on the direction of the frame's tangent (an anisotropic
            roughness): they run in the UV tangent frame, s from the mesh's dp/du as Mitsuba builds
            it (:mod:`invrender.core.shading`); else (the default) in any frame about the normal
            (:func:`invrender.core.lanes.frame`, whose bits isotropic renders keep).
    """

    keys: tuple[tuple[str, int], ...]
    eval: Callable
    sample: Callable
    world: bool = False
    tangent: bool = False


def grey_channel(v: torch.Tensor) -> torch.Tensor:
    """A grey parameter's value (N,) at points from its three equal channels ``v`` (N, 3): channel
    0's value exactly (a render is bit-identical to one with the value as a constant) with the
    gradient of the channels' mean (autograd and forward-mode tangents), so the three channels
    move together."""
    alpha = v[:, 0]
    if v.requires_grad or fwAD.unpack_dual(v).tangent is not None:
        m = v.mean(dim=1)
        alpha = alpha.detach() + (m - m.detach())
    return alpha


class BSDF(Declared, ABC):
    """Base class of the materials: one instance holds every material of one type in a scene.

    A subclass is the whole description of a material type: it declares the class attributes
    below and implements :meth:`eval`, :meth:`pdf` and :meth:`sample` (materials with delta lobes
    also :meth:`specular_lobes`); registered with ``@MATERIALS.register``
    (:data:`invrender.registry.MATERIALS`), it is known to the scene formats, the renderer, error
    messages and the docs.

    Attributes:
        values: per material of this type, parameter key -> tensor (3,) or (h, w, 3).
        constants: per material, constant key -> float.
        sampling: how :meth:`sample` draws directions (and so what :meth:`pdf` returns).
    """

    #: the kinds of lobe it has (several for layered materials)
    lobes: ClassVar[Lobe]

    def __init__(
        self, values: list[dict[str, torch.Tensor]], constants: list[dict[str, float]], flat: bool = False, sampling: BSDFSampling | None = None,
        sampling_values: list[dict[str, torch.Tensor]] | None = None, texture_sampling: list[dict[str, TextureSampling]] | None = None,
    ):  # fmt: skip
        self.values, self.constants = values, constants
        #: per material, parameter key -> how its texture is read (absent: the default)
        self.texture_sampling = texture_sampling or [{} for _ in values]
        #: per material, the (detached) values its sampling reads (:meth:`sampling_param`)
        self.sampling_values = sampling_values or [{k: v.detach() for k, v in m.items()} for m in values]
        self.sampling = sampling or BSDFSampling()
        #: no shading normals in the scene: ``n`` is the geometric normal, ``wo`` always above it
        self.flat = flat
        self._constant_tables: dict = {}  # (key, device) -> (M,) float32, built on first use

    @classmethod
    def has(cls, lobes: Lobe) -> bool:
        """Does this material have any of ``lobes``?"""
        return bool(cls.lobes & lobes)

    def param(self, key: str, sp: ShadingPoint) -> torch.Tensor:
        """Parameter ``key`` at each point (N, 3), differentiable (textures filtered at ``sp.uv``);
        looked up once per point set."""
        token = (id(self), key)
        if token not in sp.cache:
            sp.cache[token] = gather_rgb([v[key] for v in self.values], sp.material, sp.uv, [t.get(key) for t in self.texture_sampling], sp.corners, sp.bary)
        return sp.cache[token]

    def sampling_param(self, key: str, sp: ShadingPoint) -> torch.Tensor:
        """Parameter ``key`` at each point (N, 3) as sampling and ``pdf`` read it: detached, and
        the unperturbed value where a render holds sampling fixed (``sampling_params``)."""
        token = (id(self), key, "sampling")
        if token not in sp.cache:
            sp.cache[token] = gather_rgb([v[key] for v in self.sampling_values], sp.material, sp.uv, [t.get(key) for t in self.texture_sampling], sp.corners, sp.bary)
        return sp.cache[token]

    def constant(self, key: str, sp: ShadingPoint) -> torch.Tensor:
        """Constant ``key`` at each point (N,)."""
        token = (key, sp.wo.device)
        if token not in self._constant_tables:
            self._constant_tables[token] = torch.tensor([c[key] for c in self.constants], dtype=torch.float32, device=sp.wo.device)
        return self._constant_tables[token].index_select(0, sp.material)

    @abstractmethod
    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """``f(wo, wi) |cos theta_i|`` (N, 3) for directions ``wi`` (N, 3); 0 for delta lobes."""

    @abstractmethod
    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        """Solid-angle density (N,) of :meth:`sample` producing ``wi``; 0 for delta lobes."""

    @abstractmethod
    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        """One direction per point from uniforms ``u_lobe`` (N,) (which lobe, for materials with
        several) and ``u_dir`` (N, 2) (the direction within it); the weight is ``f |cos| / pdf``
        of the whole BSDF's sampling density (for a delta lobe: its weight over its choice
        probability)."""

    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Every delta lobe as ``(wi (N, 3), weight (N, 3))``, weights not divided by any choice
        probability (Whitted's split: a dielectric's reflection F and refraction 1 - F); none for
        materials without delta lobes."""
        return []

    def lane_form(self) -> LaneForm | None:
        """This type's BSDF in lane form (:class:`LaneForm`), which puts its scenes on the compiled
        bounce; None (the default): the torch bounce evaluates it by its methods."""
        return None

    def fused_albedo(self) -> torch.Tensor | None:
        """(M, 3) the reflectance of each of this type's materials when every one is Lambertian
        with an RGB constant (``rho / pi``, sampled by the cosine), for the fused primal bounce
        (:mod:`invrender.core.fused`), which then evaluates and samples them itself; None (the
        default) = the BSDF is evaluated by its own methods."""
        return None

    def diffuse_reflectance(self, sp: ShadingPoint) -> torch.Tensor | None:
        """The Lambertian albedo k_d (N, 3) the ambient term ``k_d eps0`` reflects; None = no
        diffuse part."""
        return None

    @classmethod
    def not_polynomial(cls, key: str, constants: dict) -> str | None:
        """Why parameter ``key`` of a material with ``constants`` is not one factor of each of its
        sample weights and ``eval`` values (path records need one monomial per contribution), or
        None when it is (every reflectance-like factor of the single-lobe materials)."""
        return None


class DeltaBSDF(BSDF):
    """A BSDF with delta lobes only (mirror, smooth glass): no density to evaluate or sample
    towards, so ``eval`` and ``pdf`` are zero and integrators follow :meth:`specular_lobes`."""

    lobes = Lobe.DELTA_REFLECTION

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        return sp.wo.new_zeros(sp.count, 3)

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        return sp.wo.new_zeros(sp.count)

    @abstractmethod
    def specular_lobes(self, sp: ShadingPoint) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Every delta lobe as ``(wi (N, 3), weight (N, 3))``."""

    def delta_sample(self, wi: torch.Tensor, weight: torch.Tensor) -> BSDFSample:
        """A sample of a delta lobe: no density, flagged delta."""
        n = wi.shape[0]
        return BSDFSample(wi, weight, wi.new_zeros(n), torch.ones(n, dtype=torch.bool, device=wi.device))


class LaneBSDF(BSDF):
    """A BSDF written once, as its :class:`LaneForm`: :meth:`eval`, :meth:`pdf` and :meth:`sample`
    are that form evaluated as eager torch (differentiable in the material's parameters, textures
    included), and the compiled bounce runs the same functions. A subclass implements
    :meth:`lane_form` (and, for delta lobes, :meth:`specular_lobes`)."""

    @abstractmethod
    def lane_form(self) -> LaneForm:
        """The type's lane functions (:class:`LaneForm`)."""

    def lane_values(self, sp: ShadingPoint, sampling: bool) -> dict:
        """``p`` (or, with ``sampling``, ``ps``) of :class:`LaneForm` at the points ``sp``: each
        key's (N,) columns, differentiable in the parameters (detached for sampling); a grey
        parameter (a roughness) read as one number by :func:`grey_channel`; a key of more than 3
        floats (:meth:`lane_rows`) as a :class:`~invrender.core.lanes.Row`."""
        out = {}
        for key, size in self.lane_form().keys:
            if key in self.params:
                value = (self.sampling_param if sampling else self.param)(key, sp)
                if size == 1 and self.params[key].kind.grey:
                    out[key] = grey_channel(value)
                    continue
            elif (rows := self.lane_rows(key, sampling, sp.wo.device)) is not None:
                if size > 3:
                    out[key] = lanes.Row(rows.reshape(-1), sp.material * size)
                    continue
                value = rows.index_select(0, sp.material)
            else:
                value = self.constant_rgb(key, sp)
            out[key] = value[:, 0] if size == 1 else tuple(value.unbind(1))
        return out

    def _both_values(self, sp: ShadingPoint) -> tuple[dict, dict]:
        """``(p, ps)``: one dict for both (a form may then skip its second evaluation: ``p is ps``)
        where nothing is differentiated and sampling reads the values themselves."""
        ps = self.lane_values(sp, True)
        for values, frozen in zip(self.values, self.sampling_values):
            for key, v in values.items():
                vs = frozen[key]
                if v.requires_grad or fwAD.unpack_dual(v).tangent is not None or (v.data_ptr() != vs.data_ptr() and not torch.equal(v, vs)):
                    return self.lane_values(sp, False), ps
        return ps, ps

    def lane_rows(self, key: str, sampling: bool, device) -> torch.Tensor | None:
        """(M, size) the values of :class:`LaneForm` key ``key`` for this BSDF's M materials where
        the material derives them from its constants and values (a relative index, a table of a
        rough interface): differentiable in the values, or, with ``sampling``, of the values
        sampling reads, detached; None (the default) for a parameter or a constant."""
        return None

    def constant_rgb(self, key: str, sp: ShadingPoint) -> torch.Tensor:
        """Constant ``key`` at each point (N, 3): an RGB constant, or a number repeated."""
        token = (key, "rgb", sp.wo.device)
        if token not in self._constant_tables:
            values = [c.get(key, type(self).constants[key].default) for c in self.constants]
            rows = [v if isinstance(v, (tuple, list)) else (v,) * 3 for v in values]
            self._constant_tables[token] = torch.tensor(rows, dtype=torch.float32, device=sp.wo.device).reshape(-1, 3)
        return self._constant_tables[token].index_select(0, sp.material)

    def _local(self, sp: ShadingPoint, wi: torch.Tensor | None = None):
        wo = tuple(sp.wo_local.unbind(1))
        return wo if wi is None else (wo, tuple(sp.frame.to_local(wi).unbind(1)))

    def eval(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        if not self.has(Lobe.SMOOTH):  # delta lobes only: no density (the form's eval is 0), nothing to compute
            return sp.wo.new_zeros(sp.count, 3)
        wo, wl = self._local(sp, wi)
        f, _ = self.lane_form().eval(TORCH, *self._both_values(sp), wo, wl, sp.front)
        return torch.stack(f, dim=1)

    def pdf(self, sp: ShadingPoint, wi: torch.Tensor) -> torch.Tensor:
        if not self.has(Lobe.SMOOTH):
            return sp.wo.new_zeros(sp.count)
        wo, wl = self._local(sp, wi)
        ps = self.lane_values(sp, True)
        _, pdf = self.lane_form().eval(TORCH, ps, ps, wo, wl, sp.front)
        return pdf

    def sample(self, sp: ShadingPoint, u_lobe: torch.Tensor, u_dir: torch.Tensor) -> BSDFSample:
        wo, form = self._local(sp), self.lane_form()
        world = {"frame": tuple(tuple(v.unbind(1)) for v in (sp.frame.s, sp.frame.t, sp.frame.n))} if form.world else {}
        wi, weight, pdf, delta = form.sample(TORCH, *self._both_values(sp), wo, sp.front, u_lobe, u_dir[:, 0], u_dir[:, 1], **world)
        return BSDFSample(sp.frame.to_world(torch.stack(wi, dim=1)), torch.stack(weight, dim=1), pdf, delta)

