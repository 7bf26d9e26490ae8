"""The bounce's detached maths, written once per component against the array interface.

Every function takes the array namespace ``xp`` first (:mod:`invrender.backends.arrays`: eager
torch, the reference, or Dr.Jit, compiled) and works on 1-D arrays, one lane per path; a 3-vector
is a tuple ``(x, y, z)`` of arrays; branches are masks (:meth:`select`), never data-dependent
shapes. :func:`invrender.core.compiled.run` evaluates them on torch tensors.

- the counter-based random numbers (:func:`uniform`, bit for bit those of
  :func:`invrender.core.sampler.uniform`), path keys (:func:`path_key`) and the pixels'
  multi-jittered patterns (:func:`permuted`, :func:`multijitter`);
- the scene's tables as rows (:func:`triangle_rows`, :func:`light_rows`, :class:`Triangle`), a
  hit's geometry (:func:`hit`), the origin of a ray leaving a surface (:func:`spawn`), Veach's
  power heuristic, the choice of an emissive triangle by its cdf (:func:`pick_light`);
- shading frames (:func:`frame`), the materials' tables (:func:`material_rows`) and their dispatch
  by type with masks (:class:`Point`);
- :func:`path_vertex`: one primal bounce of the random walk and the path tracer lit by emissive
  triangles (:mod:`invrender.core.fused` documents it), composed of the above and of the plugins'
  own lane functions: each material's lane form (:class:`~invrender.core.bsdf.LaneForm`) and the
  emitter's point sampling (``Area``'s ``triangle_lanes``).
"""

from __future__ import annotations

import functools
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


#: floats per scene material in the shading table (:func:`invrender.core.shading.tables`): UV frame
#: (1.0) or not, the perturbation (0 none, 1 normal map, 2 bump map), its texture's id, the bump
#: map's scale, the base frame turned to the ray's side (``twosided`` around the map), flip invalid
#: normals, the shadowing term, a pad
SHADING_ROW = 8
#: Rec. 709 luminance (Mitsuba's ``luminance``: a bump map's height of an RGB texel)
LUMINANCE = (0.212671, 0.715160, 0.072169)


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def shading_frame(xp, frames, perturb, ns, ng, front, prim, b1, b2, wo, mat):
    """The shading frame (:mod:`invrender.core.shading` gives the conventions: Mitsuba's) of hits on triangles ``prim`` (UInt) at barycentrics (b1, b2) of scene
    materials ``mat`` (UInt), seen along ``-wo``: ``ns``, ``ng`` the shading and geometric normals
    turned to ``wo``'s side (``front``: the triangle's front). ``frames``, ``perturb``: :func:`invrender.core.shading.tables`
    (``frames`` not None).

    Returns:
        ``(s, t, n)`` the frame (world 3-vectors; z the normal turned to ``wo``), ``front`` as the
        material sees it (the perturbed normal's outer side), and the bend :func:`bend_lanes`
        reads: the base normal, the perturbed one (3-vectors), alpha^2 of the shadowing term (0:
        none) and whether the lane is perturbed (Bool); None without ``perturb``.
    """
    tangents, uvs, rows = frames
    duff = frame(xp, ns)
    r = xp.gather_rows(rows, mat, SHADING_ROW)
    side = xp.select(front, 1.0, -1.0)
    n_front = scale(ns, side)
    g = xp.gather_rows(tangents, prim, 8)
    dpdu, dpdv = g[0:3], g[3:6]
    s = _orthogonal(xp, dpdu, n_front)
    t = cross(n_front, s)
    use = r[0] > 0.5
    base = (select3(xp, use, s, duff[0]), select3(xp, use, t, duff[1]), ns)
    if perturb is None:
        return base, front, None
    texrows, texels = perturb
    kind = r[1]
    perturbed = kind > 0.5
    sigma = xp.select(r[4] > 0.5, side, 1.0)
    nb = scale(n_front, sigma)
    B = (s, t, nb)
    a = to_local(B, wo)
    # the texture's four texels and weights at the hit's uv
    uv = uv_at(xp, uvs, prim, b1, b2)
    tex = xp.gather_rows(texrows, xp.uint(xp.maximum(r[2], 0.0)), 16)
    index, weight = _filter(xp, uv, tex)
    first = xp.uint(tex[0])
    texel = [xp.gather_rows(texels, first + i, 4)[:3] for i in index]
    rgb = None
    for c, w in zip(texel, weight):
        rgb = scale(c, w) if rgb is None else add(rgb, scale(c, w))
    # normal map: tangent-space normal 2 c - 1
    p_map = (2.0 * rgb[0] - 1.0, 2.0 * rgb[1] - 1.0, 2.0 * rgb[2] - 1.0)
    # bump map: the bilinear filter's gradient of the luminance over uv, times scale
    lum = [LUMINANCE[0] * c[0] + LUMINANCE[1] * c[1] + LUMINANCE[2] * c[2] for c in texel]
    fx, fy = weight[1] + weight[3], weight[2] + weight[3]
    df_dx = (1.0 - fy) * (lum[1] - lum[0]) + fy * (lum[3] - lum[2])
    df_dy = (1.0 - fx) * (lum[2] - lum[0]) + fx * (lum[3] - lum[1])
    w, h = tex[1], tex[2]
    ta, tb, td, te = tex[5], tex[6], tex[8], tex[9]  # to_uv: u' = a u + b v + c, v' = d u + e v + f; x = u' w, y = (1 - v') h
    g_u = r[3] * (df_dx * w * ta - df_dy * h * td)
    g_v = r[3] * (df_dx * w * tb - df_dy * h * te)
    du = add(dpdu, scale(n_front, g_u - dot(n_front, dpdu)))
    dv = add(dpdv, scale(n_front, g_v - dot(n_front, dpdv)))
    bump = normalize(xp, cross(du, dv))
    bump = scale(bump, xp.select(dot(scale(ng, side), bump) < 0.0, -1.0, 1.0))  # to the geometric normal's (front) side
    bump = to_local((s, t, n_front), bump)
    is_bump = kind > 1.5
    p = select3(xp, is_bump, bump, p_map)
    # flip invalid normals: the camera's direction on the perturbed normal's side of the base frame
    flip = (r[5] > 0.5) & (a[2] * dot(a, p) <= 0.0)
    p = (xp.select(flip, -p[0], p[0]), xp.select(flip, -p[1], p[1]), p[2])
    pn = normalize(xp, p)
    # the perturbed frame in B: s' from x (normal map) or dp/du in B (bump map), made orthogonal to p
    along = select3(xp, is_bump, to_local(B, dpdu), (1.0 + 0.0 * a[0], 0.0 * a[0], 0.0 * a[0]))
    sp = _orthogonal(xp, along, pn)
    tp = cross(pn, sp)
    Pw = tuple(to_world(B, v) for v in (sp, tp, pn))
    z = dot(wo, Pw[2])
    turn = xp.select(z < 0.0, -1.0, 1.0)
    out = (select3(xp, perturbed, Pw[0], base[0]), select3(xp, perturbed, Pw[1], base[1]), select3(xp, perturbed, scale(Pw[2], turn), base[2]))
    front_m = xp.select(perturbed, ~((z > 0.0) ^ (sigma > 0.0)), front)
    pz2 = pn[2] * pn[2]
    tan2_p = xp.maximum(1.0 - pz2, 0.0) / xp.maximum(pz2, 1e-30)
    alpha2 = xp.select(perturbed & (r[6] > 0.5), xp.minimum(0.125 * tan2_p, 1.0), 0.0)
    return out, front_m, (select3(xp, perturbed, nb, ns), select3(xp, perturbed, Pw[2], ns), alpha2, perturbed)


