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

Written once (:class:`~invrender.core.lights.LightLanes`): the lookup (the latitude-longitude
coordinates, the bilinear filter's texels and weights), the density and the sampling of directions
are lane functions (:func:`envmap_sample`, :func:`envmap_escaped`) reading flat tables made once per
instance (:attr:`Envmap.lane_tables`); the torch methods evaluate them
(:func:`invrender.core.compiled.run`) and keep only the radiance, a weighted sum of the
differentiable texels, in torch.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from invrender import registry
from invrender.errors import SceneError
from invrender.scene.kinds import EMISSION
from invrender.scene.plugins import Constant, Param
from invrender.scene.scene import scene_extent
from invrender.core import compiled, lanes
from invrender.core.compiled import TORCH
from invrender.core.lights import Light, LightLanes, LightSample
from invrender.validate import FLOAT32_MAX

#: Mitsuba's luminance weights of linear RGB (Rec. 709)
LUMINANCE = (0.212671, 0.715160, 0.072169)
#: the smallest size Mitsuba pads a map to: (rows, columns)
MIN_ROWS, MIN_COLUMNS = 3, 2
#: the rotation's unit quaternion (w, x, y, z) as constants
QUATERNION = ("rotation_w", "rotation_x", "rotation_y", "rotation_z")
#: how far from orthonormal a to_world's 3x3 part may be
ROTATION_TOLERANCE = 1e-4
#: floats per map in the lanes' map table (:attr:`Envmap.lane_tables`): to_world (9, row-major),
#: scale, the probability of choosing the map, the padded map's rows and columns, its first texel
#: block, its density's rows and columns (:class:`Distribution`)
MAP_ROW = 16
#: a map's texels and density cells start at a multiple of this many rows of their tables, so
#: that their places (in blocks) are exact floats however large the maps
BLOCK = 256


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


def uv_lanes(xp, v):
    """Mitsuba's latitude-longitude coordinates ``(u, v')`` of local unit directions ``v`` (a
    3-tuple), against the array interface: u wrapped to [0, 1), v' = theta / pi in [0, 1]."""
    u = xp.atan2(v[0] + 0.0, 0.0 - v[2]) * (0.5 / math.pi)  # +0.0: no signed zeros, as Dr.Jit at the poles
    u = u - xp.floor(u)
    return u, xp.acos(xp.minimum(xp.maximum(v[1], -1.0), 1.0)) * (1.0 / math.pi)


def direction_lanes(xp, u, v):
    """(local unit direction (3-tuple), sin theta) of latitude-longitude coordinates ``(u, v')``."""
    theta, phi = v * math.pi, u * (2.0 * math.pi)
    st, ct = xp.sin(theta), xp.cos(theta)
    return (xp.sin(phi) * st, ct, -(xp.cos(phi) * st)), st


def uv_to_direction(uv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(local directions (N, 3), sin theta (N,)) of latitude-longitude coordinates ``uv`` (N, 2):
    :func:`direction_lanes` as eager torch (in ``uv``'s dtype)."""
    d, st = direction_lanes(TORCH, uv[:, 0], uv[:, 1])
    return torch.stack(d, dim=1), st


def filter_lanes(xp, h, w, u, v):
    """Mitsuba's bilinear filter of an h x w map (Floats or numbers) at ``(u, v')``, against the
    array interface: four texel indices (UInt, ``row * w + column`` into the flattened texels) and
    their weights. Columns periodic with centres at (j + 0.5) / w; rows clamped with centres at
    i / (h - 1)."""
    x = u * w - 0.5
    y = xp.minimum(xp.maximum(v, 0.0), 1.0) * (h - 1.0)
    x0 = xp.floor(x)
    y0 = xp.minimum(xp.maximum(xp.floor(y), 0.0), h - 1.0)
    fx, fy = x - x0, y - y0
    j0 = x0 - w * xp.floor(x0 / w)
    j1 = xp.select(j0 + 1.0 >= w, 0.0 * j0, j0 + 1.0)
    i1 = xp.minimum(y0 + 1.0, h - 1.0)
    wu = xp.uint(w) if not isinstance(w, (int, float)) else int(w)
    r0, r1, c0, c1 = xp.uint(y0) * wu, xp.uint(i1) * wu, xp.uint(j0), xp.uint(j1)
    return (r0 + c0, r0 + c1, r1 + c0, r1 + c1), ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy)


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
    """The detached sampling density of one map (h x w after padding), as the tables the lane
    functions sample and evaluate it by (:attr:`Envmap.lane_tables`): piecewise constant over the
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
        else:  # no light: nothing is sampled (pdf 0)
            self.pdf_uv = torch.zeros(h - 1, w, dtype=torch.float32, device=t.device)
            self.row_cdf, self.row_p = torch.zeros(h - 1, device=t.device), torch.zeros(h - 1, device=t.device)
            self.col_cdf, self.col_p = torch.zeros(h - 1, w, device=t.device), torch.zeros(h - 1, w, device=t.device)

    def bands(self) -> torch.Tensor:
        """(h - 1, 2) float32 per row of cells: its cdf entry (the rows' cumulative probabilities)
        and its probability."""
        return torch.stack([self.row_cdf, self.row_p], dim=1).float()

    def cells(self) -> torch.Tensor:
        """((h - 1) w, 4) float32 per cell, row by row: its cdf entry within its row, its
        probability given the row, its density over the unit uv square, 0."""
        return torch.stack([self.col_cdf, self.col_p, self.pdf_uv, torch.zeros_like(self.pdf_uv)], dim=2).reshape(-1, 4).float()


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
        self.device = triangles.p0.device
        self.scale = [float(c.get("scale", 1.0)) for c in constants]
        #: per emitter, its to_world rotation (3, 3) float32 on the render device
        self.R = [torch.tensor(rotation_of(c), dtype=torch.float32, device=self.device) for c in constants]
        #: per emitter, its sampling density (:class:`Distribution`, from the sampling values)
        self.dist = [Distribution(padded(v["emission"])) for v in self.sampling]
        weights = [d.total * s for d, s in zip(self.dist, self.scale)]
        total = sum(weights)
        #: per emitter, the probability of being chosen for a sample
        self.choice = [wk / total if total > 0 else 0.0 for wk in weights]
        self._cdf = torch.tensor(self.choice, dtype=torch.float64).cumsum(0).float().to(self.device)

    @property
    def power(self) -> float:
        radius = 0.5 * math.sqrt(3.0) * scene_extent(self.triangles)  # the bounding box's sphere
        return 4.0 * math.pi * radius * radius * sum(d.mean * s for d, s in zip(self.dist, self.scale))

    @functools.cached_property
    def lane_tables(self) -> tuple[torch.Tensor, ...]:
        """The flat float32 tables the lane functions read, on the render device, made once (from
        :attr:`dist` as it stands at the first query): ``(choice (K * 2,), maps (K * 16,), starts
        (K * 2,), bands, cells, texels)``:

        - choice: the maps' cdf as a light table (:func:`invrender.core.lanes.light_rows`, the
          map's index in place of a triangle's);
        - maps: per map, :data:`MAP_ROW` floats (to_world, scale, probability, the padded map's
          size, its first texel block, its density's size);
        - starts: per map, its first row of ``bands`` and its first block of ``cells``;
        - bands, cells: every map's :meth:`Distribution.bands` (2 floats a row) and
          :meth:`Distribution.cells` (4 a cell), each map's cells from a multiple of :data:`BLOCK`;
        - texels: every map's padded texels (:func:`padded`, detached ``values``; RGB then 0), each
          map's from a multiple of :data:`BLOCK`.
        """
        maps, starts, bands, cells, texels = [], [], [], [], []
        band = cell = texel = 0
        for k, d in enumerate(self.dist):
            t = padded(self.values[k]["emission"].detach()).float()
            h, w = t.shape[0], t.shape[1]
            R = [float(x) for x in self.R[k].reshape(-1).tolist()]
            maps.append(R + [self.scale[k], self.choice[k], float(h), float(w), float(texel), float(d.h), float(d.w)])
            starts.append([float(band), float(cell)])
            bands.append(d.bands().to(self.device))
            cells.append(_blocks(d.cells().to(self.device)))
            texels.append(_blocks(torch.nn.functional.pad(t.reshape(-1, 3).to(self.device), (0, 1))))
            band += bands[-1].shape[0]
            cell += cells[-1].shape[0] // BLOCK
            texel += texels[-1].shape[0] // BLOCK
        choice = lanes.light_rows(self._cdf, torch.arange(len(self.dist), device=self.device))
        flat = [torch.tensor(maps, dtype=torch.float32), torch.tensor(starts, dtype=torch.float32)]
        flat = [x.reshape(-1).to(self.device) for x in flat] + [torch.cat(x).reshape(-1).contiguous() for x in (bands, cells, texels)]
        return (choice, *flat)

    def lanes(self) -> LightLanes | None:
        """The maps in lane form: :func:`envmap_sample` and :func:`envmap_escaped` on
        :attr:`lane_tables`. It applies to every render, one that holds sampling fixed included
        (the tables hold the density of the sampling values and the texels of the values); None
        for a subclass that answers the queries by other means than the lane functions."""
        if any(getattr(type(self), m) is not getattr(Envmap, m) for m in ("sample_from", "escaped", "pdf_escaped", "_radiance")):
            return None
        return LightLanes(functools.partial(envmap_sample, **self._static), self.lane_tables, escaped=functools.partial(envmap_escaped, count=len(self.dist)))

    @property
    def _static(self) -> dict:
        """The lane functions' static arguments: how many maps, halvings over rows and columns."""
        return {"count": len(self.dist), "rows": max(d.h - 1 for d in self.dist).bit_length(), "columns": max(d.w for d in self.dist).bit_length()}

    def _filters(self, d: torch.Tensor, which: tuple[int, ...]):
        """Per map k of ``which``: the texel indices (N, 4) int64 into its padded, flattened texels
        and their weights (N, 4) along world directions ``d`` (N, 3) (:func:`envmap_filters`)."""
        out = compiled.run(envmap_filters, self.device, self.lane_tables[1], d.detach().float(), which=which)
        return [(torch.stack(out[8 * i : 8 * i + 4], dim=1).long(), torch.stack(out[8 * i + 4 : 8 * i + 8], dim=1)) for i in range(len(which))]

    def texels(self, k: int, d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Which texels of emitter k's map the radiance along world directions ``d`` (N, 3) reads:
        (indices (N, 4) into the flattened h * w texels, bilinear weights (N, 4)); the radiance is
        ``scale * sum_j weight_j * texel_j``, linear in the map (path records use it). A padded
        map's extra row or column repeats the last one, so its indices fold back onto that one."""
        (index, weight), = self._filters(d, (k,))
        e = self.values[k]["emission"]
        h, w = (1, 1) if e.ndim == 1 else (e.shape[0], e.shape[1])
        wp = max(w, MIN_COLUMNS)
        if (max(h, MIN_ROWS), wp) != (h, w):
            index = (index // wp).clamp_max(h - 1) * w + (index % wp).clamp_max(w - 1)
        return index, weight

    def _radiance(self, filters) -> torch.Tensor:
        """(N, 3) the maps' radiance read by ``filters`` (:meth:`_filters` of every map):
        differentiable in the maps."""
        out = None
        for k, (index, weight) in enumerate(filters):
            texels = padded(self.values[k]["emission"]).reshape(-1, 3)[index]
            part = (texels * weight[:, :, None].to(texels.dtype)).sum(1) * self.scale[k]
            out = part if out is None else out + part
        return out

    def escaped(self, d: torch.Tensor) -> torch.Tensor:
        return self._radiance(self._filters(d, tuple(range(len(self.dist)))))

    def pdf_escaped(self, d: torch.Tensor) -> torch.Tensor:
        """The maps' :func:`envmap_density` weighted by their probabilities (compiled where Dr.Jit runs)."""
        t = self.lane_tables
        (pdf,) = compiled.run(_pdf, self.device, t[1], t[2], t[4], d.detach().float(), count=len(self.dist))
        return pdf

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """Directions by the maps' densities: ``u[:, 0]`` picks the map (when there are several),
        ``u[:, 1:3]`` the direction (:func:`envmap_directions`, compiled where Dr.Jit runs); the
        radiance in torch from the texels and weights the lanes read."""
        maps = len(self.dist)
        u = u.detach().float()
        x, nx = x.detach().float(), nx.detach().float()
        o, wl, tmax, pdf, facing, *filters = compiled.run(_sample_filters, self.device, self.lane_tables, u[:, 0], u[:, 1], u[:, 2], x, nx, float(offset), **self._static)
        Le = self._radiance([(torch.stack(filters[8 * k : 8 * k + 4], dim=1).long(), torch.stack(filters[8 * k + 4 : 8 * k + 8], dim=1)) for k in range(maps)])
        return LightSample(o, wl, tmax, facing, pdf, Le)

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


def _blocks(rows: torch.Tensor) -> torch.Tensor:
    """``rows`` (n, c) padded with zero rows to a multiple of :data:`BLOCK` rows."""
    return torch.nn.functional.pad(rows, (0, 0, 0, -rows.shape[0] % BLOCK))


# ---- the lane functions: one map's lookup, the density, the sampling of directions --------------


def _local(r, d):
    """``R^T d``: world directions ``d`` into the frame of the map of row ``r`` (to_world R row-major)."""
    return tuple(r[b] * d[0] + r[3 + b] * d[1] + r[6 + b] * d[2] for b in range(3))


def _map(xp, maps, k: int, d):
    """Map ``k``'s row (read for every lane) and the coordinates ``(u, v')`` of world directions ``d``
    in it, with the local direction."""
    r = xp.gather_rows(maps, xp.full(k, d[0]), MAP_ROW)
    v = _local(r, d)
    u, w = uv_lanes(xp, v)
    return r, v, u, w


def envmap_filters(xp, maps, d, *, which: tuple[int, ...]):
    """For each map k of ``which`` (indices into the map table ``maps``), the bilinear filter along
    world directions ``d`` (:func:`filter_lanes`): four texel indices (UInt, into the map's padded,
    flattened texels) then their four weights."""
    out = ()
    for k in which:
        r, _, u, w = _map(xp, maps, k, d)
        index, weight = filter_lanes(xp, r[11], r[12], u, w)
        out += index + weight
    return out


def envmap_density(xp, r, starts, cells, v, u, w):
    """The solid-angle density ``pdf_uv / (2 pi^2 sin theta)`` of the map of row ``r`` at local
    directions ``v`` of coordinates ``(u, v')``, its probability not included."""
    h, wd = r[14], r[15]
    x = u * wd - 0.5
    j = xp.floor(x)
    j = j - wd * xp.floor(j / wd)
    i = xp.minimum(xp.maximum(xp.floor(w * (h - 1.0)), 0.0), h - 2.0)
    first = xp.uint(starts[1]) * BLOCK
    pdf_uv = xp.gather_rows(cells, first + xp.uint(i) * xp.uint(wd) + xp.uint(j), 4)[2]
    sin_theta = xp.maximum(xp.sqrt(v[0] * v[0] + v[2] * v[2]), 1e-7)
    return pdf_uv / ((2.0 * math.pi * math.pi) * sin_theta)


def _pdf(xp, maps, starts, cells, d, *, count: int):
    """The density (probabilities included) with which :func:`envmap_directions` samples world
    directions ``d``: what :meth:`Envmap.pdf_escaped` returns."""
    return (_escaped(xp, maps, starts, cells, None, d, count, radiance=False)[1],)


def _escaped(xp, maps, starts, cells, texels, d, count: int, radiance: bool = True):
    Le, pdf = (0.0, 0.0, 0.0), 0.0
    for k in range(count):
        r, v, u, w = _map(xp, maps, k, d)
        pdf = pdf + r[10] * envmap_density(xp, r, xp.gather_rows(starts, xp.full(k, d[0]), 2), cells, v, u, w)
        if radiance:
            index, weight = filter_lanes(xp, r[11], r[12], u, w)
            first = xp.uint(r[13]) * BLOCK
            texel = [xp.gather_rows(texels, first + i, 4) for i in index]
            Le = tuple(Le[c] + (texel[0][c] * weight[0] + texel[1][c] * weight[1] + texel[2][c] * weight[2] + texel[3][c] * weight[3]) * r[9] for c in range(3))
    return Le, pdf


def envmap_escaped(xp, t, d, *, count: int):
    """:attr:`LightLanes.escaped <invrender.core.lights.LightLanes>` of the maps (``t``:
    :attr:`Envmap.lane_tables`, ``count`` maps): the radiance along world directions ``d`` (the
    maps' bilinear lookups times their scales, summed) and the density of having sampled them."""
    return _escaped(xp, t[1], t[2], t[4], t[5], d, count)


def _search(xp, table, width: int, first, count, u, steps: int):
    """The first j in [0, count) (UInt per lane) whose cdf entry, column 0 of row ``first + j`` of
    ``table`` (rows of ``width``), exceeds ``u`` (``searchsorted``, ``right=True``), clamped to
    ``count - 1``: ``steps`` masked halvings (at least the bit length of the largest count)."""
    lo, hi = xp.full(0, u), count + 0
    last = count - 1
    for _ in range(steps):
        active = lo < hi
        mid = xp.shr(lo + hi, 1)
        right = active & (xp.gather_rows(table, first + xp.minimum(mid, last), width)[0] <= u)
        lo = xp.select(right, mid + 1, lo)
        hi = xp.select(active & ~right, mid, hi)
    return xp.minimum(lo, last)


def _stretched(xp, table, width: int, first, i, u):
    """``u`` stretched back to [0, 1) within entry ``i`` (column 0 the cdf, column 1 the
    probability) of rows ``first + ...`` of ``table``, and entry i's row."""
    before = xp.gather_rows(table, first + xp.maximum(i, 1) - 1, width)[0]
    lo = xp.select(i > 0, before, 0.0 * u)
    row = xp.gather_rows(table, first + i, width)
    return xp.minimum(xp.maximum((u - lo) / xp.maximum(row[1], 1e-30), 0.0), 1.0 - 2.0**-24), row


def envmap_directions(xp, t, u0, u1, u2, *, count: int, rows: int, columns: int):
    """World directions sampled by the maps' densities, written once against the array interface:
    the map by ``u0`` through the choice's cdf (:func:`invrender.core.lanes.pick_light`), the row of
    cells by ``u1``, the cell in it by ``u2`` (``rows``, ``columns`` masked halvings), the point in
    the cell by what is left of each; returned unit length (a 3-tuple)."""
    choice, maps, starts, bands, cells = t[:5]
    k = lanes.pick_light(xp, choice, count, u0)
    r = xp.gather_rows(maps, k, MAP_ROW)
    start = xp.gather_rows(starts, k, 2)
    h, w = r[14], r[15]
    band, wu = xp.uint(start[0]), xp.uint(w)
    i = _search(xp, bands, 2, band, xp.uint(h) - 1, u1, rows)
    fv, _ = _stretched(xp, bands, 2, band, i, u1)
    first = xp.uint(start[1]) * BLOCK + i * wu
    j = _search(xp, cells, 4, first, wu, u2, columns)
    fu, _ = _stretched(xp, cells, 4, first, j, u2)
    u = (xp.bits24(j) + 0.5 + fu) / w
    local, _ = direction_lanes(xp, u - xp.floor(u), (xp.bits24(i) + fv) / (h - 1.0))
    world = tuple(r[3 * a] * local[0] + r[3 * a + 1] * local[1] + r[3 * a + 2] * local[2] for a in range(3))
    n = xp.maximum(xp.sqrt(lanes.dot(world, world)), 1e-12)
    return (world[0] / n, world[1] / n, world[2] / n)


def envmap_sample(xp, t, u0, u1, u2, x, nx, offset: float, *, count: int, rows: int, columns: int):
    """:attr:`LightLanes.sample <invrender.core.lights.LightLanes>` of the maps (``t``:
    :attr:`Envmap.lane_tables`): directions by :func:`envmap_directions`, their radiance and density
    by :func:`envmap_escaped`, shadow rays without end. Returns (origin, wl, tmax, Le, pdf, facing)."""
    wl = envmap_directions(xp, t, u0, u1, u2, count=count, rows=rows, columns=columns)
    Le, pdf = envmap_escaped(xp, t, wl, count=count)
    facing = (lanes.dot(nx, wl) > 0.0) & (pdf > 0.0)
    return lanes.add(x, lanes.scale(nx, offset)), wl, xp.full(math.inf, u0), Le, pdf, facing


def _sample_filters(xp, t, u0, u1, u2, x, nx, offset: float, *, count: int, rows: int, columns: int):
    """:meth:`Envmap.sample_from`'s detached part: (origin, wl, tmax, pdf, facing), then every map's
    filter along wl (:func:`envmap_filters`) for the radiance in torch."""
    wl = envmap_directions(xp, t, u0, u1, u2, count=count, rows=rows, columns=columns)
    _, pdf = _escaped(xp, t[1], t[2], t[4], None, wl, count, radiance=False)
    facing = (lanes.dot(nx, wl) > 0.0) & (pdf > 0.0)
    out = (lanes.add(x, lanes.scale(nx, offset)), wl, xp.full(math.inf, u0), pdf, facing)
    return out + envmap_filters(xp, t[1], wl, which=tuple(range(count)))
