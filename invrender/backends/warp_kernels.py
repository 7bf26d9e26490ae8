"""The Warp kernels of :mod:`invrender.backends.kernels`, in a module of their own so that
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


@wp.func
def _uniform(key: wp.uint32, salt: wp.int32) -> wp.float32:
    """The uniform of path key ``key`` for one salt (bounce and dimension): lowbias32 of ``(key & ~1)
    ^ salt``, every bit flipped for a mirrored (odd) key, low 24 bits / 2^24."""
    flip = wp.uint32(0) - (key & wp.uint32(1))
    h = _lowbias32((key & ~wp.uint32(1)) ^ wp.uint32(salt)) ^ flip
    return wp.float32(h & wp.uint32(0xFFFFFF)) * (1.0 / 16777216.0)


@wp.kernel
def uniform_kernel(keys: wp.array(dtype=wp.int32), salts: wp.array(dtype=wp.int32), u: wp.array2d(dtype=wp.float32)):
    i = wp.tid()
    key = wp.uint32(keys[i])
    for j in range(salts.shape[0]):
        u[i, j] = _uniform(key, salts[j])


#: floats per triangle in the packed table (``Triangles.packed``, passed flat: kernels whose arrays
#: are all one-dimensional get Warp's contiguous CPU code)
_ROW = wp.constant(wp.int64(18))


@wp.func
def _vec(packed: wp.array(dtype=wp.float32), k: wp.int64, j: wp.int64) -> wp.vec3:
    """Floats j .. j + 2 of triangle k's row of the flat packed table."""
    b = k * _ROW + j
    return wp.vec3(packed[b], packed[b + wp.int64(1)], packed[b + wp.int64(2)])


@wp.func
def _point(packed: wp.array(dtype=wp.float32), k: wp.int64, b1: wp.float32, b2: wp.float32) -> wp.vec3:
    """The point of triangle k at barycentrics (b1, b2): ``p0 + b1 e1 + b2 e2`` (Triangles.packed)."""
    return _vec(packed, k, wp.int64(0)) + b1 * _vec(packed, k, wp.int64(3)) + b2 * _vec(packed, k, wp.int64(6))


@wp.func
def _normal(packed: wp.array(dtype=wp.float32), k: wp.int64) -> wp.vec3:
    """Triangle k's unit geometric normal (its front side)."""
    return _vec(packed, k, wp.int64(9))


@wp.func
def _write_uv(
    packed: wp.array(dtype=wp.float32), k: wp.int64, b1: wp.float32, b2: wp.float32, uv: wp.array2d(dtype=wp.float32), i: int
):
    """uv[i] = the texture coordinates of triangle k at barycentrics (b1, b2)."""
    b0 = 1.0 - b1 - b2
    base = k * _ROW + wp.int64(12)
    uv[i, 0] = b0 * packed[base] + b1 * packed[base + wp.int64(2)] + b2 * packed[base + wp.int64(4)]
    uv[i, 1] = b0 * packed[base + wp.int64(1)] + b1 * packed[base + wp.int64(3)] + b2 * packed[base + wp.int64(5)]


@wp.func
def _hit(packed: wp.array(dtype=wp.float32), k: wp.int64, b1: wp.float32, b2: wp.float32, d: wp.vec3):
    """A ray's hit on triangle k at barycentrics (b1, b2): (point, geometric normal turned towards
    the ray's origin, the cosine ``-ng . d``: > 0 on the front side)."""
    ng = _normal(packed, k)
    c = -wp.dot(ng, d)
    n = ng
    if c <= 0.0:
        n = -ng
    return _point(packed, k, b1, b2), n, c


@wp.kernel
def hit_kernel(
    packed: wp.array(dtype=wp.float32), tri: wp.array(dtype=wp.int64), bu: wp.array(dtype=wp.float32), bv: wp.array(dtype=wp.float32),
    d: wp.array(dtype=wp.vec3), with_uv: wp.int32,
    p: wp.array(dtype=wp.vec3), n: wp.array(dtype=wp.vec3), front: wp.array(dtype=wp.bool), cos_o: wp.array(dtype=wp.float32), uv: wp.array2d(dtype=wp.float32),
):  # fmt: skip
    i = wp.tid()
    k = tri[i]
    b1 = bu[i]
    b2 = bv[i]
    point, normal, c = _hit(packed, k, b1, b2, d[i])
    p[i] = point
    n[i] = normal
    front[i] = c > 0.0
    cos_o[i] = wp.abs(c)
    if with_uv != 0:
        _write_uv(packed, k, b1, b2, uv, i)


