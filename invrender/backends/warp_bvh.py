"""NVIDIA Warp's BVH (``wp.Mesh``) as an intersection backend: the fast path on CUDA, and on the CPU
a check of the other backends (Warp compiles the same kernel for both).

Rays and results are torch tensors shared with Warp without copies (``wp.from_torch``); on CUDA the
kernels are launched on torch's current stream, so a query is ordered with the torch operations
around it and nothing waits for the GPU between bounces. Imported only when the backend is asked
for (without ``warp-lang``, a one-line :class:`~invrender.errors.MissingPackageError`): ``warp-lang``
compiles its kernels on first use (a few seconds, then cached on disk).

Rays with a NaN, infinite or huge component are not traced (a miss, not occluded), in the kernels
themselves (:func:`traceable`, the rule of :func:`invrender.backends.accel.traceable`): Warp
alone answered an infinite direction with a hit at ``t = 0``.

Warp reports barycentrics as the weights of a triangle's first and second vertex; the backends'
convention (Embree's) is the weights of the second and third, so the kernels convert.
"""

from __future__ import annotations

import torch

from invrender.backends import kernels, packages
from invrender.backends.kernels import Vec3, launch

wp = packages.require("warp", "the warp intersection backend", "use backend 'torch'")
kernels.warp_kernels()  # wp.init(), quietly, before the first wp.Mesh


#: accel.RAY_LIMIT: rays with a component beyond it (or NaN, or infinite) are not traced
RAY_LIMIT = wp.constant(1.844e18)


@wp.func
def traceable(o: wp.vec3, d: wp.vec3) -> bool:
    """Every component of origin ``o`` and direction ``d`` finite and within RAY_LIMIT (false for NaN)."""
    ok = True
    for j in range(3):
        if not (wp.abs(o[j]) <= RAY_LIMIT and wp.abs(d[j]) <= RAY_LIMIT):
            ok = False
    return ok


@wp.kernel
def _closest_kernel(
    mesh: wp.uint64,
    o: wp.array(dtype=wp.vec3),
    d: wp.array(dtype=wp.vec3),
    t: wp.array(dtype=wp.float32),
    prim: wp.array(dtype=wp.int64),
    u: wp.array(dtype=wp.float32),
    v: wp.array(dtype=wp.float32),
):
    i = wp.tid()
    t[i] = wp.inf  # a miss, unless the ray is traced and hits
    prim[i] = wp.int64(-1)
    u[i] = 0.0
    v[i] = 0.0
    if traceable(o[i], d[i]):
        q = wp.mesh_query_ray(mesh, o[i], d[i], 3.0e38)
        if q.result:
            t[i] = q.t
            prim[i] = wp.int64(q.face)
            u[i] = q.v  # weight of the second vertex
            v[i] = 1.0 - q.u - q.v  # weight of the third


@wp.kernel
def _occluded_kernel(mesh: wp.uint64, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3), tmax: wp.array(dtype=wp.float32), hit: wp.array(dtype=wp.bool)):
    i = wp.tid()
    hit[i] = False
    if tmax[i] > 0.0 and traceable(o[i], d[i]):  # else not traced (accel.Intersector)
        hit[i] = wp.mesh_query_ray_anyhit(mesh, o[i], d[i], tmax[i])


class WarpBVH:
    """A ``wp.Mesh`` over triangle corners (T, 3, 3) on their device, and the two ray queries."""

    def __init__(self, corners: torch.Tensor):
        points = corners.detach().reshape(-1, 3).to(torch.float32).contiguous()
        self._points = points  # Warp does not own the buffers: keep them alive with the mesh
        self._indices = torch.arange(points.shape[0], dtype=torch.int32, device=points.device)
        self.device = points.device
        self._mesh = wp.Mesh(points=wp.from_torch(points, dtype=wp.vec3), indices=wp.from_torch(self._indices))
        kernels.load(self.device, __name__)  # compiled (or loaded) here, not in each render worker

    def _launch(self, kernel, n: int, inputs: list) -> None:
        launch(kernel, n, [self._mesh.id, *inputs], self.device)

    def closest(self, o: torch.Tensor, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """(t, prim, u, v) of the closest hits of rays ``o``, ``d`` (N, 3) float32 contiguous."""
        n = o.shape[0]
        t, u, v = (torch.empty(n, dtype=torch.float32, device=self.device) for _ in range(3))
        prim = torch.empty(n, dtype=torch.int64, device=self.device)
        if n:
            self._launch(_closest_kernel, n, [Vec3(o), Vec3(d), t, prim, u, v])
        return t, prim, u, v

    def occluded(self, o: torch.Tensor, d: torch.Tensor, tmax: torch.Tensor) -> torch.Tensor:
        """(N,) bool: any hit strictly before ``tmax`` (N,)?"""
        n = o.shape[0]
        hit = torch.empty(n, dtype=torch.bool, device=self.device)
        if n:
            self._launch(_occluded_kernel, n, [Vec3(o), Vec3(d), tmax.to(torch.float32), hit])
        return hit
