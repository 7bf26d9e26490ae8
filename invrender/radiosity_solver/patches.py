"""Meshing a scene into radiosity patches, finding the patch under a point, and averaging the
scene's reflectance and emission over each patch.

Every scene triangle is cut into ``n^2`` congruent sub-triangles by a grid of ``n`` segments along
each edge (``n`` = the triangle's subdivision); each sub-triangle is a patch. In the triangle's
barycentric coordinates ``(u, v)`` (the hit point is ``p0 + u e1 + v e2``, as the intersection
backends report it) the grid cell ``(i, j) = (floor(n u), floor(n v))`` holds a *lower* patch
(corners ``(i, j), (i+1, j), (i, j+1)`` in units of 1/n) and, unless it lies on the hypotenuse, an
*upper* one (``(i+1, j), (i+1, j+1), (i, j+1)``). Patches are numbered triangle by triangle: first
the triangle's lower patches row by row (i, then j), then its upper ones.

A patch has two sides (the diffuse material is two-sided): side ``2 k`` is patch k's front (the
triangle's front, the side an emitter emits from), side ``2 k + 1`` its back. The radiosity system
has one unknown per side (docs/radiosity.md#patches-and-sides).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.errors import ParameterError
from invrender.scene.scene import Triangles

#: largest subdivision (segments per triangle edge) accepted
MAX_SUBDIVISION = 64
#: largest number of patches accepted (the system holds two sides per patch)
MAX_PATCHES = 16384


@dataclass(frozen=True)
class Patches:
    """The patches of a scene, detached, on one device.

    Attributes:
        tri: (P,) int64 scene triangle each patch lies in.
        corners: (P, 3, 3) corner positions (counter-clockwise seen from the triangle's front).
        bary: (P, 3, 2) barycentric coordinates ``(u, v)`` of the corners in their triangle.
        normal: (P, 3) unit normal of the triangle's front side.
        area: (P,) area.
        subdivision: (T,) int64 segments per edge of each scene triangle (``n_t``).
        first: (T,) int64 index of each triangle's first patch (triangle t owns ``n_t^2`` patches
            from ``first[t]`` on).
    """

    tri: torch.Tensor
    corners: torch.Tensor
    bary: torch.Tensor
    normal: torch.Tensor
    area: torch.Tensor
    subdivision: torch.Tensor
    first: torch.Tensor

    @property
    def count(self) -> int:
        """Number of patches P."""
        return int(self.tri.shape[0])

    def at(self, tri: torch.Tensor, u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """(N,) int64 patch holding the points of triangles ``tri`` (N,) at barycentrics ``u``, ``v`` (N,)."""
        n = self.subdivision[tri]
        nf = n.to(torch.float32)
        un, vn = u.detach().float() * nf, v.detach().float() * nf
        i = torch.minimum(un.long().clamp_min(0), n - 1)  # truncation = floor for un >= 0
        j = torch.minimum(vn.long().clamp_min(0), n - 1 - i)
        upper = ((un - i) + (vn - j) > 1.0) & (i + j < n - 1)
        row = (i * (i - 1)) >> 1  # i (i - 1) / 2: products of consecutive integers are even
        lower_index = i * n - row + j
        upper_index = ((n * (n + 1)) >> 1) + i * (n - 1) - row + j
        return self.first[tri] + torch.where(upper, upper_index, lower_index)

    def locate(self, triangles: Triangles, tri: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """(N,) int64 patch holding points ``p`` (N, 3) that lie on triangles ``tri`` (N,)."""
        p0, e1, e2 = triangles.p0[tri], triangles.e1[tri], triangles.e2[tri]
        d = (p.detach() - p0).double()
        e1, e2 = e1.double(), e2.double()
        g11, g12, g22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        r1, r2 = (d * e1).sum(1), (d * e2).sum(1)
        det = g11 * g22 - g12 * g12
        return self.at(tri, (g22 * r1 - g12 * r2) / det, (g11 * r2 - g12 * r1) / det)

    def points(self, b: torch.Tensor, patch: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Points of patches at barycentric weights ``b`` (N, 2) of their second and third corner.

        Args:
            b: (N, 2) weights (``b_1, b_2 >= 0``, ``b_1 + b_2 <= 1``).
            patch: (N,) int64 patches; None = patch k for row k (N = P).
        Returns:
            positions (N, 3) and the barycentric coordinates ``(u, v)`` (N, 2) in their scene
            triangle (for texture coordinates).
        """
        corners = self.corners if patch is None else self.corners[patch]
        bary = self.bary if patch is None else self.bary[patch]
        w = torch.cat([1.0 - b.sum(1, keepdim=True), b], dim=1).to(corners.dtype)  # (N, 3)
        return (w[:, :, None] * corners).sum(1), (w[:, :, None] * bary).sum(1)


