"""Area lights: emissive triangles, Mitsuba's ``area`` emitter.

The shapes that name an area emitter emit radiance eps (an RGB triple or an (h, w, 3) texture over
their UVs) from their front side (counter-clockwise winding), uniformly in direction. Next-event
estimation picks an emissive triangle with probability proportional to ``area x mean(eps)`` (eps read
without gradient when the render starts), then a point uniformly on it, so no pdf depends on the
differentiable eps (docs/architecture.md#detached-sampling-differentiable-evaluation). The points'
shadow rays and solid-angle pdfs are :func:`triangle_lanes`, written once against the array
interface (:mod:`invrender.core.lanes`) and compiled where Dr.Jit runs; the fused bounce calls the
same function.

**Spheres by solid angle.** The triangles of an emitting sphere (a mesh inscribed in an analytic
sphere, :attr:`Triangles.sphere <invrender.scene.scene.Triangles>`, with a constant eps) form the
*sphere group*, picked with probability ``P_group`` (their share of ``area x mean(eps)``); the rest
form the triangle group, sampled as above. Within the sphere group the sphere k is chosen per
shadow-ray origin ``o``, with probability ``q_k(o)`` proportional to ``mean(eps_k) (1 - cos
theta_max,k)`` (its radiance times the solid angle of its cone; ``1`` from near it), so that a large
far light does not take the samples of small near ones (by power alone above :data:`MAX_CHOICE`
spheres). From a distance ``d > (1 + NEAR) r`` the direction is then uniform in the cone the
analytic sphere subtends (``sin theta_max = r / d``), solid-angle pdf ``P_group q_k / (2 pi (1 -
cos theta_max))``, and the shadow ray ends at the analytic sphere's first intersection, which it
reaches before the inscribed mesh; from nearer (or inside) a point uniformly on the sphere's mesh
by area. :meth:`Area.pdf_hit` gives a BSDF ray's hit on the mesh the same density, by the same
choice and test at its origin. Everything is read from detached values when the render starts.
The mesh being inscribed, the cone is a little wider than the mesh's silhouette:
docs/sampling.md#spheres-by-solid-angle gives the radial error and what it does to an estimate.
"""

from __future__ import annotations

import functools
import torch

from dataclasses import dataclass

from invrender import registry
from invrender.scene.kinds import EMISSION
from invrender.scene.plugins import Param
from invrender.scene.scene import Triangles
from invrender.core import compiled, lanes
from invrender.core.lights import Light, LightLanes, LightSample
from invrender.core.surface import Surface
from invrender.core.textures import gather_rgb
from invrender.vec import dot, norm

#: cone sampling only from origins farther than (1 + NEAR) radii from the centre (else by area)
NEAR = 1e-2
#: the share of the uniform choice among cone spheres mixed into the choice by solid angle
UNIFORM = 0.5
#: above this many cone spheres, the sphere is chosen by power alone (not per origin)
MAX_CHOICE = 16


@dataclass(frozen=True)
class AreaSample:
    """N points sampled on emissive triangles as seen from N surface points x.

    Attributes:
        tri: (N,) int64 emitter triangle of each point.
        uv: (N, 2) texture coordinates at the points (zeros when no emission is textured).
        o: (N, 3) shadow-ray origins, x offset off its surface along its geometric normal.
        wl: (N, 3) unit directions from ``o`` to the points.
        tmax: (N,) distance from ``o`` to the point minus the offset (where the shadow ray stops).
        facing: (N,) bool: the point lies in front of x's geometric normal and x in front of the
            emitter (its emitting side).
        pdf: (N,) solid-angle density at ``o`` of having sampled the point.
    """

    tri: torch.Tensor
    uv: torch.Tensor
    o: torch.Tensor
    wl: torch.Tensor
    tmax: torch.Tensor
    facing: torch.Tensor
    pdf: torch.Tensor