def _orthogonal(xp, v, n):
    """``v`` made orthogonal to the unit ``n`` and normalized (Gram-Schmidt); the coordinate
    system's first axis of ``n`` where nothing is left of ``v``."""
    o = sub(v, scale(n, dot(n, v)))
    length2 = dot(o, o)
    ok = length2 > 1e-24
    u = scale(o, 1.0 / xp.sqrt(xp.select(ok, length2, 1.0)))
    return select3(xp, ok, u, frame(xp, n)[0])


def _filter(xp, uv, tex):
    """The four texel indices and weights of a texture row ``tex`` (:class:`~invrender.core.TextureTable`) at ``uv``."""
    from invrender.core.textures import filter_lanes

    return filter_lanes(xp, uv[0], uv[1], tex[2], tex[1], tex[3] > 0.5, tex[4], tex[5:11])


def bend_lanes(xp, bend, wi):
    """The factor of a perturbed normal on a material's value for world direction ``wi``: 0 unless
    ``wi`` lies on the same side of the base normal and of the perturbed one, else the shadowing
    term ``2 / (1 + sqrt(1 + alpha^2 tan^2))`` at ``wi``'s angle to the base normal (1 where alpha^2
    is 0); and the pdf's mask (a Bool). ``bend``: :func:`shading_frame`'s."""
    nb, npert, alpha2, perturbed = bend
    cb, cp = dot(wi, nb), dot(wi, npert)
    active = ~perturbed | (cb * cp > 0.0)
    c2 = xp.maximum(cb * cb, 1e-30)
    tan2 = xp.maximum(1.0 - c2, 0.0) / c2
    g = xp.select(alpha2 > 0.0, 2.0 / (1.0 + xp.sqrt(1.0 + alpha2 * tan2)), 1.0)
    return xp.select(active, g, 0.0), active


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


def path_key(xp, salt, pixel, sample):
    """The key of the paths of UInt counters ``pixel`` and ``sample`` (their low 32 bits) for the
    seed's ``salt`` (:func:`invrender.core.sampler.seed_salt`): ``lowbias32(lowbias32(pixel ^
    salt) ^ sample)``, the lowest bit clear (:func:`invrender.core.sampler.path_keys`)."""
    return lowbias32(xp, lowbias32(xp, pixel ^ salt) ^ sample) & xp.u32(0xFFFFFFFE)


