"""Surface interactions: what the renderer needs to know at the point a ray hit."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.scene.scene import Triangles
from invrender.transport.accel import Hits


@dataclass(frozen=True)
class Surface:
    """N ray-surface hits (all valid).

    Attributes:
        p: (N, 3) hit position.
        n: (N, 3) unit geometric normal turned towards the incoming ray (the side light leaves from).
        front: (N,) bool, True where the ray hit the triangle's front side (the emitting side).
        cos_o: (N,) cosine between ``n`` and the direction back along the ray (> 0).
        uv: (N, 2) texture coordinates.
        tri: (N,) int64 triangle index.
        t: (N,) distance from the ray origin.
    """

    p: torch.Tensor
    n: torch.Tensor
    front: torch.Tensor
    cos_o: torch.Tensor
    uv: torch.Tensor
    tri: torch.Tensor
    t: torch.Tensor

    def select(self, index: torch.Tensor) -> "Surface":
        """The hits at ``index`` (M,) int64 (or where a (N,) bool mask is True)."""
        return Surface(*(getattr(self, f)[index] for f in self.__dataclass_fields__))


def surface_at(triangles: Triangles, hits: Hits, o: torch.Tensor, d: torch.Tensor) -> Surface:
    """The :class:`Surface` of valid ``hits`` of rays ``o + t d`` (N, 3 each)."""
    tri = hits.prim
    u, v = hits.u[:, None], hits.v[:, None]
    p = triangles.p0[tri] + u * triangles.e1[tri] + v * triangles.e2[tri]
    ng = triangles.normal[tri]
    cos = -(ng * d).sum(-1)
    front = cos > 0
    n = torch.where(front[:, None], ng, -ng)
    uv3 = triangles.uv[tri]
    uv = (1 - u - v) * uv3[:, 0] + u * uv3[:, 1] + v * uv3[:, 2]
    return Surface(p, n, front, cos.abs(), uv, tri, hits.t)
