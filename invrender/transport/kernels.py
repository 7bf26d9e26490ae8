"""Fused per-bounce kernels (NVIDIA Warp) for the steps of a bounce that never carry a gradient.

A bounce in eager torch is a few hundred small operations, each a pass over megabytes of (N,) and
(N, 3) tensors; the steps below are pure geometry and random numbers (no parameter enters them:
sampling and hit geometry are detached by design), so each is one Warp kernel here, one pass over
its inputs, compiled for the CPU and for CUDA from the same source and cached on disk by Warp
(``~/.cache/warp``) after the first compile. The torch expressions they replace stay beside them as
the reference: they run on devices Warp has no backend for, with ``INVRENDER_KERNELS=torch``, and
in the tests that check the two agree (the random numbers bit for bit, the geometry to float
rounding).

- :func:`hash_uniforms`: the counter-based uniforms of :func:`invrender.transport.sampler.uniform`;
- :func:`hit_geometry`: position, facing normal, side, cosine and texture coordinates of hits
  (:func:`invrender.transport.surface.surface_at`);
- :func:`emitter_geometry`: points sampled on emitters as seen from surface points, the shadow ray
  towards each and its solid-angle pdf (:meth:`invrender.emitters.area.Area.geometry`);
- :func:`cosine_directions`: the diffuse BSDF's cosine-weighted directions and their pdf;
- :func:`offset_origins`: the origins of rays leaving surfaces (``TransportContext.spawn``).

Tensors are shared with Warp without copies (``wp.from_torch``); on CUDA the kernels run on torch's
current stream. Warp's CPU launches run in the calling thread without the GIL, so the render's
worker threads run theirs side by side.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

import torch

from invrender.errors import ParameterError

#: set INVRENDER_KERNELS=torch to run the torch reference expressions instead of the Warp kernels
ENV = "INVRENDER_KERNELS"

try:
    import warp as wp
except ImportError:  # pragma: no cover - warp-lang is a dependency; this guards broken installs
    wp = None


@contextlib.contextmanager
def _quiet_stderr():
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
    with _quiet_stderr():
        wp.init()


if wp is not None:
    _init()


def enabled(device: torch.device) -> bool:
    """Do renders on ``device`` use the Warp kernels (CPU or CUDA, warp-lang importable, not
    switched off by ``INVRENDER_KERNELS=torch``)? Another value of the variable than ``warp`` or
    ``torch`` is a one-line :class:`~invrender.errors.ParameterError` (first met when a render's
    context is built, before any work)."""
    choice = os.environ.get(ENV, "warp")
    if choice not in ("warp", "torch"):
        raise ParameterError(f"{ENV} must be 'warp' or 'torch', got {choice!r}")
    return wp is not None and device.type in ("cpu", "cuda") and choice == "warp"


_loaded: set[tuple[str, str]] = set()
_loading = threading.Lock()  # one thread at a time redirects stderr and compiles


def load(device: torch.device, module: str = __name__) -> None:
    """Compile (or load from Warp's cache) the kernels of ``module`` (default: this module's, when
    they are :func:`enabled`) for ``device``, once per process, before render threads launch them.
    Nothing is printed, compiler warnings included."""
    key = (module, str(device))
    if key in _loaded or (module == __name__ and not enabled(device)):
        return
    with _loading:
        if key in _loaded:
            return
        with _quiet_stderr():
            wp.load_module(sys.modules[module], device=wp.device_from_torch(device))
        _loaded.add(key)


def launch(kernel, n: int, inputs: list, device: torch.device) -> None:
    """Run ``kernel`` over ``n`` threads on ``device`` (on torch's current stream on CUDA).

    ``inputs``: torch tensors (passed as Warp arrays of their dtype and shape, made contiguous:
    outputs must be contiguous already, or the kernel writes into a copy), :class:`Vec3` tensors,
    and scalars. Tensors go to Warp as launch descriptors, not ``wp.array``
    objects (which cost tens of microseconds each to build); the tensors they point to are held
    here until the launch returns (on CUDA, torch's allocator orders their reuse after the kernel).
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


if wp is not None:
    _M1 = wp.constant(wp.uint32(0x7FEB352D))
    _M2 = wp.constant(wp.uint32(0x846CA68B))

    @wp.func
    def _lowbias32(x: wp.uint32) -> wp.uint32:
        x = x ^ (x >> wp.uint32(16))
        x = x * _M1
        x = x ^ (x >> wp.uint32(15))
        x = x * _M2
        return x ^ (x >> wp.uint32(16))

    @wp.kernel
    def _uniform_kernel(keys: wp.array(dtype=wp.int32), salts: wp.array(dtype=wp.int32), u: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        key = wp.uint32(keys[i])
        flip = wp.uint32(0) - (key & wp.uint32(1))  # mirrored key: every bit of the hash flipped
        base = key & ~wp.uint32(1)
        for j in range(salts.shape[0]):
            h = _lowbias32(base ^ wp.uint32(salts[j])) ^ flip
            u[i, j] = wp.float32(h & wp.uint32(0xFFFFFF)) * (1.0 / 16777216.0)

    @wp.func
    def _point(packed: wp.array2d(dtype=wp.float32), k: wp.int64, b1: wp.float32, b2: wp.float32) -> wp.vec3:
        """The point of triangle k at barycentrics (b1, b2): ``p0 + b1 e1 + b2 e2`` (Triangles.packed)."""
        p0 = wp.vec3(packed[k, 0], packed[k, 1], packed[k, 2])
        e1 = wp.vec3(packed[k, 3], packed[k, 4], packed[k, 5])
        e2 = wp.vec3(packed[k, 6], packed[k, 7], packed[k, 8])
        return p0 + b1 * e1 + b2 * e2

    @wp.func
    def _normal(packed: wp.array2d(dtype=wp.float32), k: wp.int64) -> wp.vec3:
        """Triangle k's unit geometric normal (its front side)."""
        return wp.vec3(packed[k, 9], packed[k, 10], packed[k, 11])

    @wp.func
    def _write_uv(
        packed: wp.array2d(dtype=wp.float32), k: wp.int64, b1: wp.float32, b2: wp.float32, uv: wp.array2d(dtype=wp.float32), i: int
    ):
        """uv[i] = the texture coordinates of triangle k at barycentrics (b1, b2)."""
        b0 = 1.0 - b1 - b2
        for j in range(2):
            uv[i, j] = b0 * packed[k, 12 + j] + b1 * packed[k, 14 + j] + b2 * packed[k, 16 + j]

    @wp.kernel
    def _hit_kernel(
        packed: wp.array2d(dtype=wp.float32), tri: wp.array(dtype=wp.int64), bu: wp.array(dtype=wp.float32), bv: wp.array(dtype=wp.float32),
        d: wp.array(dtype=wp.vec3), with_uv: wp.int32,
        p: wp.array(dtype=wp.vec3), n: wp.array(dtype=wp.vec3), front: wp.array(dtype=wp.bool), cos_o: wp.array(dtype=wp.float32), uv: wp.array2d(dtype=wp.float32),
    ):  # fmt: skip
        i = wp.tid()
        k = tri[i]
        b1 = bu[i]
        b2 = bv[i]
        ng = _normal(packed, k)
        p[i] = _point(packed, k, b1, b2)
        c = -wp.dot(ng, d[i])
        front[i] = c > 0.0
        if c > 0.0:
            n[i] = ng
        else:
            n[i] = -ng
        cos_o[i] = wp.abs(c)
        if with_uv != 0:
            _write_uv(packed, k, b1, b2, uv, i)

    @wp.kernel
    def _emitter_kernel(
        packed: wp.array2d(dtype=wp.float32), light_tri: wp.array(dtype=wp.int64), cdf: wp.array(dtype=wp.float32), pdf_area: wp.array(dtype=wp.float32),
        u: wp.array2d(dtype=wp.float32), x: wp.array(dtype=wp.vec3), nx: wp.array(dtype=wp.vec3), offset: wp.float32, with_uv: wp.int32,
        tri: wp.array(dtype=wp.int64), o: wp.array(dtype=wp.vec3), wl: wp.array(dtype=wp.vec3), tmax: wp.array(dtype=wp.float32),
        facing: wp.array(dtype=wp.bool), pdf: wp.array(dtype=wp.float32), uv: wp.array2d(dtype=wp.float32),
    ):  # fmt: skip
        i = wp.tid()
        # the emitter triangle: the first cdf entry above u_pick (searchsorted, right=True), clamped
        lo = int(0)
        hi = cdf.shape[0]
        pick = u[i, 0]
        while lo < hi:
            mid = (lo + hi) // 2
            if cdf[mid] <= pick:
                lo = mid + 1
            else:
                hi = mid
        k = light_tri[wp.min(lo, cdf.shape[0] - 1)]
        tri[i] = k
        su = wp.sqrt(u[i, 1])
        b1 = su * (1.0 - u[i, 2])
        b2 = su * u[i, 2]
        y = _point(packed, k, b1, b2)
        start = x[i] + offset * nx[i]
        o[i] = start
        to_light = y - start
        dist = wp.max(wp.length(to_light), 1.0e-12)
        w = to_light / dist
        wl[i] = w
        tmax[i] = dist - offset
        cos_l = -wp.dot(_normal(packed, k), w)
        facing[i] = wp.dot(nx[i], w) > 0.0 and cos_l > 0.0
        pdf[i] = pdf_area[k] * dist * dist / wp.max(cos_l, 1.0e-12)
        if with_uv != 0:
            _write_uv(packed, k, b1, b2, uv, i)

    @wp.kernel
    def _cosine_kernel(
        n: wp.array(dtype=wp.vec3), u: wp.array2d(dtype=wp.float32), wi: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32)
    ):
        i = wp.tid()
        z = 1.0 - 2.0 * u[i, 0]
        r = wp.sqrt(wp.max(1.0 - z * z, 0.0))
        phi = (2.0 * wp.pi) * u[i, 1]
        a = n[i] + wp.vec3(r * wp.cos(phi), r * wp.sin(phi), z)
        w = a / wp.max(wp.length(a), 1.0e-30)
        wi[i] = w
        pdf[i] = wp.max(wp.dot(n[i], w), 0.0) * (1.0 / wp.pi)

    @wp.kernel
    def _spawn_kernel(
        p: wp.array(dtype=wp.vec3), n: wp.array(dtype=wp.vec3), wi: wp.array(dtype=wp.vec3), offset: wp.float32, o: wp.array(dtype=wp.vec3)
    ):
        i = wp.tid()
        if wp.dot(n[i], wi[i]) >= 0.0:
            o[i] = p[i] + offset * n[i]
        else:
            o[i] = p[i] - offset * n[i]


def hash_uniforms(keys: torch.Tensor, salts: torch.Tensor) -> torch.Tensor:
    """(N, D) float32 uniforms: lowbias32 of ``(keys & ~1) ^ salt_j`` (N,) x (D,) int32, all bits
    flipped for odd (mirrored) keys, low 24 bits / 2^24 (the kernel of ``sampler.uniform``)."""
    out = torch.empty(keys.shape[0], salts.shape[0], dtype=torch.float32, device=keys.device)
    launch(_uniform_kernel, keys.shape[0], [keys, salts, out], keys.device)
    return out


def hit_geometry(packed: torch.Tensor, tri: torch.Tensor, u: torch.Tensor, v: torch.Tensor, d: torch.Tensor, with_uv: bool):
    """Hits of rays ``d`` (N, 3) on triangles ``tri`` (N,) at barycentrics ``u``, ``v`` (N,) (the
    weights of corners 1 and 2), from the (T, 18) packed table (``Triangles.packed``).

    Returns:
        p (N, 3), n (N, 3) the geometric normal turned towards the ray's origin, front (N,) bool,
        cos_o (N,) |cos| between them, uv (N, 2) (zeros unless ``with_uv``).
    """
    count, dev = tri.shape[0], tri.device
    p, n = (torch.empty(count, 3, device=dev) for _ in range(2))
    front = torch.empty(count, dtype=torch.bool, device=dev)
    cos_o = torch.empty(count, device=dev)
    uv = torch.empty(count, 2, device=dev) if with_uv else torch.zeros(1, 2, device=dev)
    inputs = [packed, tri, u, v, Vec3(d), int(with_uv), Vec3(p), Vec3(n), front, cos_o, uv]
    launch(_hit_kernel, count, inputs, dev)
    return p, n, front, cos_o, uv if with_uv else uv.expand(count, 2)


def emitter_geometry(packed, light_tri, cdf, pdf_area, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float, with_uv: bool):
    """Emitter samples seen from points ``x`` (N, 3) with normals ``nx`` (N, 3), from uniforms ``u``
    (N, 3) (pick, then the point), the area lights' tables (:class:`~invrender.emitters.area.Area`) and the (T, 18) packed
    triangles.

    Returns:
        tri (N,) int64, o (N, 3) shadow-ray origins ``x + offset nx``, wl (N, 3) unit directions to
        the points, tmax (N,) their distance minus ``offset``, facing (N,) bool (the point is in
        front of ``nx`` and ``x`` in front of the emitter), pdf (N,) solid-angle density of the
        sample at ``o``, uv (N, 2) at the points (zeros unless ``with_uv``).
    """
    count, dev = x.shape[0], x.device
    tri = torch.empty(count, dtype=torch.int64, device=dev)
    o, wl = (torch.empty(count, 3, device=dev) for _ in range(2))
    tmax, pdf = (torch.empty(count, device=dev) for _ in range(2))
    facing = torch.empty(count, dtype=torch.bool, device=dev)
    uv = torch.empty(count, 2, device=dev) if with_uv else torch.zeros(1, 2, device=dev)
    inputs = [
        packed,
        light_tri,
        cdf,
        pdf_area,
        u,
        Vec3(x),
        Vec3(nx),
        float(offset),
        int(with_uv),
        tri,
        Vec3(o),
        Vec3(wl),
        tmax,
        facing,
        pdf,
        uv,
    ]
    launch(_emitter_kernel, count, inputs, dev)
    return tri, o, wl, tmax, facing, pdf, uv if with_uv else uv.expand(count, 2)


def cosine_directions(n: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Cosine-weighted directions about unit normals ``n`` (N, 3) from uniforms ``u`` (N, 2), as
    ``normalize(n + s)`` with ``s`` uniform on the sphere (``z = 1 - 2 u_0``, ``phi = 2 pi u_1``):
    (wi (N, 3), their pdf ``max(cos, 0) / pi`` (N,))."""
    count = n.shape[0]
    wi, pdf = torch.empty(count, 3, device=n.device), torch.empty(count, device=n.device)
    launch(_cosine_kernel, count, [Vec3(n), u, Vec3(wi), pdf], n.device)
    return wi, pdf


def offset_origins(p: torch.Tensor, n: torch.Tensor, wi: torch.Tensor, offset: float) -> torch.Tensor:
    """Ray origins (N, 3) ``p +- offset n``, on the side of ``n`` (N, 3) that ``wi`` (N, 3) points to."""
    o = torch.empty(p.shape[0], 3, device=p.device)
    launch(_spawn_kernel, p.shape[0], [Vec3(p), Vec3(n), Vec3(wi), float(offset), Vec3(o)], p.device)
    return o
