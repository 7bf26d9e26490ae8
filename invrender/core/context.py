"""The per-render context the integrators read, and the loop state of a chunk of paths."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from invrender.scene.kinds import param_name
from invrender.scene.scene import AMBIENT, Scene, Triangles, scene_extent
from invrender.backends import kernels
from invrender.backends.accel import intersector_for
from invrender.core import compiled, lanes, shading
from invrender.core.frame import Frame
from invrender.core.bsdfs import BSDFSampling, Materials, ShadingPoint
from invrender.core.lights import Lights
from invrender.core.surface import Surface, VertexNormals, carries_derivative
from invrender.backends.arrays import TORCH
from invrender.core.textures import gather_rgb
from invrender.vec import where_true
from invrender.vec import dot


@dataclass(frozen=True)
class TransportContext:
    """Everything an integrator reads while tracing one render.

    Attributes:
        triangles: scene geometry on the render device.
        accel: the intersection backend.
        lights: the scene's emitters (:class:`~invrender.core.lights.Lights`; differentiable
            in their parameters); ``lights.count`` is 0 when nothing can be sampled.
        materials: the scene's BSDFs (differentiable in their parameters), indexed by
            ``triangles.material``.
        eps: per scene emitter, its ``emission`` parameter (differentiable; zero for emitter types
            without one), indexed by ``triangles.emitter``.
        ambient: (3,) the ambient radiance eps0 of the Utah, Whitted and distributed models
            (differentiable), or None.
        ray_offset: distance new rays start off a surface, to avoid self-intersection.
        textured: does any parameter vary over UVs (else hits skip texture coordinates)?
        per_vertex: is any material parameter per vertex (shading points then carry the hit
            triangles' corner rows and barycentric weights)?
        extra: what an integrator's pre-pass computed for its ``trace`` (None without one).
        hide_emitters: camera rays see no emission (the integrator's ``hide_emitters``).
        normals: the vertex normals hits shade with (:class:`~invrender.core.surface.VertexNormals`:
            differentiable in the ``"<material>.normals"`` parameters); None = the triangles' own.
    """

    triangles: Triangles
    accel: object
    lights: Lights
    materials: Materials
    eps: list[torch.Tensor]
    ambient: torch.Tensor | None
    ray_offset: float
    textured: bool
    per_vertex: bool = False
    extra: object = None
    hide_emitters: bool = False
    normals: VertexNormals | None = None

    @staticmethod
    def build(
        scene: Scene, device: torch.device, backend: str | None = None, embree_threads: int | None = None, params: dict | None = None, sampling: BSDFSampling | None = None,
        sampling_params: dict | None = None,
    ) -> "TransportContext":  # fmt: skip
        """The context for rendering ``scene`` on ``device`` (parameters moved differentiably).

        ``backend``: intersection backend name (None = the device's default); its acceleration
        structure is built once per geometry and reused.
        ``embree_threads``: threads each Embree query is split across (None = one per core).
        ``params``: values to use instead of ``scene.params`` (same names; all or some).
        ``sampling``: how the BSDFs draw directions (None = cosine-weighted diffuse lobes).
        ``sampling_params``: values (same names; all or some) the emitters' and BSDFs' sampling is
            built from instead of the render's own (:class:`~invrender.core.lights.Light`); None = none.
        """
        tris = scene.triangles.to(device)
        kernels.fused_bounce(device)  # a bad INVRENDER_KERNELS is said here, before any work
        values = {**scene.params, **(params or {})}
        specs = [scene.material_spec(i) for i in range(len(scene.materials))]
        material_values = [{key: values[param_name(m, key)].to(device) for key in spec.spec.params} for m, spec in zip(scene.materials, specs)]
        emitters = [scene.emitter_spec(i) for i in range(len(scene.emitters))]
        light_values = [{key: values[param_name(e, key)].to(device) for key in spec.spec.params} for e, spec in zip(scene.emitters, emitters)]
        eps = [v.get("emission", torch.zeros(3, device=device)) for v in light_values]
        frozen = frozen_materials = sampled_from = None
        if sampling_params:
            sampled_from = {**values, **sampling_params}
            frozen = [{key: sampled_from[param_name(e, key)].detach().to(device) for key in spec.spec.params} for e, spec in zip(scene.emitters, emitters)]
            frozen_materials = [{key: sampled_from[param_name(m, key)].detach().to(device) for key in spec.spec.params} for m, spec in zip(scene.materials, specs)]
        return TransportContext(
            triangles=tris,
            accel=intersector_for(tris, backend, embree_threads),
            lights=Lights([e.type for e in emitters], light_values, [dict(e.constants) for e in emitters], tris, frozen),
            materials=Materials(
                [s.type for s in specs], material_values, [dict(s.constants) for s in specs], device, flat=not tris.any_smooth, sampling=sampling, sampling_values=frozen_materials,
                one_sided=[s.one_sided for s in specs], perturbations=[_perturbation(s, m, values, device) for m, s in zip(scene.materials, specs)],
                sampling_perturbations=_held_perturbations(scene, specs, values, sampled_from, device),
                texture_sampling=[{key: scene.texture_sampling[param_name(m, key)] for key in spec.spec.params if param_name(m, key) in scene.texture_sampling} for m, spec in zip(scene.materials, specs)],
            ),
            eps=eps,
            ambient=values[AMBIENT].to(device) if AMBIENT in values else None,
            ray_offset=1e-4 * max(scene_extent(tris), 1e-3),
            textured=any(p.ndim == 3 for p in [v for m in light_values + material_values for v in m.values()]),
            per_vertex=any(p.ndim == 2 for m in material_values for p in m.values()),
            normals=_vertex_normals(scene, tris, values, sampled_from, device),
        )

    def material(self, s: Surface) -> torch.Tensor:
        """(N,) int64 scene material of each hit."""
        return self.triangles.material.index_select(0, s.tri)

    @property
    def shading(self) -> tuple:
        """The shading frames' tables (:func:`invrender.core.shading.tables`): ``(frames,
        perturb)``, None each where no material needs the UV frame or has a perturbed normal."""
        return shading.tables(self)

    def shading_point(self, s: Surface, wo: torch.Tensor) -> ShadingPoint:
        """The hits as their BSDFs see them, for outgoing directions ``wo`` (N, 3): in the UV
        tangent frame, or the perturbed one, where a material needs it (:mod:`invrender.core.shading`,
        the functions the compiled bounce runs)."""
        material = self.material(s)
        vertex = {"corners": self.triangles.vertex.index_select(0, s.tri), "bary": s.bary} if self.per_vertex else {}
        sp = self._point(s, wo, material, vertex, s.ns, *shading.tables(self))
        if self.normals_turn:  # differentiated normals: sampling reads the frame at the values it is held at, detached
            ns = s.ns.detach() if self.normals is None else self.normals.sampling_normal(s)
            with torch.no_grad():
                sampling = self._point(s, wo, material, vertex, ns, *shading.tables(self, sampling=True))
            sp.__dict__["sampling"] = sampling
        return sp

    @property
    def normals_turn(self) -> bool:
        """Can a hit's shading frame differ from the one sampling reads: the frame carries a
        derivative (a differentiated ``"<material>.normals"`` or ``"<material>.normalmap"``), or
        sampling is held at other normals (``sampling_params``)? (Then the torch bounce runs,
        sampling in the detached frame: :attr:`ShadingPoint.sampling`.)"""
        n, materials = self.normals, self.materials
        if n is not None and (n.carries_derivative or n.sampling is not None):
            return True
        if getattr(materials, "sampling_perturbations", None) is not None:
            return True
        return any(p is not None and carries_derivative(p.texture) for p in getattr(materials, "perturbations", None) or [])

    def _point(self, s: Surface, wo, material, vertex: dict, ns, frames, perturb) -> ShadingPoint:
        """The :class:`ShadingPoint` of hits ``s`` of shading normal ``ns`` with the shading tables
        ``frames``, ``perturb`` (:func:`invrender.core.shading.tables`); eager torch where a
        normal carries a derivative, else compiled."""
        if frames is None:
            return self.materials.shading_point(material, wo, ns, s.n, s.front, s.uv, **vertex)
        args = (frames, perturb, ns, s.n, s.front, s.tri, s.bary[:, 1].contiguous(), s.bary[:, 2].contiguous(), wo, material.to(torch.int32))
        if carries_derivative(ns) or (perturb is not None and carries_derivative(perturb[1])):  # differentiable normals: eager torch
            out = compiled.evaluate(TORCH, shading.shading_point_lanes, *args)
        else:
            out = compiled.run(shading.shading_point_lanes, wo.device, *args)
        frame = Frame(*out[:3])
        bend = None if perturb is None else tuple(out[4:])
        return self.materials.shading_point(material, wo, frame.n, s.n, out[3], s.uv, frame=frame, bend=bend, **vertex)

    def emission(self, emitter: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """Surface emission eps (N, 3) of scene emitters ``emitter`` (N,) int64 (-1 = none) at
        ``uv`` (N, 2) (for methods that read emission off the triangles, e.g. radiosity's patches)."""
        return gather_rgb(self.eps, emitter, uv)

    def spawn(self, s: Surface, wi: torch.Tensor) -> torch.Tensor:
        """Origins (N, 3) of new rays leaving ``s`` in directions ``wi``, offset off the surface on
        the geometric side ``wi`` points to (so refracted rays start inside)."""
        (origin,) = compiled.run(_spawn, wi.device, s.p, s.n, wi, float(self.ray_offset))
        return origin


def _perturbation(spec, material: str, values: dict, device):
    """A material's normal perturbation (None: none) as this render reads it: a normal map's
    texels are the parameter ``"<material>.normalmap"`` (differentiable), a bump map's the spec's."""
    p = getattr(spec, "perturbation", None)
    name = param_name(material, "normalmap")
    if p is None or p.kind != "normalmap" or name not in values:
        return p
    return dataclasses.replace(p, texture=values[name].to(device))


def _held_perturbations(scene: Scene, specs, values: dict, sampled_from: dict | None, device) -> list | None:
    """Per scene material, the normal perturbation sampling reads where ``sampling_params`` hold a
    normal map at other texels than the render's (a finite difference's); None where none does."""
    if sampled_from is None:
        return None
    held = [_perturbation(s, m, sampled_from, device) for m, s in zip(scene.materials, specs)]
    names = [param_name(m, "normalmap") for m in scene.materials]
    if all(n not in values or torch.equal(values[n].detach().to(device), sampled_from[n].detach().to(device)) for n in names):
        return None
    return [None if p is None else dataclasses.replace(p, texture=p.texture.detach()) for p in held]


def _vertex_normals(scene: Scene, triangles: Triangles, values: dict, sampled_from: dict | None, device) -> VertexNormals | None:
    """The render's vertex normals (:class:`~invrender.core.surface.VertexNormals`, with the ones
    sampling is held at where ``sampling_params`` give others), None where no triangle has any."""
    if not triangles.any_smooth:
        return None
    names = [n for n in (param_name(m, "normals") for m in scene.materials) if n in values]
    own = [values[n].to(device) for n in names]
    held = None
    if sampled_from is not None:
        held = [sampled_from[n].detach().to(device) for n in names]
        held = None if all(torch.equal(a.detach(), b) for a, b in zip(own, held)) else held
    return VertexNormals(triangles, own, held)


def _spawn(xp, p, n, wi, offset: float):
    return (lanes.spawn(xp, p, n, wi, offset),)


@dataclass(frozen=True)
class PathState:
    """The live paths of one chunk (loop state of the bounce loop).

    Attributes:
        keys: (N,) int32 counter-based random keys, one per path.
        pixel: (N,) int64 film index each path contributes to (the pixel; path replay's films use
            one index per path instead).
        o: (N, 3) origin of the current ray.
        d: (N, 3) unit direction of the current ray.
        beta: (N, 3) path throughput: the product of BSDF sample weights / RR survival so far.
        pdf_dir: (N,) solid-angle pdf with which ``d`` was sampled (for MIS); unused at depth 0.
        delta: (N,) bool, ``d`` came from a delta lobe (or the camera): no MIS on what it hits.
        strata: (N, 4) float32 the first vertex's stratified numbers of the sampler
            ``"stratified_direct"`` (:data:`~invrender.core.lanes.DIRECT_PAIRS`), drawn
            in place of its hashed ones; None otherwise and once that vertex is past.
    """

    keys: torch.Tensor
    pixel: torch.Tensor
    o: torch.Tensor
    d: torch.Tensor
    beta: torch.Tensor
    pdf_dir: torch.Tensor
    delta: torch.Tensor
    strata: torch.Tensor | None = None

    def select(self, mask: torch.Tensor) -> "PathState":
        """The paths where ``mask`` (N,) bool is True, or at ``mask`` (M,) int64 (compaction:
        dead paths are dropped, not masked)."""
        index = mask.nonzero()[:, 0] if mask.dtype == torch.bool else mask
        return PathState(*(None if x is None else x.index_select(0, index) for x in self._fields()))

    @staticmethod
    def cat(states: list["PathState"]) -> "PathState":
        """The paths of ``states`` one after the other (for integrators whose paths split)."""
        columns = zip(*(s._fields() for s in states))
        return PathState(*(None if any(x is None for x in c) else torch.cat(c) for c in columns))

    def _fields(self) -> tuple:
        return tuple(getattr(self, f) for f in self.__dataclass_fields__)

    def replace(self, **changes) -> "PathState":
        return dataclasses.replace(self, **changes)

    @property
    def count(self) -> int:
        return int(self.keys.shape[0])


def russian_roulette(state: PathState, u: torch.Tensor, depth: int, rr_depth: int, dead: torch.Tensor | None = None) -> PathState:
    """Unbiased Russian roulette after vertex ``depth`` once ``depth + 1 >= rr_depth``.

    Survival probability ``q = min(max_c beta_c, 0.95)`` from the detached throughput (Mitsuba's
    rule); survivors' throughput is divided by q. ``u`` (N,) uniforms. Paths flagged in ``dead``
    (N,) bool end in any case (before ``rr_depth`` too).
    """
    if depth + 1 < rr_depth:
        return state if dead is None else state.select(~dead)
    q = state.beta.detach().amax(dim=1).clamp(max=0.95)
    alive = where_true(u < q)  # one synchronization: the survivors' count
    state = state.select(alive)
    return dataclasses.replace(state, beta=state.beta / q.index_select(0, alive)[:, None])