def _kensler(xp, x, p, w):
    """One round of Kensler's permutation hash (2013) of UInt ``x`` by pattern ``p`` on the bits of
    mask ``w``: xors with the pattern, odd multiplications modulo 2^32, masked xor-shifts."""
    x = (x ^ p) * xp.u32(0xE170893D)
    x = x ^ xp.shr(p, 16)
    x = x ^ xp.shr(x & w, 4)
    x = x ^ xp.shr(p, 8)
    x = x * xp.u32(0x0929EB3F)
    x = x ^ xp.shr(p, 23)
    x = x ^ xp.shr(x & w, 1)
    x = x * (xp.shr(p, 27) | 1)
    x = x * xp.u32(0x6935FA69)
    x = x ^ xp.shr(x & w, 11)
    x = x * xp.u32(0x74DCB303)
    x = x ^ xp.shr(x & w, 2)
    x = x * xp.u32(0x9E501CC3)
    x = x ^ xp.shr(x & w, 2)
    x = (x * xp.u32(0xC860A3DF)) & w
    return x ^ xp.shr(x, 5)


def permuted(xp, i, n, p):
    """Element ``i`` (UInt, < n) of the pseudo-random permutation of ``0 .. n - 1`` chosen by
    pattern ``p`` (Kensler 2013, section 3): his hash, a bijection of the k-bit words (2^k >= n),
    walked until it lands below n (cycle walking keeps it a bijection of 0 .. n - 1), then offset
    by ``p`` modulo n. ``n`` (>= 1) and ``p``: UInt arrays or scalars."""
    w = n - 1
    for s in (1, 2, 4, 8, 16):
        w = w | xp.shr(w, s)
    x = _kensler(xp, i, p, w)
    (x,) = xp.while_loop((x,), (n, p, w), lambda x, n, p, w: ~xp.ult(x, n), lambda x, n, p, w: (_kensler(xp, x, p, w),))
    q = xp.umod(p, n)
    t = n - q  # (x + p) mod n without leaving 32 bits: x + q below n, else x - (n - q)
    return xp.select(xp.ult(x, t), x + q, x - t)


def multijitter(xp, pattern, cell, cells, m, jitter):
    """Film positions in the unit pixel of correlated multi-jittered samples
    (:func:`invrender.core.sampler.multijitter` documents the construction): sample ``cell`` of
    ``cells`` (factored ``m`` by ``cells / m``) of pattern ``pattern`` (UInt), placed in its
    sub-cell by ``jitter`` (2 Floats in [0, 1)). Returns 2 Floats in [0, 1)."""
    r = xp.udiv(cells, m)
    s = permuted(xp, cell, cells, pattern * xp.u32(0x51633E2D))
    col, row = xp.umod(s, m), xp.udiv(s, m)
    sub_col = permuted(xp, row, r, pattern * xp.u32(0x63D83595))  # distinct per row: x strata distinct
    sub_row = permuted(xp, col, m, pattern * xp.u32(0xA511E9B3))
    fm, fr = xp.float(m), xp.float(r)
    x = (xp.float(col) + (xp.float(sub_col) + jitter[0]) / fr) / fm
    y = (xp.float(row) + (xp.float(sub_row) + jitter[1]) / fm) / fr
    below = 1.0 - 2.0**-24
    return xp.minimum(x, below), xp.minimum(y, below)


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


