"""An environment map: Mitsuba 3's ``envmap`` emitter, an equirectangular (latitude-longitude) HDR
map infinitely far away.

Conventions (Mitsuba 3's src/emitters/envmap.cpp, v3.9): a world direction ``d`` is taken into the
map's frame by the inverse of ``to_world`` (a rotation, so its transpose), ``v = R^T d``, and reads
the map at

    u = atan2(v.x, -v.z) / (2 pi)   (wrapped to [0, 1)),   v' = acos(v.y) / pi

so +Y is up (row 0 of the image is the zenith, the last row the nadir), -Z is the centre column's
left edge (u = 0) and +X a quarter of the way across (u = 1/4). The lookup is bilinear: columns are
texel-centred and periodic (column j's centre at ``u = (j + 0.5) / w``, the last column blending
into the first), rows align with the poles (row i's centre at ``v' = i / (h - 1)``, clamped at
both ends). Maps smaller than 2 columns x 3 rows are padded to that size by repeating the last
column and row, as Mitsuba pads them. The radiance is ``scale x`` that lookup, a weighted sum of
four texels: differentiable in the texture (the scene parameter ``NAME.emission``).

Next-event estimation samples directions from a piecewise-constant density over the cells between
texel centres (w cells around, h - 1 from pole to pole), each proportional to the mean luminance
of its four corner texels times its mean sin(theta): no cell where the radiance is positive has
zero probability. The density, built from detached values when a render starts, is ``pdf_uv /
(2 pi^2 sin theta)`` in solid angle. Several envmaps in one scene add up; one is chosen per sample
by power. The power (for choosing between it and other emitter types) is, as for ``constant``,
``4 pi r^2`` times the map's solid-angle mean radiance, r the radius of the scene's bounding sphere.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from invrender import registry
from invrender.errors import SceneError
from invrender.scene.kinds import EMISSION
from invrender.scene.plugins import Constant, Param
from invrender.scene.scene import scene_extent
from invrender.core.lights import Light, LightSample
from invrender.validate import FLOAT32_MAX
from invrender.vec import dot

#: Mitsuba's luminance weights of linear RGB (Rec. 709)
LUMINANCE = (0.212671, 0.715160, 0.072169)
#: the smallest size Mitsuba pads a map to: (rows, columns)
MIN_ROWS, MIN_COLUMNS = 3, 2
#: the rotation's unit quaternion (w, x, y, z) as constants
QUATERNION = ("rotation_w", "rotation_x", "rotation_y", "rotation_z")
#: how far from orthonormal a to_world's 3x3 part may be
ROTATION_TOLERANCE = 1e-4


def quaternion_of(matrix, where: str) -> dict[str, float]:
    """The rotation constants (a unit quaternion) of a to_world matrix (3x3 or 4x4; a 4x4's
    translation has no effect on directions and is ignored, as in Mitsuba); a :class:`SceneError`
    naming ``where`` when its 3x3 part is not a rotation (orthonormal with determinant +1)."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape == (4, 4):
        m = m[:3, :3]
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise SceneError(f"{where}: to_world must be a 3x3 rotation or a 4x4 transform, got shape {m.shape}")
    error = float(np.abs(m @ m.T - np.eye(3)).max())
    if error > ROTATION_TOLERANCE or np.linalg.det(m) < 0:
        raise SceneError(f"{where}: to_world of an envmap must be a rotation (orthonormal, determinant +1), got {np.round(m, 4).tolist()}")
    # Shepperd's method: the largest of the four squared components first
    t = np.trace(m)
    k = int(np.argmax([t, m[0, 0], m[1, 1], m[2, 2]]))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + t)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    q = np.asarray(q) / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return {k: float(v) for k, v in zip(QUATERNION, q)}


def rotation_of(constants: dict) -> np.ndarray:
    """The (3, 3) float64 to_world rotation of an envmap's constants (its unit quaternion)."""
    w, x, y, z = (float(constants.get(k, 1.0 if k == "rotation_w" else 0.0)) for k in QUATERNION)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def padded(texture: torch.Tensor) -> torch.Tensor:
    """The map as an (h, w, 3) tensor at least 3 rows x 2 columns (an RGB value is a 1 x 1 map),
    the last column and row repeated as Mitsuba pads (differentiable: an index_select)."""
    t = texture.reshape(1, 1, 3) if texture.ndim == 1 else texture
    h, w = t.shape[0], t.shape[1]
    if w < MIN_COLUMNS:
        t = t.index_select(1, torch.arange(MIN_COLUMNS, device=t.device).clamp_max(w - 1))
    if h < MIN_ROWS:
        t = t.index_select(0, torch.arange(MIN_ROWS, device=t.device).clamp_max(h - 1))
    return t