@wp.func
def _area_sample(
    packed: wp.array(dtype=wp.float32), light_tri: wp.array(dtype=wp.int64), cdf: wp.array(dtype=wp.float32), pdf_area: wp.array(dtype=wp.float32),
    u0: wp.float32, u1: wp.float32, u2: wp.float32, x: wp.vec3, nx: wp.vec3, offset: wp.float32,
):  # fmt: skip
    """A point on the emissive triangles picked by ``u0`` (by the cdf) and placed by ``u1``, ``u2``,
    seen from ``x`` with normal ``nx``: (triangle, barycentrics b1 b2, shadow-ray origin, unit
    direction, tmax, facing, solid-angle pdf)."""
    # the emitter triangle: the first cdf entry above u0 (searchsorted, right=True), clamped
    lo = int(0)
    hi = cdf.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] <= u0:
            lo = mid + 1
        else:
            hi = mid
    k = light_tri[wp.min(lo, cdf.shape[0] - 1)]
    su = wp.sqrt(u1)
    b1 = su * (1.0 - u2)
    b2 = su * u2
    y = _point(packed, k, b1, b2)
    start = x + offset * nx
    to_light = y - start
    dist = wp.max(wp.length(to_light), 1.0e-12)
    w = to_light / dist
    cos_l = -wp.dot(_normal(packed, k), w)
    facing = wp.dot(nx, w) > 0.0 and cos_l > 0.0
    pdf = pdf_area[k] * dist * dist / wp.max(cos_l, 1.0e-12)
    return k, b1, b2, start, w, dist - offset, facing, pdf


@wp.kernel
def emitter_kernel(
    packed: wp.array(dtype=wp.float32), light_tri: wp.array(dtype=wp.int64), cdf: wp.array(dtype=wp.float32), pdf_area: wp.array(dtype=wp.float32),
    u: wp.array2d(dtype=wp.float32), x: wp.array(dtype=wp.vec3), nx: wp.array(dtype=wp.vec3), offset: wp.float32, with_uv: wp.int32,
    tri: wp.array(dtype=wp.int64), o: wp.array(dtype=wp.vec3), wl: wp.array(dtype=wp.vec3), tmax: wp.array(dtype=wp.float32),
    facing: wp.array(dtype=wp.bool), pdf: wp.array(dtype=wp.float32), uv: wp.array2d(dtype=wp.float32),
):  # fmt: skip
    i = wp.tid()
    k, b1, b2, start, w, t, ok, density = _area_sample(packed, light_tri, cdf, pdf_area, u[i, 0], u[i, 1], u[i, 2], x[i], nx[i], offset)
    tri[i] = k
    o[i] = start
    wl[i] = w
    tmax[i] = t
    facing[i] = ok
    pdf[i] = density
    if with_uv != 0:
        _write_uv(packed, k, b1, b2, uv, i)


@wp.func
def _cosine(n: wp.vec3, u0: wp.float32, u1: wp.float32):
    """A cosine-weighted direction about ``n``, ``normalize(n + s)`` (s uniform on the sphere), and its pdf."""
    z = 1.0 - 2.0 * u0
    r = wp.sqrt(wp.max(1.0 - z * z, 0.0))
    phi = (2.0 * wp.pi) * u1
    a = n + wp.vec3(r * wp.cos(phi), r * wp.sin(phi), z)
    w = a / wp.max(wp.length(a), 1.0e-30)
    return w, wp.max(wp.dot(n, w), 0.0) * (1.0 / wp.pi)


@wp.kernel
def cosine_kernel(
    n: wp.array(dtype=wp.vec3), u: wp.array2d(dtype=wp.float32), wi: wp.array(dtype=wp.vec3), pdf: wp.array(dtype=wp.float32)
):
    i = wp.tid()
    w, density = _cosine(n[i], u[i, 0], u[i, 1])
    wi[i] = w
    pdf[i] = density


@wp.func
def _spawn(p: wp.vec3, n: wp.vec3, wi: wp.vec3, offset: wp.float32) -> wp.vec3:
    """The origin of a ray leaving ``p`` along ``wi``: offset to the side of ``n`` it points to."""
    if wp.dot(n, wi) >= 0.0:
        return p + offset * n
    return p - offset * n