@registry.EMITTERS.register
class Area(Light):
    type_name = "area"
    params = {"emission": Param(EMISSION, 1.0)}
    doc = "emissive shapes: radiance eps from their front side (RGB or texture)"
    surface = True

    def __init__(self, emitters: list[int], values: list[dict[str, torch.Tensor]], constants: list[dict[str, float]], triangles: Triangles, sampling=None):
        super().__init__(emitters, values, constants, triangles, sampling)
        device = triangles.area.device
        eps = [v["emission"] for v in values]
        #: does any emission vary over UVs (else samples skip their texture coordinates)?
        self.textured = any(e.ndim == 3 for e in eps)
        #: per scene emitter, its eps (zero for emitters of other types), indexed by triangles.emitter
        count = max(emitters) + 1
        self.eps: list[torch.Tensor] = [torch.zeros(3, device=device)] * count
        for e, value in zip(emitters, eps):
            self.eps[e] = value
        power = torch.zeros(count + 1, device=device)  # the last entry: emitter -1 (and other types) -> 0
        power[torch.tensor(emitters, device=device)] = torch.tensor([float(v["emission"].mean()) for v in self.sampling], device=device)
        emitter = torch.where(triangles.emitter < count, triangles.emitter, -1)
        weight = triangles.area * power[emitter]
        self.total = float(weight.sum())
        #: (T,) bool: the triangles that emit (of this type)
        self._emitting = torch.isin(triangles.emitter, torch.tensor(emitters, device=device))
        cone = self._spheres(weight, emitter, power)
        # the triangle group: every emitting triangle not standing for a cone-sampled sphere
        tri_weight = torch.where(cone, 0.0, weight)
        self.tri = torch.nonzero(tri_weight > 0)[:, 0]
        self.count = int(self.tri.numel())
        #: (T,) pdf per unit area of the point sampler on each triangle of the triangle group (0 elsewhere)
        self.pdf_area = torch.where(tri_weight > 0, tri_weight / max(self.total, 1e-30) / triangles.area, 0.0)
        cdf = torch.cumsum(tri_weight[self.tri].double(), 0)
        self.cdf = (cdf / cdf[-1]).float() if self.count else cdf.float()

    #: the attributes :meth:`_spheres` sets (kept with the geometry, per emitter powers)
    _SPHERE_TABLES = ("spheres", "rank", "center", "radius", "sphere_area", "cone_tri", "cone_rank", "cone_cdf", "sphere_first", "sphere_last", "sphere_tri", "_cone")

    def _spheres(self, weight: torch.Tensor, emitter: torch.Tensor, power: torch.Tensor) -> torch.Tensor:
        """The tables of the sphere group (module docstring); returns (T,) bool, the triangles of
        cone-sampled spheres. What depends on the geometry alone is built once per geometry and
        set of emitting spheres (renders of one scene, and every step of a fit, share it); the
        powers are read each time."""
        textured = tuple(e.ndim == 3 for e in self.eps)
        key = ("area.spheres", tuple(self.emitters), tuple((power > 0).tolist()), textured)
        tables = self.triangles.derived(key, lambda: self._sphere_tables(weight, emitter, textured))
        for name in self._SPHERE_TABLES:
            setattr(self, name, tables[name])
        #: per cone sphere (S,) float64: power (area x mean eps) and mean eps; the sphere group's probability
        self.sphere_power = torch.zeros(self.spheres, dtype=torch.float64, device=weight.device).index_add_(0, self.cone_rank, weight[self.cone_tri].double())
        self.sphere_eps = self.sphere_power / self.sphere_area.clamp_min(1e-300)
        self.group = float(self.sphere_power.sum()) / max(self.total, 1e-30) if self.spheres else 0.0
        return self._cone

    def _sphere_tables(self, weight: torch.Tensor, emitter: torch.Tensor, textured: tuple) -> dict:
        tris = self.triangles
        device = weight.device
        flat = torch.tensor(list(textured) + [True], device=device)  # last: emitter -1
        cone = (tris.sphere >= 0) & (weight > 0) & ~flat[torch.where(emitter >= 0, emitter, len(textured))]
        # the cone spheres, as rows of tris.spheres
        ids = (torch.bincount(tris.sphere[cone], minlength=tris.spheres.shape[0]) > 0).nonzero()[:, 0]
        t = {"spheres": int(ids.numel()), "_cone": cone}  # how many spheres are cone-sampled
        # (T,) int64 rank of each triangle's cone sphere (-1: not one)
        lookup = torch.full((tris.spheres.shape[0] + 1,), -1, dtype=torch.int64, device=device)
        lookup[ids] = torch.arange(t["spheres"], device=device)
        t["rank"] = rank = torch.where(cone, lookup[torch.where(tris.sphere >= 0, tris.sphere, tris.spheres.shape[0])], -1)
        spheres = tris.spheres.index_select(0, ids).double()
        # per cone sphere (S,) float64: centre (S, 3), radius, mesh area
        t["center"], t["radius"] = spheres[:, :3], spheres[:, 3]
        members = cone.nonzero()[:, 0]
        r, perm = torch.sort(rank[members], stable=True)
        order = members[perm]
        area = tris.area[order].double()
        t["sphere_area"] = torch.zeros(t["spheres"], dtype=torch.float64, device=device).index_add_(0, r, area)
        # (M,) the cone spheres' triangles, sphere by sphere, their sphere and their cdf: sphere k's runs from k to k + 1
        t["cone_tri"], t["cone_rank"] = order, r
        cum = torch.cumsum(area, 0)
        first = torch.searchsorted(r, torch.arange(t["spheres"], device=device))
        before = torch.where(first > 0, cum.index_select(0, (first - 1).clamp_min(0)), 0.0)
        t["cone_cdf"] = r + (cum - before.index_select(0, r)) / t["sphere_area"].index_select(0, r)
        # (S,) the first and last index into cone_tri of each cone sphere; a triangle of it
        t["sphere_first"] = first
        t["sphere_last"] = torch.cat([first[1:], first.new_tensor([order.numel()])]) - 1
        t["sphere_tri"] = order.index_select(0, first)
        return t

    @property
    def power(self) -> float:
        return self.total  # sum of area x mean(eps): proportional to the power emitted

    def lanes(self) -> LightLanes | None:
        """The lane form (:func:`area_sample`, :func:`area_hit`), when no emission is textured, no
        sphere is sampled by solid angle and sampling reads the values the render evaluates; not for
        a subclass that changes what the emitter does."""
        changed = any(getattr(type(self), m) is not getattr(Area, m) for m in ("sample_from", "geometry", "radiance", "emits", "emitted", "pdf_hit", "params"))
        held = any(not torch.equal(v["emission"].detach(), s["emission"]) for v, s in zip(self.values, self.sampling))
        if changed or held or self.textured or self.spheres or not self.count:
            return None
        eps = torch.nn.functional.pad(torch.stack(self.eps).detach().float(), (0, 1)).reshape(-1).contiguous()
        return LightLanes(functools.partial(area_sample, lights=self.count), (self.lane_rows, self.lane_lights, eps), hit=area_hit)

    def radiance(self, emitter: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """eps (N, 3) of scene emitters ``emitter`` (N,) int64 (-1 = none) at ``uv`` (N, 2)."""
        return gather_rgb(self.eps, emitter, uv)

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """Points from uniforms ``u`` (N, 3) (pick, then the point) as seen from points ``x``."""
        g = self.geometry(u, x, nx, offset)
        Le = self.radiance(self.triangles.emitter.index_select(0, g.tri), g.uv)
        return LightSample(g.o, g.wl, g.tmax, g.facing, g.pdf, Le)

    def geometry(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> AreaSample:
        """The detached part of :meth:`sample_from`: the points picked and their shadow rays (the
        triangle group by :func:`triangle_lanes`; the sphere group in torch)."""
        n = x.shape[0]
        if self.count:
            ut = u
            if self.spheres:  # stretch the triangle group's share of u[:, 0] back to [0, 1)
                ut = u.clone()
                ut[:, 0] = ((u[:, 0] - self.group) / max(1.0 - self.group, 1e-30)).clamp(0.0, 1.0 - 2**-24)
            tri, o, wl, tmax, facing, pdf, uv = self._triangle_points(ut, x, nx, offset)
        else:
            o = x + offset * nx
            tri = torch.zeros(n, dtype=torch.int64, device=x.device)
            wl, tmax, pdf = x.new_zeros(n, 3), x.new_zeros(n), x.new_zeros(n)
            facing = torch.zeros(n, dtype=torch.bool, device=x.device)
            uv = x.new_zeros(n, 2) if self.textured else x.new_zeros(()).expand(n, 2)
        if self.spheres:
            i = (u[:, 0] < self.group).nonzero()[:, 0]
            if i.numel():
                part = self._sphere_points(u.index_select(0, i), o.index_select(0, i), nx.index_select(0, i), offset)
                tri, wl, tmax, facing, pdf = (a.index_put((i,), b.to(a.dtype)) for a, b in zip((tri, wl, tmax, facing, pdf), part))
                if self.textured:
                    uv = uv.index_put((i,), uv.new_zeros(i.numel(), 2))  # constant emission: any uv
        return AreaSample(tri, uv, o, wl, tmax, facing, pdf)

    def _triangle_points(self, u, x, nx, offset: float):
        """The triangle group's samples: (tri, o, wl, tmax, facing, pdf, uv) as :class:`AreaSample`
        (:func:`triangle_lanes`, compiled where Dr.Jit runs)."""
        tables = (self.lane_rows, self.lane_lights, lanes.uv_rows(self.triangles))
        tri, o, wl, tmax, facing, pdf, *uv = compiled.run(_sample_points, x.device, *tables, u[:, 0], u[:, 1], u[:, 2], x, nx, float(offset), lights=self.count, with_uv=self.textured)
        uv = uv[0] if self.textured else x.new_zeros(()).expand(x.shape[0], 2)
        return tri.long(), o, wl, tmax, facing, pdf, uv

    @functools.cached_property
    def lane_rows(self) -> torch.Tensor:
        """(T * 16,) the triangle table of the lane functions (:func:`invrender.core.lanes.triangle_rows`),
        made once per render: this bounce's sampling and the fused bounce read it."""
        t = self.triangles
        return lanes.triangle_rows(t.packed, t.material, t.emitter, self._emitting, self.pdf_area)

    @functools.cached_property
    def lane_lights(self) -> torch.Tensor:
        """(L * 2,) the light table of the lane functions (:func:`invrender.core.lanes.light_rows`)."""
        return lanes.light_rows(self.cdf, self.tri)

    def _choice(self, o: torch.Tensor) -> torch.Tensor:
        """(N, S) float64: the probability of each cone sphere for origins ``o`` (N, 3), given the
        sphere group: proportional to mean eps times the solid angle of its cone (one hemisphere
        from near), so that a far, large emitter does not take the samples of near ones; above
        :data:`MAX_CHOICE` spheres, by power alone."""
        if self.spheres > MAX_CHOICE:
            w = self.sphere_power.expand(o.shape[0], -1)
        else:
            w = self._solid_angles(o.double()) * self.sphere_eps
        q = w / w.sum(1, keepdim=True).clamp_min(1e-300)
        return (1 - UNIFORM) * q + UNIFORM / self.spheres

    def _solid_angles(self, o: torch.Tensor) -> torch.Tensor:
        """(N, S) float64 ``1 - cos theta_max`` of each cone sphere from ``o`` (N, 3) float64, 1 from near."""
        cols = []
        for k in range(self.spheres):
            d = norm(self.center[k] - o)
            s2 = (self.radius[k] / d.clamp_min(1e-300)).clamp_max(1.0) ** 2
            cols.append(torch.where(d > (1 + NEAR) * self.radius[k], s2 / (1 + torch.sqrt(1 - s2)), 1.0))
        return torch.stack(cols, dim=1)

    def _cone_of(self, k: torch.Tensor, o: torch.Tensor):
        """(far (N,) bool, w (N, 3) float64 unit directions to the centres, d (N,), r (N,), h (N,) = 1 -
        cos theta_max) of origins ``o`` (N, 3) seen against cone spheres ``k`` (N,)."""
        c, r = self.center.index_select(0, k), self.radius.index_select(0, k)
        to_c = c - o.double()
        d = norm(to_c).clamp_min(1e-300)
        s2 = (r / d).clamp_max(1.0) ** 2
        h = s2 / (1 + torch.sqrt(1 - s2))  # 1 - cos theta_max without cancellation
        return d > (1 + NEAR) * r, to_c / d[:, None], d, r, h

    def _sphere_points(self, u: torch.Tensor, o: torch.Tensor, nx: torch.Tensor, offset: float):
        """The sphere group's samples from origins ``o`` (N, 3), uniforms ``u`` (N, 3) (``u[:, 0]``
        spent on the group): the sphere by ``u[:, 1]`` (:meth:`_choice`), then a direction in its cone
        or, from near, a point on its mesh by area. Returns (tri, wl, tmax, facing, pdf)."""
        q = self._choice(o)
        cdf = q.cumsum(1)
        u1 = u[:, 1].double()
        k = (cdf < u1[:, None]).sum(1).clamp_max(self.spheres - 1)
        qk = q.gather(1, k[:, None])[:, 0]
        lo = torch.where(k > 0, cdf.gather(1, (k - 1).clamp_min(0)[:, None])[:, 0], 0.0)
        v = ((u1 - lo) / qk.clamp_min(1e-300)).clamp(0.0, 1.0 - 2**-52)  # u[:, 1] stretched back to [0, 1)
        far, w, d, r, h = self._cone_of(k, o)
        # far: uniform in the cone, ending on the analytic sphere (which the ray reaches before the mesh)
        hh = v * h  # 1 - cos theta, uniform in [0, h]
        cos_t, sin_t = 1 - hh, torch.sqrt((hh * (2 - hh)).clamp_min(0))
        phi = 2 * torch.pi * u[:, 2].double()
        a = torch.where((w[:, 0].abs() > 0.9)[:, None], w.new_tensor([0.0, 1.0, 0.0]), w.new_tensor([1.0, 0.0, 0.0]))
        a = a - dot(a, w)[:, None] * w
        a = a / norm(a)[:, None]
        b = torch.linalg.cross(w, a)
        wl = cos_t[:, None] * w + (sin_t * torch.cos(phi))[:, None] * a + (sin_t * torch.sin(phi))[:, None] * b
        t = d * cos_t - torch.sqrt((r * r - (d * sin_t) ** 2).clamp_min(0))
        pdf = self.group * qk / (2 * torch.pi * h)
        tri = self.sphere_tri.index_select(0, k)
        facing = dot(nx.double(), wl) > 0
        j = (~far).nonzero()[:, 0]
        if j.numel():  # near or inside: a point on the sphere's mesh, uniform by area
            kj, value = k[j], k[j] + v[j]
            m = torch.searchsorted(self.cone_cdf, value, right=True)
            m = torch.minimum(torch.maximum(m, self.sphere_first[kj]), self.sphere_last[kj])
            base = torch.where(m > self.sphere_first[kj], self.cone_cdf.index_select(0, (m - 1).clamp_min(0)), kj.double())
            rest = ((value - base) / (self.cone_cdf.index_select(0, m) - base).clamp_min(1e-300)).clamp(0.0, 1.0)
            tj = self.cone_tri.index_select(0, m)
            g = self.triangles.packed.index_select(0, tj).double()
            su = rest.sqrt()
            b1, b2 = (su * (1.0 - u[j, 2].double()))[:, None], (su * u[j, 2].double())[:, None]
            to_p = g[:, 0:3] + b1 * g[:, 3:6] + b2 * g[:, 6:9] - o.index_select(0, j).double()
            dist = norm(to_p).clamp_min(1e-12)
            wj = to_p / dist[:, None]
            cos_l = -dot(g[:, 9:12], wj)
            tri, wl, t = tri.index_put((j,), tj), wl.index_put((j,), wj), t.index_put((j,), dist)
            facing = facing.index_put((j,), (dot(nx.index_select(0, j).double(), wj) > 0) & (cos_l > 0))
            pdf = pdf.index_put((j,), self.group * qk[j] / self.sphere_area[kj] * dist * dist / cos_l.clamp_min(1e-12))
        return tri, wl, t - offset, facing, pdf

    # ---- the formats' aliases

    #: the Mitsuba emitter plugins it reads (nested in the shape that emits)
    mitsuba_plugins = ("area",)

    @classmethod
    def from_mitsuba(cls, emitter) -> dict:
        """Mitsuba's ``area``: ``radiance`` (colour or bitmap texture, default 1)."""
        eps = emitter.colour("radiance", EMISSION, 1.0)
        emitter.finish(("radiance",))
        return {"emission": eps}

    @classmethod
    def to_mitsuba(cls, values: dict, constants: dict) -> dict:
        return {"type": "area", "radiance": values["emission"]}

    def _emitter(self, s: Surface) -> torch.Tensor:
        return self.triangles.emitter.index_select(0, s.tri)

    def emits(self, s: Surface) -> torch.Tensor:
        """(N,) bool: the hit is on the front side of an emitting triangle."""
        return s.front & self._emitting.index_select(0, s.tri)

    def emitted(self, s: Surface) -> torch.Tensor:
        """eps (N, 3) leaving the hits back along the rays: zero on back sides."""
        return self.radiance(torch.where(s.front, self._emitter(s), -1), s.uv)

    def pdf_hit(self, s: Surface) -> torch.Tensor:
        """``pdf_area t^2 / cos_o`` (N,): the point's area density as a solid angle at the ray's
        origin; on a cone sphere, the density :meth:`_sphere_points` gives it from that origin
        (``P_group q_k / (2 pi (1 - cos theta_max))``, or from near by the sphere's area)."""
        pdf = self.pdf_area.index_select(0, s.tri) * s.t * s.t / s.cos_o.clamp_min(1e-12)
        if not self.spheres:
            return pdf
        k = self.rank.index_select(0, s.tri)
        i = (k >= 0).nonzero()[:, 0]
        if not i.numel():
            return pdf
        k, t, cos_o = k[i], s.t[i].double(), s.cos_o[i].double()
        o = (s.p[i] - s.t[i, None] * s.d[i]).double()
        qk = self._choice(o).gather(1, k[:, None])[:, 0]
        far, _, _, _, h = self._cone_of(k, o)
        cone = self.group * qk / (2 * torch.pi * h)
        area = self.group * qk / self.sphere_area[k] * t * t / cos_o.clamp_min(1e-12)
        return pdf.index_put((i,), torch.where(far, cone, area).to(pdf.dtype))



def triangle_lanes(xp, tri_table, light_table, lights: int, u0, u1, u2, x, nx, offset: float):
    """Points on the emissive triangles seen from points ``x`` with normals ``nx`` (3-tuples of (N,)
    arrays), written against the array interface (:mod:`invrender.core.lanes`): the triangle picked
    by ``u0`` through the cdf of the light table's ``lights`` rows (by area x emission), the point
    placed uniformly by ``u1``, ``u2``. Returns (triangle, its barycentrics b1 b2, shadow-ray
    origin, unit direction, tmax, facing: both surfaces face each other, solid-angle pdf)."""
    k = lanes.pick_light(xp, light_table, lights, u0)
    tri = lanes.Triangle(xp, tri_table, k)
    su = xp.sqrt(u1)
    b1, b2 = su * (1.0 - u2), su * u2
    y = tri.point(b1, b2)
    start = lanes.add(x, lanes.scale(nx, offset))
    to_light = lanes.sub(y, start)
    dist = xp.maximum(xp.sqrt(lanes.dot(to_light, to_light)), 1e-12)
    w = (to_light[0] / dist, to_light[1] / dist, to_light[2] / dist)
    cos_l = -lanes.dot(tri.normal, w)
    facing = (lanes.dot(nx, w) > 0.0) & (cos_l > 0.0)
    pdf = tri.pdf_area * dist * dist / xp.maximum(cos_l, 1e-12)
    return k, b1, b2, start, w, dist - offset, facing, pdf


def area_sample(xp, t, u0, u1, u2, x, nx, offset: float, *, lights: int):
    """:class:`~invrender.core.lights.LightLanes`' ``sample``: :func:`triangle_lanes` from the
    tables ``t`` (triangle rows, light rows, eps rows padded to 4), then the radiance of the point's
    emitter; and, as a surface type, that emitter's index (UInt)."""
    rows, light_rows, eps = t
    k, _, _, start, w, tmax, facing, pdf = triangle_lanes(xp, rows, light_rows, lights, u0, u1, u2, x, nx, offset)
    em, _ = lanes.Triangle(xp, rows, k).emitter(xp)
    return start, w, tmax, xp.gather_rows(eps, em, 4)[:3], pdf, facing, em


def area_hit(xp, t, tri, front, dist, cos):
    """:class:`~invrender.core.lights.LightLanes`' ``hit``: eps on the front of emitting triangles,
    the area density as a solid angle ``pdf_area dist^2 / cos``; and the emitter hit (UInt)."""
    em, has_emitter = tri.emitter(xp)
    seen = front & tri.emitting & has_emitter
    pdf = tri.pdf_area * dist * dist / xp.maximum(cos, 1e-12)
    return xp.gather_rows(t[2], em, 4)[:3], pdf, seen, em


def _sample_points(xp, rows, light_table, uvs, u0, u1, u2, x, nx, offset: float, *, lights: int, with_uv: bool):
    """:func:`triangle_lanes` with the points' texture coordinates when ``with_uv``."""
    k, b1, b2, *rest = triangle_lanes(xp, rows, light_table, lights, u0, u1, u2, x, nx, offset)
    return (k, *rest) + ((lanes.uv_at(xp, uvs, k, b1, b2),) if with_uv else ())