def direction_to_uv(v: torch.Tensor) -> torch.Tensor:
    """(N, 2) Mitsuba's latitude-longitude coordinates of local directions ``v`` (N, 3): u wrapped
    to [0, 1), v' = theta / pi in [0, 1]."""
    u = torch.atan2(v[:, 0] + 0.0, 0.0 - v[:, 2]) * (0.5 / math.pi)  # +0.0: no signed zeros, as Dr.Jit at the poles
    u = u - torch.floor(u)
    w = torch.acos(v[:, 1].clamp(-1.0, 1.0)) * (1.0 / math.pi)
    return torch.stack([u, w], dim=1)


def uv_to_direction(uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(local directions (N, 3), sin theta (N,)) of latitude-longitude coordinates ``uv`` (N, 2)."""
    theta, phi = uv[:, 1] * math.pi, uv[:, 0] * (2.0 * math.pi)
    st, ct = torch.sin(theta), torch.cos(theta)
    return torch.stack([torch.sin(phi) * st, ct, -torch.cos(phi) * st], dim=1), st


def texel_filter(h: int, w: int, uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Mitsuba's bilinear filter of an h x w map at ``uv`` (N, 2): texel indices (N, 4) int64 into
    the flattened (h * w) texels and their weights (N, 4) (never differentiable). Columns periodic
    with centres at (j + 0.5) / w; rows clamped with centres at i / (h - 1)."""
    x = uv[:, 0].detach() * w - 0.5
    y = uv[:, 1].detach().clamp(0.0, 1.0) * (h - 1)
    x0 = torch.floor(x)
    y0 = torch.floor(y).clamp(0, h - 1)
    fx, fy = x - x0, y - y0
    j0 = x0.long().remainder(w)
    j1 = (j0 + 1).remainder(w)
    i0 = y0.long()
    i1 = (i0 + 1).clamp_max(h - 1)
    index = torch.stack([i0 * w + j0, i0 * w + j1, i1 * w + j0, i1 * w + j1], dim=1)
    weight = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], dim=1)
    return index, weight


def texel_solid_angles(h: int, w: int) -> torch.Tensor:
    """(h w,) float64: the integral over the sphere of each texel's bilinear hat (its weight in the
    envmap's lookup), so ``sum(weights * texels)`` is the exact integral of the bilinear map; they
    add up to 4 pi."""
    theta = torch.arange(h, dtype=torch.float64) * (math.pi / (h - 1))
    weights = torch.zeros(h, dtype=torch.float64)
    for i in range(h):
        if i > 0:  # rising from theta_{i-1}: int (t - a) / (b - a) sin t dt
            a, b = float(theta[i - 1]), float(theta[i])
            weights[i] += (-(b - a) * math.cos(b) + math.sin(b) - math.sin(a)) / (b - a)
        if i < h - 1:  # falling to theta_{i+1}: int (c - t) / (c - b) sin t dt
            b, c = float(theta[i]), float(theta[i + 1])
            weights[i] += ((c - b) * math.cos(b) + math.sin(b) - math.sin(c)) / (c - b)
    return (weights * (2.0 * math.pi / w))[:, None].expand(h, w).reshape(-1).clone()


