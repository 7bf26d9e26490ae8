"""Scenes and closed forms for the radiosity tests."""

import torch

import invrender as ir
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, sphere

#: the two hemispheres' materials and emissions (per channel, deliberately different)
NORTH_RHO, SOUTH_RHO = (0.8, 0.5, 0.3), (0.3, 0.6, 0.7)
NORTH_EPS, SOUTH_EPS = (1.0, 0.2, 0.5), (0.1, 0.8, 0.3)


def hemispheres(subdivisions: int = 2, resolution=(16, 16), rho=(NORTH_RHO, SOUTH_RHO), eps=(NORTH_EPS, SOUTH_EPS)):
    """The inside of a flat-shaded unit icosphere whose triangles with centroid z > 0 ("north") and
    z <= 0 ("south") have their own diffuse reflectance and emission (two patches of the sphere
    interior, docs/closed_forms.md#sphere-interior). Camera at the centre looking along +x, so it sees
    both halves."""
    v, f, uv = sphere(subdivisions)
    north = v[f].mean(1)[:, 2] > 0
    shells = [
        Mesh(v, f[north], uv, material="north", emitter="north_glow").flipped(),
        Mesh(v, f[~north], uv, material="south", emitter="south_glow").flipped(),
    ]  # faces point inwards
    camera = ir.Camera(origin=(0, 0, 0), target=(1, 0, 0), up=(0, 0, 1), fov=90.0)
    return build_scene(shells, {"north": list(rho[0]), "south": list(rho[1])}, {"north_glow": list(eps[0]), "south_glow": list(eps[1])}, camera, resolution, name="hemispheres")


def area_fractions(scene) -> torch.Tensor:
    """(2,) area fractions a_k of the two hemispheres (material 0 = north, 1 = south)."""
    area = scene.triangles.area.double()
    return torch.stack([area[scene.triangles.material == k].sum() for k in (0, 1)]) / area.sum()


def sphere_closed_form(a: torch.Tensor, rho: torch.Tensor, E: torch.Tensor) -> torch.Tensor:
    """B_i = E_i + rho_i E_bar / (1 - rho_bar) per patch and channel: a (n,), rho and E (n, 3)."""
    rho_bar = (a[:, None] * rho).sum(0)
    E_bar = (a[:, None] * E).sum(0)
    return E + rho * E_bar / (1 - rho_bar)


def sphere_system(n=24, seed=0):
    """Exact sphere-interior form factors for n patches of random areas, random rho in [0.1, 0.9]
    and E in [0, 2] per patch and channel (float64)."""
    gen = torch.Generator().manual_seed(seed)
    a = torch.rand(n, generator=gen, dtype=torch.float64) + 0.2
    a = a / a.sum()
    F = a[None, :].expand(n, n).clone()  # F_ij = a_j, F_ii included
    rho = 0.1 + 0.8 * torch.rand(n, 3, generator=gen, dtype=torch.float64)
    E = 2 * torch.rand(n, 3, generator=gen, dtype=torch.float64)
    return a, F, rho, E


__all__ = ["sphere_system", "hemispheres", "area_fractions", "sphere_closed_form", "NORTH_RHO", "SOUTH_RHO", "NORTH_EPS", "SOUTH_EPS"]