@wp.kernel
def spawn_kernel(
    p: wp.array(dtype=wp.vec3), n: wp.array(dtype=wp.vec3), wi: wp.array(dtype=wp.vec3), offset: wp.float32, o: wp.array(dtype=wp.vec3)
):
    i = wp.tid()
    o[i] = _spawn(p[i], n[i], wi[i], offset)


#: the multipliers of Kensler's permutation hash (module constants: unsigned, above 2^31)
_H9E501CC3 = wp.constant(wp.uint32(0x9E501CC3))
_HA511E9B3 = wp.constant(wp.uint32(0xA511E9B3))
_HC860A3DF = wp.constant(wp.uint32(0xC860A3DF))
_HE170893D = wp.constant(wp.uint32(0xE170893D))


@wp.func
def _path_key(seed_salt: wp.uint32, pixel: wp.int64, sample: wp.int64) -> wp.uint32:
    """``sampler.path_keys``: lowbias32(lowbias32(pixel ^ seed_salt) ^ sample), lowest bit clear."""
    k = _lowbias32(wp.uint32(pixel) ^ seed_salt)
    return _lowbias32(k ^ wp.uint32(sample)) & ~wp.uint32(1)


@wp.func
def _kensler_step(x: wp.uint32, p: wp.uint32, w: wp.uint32) -> wp.uint32:
    """One round of the hash of ``sampler._permuted`` (Kensler 2013), on 32-bit words."""
    x = (x ^ p) * _HE170893D
    x = x ^ (p >> wp.uint32(16))
    x = x ^ ((x & w) >> wp.uint32(4))
    x = x ^ (p >> wp.uint32(8))
    x = x * wp.uint32(0x0929EB3F)
    x = x ^ (p >> wp.uint32(23))
    x = x ^ ((x & w) >> wp.uint32(1))
    x = x * (wp.uint32(1) | (p >> wp.uint32(27)))
    x = x * wp.uint32(0x6935FA69)
    x = x ^ ((x & w) >> wp.uint32(11))
    x = x * wp.uint32(0x74DCB303)
    x = x ^ ((x & w) >> wp.uint32(2))
    x = x * _H9E501CC3
    x = x ^ ((x & w) >> wp.uint32(2))
    x = (x * _HC860A3DF) & w
    return x ^ (x >> wp.uint32(5))


@wp.func
def _permuted(i: wp.uint32, n: wp.uint32, p: wp.uint32) -> wp.uint32:
    """``sampler._permuted``: element ``i`` of the permutation of 0 .. n - 1 chosen by ``p``."""
    w = n - wp.uint32(1)
    w = w | (w >> wp.uint32(1))
    w = w | (w >> wp.uint32(2))
    w = w | (w >> wp.uint32(4))
    w = w | (w >> wp.uint32(8))
    w = w | (w >> wp.uint32(16))
    x = _kensler_step(i, p, w)
    while x >= n:
        x = _kensler_step(x, p, w)
    return wp.uint32((wp.uint64(x) + wp.uint64(p)) % wp.uint64(n))