class Distribution:
    """The detached sampling density of one map (h x w after padding): piecewise constant over the
    w x (h - 1) cells between texel centres, cell (i, j) spanning ``u in [(j + 0.5) / w, (j + 1.5)
    / w)`` (wrapping) and ``v' in [i / (h - 1), (i + 1) / (h - 1)]``, with weight the mean luminance
    of its four corner texels times the cell's mean sin(theta) (``sin_weighted=False``: without it,
    a deliberately poor density for the tests of the sampling checks)."""

    def __init__(self, texture: torch.Tensor, sin_weighted: bool = True):
        t = texture.detach().to(torch.float64)
        h, w = t.shape[0], t.shape[1]
        self.h, self.w = h, w
        lum = t @ torch.tensor(LUMINANCE, dtype=torch.float64, device=t.device)  # (h, w)
        right = torch.roll(lum, -1, dims=1)  # column j + 1 (wrapping)
        corners = 0.25 * (lum[:-1] + right[:-1] + lum[1:] + right[1:])  # (h - 1, w)
        theta = torch.arange(h, dtype=torch.float64, device=t.device) * (math.pi / (h - 1))
        band = (torch.cos(theta[:-1]) - torch.cos(theta[1:])) / (math.pi / (h - 1))  # mean sin over each row of cells
        weight = corners * band[:, None] if sin_weighted else corners
        self.total = float(weight.sum())
        #: the map's solid-angle mean radiance (mean of RGB), for the power
        rgb = t.mean(2)
        rgb_cells = 0.25 * (rgb[:-1] + torch.roll(rgb, -1, 1)[:-1] + rgb[1:] + torch.roll(rgb, -1, 1)[1:])
        solid = (torch.cos(theta[:-1]) - torch.cos(theta[1:]))[:, None] * (2.0 * math.pi / w)
        self.mean = float((rgb_cells * solid).sum()) / (4.0 * math.pi)
        cells = (h - 1) * w
        if self.total > 0:
            p = weight / self.total
            #: (h - 1, w) density over the unit uv square of each cell
            self.pdf_uv = (p * cells).float()
            rows = p.sum(1)
            self.row_cdf = (rows.cumsum(0) / rows.sum()).float()
            self.row_p = rows.float()
            cond = p / rows.clamp_min(1e-300)[:, None]
            self.col_cdf = cond.cumsum(1).float()
            self.col_cdf[:, -1] = 1.0
            self.col_p = cond.float()
        else:
            self.pdf_uv = torch.zeros(h - 1, w, dtype=torch.float32, device=t.device)

    def sample(self, u1: torch.Tensor, u2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(uv (N, 2), pdf_uv (N,)) from uniforms ``u1``, ``u2`` (N,): the row of cells by ``u1``,
        the cell in it by ``u2``, the point in the cell by what is left of each."""
        h, w = self.h, self.w
        i = torch.searchsorted(self.row_cdf, u1.contiguous(), right=True).clamp_max(h - 2)
        lo = torch.where(i > 0, self.row_cdf.index_select(0, (i - 1).clamp_min(0)), 0.0)
        pi = self.row_p.index_select(0, i)
        fv = ((u1 - lo) / pi.clamp_min(1e-30)).clamp(0.0, 1.0 - 2**-24)
        cdf = self.col_cdf.index_select(0, i)  # (N, w)
        j = torch.searchsorted(cdf, u2.contiguous()[:, None], right=True)[:, 0].clamp_max(w - 1)
        lo = torch.where(j > 0, cdf.gather(1, (j - 1).clamp_min(0)[:, None])[:, 0], 0.0)
        pj = self.col_p.index_select(0, i).gather(1, j[:, None])[:, 0]
        fu = ((u2 - lo) / pj.clamp_min(1e-30)).clamp(0.0, 1.0 - 2**-24)
        u = (j.to(u2.dtype) + 0.5 + fu) / w
        uv = torch.stack([u - torch.floor(u), (i.to(u1.dtype) + fv) / (h - 1)], dim=1)
        return uv, self.pdf_uv[i, j]

    def density(self, uv: torch.Tensor) -> torch.Tensor:
        """pdf_uv (N,) of the cells holding ``uv`` (N, 2)."""
        x = uv[:, 0] * self.w - 0.5
        j = torch.floor(x).long().remainder(self.w)
        i = (uv[:, 1] * (self.h - 1)).floor().long().clamp(0, self.h - 2)
        return self.pdf_uv[i, j]


@registry.EMITTERS.register
class Envmap(Light):
    type_name = "envmap"
    params = {"emission": Param(EMISSION, 1.0)}
    constants = {
        "scale": Constant(1.0, 0.0, math.inf, low_open=True, high_open=True),
        **{k: Constant(1.0 if k == "rotation_w" else 0.0, -1.0, 1.0, low_open=False) for k in QUATERNION},
    }
    doc = (
        "an equirectangular HDR environment map (Mitsuba's envmap: +Y up, bilinear), times `scale`, "
        "rotated by `to_world` (stored as the unit quaternion `rotation_*`)"
    )
    surface = False
    infinite = True
    texel_lookup = True

    def __init__(self, emitters, values, constants, triangles, sampling=None):
        super().__init__(emitters, values, constants, triangles, sampling)
        device = triangles.p0.device
        self.scale = [float(c.get("scale", 1.0)) for c in constants]
        #: per emitter, its to_world rotation (3, 3) float32 on the render device
        self.R = [torch.tensor(rotation_of(c), dtype=torch.float32, device=device) for c in constants]
        self.dist = [Distribution(padded(v["emission"])) for v in self.sampling]
        weights = [d.total * s for d, s in zip(self.dist, self.scale)]
        total = sum(weights)
        #: per emitter, the probability of being chosen for a sample
        self.choice = [wk / total if total > 0 else 0.0 for wk in weights]
        self._cdf = torch.tensor(self.choice, dtype=torch.float64).cumsum(0).float().to(device)

    @property
    def power(self) -> float:
        radius = 0.5 * math.sqrt(3.0) * scene_extent(self.triangles)  # the bounding box's sphere
        return 4.0 * math.pi * radius * radius * sum(d.mean * s for d, s in zip(self.dist, self.scale))

    def _lookup(self, k: int, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Emitter k's bilinear filter towards local directions ``v`` (N, 3): indices (N, 4) into
        its own (unpadded, flattened h * w) texels and their weights (N, 4). A padded map's extra
        row or column repeats the last one, so its indices fold back onto that one."""
        e = self.values[k]["emission"]
        h, w = (1, 1) if e.ndim == 1 else (e.shape[0], e.shape[1])
        hp, wp = max(h, MIN_ROWS), max(w, MIN_COLUMNS)
        index, weight = texel_filter(hp, wp, direction_to_uv(v))
        if (hp, wp) != (h, w):
            index = (index // wp).clamp_max(h - 1) * w + (index % wp).clamp_max(w - 1)
        return index, weight

    def texels(self, k: int, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Which texels of emitter k's map the radiance along world directions ``d`` (N, 3) reads:
        (indices (N, 4) into the flattened h * w texels, bilinear weights (N, 4)); the radiance is
        ``scale * sum_j weight_j * texel_j``, linear in the map (path records use it)."""
        return self._lookup(k, d.detach() @ self.R[k])

    def _radiance(self, k: int, v: torch.Tensor) -> torch.Tensor:
        """(N, 3) emitter k's radiance towards local directions ``v`` (differentiable in the map)."""
        e = self.values[k]["emission"]
        index, weight = self._lookup(k, v)
        texels = e.reshape(-1, 3)[index]
        return (texels * weight[:, :, None].to(texels.dtype)).sum(1) * self.scale[k]

    def escaped(self, d: torch.Tensor) -> torch.Tensor:
        out = None
        for k, R in enumerate(self.R):
            part = self._radiance(k, d @ R)  # R^T d, row-wise
            out = part if out is None else out + part
        return out

    def _pdf(self, k: int, v: torch.Tensor) -> torch.Tensor:
        sin_theta = (v[:, 0] * v[:, 0] + v[:, 2] * v[:, 2]).sqrt().clamp_min(1e-7)
        return self.dist[k].density(direction_to_uv(v)) / (2.0 * math.pi * math.pi * sin_theta)

    def pdf_escaped(self, d: torch.Tensor) -> torch.Tensor:
        d = d.detach()
        out = d.new_zeros(d.shape[0])
        for k, R in enumerate(self.R):
            if self.choice[k] > 0:
                out = out + self.choice[k] * self._pdf(k, d @ R)
        return out

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """Directions by the maps' densities: ``u[:, 0]`` picks the map (when there are several),
        ``u[:, 1:3]`` the direction."""
        n = x.shape[0]
        k = torch.searchsorted(self._cdf, u[:, 0].contiguous(), right=True).clamp_max(len(self.R) - 1)
        wl = x.new_zeros(n, 3)
        for e, R in enumerate(self.R):
            index = (k == e).nonzero()[:, 0] if len(self.R) > 1 else None
            if self.choice[e] <= 0 or (index is not None and not index.numel()):
                continue
            ui = u if index is None else u.index_select(0, index)
            uv, _ = self.dist[e].sample(ui[:, 1].detach(), ui[:, 2].detach())
            local, _ = uv_to_direction(uv)
            world = local @ R.T
            wl = world if index is None else wl.index_put((index,), world)
        wl = wl / wl.norm(dim=1, keepdim=True).clamp_min(1e-12)
        pdf = self.pdf_escaped(wl)
        Le = self.escaped(wl)
        return LightSample(x + offset * nx, wl, torch.full((n,), math.inf, device=x.device), (dot(nx, wl) > 0) & (pdf > 0), pdf, Le)

    # ---- checks and the formats' aliases

    @classmethod
    def resolve(cls, where: str, values: dict, constants: dict, given: set) -> dict:
        """One-line errors naming ``where`` for an all-zero map and a rotation that is not a unit
        quaternion (the scene's checks already refuse empty, non-finite and negative maps)."""
        e = values.get("emission")
        if e is not None:
            t = torch.as_tensor(e, dtype=torch.float32) if not isinstance(e, torch.Tensor) else e.detach()
            if t.numel() and bool(torch.isfinite(t).all()) and float(t.abs().max()) == 0.0:
                raise SceneError(f"{where}: the envmap's emission is zero everywhere (an all-black map lights nothing; remove the emitter)")
            brightest = float(t.abs().max()) if t.numel() and bool(torch.isfinite(t).all()) else 0.0
            scale = float(constants.get("scale", 1.0))
            if brightest * scale > FLOAT32_MAX:
                raise SceneError(f"{where}: 'scale' {scale:g} times the map's brightest texel {brightest:g} is beyond float32's range "
                                 f"(|x| <= {FLOAT32_MAX:.4g}): the radiance would be infinite")
        q = [float(constants.get(k, 0.0)) for k in QUATERNION]
        if abs(math.sqrt(sum(c * c for c in q)) - 1.0) > ROTATION_TOLERANCE:
            raise SceneError(f"{where}: rotation_w, rotation_x, rotation_y, rotation_z must be a unit quaternion, got {q}")
        return constants

    #: the key of the TOML table holding a rotation as a list of transform steps
    toml_transform = "to_world"

    @classmethod
    def from_transform(cls, matrix, where: str) -> dict:
        """The constants of a to_world matrix (4, 4) (the rotation; an error for anything else)."""
        return quaternion_of(matrix, where)

    #: the Mitsuba emitter plugins it reads (a child of <scene>)
    mitsuba_plugins = ("envmap",)

    @classmethod
    def from_mitsuba(cls, emitter) -> dict:
        """Mitsuba's ``envmap``: ``filename`` (EXR or Radiance .hdr: linear RGB), ``scale``
        (float > 0, default 1), ``to_world`` (a rotation; a translation is ignored)."""
        from invrender.errors import InvRenderError
        from invrender.scene.formats.values import one_line
        from invrender.io import read_image

        path = emitter.filename("filename")
        try:
            texture = read_image(path)
        except InvRenderError as e:
            raise emitter.error("filename", one_line(e)) from None
        scale = emitter.number("scale", cls.constants["scale"], "the radiance's scale factor")
        try:
            rotation = quaternion_of(emitter.transform("to_world"), f"{path.name}")
        except SceneError as e:
            raise emitter.error("to_world", str(e)) from None
        emitter.finish(("filename", "scale", "to_world"))
        t = texture.detach()
        if t.ndim == 3 and t.numel() and bool(torch.isfinite(t).all()) and float(t.abs().max()) == 0.0:
            raise emitter.error("filename", f"{path}: the map is zero everywhere")
        return {"emission": texture, "scale": scale, **rotation}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        """``bitmap`` is the map (bench/mitsuba_ref.py makes it an ``mi.Bitmap``); ``to_world`` a
        4x4 nested list."""
        m = np.eye(4)
        m[:3, :3] = rotation_of(constants)
        e = values["emission"]
        return {"type": "envmap", "bitmap": e.reshape(1, 1, 3) if e.ndim == 1 else e, "scale": float(constants.get("scale", 1.0)), "to_world": m.tolist()}