def mesh_patches(triangles: Triangles, subdivision: int | None = None, patches: int | None = None) -> Patches:
    """Cut every triangle into patches.

    Args:
        triangles: the scene geometry.
        subdivision: segments per triangle edge, the same for every triangle (each triangle gives
            ``subdivision^2`` patches), in [1, 64].
        patches: instead, a target patch count: triangle t gets ``n_t = max(1, round(sqrt(target
            A_t / A)))`` segments per edge, so patches have about the same area ``A / target``
            (the count is close to the target, not equal to it).
    Raises:
        ParameterError: neither or both given, or a value out of range.
    """
    area = triangles.area.double()
    if (subdivision is None) == (patches is None):
        raise ParameterError("give radiosity either subdivision (segments per triangle edge) or patches (a target patch count), not both")
    if subdivision is not None:
        _check_count("subdivision", subdivision, MAX_SUBDIVISION)
        n = torch.full_like(triangles.material, subdivision)
    else:
        _check_count("patches", patches, MAX_PATCHES)
        n = (patches * area / area.sum()).sqrt().round().long().clamp(1, MAX_SUBDIVISION)
    total = int((n * n).sum())
    if total > MAX_PATCHES:
        raise ParameterError(f"radiosity meshing gives {total} patches, more than {MAX_PATCHES}: lower subdivision or patches")
    first = torch.cumsum(n * n, 0) - n * n
    tri_parts, bary_parts, index_parts = [], [], []
    for k in torch.unique(n).tolist():
        members = (n == k).nonzero()[:, 0]
        local = grid_triangles(k).to(triangles.p0.device)  # (k^2, 3, 2)
        tri_parts.append(members.repeat_interleave(k * k))
        bary_parts.append(local.repeat(len(members), 1, 1))
        index_parts.append((first[members][:, None] + torch.arange(k * k, device=n.device)).reshape(-1))
    order = torch.cat(index_parts).argsort()
    tri = torch.cat(tri_parts)[order]
    bary = torch.cat(bary_parts)[order]
    p0, e1, e2 = triangles.p0[tri], triangles.e1[tri], triangles.e2[tri]
    corners = p0[:, None, :] + bary[:, :, 0:1] * e1[:, None, :] + bary[:, :, 1:2] * e2[:, None, :]
    return Patches(
        tri=tri,
        corners=corners,
        bary=bary,
        normal=triangles.normal[tri],
        area=triangles.area[tri] / (n[tri] * n[tri]).to(triangles.area.dtype),
        subdivision=n,
        first=first,
    )


def grid_triangles(n: int) -> torch.Tensor:
    """The ``n^2`` sub-triangles of the unit triangle, in patch order: (n^2, 3, 2) barycentric
    corners ``(u, v)``, counter-clockwise like the triangle."""
    lower = [((i, j), (i + 1, j), (i, j + 1)) for i in range(n) for j in range(n - i)]
    upper = [((i + 1, j), (i + 1, j + 1), (i, j + 1)) for i in range(n) for j in range(n - 1 - i)]
    return torch.tensor(lower + upper, dtype=torch.float32) / n


def quadrature(m: int) -> torch.Tensor:
    """Barycentric weights (m^2, 2) of the centroids of the ``m^2`` sub-triangles of a triangle:
    equal-weight points whose mean is the triangle average of a smooth function (error O(1/m^2))."""
    return grid_triangles(m).mean(1)


def side_reflectance(ctx, patches: Patches, m: int = 3) -> torch.Tensor:
    """Per-side diffuse reflectance rho (2P, 3): each patch's average over ``m^2`` points (exact for
    constant reflectances; textures filtered bilinearly as the renderer does), the same on both
    sides. Differentiable in the reflectance parameters. ``ctx``: a TransportContext."""
    tri, uv, q = _patch_samples(ctx, patches, m)
    n = ctx.triangles.normal[tri]
    sp = ctx.materials.shading_point(ctx.triangles.material[tri], n, n, n, torch.ones_like(tri, dtype=torch.bool), uv)
    rho = ctx.materials.diffuse_reflectance(sp).reshape(patches.count, q, 3).mean(1)
    return rho.repeat_interleave(2, dim=0)


def side_emission(ctx, patches: Patches, m: int = 3) -> torch.Tensor:
    """Per-side emitted radiance eps (2P, 3): each emitting patch's average over ``m^2`` points on
    its front side, zero on back sides and elsewhere. Differentiable in the emission parameters."""
    tri, uv, q = _patch_samples(ctx, patches, m)
    eps = ctx.emission(ctx.triangles.emitter[tri], uv).reshape(patches.count, q, 3).mean(1)
    return torch.stack([eps, torch.zeros_like(eps)], dim=1).reshape(-1, 3)


def _patch_samples(ctx, patches: Patches, m: int) -> tuple[torch.Tensor, torch.Tensor, int]:
    """The points parameters are averaged at: q = m^2 per patch (1 when nothing is textured, where
    one point is exact), patch by patch: their scene triangles (P q,) and texture coordinates
    (P q, 2), and q."""
    b = quadrature(m if ctx.textured else 1).to(patches.corners.device)
    q = b.shape[0]
    patch = torch.arange(patches.count, device=b.device).repeat_interleave(q)
    _, uvw = patches.points(b.repeat(patches.count, 1), patch)
    tri = patches.tri[patch]
    return tri, _texture_uv(ctx.triangles, tri, uvw), q


def _texture_uv(triangles: Triangles, tri: torch.Tensor, uvw: torch.Tensor) -> torch.Tensor:
    """Texture coordinates (N, 2) at barycentrics ``uvw`` (N, 2) of triangles ``tri`` (N,)."""
    t = triangles.uv[tri]  # (N, 3, 2)
    u, v = uvw[:, 0:1].to(t.dtype), uvw[:, 1:2].to(t.dtype)
    return (1 - u - v) * t[:, 0] + u * t[:, 1] + v * t[:, 2]


def _check_count(name: str, value, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= high:
        raise ParameterError(f"radiosity {name} must be an integer in [1, {high}], got {value!r}")


__all__ = ["Patches", "mesh_patches", "grid_triangles", "quadrature", "side_reflectance", "side_emission", "MAX_SUBDIVISION", "MAX_PATCHES"]
