"""Area lights: emissive triangles, Mitsuba's ``area`` emitter.

The shapes that name an area emitter emit radiance eps (an RGB triple or an (h, w, 3) texture over
their UVs) from their front side (counter-clockwise winding), uniformly in direction. Next-event
estimation picks an emissive triangle with probability proportional to ``area x mean(eps)`` (eps read
without gradient when the render starts), then a point uniformly on it, so no pdf depends on the
differentiable eps (docs/architecture.md#detached-sampling-differentiable-evaluation). The points'
shadow rays and solid-angle pdfs come from one fused kernel where
:mod:`~invrender.transport.kernels` runs.

**Spheres by solid angle.** A triangle picked on an emitting sphere (a mesh inscribed in an
analytic sphere, :attr:`Triangles.sphere <invrender.scene.scene.Triangles>`, with a constant eps)
stands for the whole sphere, picked with probability ``P_s`` (the sum of its triangles' weights over
the total): seen from a shadow-ray origin ``o`` at distance ``d > (1 + NEAR) r`` from the centre, the
direction is drawn uniformly in the cone the analytic sphere subtends (``sin theta_max = r / d``),
solid-angle pdf ``P_s / (2 pi (1 - cos theta_max))``, and the shadow ray ends at the analytic
sphere's first intersection, which it reaches before the inscribed mesh; from nearer (or inside)
the point on the picked triangle stands (area sampling). :meth:`Area.pdf_hit` gives a BSDF ray's
hit on the mesh the same density, by the same test on its origin. The mesh being inscribed, the
cone is a little wider than the mesh's silhouette: docs/sampling.md#spheres-by-solid-angle gives
the radial error and what it does to an estimate.
"""

from __future__ import annotations

import torch

from dataclasses import dataclass

from invrender import registry
from invrender.scene.kinds import EMISSION
from invrender.scene.plugins import Param
from invrender.scene.scene import Triangles
from invrender.transport import kernels
from invrender.transport.lights import Light, LightSample
from invrender.transport.surface import Surface
from invrender.transport.textures import gather_rgb
from invrender.vec import dot, norm