def material_width(layout) -> int:
    """Floats per row of a material table of ``layout`` (:func:`material_rows`): the entries'
    sizes summed, rounded up to a power of two, or to a multiple of 16 above 16."""
    n = max(1, sum(_floats(size, textured) for _, size, textured in layout))
    return 1 << (n - 1).bit_length() if n <= 16 else -(-n // 16) * 16


def _floats(size: int, textured: bool) -> int:
    return 4 if textured else size


class TextureTable:
    """The textures the materials of one render read, as the compiled bounce reads them: each
    texture's texels (4 floats a texel, RGB then 0; :attr:`texels`) one after another, and a row of
    16 floats a texture (:attr:`rows`): its first texel's place, width, height, nearest filter (1.0)
    or bilinear, wrap code (:data:`~invrender.core.textures.WRAP_CODES`), ``to_uv``'s six
    coefficients (the identity where none)."""

    #: texels the table holds at most (their places are exact floats)
    LIMIT = 1 << 24
    #: the floats of a row that hold something (place, size, filter, wrap, ``to_uv``); zeros pad it to 16
    ROW_VALUES = 11

    def __init__(self):
        self._texels, self._rows, self._count = [], [], 0

    def add(self, value: torch.Tensor, sampling, graph: bool = False) -> int | None:
        """The id of texture ``value`` (h, w, 3) read by ``sampling`` (None: the default), or None
        where the table would outgrow :attr:`LIMIT`; with ``graph`` its texels keep their autograd
        graph (a differentiated normal map, read by the torch bounce), else detached."""
        from invrender.core.textures import WRAP_CODES
        from invrender.scene.textures import DEFAULT

        sampling = sampling or DEFAULT
        h, w = value.shape[0], value.shape[1]
        if self._count + h * w > self.LIMIT:
            return None
        to_uv = sampling.to_uv or (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
        self._rows.append([float(self._count), float(w), float(h), float(sampling.filter == "nearest"), WRAP_CODES[sampling.wrap], *to_uv] + [0.0] * 5)
        self._texels.append(torch.nn.functional.pad((value if graph else value.detach()).float().reshape(-1, 3).cpu(), (0, 1)))
        self._count += h * w
        return len(self._rows) - 1

    @property
    def empty(self) -> bool:
        return not self._rows

    def tables(self, device, one_as_scalars: bool = False) -> tuple:
        """(K * 16,) the textures' rows and (texels * 4,) their texels, flat float32 on ``device``;
        with ``one_as_scalars`` and one texture, its row's :data:`ROW_VALUES` as
        :class:`~invrender.core.compiled.Opaque` floats (rounded to float32) instead (:func:`texture_lookup` reads either): the same for every lane, read without
        a gather (a lane's gather of a row was 10 of the 120 ms of compiled kernels in a textured
        Cornell render), and passed as values, so its size and options change no kernel."""
        from invrender.core.compiled import Opaque

        texels = torch.cat(self._texels).reshape(-1).to(device)
        if one_as_scalars and len(self._rows) == 1:
            return tuple(Opaque(float(torch.tensor(v, dtype=torch.float32))) for v in self._rows[0][: self.ROW_VALUES]), texels
        return torch.tensor(self._rows, dtype=torch.float32).reshape(-1).to(device), texels


def material_rows(bsdf, keys, textures: TextureTable):
    """The table of ``bsdf``'s M materials' values for its lane form's ``keys``
    (:class:`~invrender.core.bsdf.LaneForm`): ``(table (M * W,) float32, layout)``, W floats a row
    (:func:`material_width`), ``layout`` the entries ``(key, size, textured)`` in row order: a
    parameter's detached value or a constant, and where some material of the type reads the key
    from a texture (added to ``textures``), four floats, the constant (RGB) or zeros then the
    texture's id (-1: none); a size-1 entry reads the first channel; a key the material derives
    from its values (:meth:`~invrender.core.bsdf.LaneBSDF.lane_rows`) of any size. None where a parameter is per vertex, a texture does not fit the table, or
    sampling reads other values than the parameters hold (a render that holds sampling fixed)."""
    layout = tuple((key, size, any(key in v and v[key].ndim == 3 for v in bsdf.values)) for key, size in keys)
    derived = {key: bsdf.lane_rows(key, True, "cpu") for key, _ in keys if key not in bsdf.params} if hasattr(bsdf, "lane_rows") else {}
    rows = []
    for m, values in enumerate(bsdf.values):
        row = []
        for key, size, textured in layout:
            texture = -1.0
            if key in values:
                v, vs = values[key], bsdf.sampling_values[m][key]
                if v.ndim not in (1, 3) or not torch.equal(v.detach(), vs):
                    return None
                if v.ndim == 3:
                    texture = textures.add(v, bsdf.texture_sampling[m].get(key))
                    if texture is None:
                        return None
                    v = torch.zeros(3)
                v = v.detach().float().reshape(-1).cpu()
            elif derived.get(key) is not None:
                v = derived[key][m].detach().float().reshape(-1).cpu()
            else:
                c = bsdf.constants[m].get(key, type(bsdf).constants[key].default)
                v = torch.tensor(c if isinstance(c, (tuple, list)) else (c,) * 3, dtype=torch.float32)
            row.append(v[:3] if textured else v[:size])
            if textured:
                row.append(torch.tensor([float(texture)]))
        row = torch.cat(row) if row else torch.zeros(0)
        rows.append(torch.nn.functional.pad(row, (0, material_width(layout) - row.shape[0])))
    return torch.stack(rows).reshape(-1).contiguous(), layout


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


def material_values(xp, table, m, layout, lookup=None):
    """``p`` of :class:`~invrender.core.bsdf.LaneForm` for lanes of materials ``m`` (UInt) from
    their table (:func:`material_rows`): key -> a Float (size 1), a 3-tuple (size 3) or a
    :class:`Row` (larger), a textured entry read through ``lookup(texture id, constant)``
    (:func:`texture_lookup`); rows are gathered only as far as the small keys reach."""
    width = material_width(layout)
    reach, at = 0, 0
    for _, size, textured in layout:
        at += _floats(size, textured)
        reach = at if size <= 3 else reach
    if width <= 16:
        flat = xp.gather_rows(table, m, width)
    else:
        chunks = width // 16
        flat = sum((xp.gather_rows(table, m * chunks + j, 16) for j in range(-(-reach // 16))), ())
    out, at = {}, 0
    for key, size, textured in layout:
        out[key] = flat[at] if size == 1 else tuple(flat[at : at + 3]) if size == 3 else Row(table, m * width + at)
        if textured:
            rgb = lookup(flat[at + 3], tuple(flat[at : at + 3]))
            out[key] = rgb[0] if size == 1 else rgb
        at += _floats(size, textured)
    return out


def texture_lookup(xp, rows, texels, uv):
    """The lookup :func:`material_values` reads textured entries with, at texture coordinates
    ``uv`` (a 2-tuple), from a :class:`TextureTable`'s ``rows`` (a table, or one texture's row of
    scalars) and ``texels``: ``(texture id, constant) -> `` the texture's filtered RGB, or the
    constant where the id is -1."""
    from invrender.core.textures import filter_lanes

    def lookup(texture, constant):
        has = texture >= 0.0
        if isinstance(rows, tuple):  # the one texture, whose texels start the table
            r, first = rows, 0
        else:
            r = xp.gather_rows(rows, xp.uint(xp.maximum(texture, 0.0)), 16)
            first = xp.uint(r[0])
        index, weight = filter_lanes(xp, uv[0], uv[1], r[2], r[1], r[3] > 0.5, r[4], r[5:11])
        rgb = None
        for i, w in zip(index, weight):
            texel = scale(xp.gather_rows(texels, first + i, 4)[:3], w)
            rgb = texel if rgb is None else add(rgb, texel)
        return select3(xp, has, rgb, constant)

    return lookup


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


def normal_rows(triangles):
    """(T * 16,) float32 each triangle's three unit vertex normals (9 floats, then zeros), made once
    per :class:`~invrender.scene.scene.Triangles`."""

    def build():
        return torch.nn.functional.pad(triangles.vertex_normal.reshape(-1, 9).float(), (0, 7)).reshape(-1).contiguous()

    return triangles.derived("lane_normals", build)


def shading_normal(xp, normals, k, b1, b2, front):
    """The interpolated vertex normals of triangles ``k`` at barycentrics (b1, b2), normalized and
    turned to the geometric side ``front`` says the ray is on (as :func:`invrender.core.surface.surface_at`)."""
    r = xp.gather_rows(normals, k, 16)
    b0 = 1.0 - b1 - b2
    v = add(add(scale(r[0:3], b0), scale(r[3:6], b1)), scale(r[6:9], b2))
    length = xp.sqrt(dot(v, v))
    side = xp.select(front, 1.0, -1.0) / xp.maximum(length, 1e-12)
    return scale(v, side)


# ---- the bounce ----------------------------------------------------------------------------------

#: floats per scene material in the material index table (:func:`invrender.core.fused.tables`):
#: its type's slot, its index among that type's materials, one-sided (1.0) or not
MATERIAL_ROW = 4


def signature(fn):
    """What a lane function computes, as a value: the function and the Python values bound to it
    (a ``functools.partial``'s), so that equal forms of two renders share one compiled recording."""
    if isinstance(fn, functools.partial):  # bound values may be lane functions too (a material's nested ones)
        return (signature(fn.func), tuple(signature(a) for a in fn.args), tuple((k, signature(v)) for k, v in sorted(fn.keywords.items())))
    if isinstance(fn, tuple):
        return tuple(signature(v) for v in fn)
    return fn


class _Static:
    """Python values that choose a kernel's code, compared and hashed by :meth:`key` (the frozen
    kernels are kept per equal static arguments: :mod:`invrender.core.compiled`)."""

    __slots__ = ()

    def key(self) -> tuple:
        """The values that decide the kernel's code (subclasses: their own)."""
        return ()

    def __eq__(self, other):
        return type(other) is type(self) and other.key() == self.key()

    def __hash__(self):
        return hash(self.key())

    def __lt__(self, other):  # never ordered by value: sorting a kernel's static arguments never reaches here
        return id(self) < id(other)


class Material(_Static):
    """The materials of one type as the bounce sees them: its lane form and which lobes it has
    (Python values: they choose the code, the same for every lane)."""

    __slots__ = ("form", "layout", "smooth", "smooth_transmission")

    def __init__(self, form, layout, smooth: bool, smooth_transmission: bool):
        self.form, self.layout, self.smooth, self.smooth_transmission = form, layout, smooth, smooth_transmission

    def key(self) -> tuple:
        f = self.form
        return (signature(f.eval), signature(f.sample), f.keys, f.world, f.tangent, self.layout, self.smooth, self.smooth_transmission)

    @property
    def textured(self) -> bool:
        return any(t for _, _, t in self.layout)


class Point:
    """The materials at N hit points, dispatched by type with masks: each type's lane functions
    run on every lane and a lane keeps its own type's answer (one type: no masks)."""

    def __init__(self, xp, types, tables, index, mat, f, wo, front, lookup, front_m=None):
        row = xp.gather_rows(index, mat, MATERIAL_ROW)
        self.xp, self.types, self.frame, self.wo = xp, types, f, wo
        self.front = front if front_m is None else front_m  # the side the materials see (a perturbed normal's)
        slot, local = xp.uint(row[0]), xp.uint(row[1])
        self.lit = ~((row[2] > 0.5) & ~front)  # a one-sided material is black from behind
        self.mine = [slot == k for k in range(len(types))] if len(types) > 1 else [None]
        self.p = [material_values(xp, table, local if m is None else xp.select(m, local, 0), kind.layout, lookup) for table, m, kind in zip(tables, self.mine, types)]

    def _merge(self, parts):
        """Each lane's own type's value of ``parts`` (per type, a tuple of arrays and 3-tuples)."""
        out = parts[0]
        for m, part in zip(self.mine[1:], parts[1:]):
            out = tuple(select3(self.xp, m, a, b) if isinstance(a, tuple) else self.xp.select(m, a, b) for a, b in zip(part, out))
        return out

    def any(self, flag: str):
        """Bool: is each lane's type one whose ``flag`` (``smooth``, ``smooth_transmission``) holds;
        True or False where every type agrees."""
        flags = [getattr(t, flag) for t in self.types]
        if all(flags) or not any(flags):
            return flags[0]
        out = None
        for m, f in zip(self.mine, flags):
            if f:
                out = m if out is None else out | m
        return out

    def eval(self, wi):
        """``f |cos|`` (3-tuple) and the pdf at local directions ``wi`` (0 behind a one-sided material)."""
        f, pdf = self._merge([t.form.eval(self.xp, p, p, self.wo, wi, self.front) for t, p in zip(self.types, self.p)])
        return scale(f, xp_lit(self.xp, self.lit)), pdf * xp_lit(self.xp, self.lit)

    def sample(self, u_lobe, u0, u1):
        """Local direction, weight (3-tuple), pdf and delta flag of one BSDF sample a lane."""
        calls = [t.form.sample(self.xp, p, p, self.wo, self.front, u_lobe, u0, u1, **({"frame": self.frame} if t.form.world else {})) for t, p in zip(self.types, self.p)]
        wi, weight, pdf, delta = self._merge(calls)
        lit = xp_lit(self.xp, self.lit)
        return wi, scale(weight, lit), pdf * lit, delta


def xp_lit(xp, lit):
    return xp.select(lit, 1.0, 0.0)


class Emitter(_Static):
    """The emitters of one type as the bounce sees them (Python values: they choose the code): its
    lane functions (:class:`~invrender.core.lights.LightLanes`), whether emitter samples pick it,
    and its kind. Its share of the uniform that picks a type and the probability hits weigh it
    with change with the emission: they are arguments (:func:`shares`)."""

    __slots__ = ("form", "sampled", "infinite", "surface")

    def __init__(self, form, sampled: bool, infinite: bool, surface: bool):
        self.form, self.sampled, self.infinite, self.surface = form, sampled, infinite, surface

    def key(self) -> tuple:
        f = self.form
        return (signature(f.sample), signature(f.escaped), signature(f.hit), f.delta, self.sampled, self.infinite, self.surface)


def shares(lights) -> tuple:
    """Per emitter type of ``lights``: ``(lo, p, choice)``, its share ``[lo, lo + p)`` of the
    uniform that picks the type of an emitter sample (p = 0: never sampled) and the probability of
    that choice as the pdfs of hits weigh it (:meth:`invrender.core.lights.Lights.share`)."""
    return tuple((*lights.share(light), lights.probability(light)) for light in lights.lights)


def sample_emitters(xp, emitters, tables, share, u0, u1, u2, x, nx, offset: float):
    """One emitter sample per lane (:meth:`invrender.core.lights.Lights.sample_from`): ``u0``
    chooses the type by its share (:func:`shares`; stretched back to [0, 1) for the type's own
    choice), then the type samples. Returns (origin, wl, tmax, Le, pdf, facing, delta, emitter):
    ``delta`` a Bool or a Python bool for every lane, ``emitter`` the scene emitter sampled (UInt)
    where the only sampled type is a surface type, else None."""
    sampled = [(e, t, s) for e, t, s in zip(emitters, tables, share) if e.sampled]
    if len(sampled) == 1:
        e, t, _ = sampled[0]
        out = e.form.sample(xp, t, u0, u1, u2, x, nx, offset)
        return out[:6] + (e.form.delta, out[6] if len(out) > 6 else None)
    merged, delta = None, False
    for i, (e, t, (lo, p, _)) in enumerate(sampled):
        ui = xp.minimum(xp.maximum((u0 - lo) / p, 0.0), 1.0 - 2.0**-24)
        origin, wl, tmax, Le, pdf, facing = e.form.sample(xp, t, ui, u1, u2, x, nx, offset)[:6]
        part = (origin, wl, tmax, Le, pdf * p, facing)
        # the lanes whose u0 falls in this type's share: the first type below the second's, the last from its own
        above = u0 >= lo if i else None
        if merged is None:
            merged = part
        else:
            merged = tuple(select3(xp, above, a, b) if isinstance(a, tuple) else xp.select(above, a, b) for a, b in zip(part, merged))
        if e.form.delta:
            mine = above if i else u0 == u0
            if i + 1 < len(sampled):
                mine = mine & (u0 < sampled[i + 1][2][0])
            delta = mine if delta is False else delta | mine
    return merged + (delta, None)


def escaped_vertex(xp, tables, share, d, beta, pdf_dir, delta, *, emitters, first: bool, mis: bool, nee_only: bool):
    """Term depth for rays ``d`` that leave the scene: ``beta w Le`` of the emitters infinitely far
    away, weighted as :func:`path_vertex` weighs emission hit (one array call: the paths' escaped
    rays). Returns the radiance (3-tuple)."""
    Le, pdf = None, None
    for e, t, (_, _, choice) in zip(emitters, tables, share):
        if e.infinite:
            Le_k, pdf_k = e.form.escaped(xp, t, d)
            Le = Le_k if Le is None else add(Le, Le_k)
            pdf = pdf_k * choice if pdf is None else pdf + pdf_k * choice
    w = xp.select(delta, 1.0, 0.0) if nee_only and not first else 1.0
    if mis and not first:
        w = xp.select(delta, 1.0, power_heuristic(xp, pdf_dir, pdf))
    return (scale(scale(beta, w), Le),)


#: the first vertex's dimensions the sampler ``"stratified_direct"`` stratifies, in pairs (of the
#: bounce's 7, :func:`path_vertex`'s salts): the BSDF sample's direction and the emitter sample's
#: position, the 2-D integrals of the light the first vertex reflects; ``strata`` holds them in
#: the order of :data:`DIRECT_DIMS`
DIRECT_PAIRS = ((0, 1), (3, 4))
DIRECT_DIMS = tuple(d for pair in DIRECT_PAIRS for d in pair)


def _number(xp, keys, salts, strata, j: int):
    """Dimension ``j`` of a vertex's numbers: the stratified one where ``strata`` holds it, else
    the hash of the path key."""
    if strata is not None and j in DIRECT_DIMS:
        return strata[DIRECT_DIMS.index(j)]
    return uniform(xp, keys, salts[j])


def path_vertex(
    xp, tri_table, emitter_tables, share, material_index, material_tables, shading, textures, prim, b1, b2, t, d, beta, pdf_dir, delta, keys, salts, strata, offset: float, *,
    materials, emitters, first: bool, mis: bool, nee_only: bool, nee: bool, more: bool, roulette: bool, absorbing: bool, tangents: bool,
):  # fmt: skip
    """One primal bounce of N paths: the random walk's and the path tracer's vertex
    (:mod:`invrender.core.fused` documents it), every material and emitter in its lane form.

    Args:
        tri_table: (T * 16,) the triangle table (:func:`triangle_rows`); emitter_tables: per emitter
            type, its tables (:class:`~invrender.core.lights.LightLanes`); share: per emitter type,
            its (lo, p, choice) (:func:`shares`, as scalars); material_index (M * 4,)
            per scene material its type's slot, index in that type, one-sided flag
            (:data:`MATERIAL_ROW`); material_tables: per type, :func:`material_rows`;
            shading: (the vertex normals (T * 16,) (:func:`normal_rows`) or None (no shading
            normals), the UV frames' and the perturbations' tables (:func:`invrender.core.shading.tables`));
            textures: (uv table (:func:`uv_rows`), texture rows, texels) (:class:`TextureTable`), or
            None (no material reads a texture).
        prim, b1, b2, t: (N,) the paths' closest hits (all valid); d, beta: 3-tuples of (N,) the
            rays' directions and the throughputs; pdf_dir (N,) the pdf ``d`` was sampled with and
            delta (N,) Bool whether from a delta lobe (or the camera); keys (N,) UInt; salts: the
            bounce's 7 salts (0-1 BSDF direction, 2-4 emitter sample, 5 roulette, 6 BSDF lobe);
            strata: None, or 4 Floats drawn for the dimensions :data:`DIRECT_DIMS` in place of
            their hashed numbers (the first vertex of the sampler ``"stratified_direct"``).
        materials: per type a :class:`Material`; emitters: per type an :class:`Emitter`.
        first: camera rays (depth 0); mis, nee_only, nee, more, roulette: the integrator's
            strategy (:class:`invrender.core.fused.FusedScene`), whether paths go on after this
            vertex, whether roulette applies; absorbing: a BSDF weight can be zero (such paths end);
            tangents: the factors are returned (one emitter type, a surface one).
    Returns:
        emitted (term depth); with ``more``: the shadow rays' origin, direction, tmax (0 where the
        sample adds nothing whatever the parameters) and the direct light each adds if unoccluded
        (term depth + 1; zeros without ``nee``), the continued rays' origin, direction, throughput,
        pdf, delta flag and alive mask; with ``tangents``: the factors beside eps of the emission and
        of the direct light, the emitters hit and sampled (-1: none) and the materials hit.
    """
    tri = Triangle(xp, tri_table, prim)
    p, n, c = hit(xp, tri, b1, b2, d)
    front = c > 0.0
    # term depth: the emission seen, weighted against the previous vertex's emitter sample
    zero = 0.0 * c
    Le, light_pdf, seen, em = (zero, zero, zero), zero, c != c, None
    for e, table, (_, _, choice) in zip(emitters, emitter_tables, share):
        if e.surface:
            Le_k, pdf_k, seen_k, em_k = e.form.hit(xp, table, tri, front, t, xp.abs(c))
            Le, light_pdf, seen = select3(xp, seen_k, Le_k, Le), xp.select(seen_k, pdf_k * choice, light_pdf), seen | seen_k
            em = em_k if em is None else em
    if nee_only and not first:
        seen = seen & delta  # only where no emitter sample competed
    w = xp.select(seen, 1.0, 0.0)
    if mis and not first:
        w = w * xp.select(delta, 1.0, power_heuristic(xp, pdf_dir, light_pdf))
    factor_e = scale(beta, w)
    emitted = scale(factor_e, Le)
    mat = tri.material(xp)
    none = xp.u32(0xFFFFFFFF)
    tangent_out = (factor_e, xp.select(seen, em, none), mat) if tangents else ()
    if not more:
        return (emitted,) + _tangents(xp, tangent_out, None, None)
    normals, frames, perturb = shading
    ns = n if normals is None else shading_normal(xp, normals, prim, b1, b2, front)
    wo = scale(d, -1.0)
    front_m, bend = None, None
    if frames is None:
        f = frame(xp, ns)
    else:  # UV tangent frames, perturbed normals (invrender.core.shading)
        f, front_m, bend = shading_frame(xp, frames, perturb, ns, n, front, prim, b1, b2, wo, mat)
    lookup = None if textures is None else texture_lookup(xp, textures[1], textures[2], uv_at(xp, textures[0], prim, b1, b2))
    point = Point(xp, materials, material_tables, material_index, mat, f, to_local(f, wo), front, lookup, front_m)
    # term depth + 1: one emitter sample (its shadow ray is cast by the caller) where the BSDF has a smooth lobe
    smooth = point.any("smooth")
    if nee and smooth is not False:
        u0, u1, u2 = (_number(xp, keys, salts, strata, j) for j in (2, 3, 4))
        so, wl, tmax, Ll, pdf, facing, light_delta, sampled = sample_emitters(xp, emitters, emitter_tables, share, u0, u1, u2, p, n, offset)
        through = point.any("smooth_transmission")
        if through is not False:  # behind a glossy transmitter: the same sample from the other side
            sob, wlb, tmaxb, Llb, pdfb, facingb, _, sampledb = sample_emitters(xp, emitters, emitter_tables, share, u0, u1, u2, p, scale(n, -1.0), offset)
            back = ~facing if through is True else through & ~facing
            so, wl, Ll = select3(xp, back, sob, so), select3(xp, back, wlb, wl), select3(xp, back, Llb, Ll)
            tmax, facing, pdf = xp.select(back, tmaxb, tmax), xp.select(back, facingb, facing), xp.select(back, pdfb, pdf)
            sampled = None if sampled is None else xp.select(back, sampledb, sampled)
        f_cos, bsdf_pdf = point.eval(to_local(f, wl))
        if bend is not None:  # a perturbed normal's masks and shadowing term
            g, kept = bend_lanes(xp, bend, wl)
            f_cos, bsdf_pdf = scale(f_cos, g), xp.select(kept, bsdf_pdf, 0.0)
        if mis:
            mis_w = power_heuristic(xp, pdf, bsdf_pdf)
            inv = (1.0 if light_delta is True else xp.select(light_delta, 1.0, mis_w) if light_delta is not False else mis_w) / pdf
        else:
            inv = 1.0 / pdf
        ok = facing if smooth is True else facing & smooth
        weight = xp.select(ok, inv, 0.0)
        shadow_t = xp.select(ok & (xp.maximum(xp.maximum(f_cos[0], f_cos[1]), f_cos[2]) > 0.0), tmax, 0.0)
        factor_d = scale(scale(beta, weight), f_cos)
        direct = scale(factor_d, Ll)
    else:
        so, wl, shadow_t = (zero, zero, zero), (zero, zero, zero), zero
        factor_d = direct = (zero, zero, zero)
        sampled = None
    if sampled is None:
        sampled = xp.full(none, mat)
    # the BSDF sample, the new ray and Russian roulette
    wi, weight, pdf_next, delta_next = point.sample(*(_number(xp, keys, salts, strata, j) for j in (6, 0, 1)))
    wi = to_world(f, wi)
    if bend is not None:
        g, kept = bend_lanes(xp, bend, wi)
        weight, pdf_next = scale(weight, g), xp.select(kept, pdf_next, 0.0)
    o_next = spawn(xp, p, n, wi, offset)
    b = scale(beta, weight)
    alive = c == c  # every path (c is never NaN for a valid hit)
    if roulette:
        q = xp.minimum(xp.maximum(xp.maximum(b[0], b[1]), b[2]), 0.95)
        alive = uniform(xp, keys, salts[5]) < q
        b = scale(b, 1.0 / xp.maximum(q, 1e-30))
    elif absorbing:
        alive = xp.maximum(xp.maximum(b[0], b[1]), b[2]) > 0.0
    out = (emitted, so, wl, shadow_t, direct, o_next, wi, b, pdf_next, delta_next, alive)
    return out + _tangents(xp, tangent_out, factor_d, sampled)


def _tangents(xp, tangent_out, factor_d, sampled):
    """The tangent outputs in :func:`path_vertex`'s order (factor_e, hit emitter, factor_d,
    sampled emitter, material hit)."""
    if not tangent_out:
        return ()
    factor_e, hit_emitter, mat = tangent_out
    if factor_d is None:
        zero = 0.0 * factor_e[0]
        factor_d, sampled = (zero, zero, zero), xp.full(xp.u32(0xFFFFFFFF), mat)
    return (factor_e, hit_emitter, factor_d, sampled, mat)
