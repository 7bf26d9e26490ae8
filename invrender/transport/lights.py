"""Sampling points on emissive triangles for next-event estimation.

Lights are sampled by detached power (docs/architecture.md#detached-sampling-differentiable-evaluation): an emissive triangle is picked with
probability proportional to ``area x mean(eps)`` (eps read without gradient when the sampler is
built), then a point uniformly on it. No pdf depends on the differentiable ``eps``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.scene.scene import Triangles
from invrender.transport import kernels
from invrender.vec import dot, norm


@dataclass(frozen=True)
class LightSample:
    """N points sampled on emitters.

    Attributes:
        tri: (N,) int64 triangle index.
        p: (N, 3) position.
        n: (N, 3) unit normal of the emitting (front) side.
        uv: (N, 2) texture coordinates (zeros when no emission is textured).
        pdf_area: (N,) density per unit area of having sampled ``p``.
    """

    tri: torch.Tensor
    p: torch.Tensor
    n: torch.Tensor
    uv: torch.Tensor
    pdf_area: torch.Tensor


@dataclass(frozen=True)
class EmitterSampleFrom:
    """N points sampled on emitters as seen from N surface points x: the shadow rays towards them.

    Attributes:
        tri: (N,) int64 emitter triangle of each point.
        uv: (N, 2) texture coordinates at the points (zeros when no emission is textured).
        o: (N, 3) shadow-ray origins, x offset off its surface along its geometric normal.
        wl: (N, 3) unit directions from ``o`` to the points.
        tmax: (N,) distance from ``o`` to the point minus the offset (where the shadow ray stops).
        facing: (N,) bool: the point lies in front of x's geometric normal and x in front of the
            emitter (its emitting side); only then can it light x.
        pdf: (N,) solid-angle density at ``o`` of having sampled the point.
    """

    tri: torch.Tensor
    uv: torch.Tensor
    o: torch.Tensor
    wl: torch.Tensor
    tmax: torch.Tensor
    facing: torch.Tensor
    pdf: torch.Tensor


class EmitterSampler:
    """Picks emissive triangles by detached power, then uniform points on them."""

    def __init__(self, triangles: Triangles, emissions: list[torch.Tensor]):
        """``emissions``: one (3,) or (h, w, 3) eps per emitter, indexed by ``triangles.emitter``."""
        self.triangles = triangles
        #: does any emission vary over UVs (else samples skip their texture coordinates)?
        self.textured = any(e.ndim == 3 for e in emissions)
        power = torch.tensor([float(e.detach().mean()) for e in emissions] + [0.0], device=triangles.area.device)
        weight = triangles.area * power[triangles.emitter]  # emitter -1 -> the appended 0
        self.tri = torch.nonzero(weight > 0)[:, 0]
        total = weight.sum()
        self.count = int(self.tri.numel())
        #: (T,) pdf per unit area of the point sampler on each triangle (0 where it never samples)
        self.pdf_area = torch.where(weight > 0, weight / total.clamp_min(1e-30) / triangles.area, 0.0)
        cdf = torch.cumsum(weight[self.tri].double(), 0)
        self.cdf = (cdf / cdf[-1]).float() if self.count else cdf.float()

    def sample(self, u_pick: torch.Tensor, u: torch.Tensor) -> LightSample:
        """Points from uniforms ``u_pick`` (N,) and ``u`` (N, 2)."""
        k = torch.searchsorted(self.cdf, u_pick.contiguous(), right=True).clamp_max(self.count - 1)
        tri = self.tri.index_select(0, k)
        g = self.triangles.packed.index_select(0, tri)
        su = u[:, 0].sqrt()
        b1, b2 = (su * (1.0 - u[:, 1]))[:, None], (su * u[:, 1])[:, None]  # uniform barycentrics (weights of p1, p2)
        p = g[:, 0:3] + b1 * g[:, 3:6] + b2 * g[:, 6:9]
        uv = (1 - b1 - b2) * g[:, 12:14] + b1 * g[:, 14:16] + b2 * g[:, 16:18] if self.textured else p.new_zeros(()).expand(len(tri), 2)
        return LightSample(tri, p, g[:, 9:12], uv, self.pdf_area.index_select(0, tri))

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> EmitterSampleFrom:
        """Points from uniforms ``u`` (N, 3) (pick, then the point) as seen from points ``x`` (N, 3)
        with geometric normals ``nx`` (N, 3): the shadow rays of next-event estimation, starting
        ``offset`` off x's surface (one fused kernel where :mod:`~invrender.transport.kernels` runs)."""
        if kernels.enabled(x.device):
            tri, o, wl, tmax, facing, pdf, uv = kernels.emitter_geometry(self.triangles.packed, self.tri, self.cdf, self.pdf_area, u, x, nx, offset, self.textured)
            return EmitterSampleFrom(tri, uv, o, wl, tmax, facing, pdf)
        ls = self.sample(u[:, 0], u[:, 1:3])
        o = x + offset * nx
        to_light = ls.p - o
        dist = norm(to_light).clamp_min(1e-12)
        wl = to_light / dist[:, None]
        cos_l = -dot(ls.n, wl)  # at the light: only its front side emits
        facing = (dot(nx, wl) > 0) & (cos_l > 0)  # light from behind x's surface does not reach it
        pdf = ls.pdf_area * dist * dist / cos_l.clamp_min(1e-12)  # area -> solid angle
        return EmitterSampleFrom(ls.tri, ls.uv, o, wl, dist - offset, facing, pdf)