@wp.kernel
def camera_samples_kernel(
    ids: wp.array(dtype=wp.int64), spp: wp.int64, width: wp.int64, mode: wp.int32, key_salt: wp.uint32, pattern_salt: wp.uint32,
    cells: wp.uint32, m: wp.uint32, salts: wp.array(dtype=wp.int32),
    with_lens: wp.int32, pixel: wp.array(dtype=wp.int64), keys: wp.array(dtype=wp.int32), film: wp.array(dtype=wp.vec2), lens: wp.array(dtype=wp.vec2),
):  # fmt: skip
    """Camera samples of path ids ``ids`` (``driver.camera_paths`` without a plan): mode 0
    stratified, 1 independent, 2 antithetic (pairs stratified as samples)."""
    i = wp.tid()
    px = ids[i] // spp
    sample = ids[i] % spp
    cell = sample
    key = wp.uint32(0)
    if mode == 2:
        cell = sample // wp.int64(2)
        key = _path_key(key_salt, px, wp.int64(2) * cell) | wp.uint32(sample % wp.int64(2))
    else:
        key = _path_key(key_salt, px, sample)
    pixel[i] = px
    keys[i] = wp.int32(key)
    fx = _uniform(key, salts[0])
    fy = _uniform(key, salts[1])
    if with_lens != 0:
        lens[i] = wp.vec2(_uniform(key, salts[2]), _uniform(key, salts[3]))
    if mode != 1:  # multijitter over the cells x m grid
        pattern = _path_key(pattern_salt, px, wp.int64(0))
        r = cells / m
        s = _permuted(wp.uint32(cell), cells, pattern * wp.uint32(0x51633E2D))
        col = s % m
        row = s / m
        sub_col = _permuted(row, r, pattern * wp.uint32(0x63D83595))
        sub_row = _permuted(col, m, pattern * _HA511E9B3)
        fx = (wp.float32(col) + (wp.float32(sub_col) + fx) / wp.float32(r)) / wp.float32(m)
        fy = (wp.float32(row) + (wp.float32(sub_row) + fy) / wp.float32(m)) / wp.float32(r)
        fx = wp.min(fx, 1.0 - 5.9604645e-08)
        fy = wp.min(fy, 1.0 - 5.9604645e-08)
    film[i] = wp.vec2(wp.float32(px % width) + fx, wp.float32(px // width) + fy)


@wp.kernel
def tangent_kernel(
    pixel: wp.array(dtype=wp.int64), counts: wp.array(dtype=wp.int32), rho: wp.array(dtype=wp.vec3), emitted: wp.array(dtype=wp.vec3),
    emitted_factor: wp.array(dtype=wp.vec3), emitter_hit: wp.array(dtype=wp.int32), direct: wp.array(dtype=wp.vec3), direct_factor: wp.array(dtype=wp.vec3),
    emitter_sampled: wp.array(dtype=wp.int32), occluded: wp.array(dtype=wp.bool), material_hit: wp.array(dtype=wp.int32), scatter: wp.int32,
    slots: wp.int32, jacobian: wp.array(dtype=wp.float64), places: wp.array(dtype=wp.int64), code_emitted: wp.array(dtype=wp.int64), code_direct: wp.array(dtype=wp.int64),
):  # fmt: skip
    """One vertex's contributions in terms of the scene's constant parameters (slots 0 .. M - 1 the
    materials' rho, M .. the emitters' eps), then the vertex's own rho counted in the path's
    throughput (``scatter``):

    - with a ``jacobian`` (P * 3 * slots,): their derivatives added per pixel, channel and slot (a
      contribution C with n factors of rho_m: ``n C / rho_m``, 0 in a channel where rho_m is 0; the
      factor beside eps for its emitter);
    - with ``places`` (slots,): each contribution's monomial code, ``sum_s k_s places[s]`` (k_s its
      factors of slot s), -1 where there is none (path records' codes; a place 0 leaves a slot out).
    """
    i = wp.tid()
    materials = rho.shape[0]
    row_i = i * materials  # counts is (N, M) flat
    m_k = material_hit[i]
    e_h = emitter_hit[i]
    e_l = emitter_sampled[i]
    lit = e_l >= 0 and not occluded[i]
    if places.shape[0] > 0:
        at_e = wp.int64(-1)
        at_d = wp.int64(-1)
        base = wp.int64(0)
        for m in range(materials):
            base += wp.int64(counts[row_i + m]) * places[m]
        if e_h >= 0:
            at_e = base + places[materials + e_h]
        if lit:
            at_d = base + places[m_k] + places[materials + e_l]
        code_emitted[i] = at_e
        code_direct[i] = at_d
    if jacobian.shape[0] > 0:
        row0 = pixel[i] * wp.int64(3)
        for c in range(3):
            row = (row0 + wp.int64(c)) * wp.int64(slots)
            ce = emitted[i][c]
            cd = float(0.0)
            if lit:
                cd = direct[i][c]
            if e_h >= 0:
                wp.atomic_add(jacobian, row + wp.int64(materials + e_h), wp.float64(emitted_factor[i][c]))
            if lit:
                wp.atomic_add(jacobian, row + wp.int64(materials + e_l), wp.float64(direct_factor[i][c]))
            for m in range(materials):
                r = rho[m][c]
                n = counts[row_i + m]
                nd = n
                if m == m_k:
                    nd = n + 1
                if r > 0.0 and nd > 0:
                    wp.atomic_add(jacobian, row + wp.int64(m), wp.float64((wp.float32(n) * ce + wp.float32(nd) * cd) / r))
    if scatter != 0:
        counts[row_i + m_k] = counts[row_i + m_k] + 1