#: cone sampling only from origins farther than (1 + NEAR) radii from the centre (else by area)
NEAR = 1e-2


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
        self.tri = torch.nonzero(weight > 0)[:, 0]
        self.total = float(weight.sum())
        self.count = int(self.tri.numel())
        #: (T,) pdf per unit area of the point sampler on each triangle (0 where it never samples)
        self.pdf_area = torch.where(weight > 0, weight / max(self.total, 1e-30) / triangles.area, 0.0)
        cdf = torch.cumsum(weight[self.tri].double(), 0)
        self.cdf = (cdf / cdf[-1]).float() if self.count else cdf.float()
        #: (T,) bool: the triangles that emit (of this type)
        self._emitting = torch.isin(triangles.emitter, torch.tensor(emitters, device=device))
        self._spheres(weight)

    def _spheres(self, weight: torch.Tensor) -> None:
        """The tables of cone sampling: per triangle the sphere it stands for (``self.cone``, -1 =
        by area), per sphere its centre, radius and probability of being picked."""
        tris = self.triangles
        sphere = tris.sphere
        textured = torch.tensor([e.ndim == 3 for e in self.eps] + [True], device=sphere.device)  # last: emitter -1
        emitter = torch.where((tris.emitter >= 0) & (tris.emitter < len(self.eps)), tris.emitter, len(self.eps))
        cone = (sphere >= 0) & (weight > 0) & ~textured[emitter]
        #: (T,) int64: the analytic sphere a picked triangle stands for (-1: sampled by area)
        self.cone = torch.where(cone, sphere, -1)
        self.cones = bool(cone.any())
        spheres = tris.spheres.double()
        #: (S, 3), (S,) float64 centres and radii; (S,) probability of picking each sphere
        self.sphere_c, self.sphere_r = spheres[:, :3], spheres[:, 3]
        self.sphere_p = torch.zeros(spheres.shape[0], dtype=torch.float64, device=sphere.device)
        if self.cones:
            self.sphere_p.index_add_(0, sphere[cone], weight[cone].double() / max(self.total, 1e-30))

    @property
    def power(self) -> float:
        return self.total  # sum of area x mean(eps): proportional to the power emitted

    def radiance(self, emitter: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """eps (N, 3) of scene emitters ``emitter`` (N,) int64 (-1 = none) at ``uv`` (N, 2)."""
        return gather_rgb(self.eps, emitter, uv)

    def sample_from(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> LightSample:
        """Points from uniforms ``u`` (N, 3) (pick, then the point) as seen from points ``x``."""
        g = self.geometry(u, x, nx, offset)
        Le = self.radiance(self.triangles.emitter.index_select(0, g.tri), g.uv)
        return LightSample(g.o, g.wl, g.tmax, g.facing, g.pdf, Le)

    def geometry(self, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float) -> AreaSample:
        """The detached part of :meth:`sample_from`: the points picked and their shadow rays (one
        fused kernel where :mod:`~invrender.transport.kernels` runs, else the torch reference)."""
        if kernels.enabled(x.device):
            tri, o, wl, tmax, facing, pdf, uv = kernels.emitter_geometry(self.triangles.packed, self.tri, self.cdf, self.pdf_area, u, x, nx, offset, self.textured)
        else:
            tri, p, n, uv = self._points(u[:, 0], u[:, 1:3])
            o = x + offset * nx
            to_light = p - o
            dist = norm(to_light).clamp_min(1e-12)
            wl = to_light / dist[:, None]
            cos_l = -dot(n, wl)  # at the light: only its front side emits
            facing = (dot(nx, wl) > 0) & (cos_l > 0)  # light from behind x's surface does not reach it
            pdf = self.pdf_area.index_select(0, tri) * dist * dist / cos_l.clamp_min(1e-12)  # area -> solid angle
            tmax = dist - offset
        if self.cones:
            wl, tmax, facing, pdf = self._cone(tri, u[:, 1:3], o, nx, wl, tmax, facing, pdf, offset)
        return AreaSample(tri, uv, o, wl, tmax, facing, pdf)

    def _outside(self, k: torch.Tensor, o: torch.Tensor):
        """(far (N,) bool, w (N, 3) float64 unit directions to the centres, d (N,), h (N,) = 1 -
        cos theta_max) of origins ``o`` (N, 3) seen against spheres ``k`` (N,) (-1 = none)."""
        kk = k.clamp_min(0)
        c, r = self.sphere_c.index_select(0, kk), self.sphere_r.index_select(0, kk)
        to_c = c - o.double()
        d = norm(to_c).clamp_min(1e-300)
        far = (k >= 0) & (d > (1 + NEAR) * r)
        s2 = (r / d).clamp_max(1.0) ** 2
        h = s2 / (1 + torch.sqrt(1 - s2))  # 1 - cos theta_max without cancellation
        return far, to_c / d[:, None], d, r, h

    def _cone(self, tri, u, o, nx, wl, tmax, facing, pdf, offset: float):
        """Replace the samples of picked sphere triangles seen from far enough by directions
        uniform in the sphere's cone (uniforms ``u`` (N, 2)), ending on the analytic sphere."""
        k = self.cone.index_select(0, tri)
        far, w, d, r, h = self._outside(k, o)
        i = far.nonzero()[:, 0]
        if not i.numel():
            return wl, tmax, facing, pdf
        w, d, r, h, ui = w[i], d[i], r[i], h[i], u.index_select(0, i).double()
        hh = ui[:, 0] * h  # 1 - cos theta, uniform in [0, h]
        cos_t = 1 - hh
        sin_t = torch.sqrt((hh * (2 - hh)).clamp_min(0))
        phi = 2 * torch.pi * ui[:, 1]
        a = torch.where((w[:, 0].abs() > 0.9)[:, None], w.new_tensor([0.0, 1.0, 0.0]), w.new_tensor([1.0, 0.0, 0.0]))
        a = a - dot(a, w)[:, None] * w
        a = a / norm(a)[:, None]
        b = torch.linalg.cross(w, a)
        dirs = cos_t[:, None] * w + (sin_t * torch.cos(phi))[:, None] * a + (sin_t * torch.sin(phi))[:, None] * b
        # first intersection with the analytic sphere: t = d cos - sqrt(r^2 - d^2 sin^2)
        t = d * cos_t - torch.sqrt((r * r - (d * sin_t) ** 2).clamp_min(0))
        dirs = dirs.to(wl.dtype)
        wl = wl.index_put((i,), dirs)
        tmax = tmax.index_put((i,), (t - offset).to(tmax.dtype))
        facing = facing.index_put((i,), dot(nx.index_select(0, i), dirs) > 0)
        pdf = pdf.index_put((i,), (self.sphere_p.index_select(0, k[i]) / (2 * torch.pi * h)).to(pdf.dtype))
        return wl, tmax, facing, pdf

    def _points(self, u_pick: torch.Tensor, u: torch.Tensor):
        """(tri (N,) int64, p (N, 3), front normal n (N, 3), uv (N, 2)) of points picked by
        ``u_pick`` (N,) and placed by ``u`` (N, 2): the torch reference of the fused kernel."""
        k = torch.searchsorted(self.cdf, u_pick.contiguous(), right=True).clamp_max(self.count - 1)
        tri = self.tri.index_select(0, k)
        g = self.triangles.packed.index_select(0, tri)
        su = u[:, 0].sqrt()
        b1, b2 = (su * (1.0 - u[:, 1]))[:, None], (su * u[:, 1])[:, None]  # uniform barycentrics (weights of p1, p2)
        p = g[:, 0:3] + b1 * g[:, 3:6] + b2 * g[:, 6:9]
        uv = (1 - b1 - b2) * g[:, 12:14] + b1 * g[:, 14:16] + b2 * g[:, 16:18] if self.textured else p.new_zeros(()).expand(len(tri), 2)
        return tri, p, g[:, 9:12], uv

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
        origin; on a sphere sampled by its cone from that origin, ``P_s / (2 pi (1 - cos theta_max))``."""
        pdf = self.pdf_area.index_select(0, s.tri) * s.t * s.t / s.cos_o.clamp_min(1e-12)
        if not self.cones:
            return pdf
        k = self.cone.index_select(0, s.tri)
        far, _, _, _, h = self._outside(k, s.p - s.t[:, None] * s.d)
        cone = self.sphere_p.index_select(0, k.clamp_min(0)) / (2 * torch.pi * h.clamp_min(1e-300))
        return torch.where(far, cone.to(pdf.dtype), pdf)
