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

import contextlib
import os
import sys
import threading

import torch

from invrender import first_use
from invrender.backends import packages

wp = packages.require("warp", "the warp intersection backend", "use backend 'torch'")


@contextlib.contextmanager
def quiet_stderr():
    """File descriptor 2 on /dev/null meanwhile: Warp's native library and its compiler write there
    directly, not through Python."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _init() -> None:
    """``wp.init()`` without console output: no banner or compile timings, and on a machine without
    a CUDA driver (where torch sees none either) not the native library's note that it found none."""
    wp.config.log_level = wp.LOG_ERROR
    wp.config.quiet = True
    if torch.cuda.is_available():
        wp.init()
        return
    with quiet_stderr():
        wp.init()


_init()  # before the first wp.Mesh

_loaded: set[str] = set()
_loading = threading.Lock()  # one thread at a time redirects stderr and compiles


def load(device: torch.device) -> None:
    """Compile (or load from Warp's cache, ``~/.cache/warp``) this module's kernels for ``device``,
    once per process, before render threads launch them. Warp's own output, compiler warnings
    included, is silenced; a compile (not a load from the cache) is announced in one line and its
    time counted (:mod:`invrender.first_use`)."""
    key = str(device)
    if key in _loaded:
        return
    with _loading:
        if key in _loaded:
            return
        wp_device = wp.device_from_torch(device)
        with first_use.compiling(f"the warp_bvh kernels (Warp, {device.type})", _cached(wp_device)):
            with quiet_stderr():
                wp.load_module(sys.modules[__name__], device=wp_device)
        _loaded.add(key)


def _cached(device) -> bool:
    """Are this module's kernels compiled for ``device`` in Warp's kernel cache already? Warp keeps
    each build in a folder named by the module's identifier (a hash of its code and its block size,
    1 on the CPU); True where that cannot be told (nothing is announced then)."""
    try:
        identifier = wp.get_module(__name__).get_module_identifier(block_dim=1 if device.is_cpu else None)
        return os.path.isdir(os.path.join(wp.config.kernel_cache_dir, identifier))
    except Exception:  # another Warp's internals: say nothing rather than something false
        return True


def launch(kernel, n: int, inputs: list, device: torch.device) -> None:
    """Run ``kernel`` over ``n`` threads on ``device`` (on torch's current stream on CUDA).

    ``inputs``: torch tensors (passed as Warp arrays of their dtype and shape, made contiguous:
    outputs must be contiguous already, or the kernel writes into a copy), :class:`Vec3` tensors,
    and scalars. Tensors go to Warp as launch descriptors, not ``wp.array`` objects (which cost
    tens of microseconds each to build); the tensors they point to are held here until the launch
    returns (on CUDA, torch's allocator orders their reuse after the kernel). Warp's CPU launches
    run in the calling thread without the GIL, so the render's worker threads run theirs side by side.
    """
    if not n:
        return
    held, args = [], []
    for x in inputs:
        if isinstance(x, Vec3):
            x = x.tensor.to(torch.float32).contiguous()
            args.append(wp.from_torch(x, dtype=wp.vec3, return_ctype=True))
        elif isinstance(x, torch.Tensor):
            x = x.contiguous()
            args.append(wp.from_torch(x, return_ctype=True))
        else:
            args.append(x)
        held.append(x)
    stream = wp.stream_from_torch(torch.cuda.current_stream(device)) if device.type == "cuda" else None
    wp.launch(kernel, dim=n, inputs=args, device=wp.device_from_torch(device), stream=stream)


class Vec3:
    """A (N, 3) tensor to be passed to a kernel as an array of ``wp.vec3`` (see :func:`launch`)."""

    __slots__ = ("tensor",)

    def __init__(self, tensor: torch.Tensor):
        self.tensor = tensor


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
        load(self.device)  # compiled (or loaded) here, not in each render worker

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
