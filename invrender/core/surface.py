"""Surface interactions: what the renderer needs to know at the point a ray hit."""

from __future__ import annotations

from dataclasses import dataclass

import torch

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


def surface_at(triangles: Triangles, hits: Hits, d: torch.Tensor, with_uv: bool = True) -> Surface:
    """The :class:`Surface` of valid ``hits`` of rays with directions ``d`` (N, 3).

    ``with_uv=False`` skips interpolating texture coordinates (for scenes without textures).
    Shading normals are interpolated only when some triangle has vertex normals. The geometry is
    :func:`invrender.core.lanes.surface`, compiled where Dr.Jit runs (:mod:`invrender.core.compiled`).
    """
    tri = hits.prim
    u, v = hits.u[:, None], hits.v[:, None]
    p, n, front, cos_o, *uv = compiled.run(lanes.surface, d.device, lanes.geometry_rows(triangles), lanes.uv_rows(triangles), tri, hits.u, hits.v, d, with_uv=with_uv)
    uv = uv[0] if with_uv else p.new_zeros(()).expand(len(tri), 2)
    if triangles.any_smooth:
        side = torch.where(front, 1.0, -1.0)[:, None]  # the geometric side, for the shading normal too
        vn = triangles.vertex_normal.index_select(0, tri)
        ns = normalize((1 - u - v) * vn[:, 0] + u * vn[:, 1] + v * vn[:, 2]) * side
    else:
        ns = n
    return Surface(p, n, ns, front, cos_o, uv, tri, hits.t, d, torch.cat([1 - u - v, u, v], dim=1))
