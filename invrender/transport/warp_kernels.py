"""The Warp kernels of :mod:`invrender.transport.kernels`, in a module of their own so that
``warp-lang`` is imported only when a render first uses them (:func:`kernels.enabled`), never at
``import invrender``. Each kernel's torch reference and its documentation are in ``kernels``.
"""

from __future__ import annotations

import contextlib
import os
import sys

import torch
import warp as wp


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


_init()

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
def uniform_kernel(keys: wp.array(dtype=wp.int32), salts: wp.array(dtype=wp.int32), u: wp.array2d(dtype=wp.float32)):
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
def hit_kernel(
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
def emitter_kernel(
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
def cosine_kernel(
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
def spawn_kernel(
    p: wp.array(dtype=wp.vec3), n: wp.array(dtype=wp.vec3), wi: wp.array(dtype=wp.vec3), offset: wp.float32, o: wp.array(dtype=wp.vec3)
):
    i = wp.tid()
    if wp.dot(n[i], wi[i]) >= 0.0:
        o[i] = p[i] + offset * n[i]
    else:
        o[i] = p[i] - offset * n[i]
