"""Surface interactions: what the renderer needs to know at the point a ray hit."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.autograd.forward_ad as fwAD

from invrender.scene.scene import Triangles
from invrender.backends.accel import Hits
from invrender.core import compiled, lanes
from invrender.vec import normalize


@dataclass(frozen=True)
class Surface:
    """N ray-surface hits (all valid).

    Attributes:
        p: (N, 3) hit position.
        n: (N, 3) unit geometric normal turned towards the incoming ray (the side light leaves from).
        ns: (N, 3) unit shading normal (interpolated vertex normals, or ``n``), turned to the same
            geometric side as ``n``: geometric normals decide which side a ray is on.
        front: (N,) bool, True where the ray hit the triangle's front side (the emitting side).
        cos_o: (N,) cosine between ``n`` and the direction back along the ray (> 0).
        uv: (N, 2) texture coordinates (zeros when the scene has no textures).
        tri: (N,) int64 triangle index.
        t: (N,) distance from the ray origin.
        d: (N, 3) unit direction of the ray (its origin is ``p - t d``).
        bary: (N, 3) barycentric weights of the triangle's three corners at ``p`` (for per-vertex
            parameters).
    """

    p: torch.Tensor
    n: torch.Tensor
    ns: torch.Tensor
    front: torch.Tensor
    cos_o: torch.Tensor
    uv: torch.Tensor
    tri: torch.Tensor
    t: torch.Tensor
    d: torch.Tensor
    bary: torch.Tensor

    def select(self, index: torch.Tensor) -> "Surface":
        """The hits at ``index`` (M,) int64 (or where a (N,) bool mask is True)."""
        return Surface(*(getattr(self, f)[index] for f in self.__dataclass_fields__))


class VertexNormals:
    """The vertex normals a render shades with: the triangles' own (``Triangles.vertex_normal``),
    and for the materials with a ``"<material>.normals"`` parameter its current values (which may
    carry derivatives: the shading normal is then differentiable in them).

    Args:
        triangles: the scene's triangles (``normal_row`` maps their corners to the parameters).
        values: the ``"<material>.normals"`` values (V_m, 3), in the order of the scene's materials.
        sampling: the values sampling reads where a render holds it at other values than these
            (``sampling_params``: a finite difference's perturbed normals), detached; None = these.
    """

    def __init__(self, triangles: Triangles, values: list[torch.Tensor], sampling: list[torch.Tensor] | None = None):
        self.triangles, self.values, self.sampling = triangles, values, sampling
        self._tables: dict = {}

    @property
    def carries_derivative(self) -> bool:
        """Does some value carry a derivative (requires grad where grad is on, or a forward-mode tangent)?"""
        return any(carries_derivative(v) for v in self.values)

    def _table(self, sampling: bool) -> torch.Tensor:
        """(R, 3) the values (or, with ``sampling``, the ones sampling reads, detached) one after
        another (as ``normal_row`` numbers them), built once per grad mode."""
        key = (torch.is_grad_enabled(), sampling)
        if key not in self._tables:
            values = self.values if not sampling else self.sampling or [v.detach() for v in self.values]
            self._tables[key] = values[0] if len(values) == 1 else torch.cat(values)
        return self._tables[key]

    def corners(self, tri: torch.Tensor, sampling: bool = False) -> torch.Tensor:
        """(N, 3, 3) the three vertex normals of triangles ``tri`` (N,) int64: the parameter's rows
        where the triangle's material has one (the same floats as the triangles' own until they
        are changed), else the triangles' own; with ``sampling``, those sampling reads."""
        own = self.triangles.vertex_normal.index_select(0, tri)
        if not self.values or self.triangles.normal_row is None:
            return own
        rows = self.triangles.normal_row.index_select(0, tri)
        got = self._table(sampling).index_select(0, rows.clamp_min(0).reshape(-1)).reshape(-1, 3, 3)
        return torch.where((rows[:, :1] >= 0)[:, :, None], got, own)

    def sampling_normal(self, s: "Surface") -> torch.Tensor:
        """(N, 3) the shading normal at the hits ``s`` as sampling reads it (detached): ``s.ns``
        itself unless sampling is held at other values (:attr:`sampling`)."""
        if self.sampling is None:
            return s.ns.detach()
        return interpolated(self.corners(s.tri, sampling=True), s.bary, s.front)

    def rows(self) -> torch.Tensor:
        """(T * 16,) float32 the compiled bounce's vertex normal table
        (:func:`~invrender.core.lanes.normal_rows`) of the current values, detached; rebuilt only
        when the values changed (one table kept per geometry, with the values it was built from)."""
        t = self.triangles
        if not self.values or t.normal_row is None:
            return lanes.normal_rows(t)
        with torch.no_grad():
            values = [v.detach() for v in self.values]
            kept = t.__dict__.get("_parameter_normals")
            if kept is not None and len(kept[0]) == len(values) and all(a.shape == b.shape and torch.equal(a, b) for a, b in zip(kept[0], values)):
                return kept[1]
            corners = self.corners(torch.arange(t.count, device=t.p0.device))
            kept = ([v.clone() for v in values], torch.nn.functional.pad(corners.reshape(-1, 9).float(), (0, 7)).reshape(-1).contiguous())
            t.__dict__["_parameter_normals"] = kept  # not a field: frozen, never compared
        return kept[1]


def carries_derivative(x: torch.Tensor) -> bool:
    """Does ``x`` carry a derivative: it requires grad where grad is on, or has a forward-mode tangent?"""
    return (x.requires_grad and torch.is_grad_enabled()) or fwAD.unpack_dual(x).tangent is not None


def surface_at(triangles: Triangles, hits: Hits, d: torch.Tensor, with_uv: bool = True, normals: VertexNormals | None = None) -> Surface:
    """The :class:`Surface` of valid ``hits`` of rays with directions ``d`` (N, 3).

    ``with_uv=False`` skips interpolating texture coordinates (for scenes without textures).
    Shading normals are interpolated only when some triangle has vertex normals, from ``normals``
    (the render's, differentiable in the ``"<material>.normals"`` parameters) or else the
    triangles' own. The geometry is :func:`invrender.core.lanes.surface`, compiled where Dr.Jit
    runs (:mod:`invrender.core.compiled`).
    """
    tri = hits.prim
    u, v = hits.u[:, None], hits.v[:, None]
    p, n, front, cos_o, *uv = compiled.run(lanes.surface, d.device, lanes.geometry_rows(triangles), lanes.uv_rows(triangles), tri, hits.u, hits.v, d, with_uv=with_uv)
    uv = uv[0] if with_uv else p.new_zeros(()).expand(len(tri), 2)
    bary = torch.cat([1 - u - v, u, v], dim=1)
    if triangles.any_smooth:
        ns = interpolated(triangles.vertex_normal.index_select(0, tri) if normals is None else normals.corners(tri), bary, front)
    else:
        ns = n
    return Surface(p, n, ns, front, cos_o, uv, tri, hits.t, d, bary)


def interpolated(vn: torch.Tensor, bary: torch.Tensor, front: torch.Tensor) -> torch.Tensor:
    """(N, 3) the shading normal: the corners' normals ``vn`` (N, 3, 3) interpolated at barycentric
    weights ``bary`` (N, 3), normalized, turned to the geometric side ``front`` says the ray is on."""
    side = torch.where(front, 1.0, -1.0)[:, None]  # the geometric side, for the shading normal too
    return normalize(bary[:, 0:1] * vn[:, 0] + bary[:, 1:2] * vn[:, 1] + bary[:, 2:3] * vn[:, 2]) * side
