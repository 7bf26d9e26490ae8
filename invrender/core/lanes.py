"""The bounce's detached maths, written once per component against the array interface.

Every function takes the array namespace ``xp`` first (:mod:`invrender.backends.arrays`: eager
torch, the reference, or Dr.Jit, compiled) and works on 1-D arrays, one lane per path; a 3-vector
is a tuple ``(x, y, z)`` of arrays; branches are masks (:meth:`select`), never data-dependent
shapes. :func:`invrender.core.compiled.run` evaluates them on torch tensors.

- the counter-based random numbers (:func:`uniform`, bit for bit those of
  :func:`invrender.core.sampler.uniform`);
- the scene's tables as rows (:func:`triangle_rows`, :func:`light_rows`, :class:`Triangle`), a
  hit's geometry (:func:`hit`), the origin of a ray leaving a surface (:func:`spawn`), Veach's
  power heuristic, the choice of an emissive triangle by its cdf (:func:`pick_light`);
- :func:`lambert_vertex`: one primal bounce of the random walk and the path tracer on Lambertian
  surfaces lit by emissive triangles (:mod:`invrender.core.fused` documents it), composed of the
  above and of the plugins' own lane functions: the material's direction sampling
  (``Diffuse.sample_lanes``) and the emitter's point sampling (``Area.sample_lanes``).
"""

from __future__ import annotations

import math

import torch

_M1, _M2 = 0x7FEB352D, 0x846CA68B


# ---- 3-vectors as tuples of arrays -------------------------------------------------------------


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def scale(a, s):
    """``a * s``, ``s`` an array or number, or a 3-tuple (componentwise)."""
    if isinstance(s, tuple):
        return (a[0] * s[0], a[1] * s[1], a[2] * s[2])
    return (a[0] * s, a[1] * s, a[2] * s)


def select3(xp, mask, a, b):
    return tuple(xp.select(mask, x, y) for x, y in zip(a, b))


def normalize(xp, a):
    """``a / |a|`` (zero vectors stay zero, as :func:`invrender.vec.normalize`)."""
    length = xp.maximum(xp.sqrt(dot(a, a)), 1e-30)
    return (a[0] / length, a[1] / length, a[2] / length)


def reflect(a, n):
    """``a`` mirrored about the unit vector ``n``: ``2 (a . n) n - a``."""
    return sub(scale(n, 2.0 * dot(a, n)), a)


# ---- shading frames ---------------------------------------------------------------------------


def frame(xp, n):
    """The orthonormal frame ``(s, t, n)`` whose z axis is the unit normal ``n`` (Duff et al. 2017;
    the same expressions as :meth:`invrender.core.frame.Frame.from_normal`)."""
    sign = xp.select(n[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    s = (1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    t = (b, sign + n[1] * n[1] * a, -n[1])
    return s, t, n


def to_local(f, v):
    """World vector ``v`` in frame ``f`` (:func:`frame`)."""
    return (dot(v, f[0]), dot(v, f[1]), dot(v, f[2]))


def to_world(f, v):
    """Local coordinates ``v`` in frame ``f`` as a world vector."""
    return add(add(scale(f[0], v[0]), scale(f[1], v[1])), scale(f[2], v[2]))


# ---- random numbers ----------------------------------------------------------------------------


def lowbias32(xp, x):
    """Wellons' lowbias32 hash of UInt ``x``."""
    x = x ^ xp.shr(x, 16)
    x = x * xp.u32(_M1)
    x = x ^ xp.shr(x, 15)
    x = x * xp.u32(_M2)
    return x ^ xp.shr(x, 16)


def uniform(xp, key, salt):
    """The uniform in [0, 1) of path keys ``key`` (UInt) for one salt (a bounce's dimension): the low
    24 bits of ``lowbias32((key & ~1) ^ salt)`` / 2^24, all bits flipped for a mirrored (odd) key."""
    flip = xp.u32(0) - (key & 1)
    h = lowbias32(xp, (key & xp.u32(0xFFFFFFFE)) ^ salt) ^ flip
    return xp.bits24(h) * (1.0 / 16777216.0)


# ---- tables, read by rows ----------------------------------------------------------------------

#: floats per triangle in the lanes' triangle table (:func:`triangle_rows`)
TRIANGLE_ROW = 16
#: floats per emissive triangle in the lanes' light table (:func:`light_rows`): its cdf, its index
LIGHT_ROW = 2


def triangle_rows(packed, material, emitter, emitting, pdf_area):
    """(T * 16,) float32 the triangle table the lane functions read, one row a triangle:
    ``p0, n_x, e1, n_y, e2, n_z, material, emitter, emitting, pdf_area`` (p0, e1, e2 as 3 floats;
    indices as exact floats, -1 = none), from ``packed`` (T, 18) (``Triangles.packed``: p0, e1,
    e2, the unit normal, uv), material, emitter (T,) int64, emitting (T,) bool, pdf_area (T,)."""
    p = packed.reshape(-1, 18)
    cols = [p[:, 0:3], p[:, 9:10], p[:, 3:6], p[:, 10:11], p[:, 6:9], p[:, 11:12]]
    cols += [x.to(torch.float32)[:, None] for x in (material, emitter, emitting, pdf_area)]
    return torch.cat(cols, dim=1).reshape(-1).contiguous()


def geometry_rows(triangles):
    """The triangle table (:func:`triangle_rows`) of a scene's geometry alone (no material or light
    columns), made once per :class:`~invrender.scene.scene.Triangles`."""

    def build():
        zero = torch.zeros(triangles.count, device=triangles.p0.device)
        return triangle_rows(triangles.packed, zero, zero, zero, zero)

    return triangles.derived("lane_rows", build)


def uv_rows(triangles):
    """(T * 8,) float32 each triangle's corner texture coordinates ``u0 v0 u1 v1 u2 v2`` (and two
    zeros), made once per :class:`~invrender.scene.scene.Triangles`."""

    def build():
        p = triangles.packed.reshape(-1, 18)
        return torch.nn.functional.pad(p[:, 12:18], (0, 2)).reshape(-1).contiguous()

    return triangles.derived("lane_uv", build)


def light_rows(cdf, tri):
    """(L * 2,) float32 the light table: each emissive triangle's cdf entry and index (< 2^24)."""
    return torch.stack([cdf.to(torch.float32), tri.to(torch.float32)], dim=1).reshape(-1).contiguous()


class Triangle:
    """Rows of the triangle table (:func:`triangle_rows`) read for N lanes."""

    __slots__ = ("r",)

    def __init__(self, xp, table, k):
        self.r = xp.gather_rows(table, k, TRIANGLE_ROW)

    @property
    def p0(self):
        return self.r[0:3]

    @property
    def e1(self):
        return self.r[4:7]

    @property
    def e2(self):
        return self.r[8:11]

    @property
    def normal(self):
        """The unit geometric normal (the front side)."""
        return (self.r[3], self.r[7], self.r[11])

    def point(self, b1, b2):
        """The point at barycentrics (b1, b2): ``p0 + b1 e1 + b2 e2``."""
        return add(self.p0, add(scale(self.e1, b1), scale(self.e2, b2)))

    def material(self, xp):
        return xp.uint(self.r[12])

    def emitter(self, xp):
        """The emitter's index (-1 as 0xFFFFFFFF where none)."""
        return xp.uint(xp.maximum(self.r[13], 0.0)), self.r[13] >= 0.0

    @property
    def emitting(self):
        return self.r[14] > 0.5

    @property
    def pdf_area(self):
        return self.r[15]


def material_width(keys) -> int:
    """Floats per row of a material table with ``keys`` (:class:`~invrender.core.bsdf.LaneForm`):
    their sizes summed, rounded up to a power of two, or to a multiple of 16 above 16."""
    n = max(1, sum(size for _, size in keys))
    return 1 << (n - 1).bit_length() if n <= 16 else -(-n // 16) * 16


def material_rows(bsdf, keys) -> torch.Tensor | None:
    """(M * W,) float32 the table of ``bsdf``'s M materials' values for its lane form's ``keys``
    (:func:`material_width` W floats a row): a parameter's detached value, a constant, or what the
    material derives from them (:meth:`~invrender.core.bsdf.LaneBSDF.lane_rows`: a key of any size);
    None where a parameter is not one colour for every material (a texture, per-vertex values) or
    sampling reads other values than the parameters hold (a render that holds sampling fixed)."""
    derived = {key: bsdf.lane_rows(key, True, "cpu") for key, _ in keys if key not in bsdf.params} if hasattr(bsdf, "lane_rows") else {}
    rows = []
    for m, values in enumerate(bsdf.values):
        row = []
        for key, size in keys:
            if key in values:
                v, vs = values[key], bsdf.sampling_values[m][key]
                if v.ndim != 1 or not torch.equal(v.detach(), vs):
                    return None
                v = v.detach().float().reshape(-1)
            elif derived.get(key) is not None:
                v = derived[key][m].detach().float().reshape(-1)
            else:
                c = bsdf.constants[m][key]
                v = torch.tensor(c if isinstance(c, (tuple, list)) else (c,) * 3, dtype=torch.float32)
            row.append(v.to("cpu")[:size])
        row = torch.cat(row) if row else torch.zeros(0)
        rows.append(torch.nn.functional.pad(row, (0, material_width(keys) - row.shape[0])))
    return torch.stack(rows).reshape(-1).contiguous()


class Row:
    """A key of more than 3 floats a material holds (a table, :meth:`~invrender.core.bsdf.LaneBSDF.lane_rows`),
    which lanes read at positions they compute (:func:`row_at`) rather than whole: each lane's
    entries are ``table[start + j]``, ``start`` (N,) indices into the flat ``table``."""

    __slots__ = ("table", "start")

    def __init__(self, table, start):
        self.table, self.start = table, start


def row_at(xp, row: Row, j):
    """Entry ``j`` (UInt, per lane: :meth:`uint` of a Float) of each lane's :class:`Row`."""
    return xp.gather_rows(row.table, row.start + j, 1)[0]


def material_values(xp, table, m, keys):
    """``p`` of :class:`~invrender.core.bsdf.LaneForm` for lanes of materials ``m`` (UInt) from
    their table (:func:`material_rows`): key -> a Float (size 1), a 3-tuple (size 3) or a
    :class:`Row` (larger); rows are gathered only as far as the small keys reach."""
    width = material_width(keys)
    reach, at = 0, 0
    for _, size in keys:
        at += size
        reach = at if size <= 3 else reach
    if width <= 16:
        flat = xp.gather_rows(table, m, width)
    else:
        chunks = width // 16
        flat = sum((xp.gather_rows(table, m * chunks + j, 16) for j in range(-(-reach // 16))), ())
    out, at = {}, 0
    for key, size in keys:
        out[key] = flat[at] if size == 1 else tuple(flat[at : at + 3]) if size == 3 else Row(table, m * width + at)
        at += size
    return out


# ---- geometry ----------------------------------------------------------------------------------


def uv_at(xp, uvs, k, b1, b2):
    """Texture coordinates (a 2-tuple) of triangles ``k`` at barycentrics (b1, b2), from the uv
    table (:func:`uv_rows`)."""
    r = xp.gather_rows(uvs, k, 8)
    b0 = 1.0 - b1 - b2
    return (b0 * r[0] + b1 * r[2] + b2 * r[4], b0 * r[1] + b1 * r[3] + b2 * r[5])


def surface(xp, rows, uvs, k, b1, b2, d, *, with_uv: bool):
    """The geometry of hits of rays ``d`` on triangles ``k`` (UInt) at barycentrics (b1, b2):
    (point, geometric normal towards the ray's origin, front side, ``|cos|`` between them, and
    with ``with_uv`` the texture coordinates); ``rows``, ``uvs``: :func:`geometry_rows`, :func:`uv_rows`."""
    p, n, c = hit(xp, Triangle(xp, rows, k), b1, b2, d)
    out = (p, n, c > 0.0, xp.abs(c))
    return out + (uv_at(xp, uvs, k, b1, b2),) if with_uv else out


def uniforms(xp, keys, salts):
    """:func:`uniform` of path keys ``keys`` for each of the ``salts``: a tuple of arrays."""
    return tuple(uniform(xp, keys, s) for s in salts)


def hit(xp, tri: Triangle, b1, b2, d):
    """Rays of directions ``d`` hitting triangles ``tri`` at barycentrics (b1, b2): (point,
    geometric normal turned towards the ray's origin, ``-ng . d``: > 0 on the front side)."""
    ng = tri.normal
    c = -dot(ng, d)
    n = select3(xp, c > 0.0, ng, scale(ng, -1.0))
    return tri.point(b1, b2), n, c


def spawn(xp, p, n, w, offset: float):
    """The origins of rays leaving ``p`` along ``w``: offset to the side of ``n`` that ``w`` points to."""
    side = xp.select(dot(n, w) >= 0.0, offset, -offset)
    return add(p, scale(n, side))


def power_heuristic(xp, a, b):
    """Veach's power heuristic: the weight of a strategy of pdf ``a`` against one of pdf ``b``."""
    a2 = a * a
    return xp.select(a2 > 0.0, a2 / xp.maximum(a2 + b * b, 1e-30), 0.0)


def pick_light(xp, lights, size: int, u):
    """The emissive triangle whose cdf interval holds ``u``: the first row of the light table
    (:func:`light_rows`, ``size`` rows) with cdf above ``u`` (``searchsorted``, ``right=True``),
    clamped to the last, by a fixed number of masked halvings. Returns its triangle index (UInt)."""
    lo = xp.full(0, u)
    hi = xp.full(size, u)
    for _ in range(max(1, size.bit_length())):
        active = lo < hi
        mid = xp.shr(lo + hi, 1)
        right = active & (xp.gather_rows(lights, xp.minimum(mid, size - 1), LIGHT_ROW)[0] <= u)
        lo = xp.select(right, mid + 1, lo)
        hi = xp.select(active & ~right, mid, hi)
    return xp.uint(xp.gather_rows(lights, xp.minimum(lo, size - 1), LIGHT_ROW)[1])


# ---- the Lambertian bounce ---------------------------------------------------------------------


def lambert_vertex(
    xp, tri_table, light_table, rho, eps, prim, b1, b2, t, d, beta, pdf_dir, keys, salts, offset: float, *,
    sample_direction, sample_light, lights: int, first: bool, mis: bool, nee_only: bool, nee: bool, more: bool, roulette: bool, tangents: bool,
):  # fmt: skip
    """One primal bounce of N paths on Lambertian surfaces lit by emissive triangles.

    Args:
        tri_table: (T * 16,) the triangle table (:func:`triangle_rows`); light_table (L * 2,) the
            emissive triangles' (:func:`light_rows`); rho (M * 4,), eps (E * 4,) RGB rows padded to 4.
        prim, b1, b2, t: (N,) the paths' closest hits (all valid); d, beta: 3-tuples of (N,) the
            rays' directions and the throughputs; pdf_dir (N,) the pdf ``d`` was sampled with;
            keys (N,) UInt; salts: the bounce's 7 salts (0-1 BSDF direction, 2-4 emitter sample,
            5 roulette).
        sample_direction: the material's lane sampler ``(xp, n, u0, u1) -> (wi, pdf)``;
            sample_light: the emitter's ``(xp, tri_table, light_table, lights, u0, u1, u2, x, nx,
            offset) -> (k, b1, b2, origin, w, tmax, facing, pdf)``; lights: L.
        first: camera rays (depth 0); mis, nee_only, nee, more, roulette, tangents: the
            integrator's strategy (:class:`invrender.core.fused.FusedScene`), whether paths go on
            after this vertex, whether roulette applies, whether the factors are returned.
    Returns:
        emitted (term depth); with ``more``: the shadow rays' origin, direction, tmax (0 where the
        sample adds nothing whatever the parameters) and the direct light each adds if unoccluded
        (term depth + 1; zeros without ``nee``), the continued rays' origin, direction, throughput,
        pdf and alive mask; with ``tangents``: the factors beside eps of the emission and of the
        direct light, the emitters hit and sampled (-1: none) and the materials hit.
    """
    tri = Triangle(xp, tri_table, prim)
    p, n, c = hit(xp, tri, b1, b2, d)
    # term depth: the emission seen, weighted against the previous vertex's emitter sample
    em, has_emitter = tri.emitter(xp)
    seen = (c > 0.0) & tri.emitting & has_emitter
    if nee_only and not first:
        seen = c != c  # none (c is never NaN for a valid hit)
    w = xp.select(seen, 1.0, 0.0)
    if mis and not first:
        light_pdf = tri.pdf_area * t * t / xp.maximum(xp.abs(c), 1e-12)
        w = w * power_heuristic(xp, pdf_dir, light_pdf)
    factor_e = scale(beta, w)
    emitted = scale(factor_e, xp.gather_rows(eps, em, 4)[:3])
    mat = tri.material(xp)
    none = xp.u32(0xFFFFFFFF)
    tangent_out = (factor_e, xp.select(seen, em, none), mat) if tangents else ()
    if not more:
        return (emitted,) + _tangents(xp, tangent_out, None, None)
    r = xp.gather_rows(rho, mat, 4)[:3]
    # term depth + 1: one emitter sample; its shadow ray is cast by the caller
    zero = 0.0 * w
    if nee:
        u0, u1, u2 = (uniform(xp, keys, salts[j]) for j in (2, 3, 4))
        kl, _, _, so, wl, tmax, facing, pdf = sample_light(xp, tri_table, light_table, lights, u0, u1, u2, p, n, offset)
        cos_i = xp.maximum(dot(n, wl), 0.0)
        bsdf_pdf = cos_i * (1.0 / math.pi)
        inv = power_heuristic(xp, pdf, bsdf_pdf) / pdf if mis else 1.0 / pdf
        weight = xp.select(facing, inv, 0.0)
        shadow_t = xp.select(facing & (cos_i > 0.0), tmax, 0.0)
        factor_d = scale(scale(beta, weight * bsdf_pdf), r)
        sampled, _ = Triangle(xp, tri_table, kl).emitter(xp)
        direct = scale(factor_d, xp.gather_rows(eps, sampled, 4)[:3])
    else:
        so, wl, shadow_t = (zero, zero, zero), (zero, zero, zero), zero
        factor_d = direct = (zero, zero, zero)
        sampled = xp.full(none, mat)
    # the BSDF sample, the new ray and Russian roulette
    up = (zero, zero, zero + 1.0)
    wi, pdf_next = sample_direction(xp, up, uniform(xp, keys, salts[0]), uniform(xp, keys, salts[1]))
    wi = to_world(frame(xp, n), wi)  # sampled in the shading frame, as the torch BSDF samples
    o_next = spawn(xp, p, n, wi, offset)
    b = scale(beta, r)
    alive = c == c  # every path (c is never NaN for a valid hit)
    if roulette:
        q = xp.minimum(xp.maximum(xp.maximum(b[0], b[1]), b[2]), 0.95)
        alive = uniform(xp, keys, salts[5]) < q
        b = scale(b, 1.0 / q)
    out = (emitted, so, wl, shadow_t, direct, o_next, wi, b, pdf_next, alive)
    return out + _tangents(xp, tangent_out, factor_d, sampled)


def _tangents(xp, tangent_out, factor_d, sampled):
    """The tangent outputs in :func:`lambert_vertex`'s order (factor_e, hit emitter, factor_d,
    sampled emitter, material hit)."""
    if not tangent_out:
        return ()
    factor_e, hit_emitter, mat = tangent_out
    if factor_d is None:
        zero = 0.0 * factor_e[0]
        factor_d, sampled = (zero, zero, zero), xp.full(xp.u32(0xFFFFFFFF), mat)
    return (factor_e, hit_emitter, factor_d, sampled, mat)
