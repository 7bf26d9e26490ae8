"""The sphere interior with two patches (hemispheres of different rho and eps), rendered: radiosity
and the path tracer against the closed form (docs/closed_forms.md#sphere-interior),
``L_h = E_h + rho_h E_bar / (1 - rho_bar)`` on hemisphere h, and their gradients.

The closed-form image weights L_h by the share of each pixel's camera samples that land on
hemisphere h, measured by rendering the same camera samples (same seed and spp) with the
emission (1, 0, 0) north and (0, 1, 0) south and no reflection. The icosphere is flat-shaded, so its
form factors differ from the sphere's by O(h^2): 0.2% at level 2 (test_form_factors), which moves
the image by under 0.1% (the radiosity render below); the path tracer's standard error here is
0.15-0.3%.
"""

import pytest
import torch

import invrender as ir
from tests.radiosity.conftest import NORTH_EPS, NORTH_RHO, SOUTH_EPS, SOUTH_RHO, area_fractions, hemispheres, sphere_closed_form

LEVEL, RESOLUTION, SPP = 2, (16, 16), 64
NAMES = ["north.reflectance", "south.reflectance", "north_glow.emission", "south_glow.emission"]


@pytest.fixture(scope="module")
def sphere():
    """The scene, its closed-form image (seed 0) and the closed form's gradient of the image mean."""
    scene = hemispheres(LEVEL, RESOLUTION)
    marker = hemispheres(LEVEL, RESOLUTION, rho=((0, 0, 0), (0, 0, 0)), eps=((1, 0, 0), (0, 1, 0)))
    share = ir.render(marker, "path", spp=SPP, max_depth=1, seed=0, progress=False).double()  # (H, W, 3): north, south, 0
    assert torch.allclose(share[..., 0] + share[..., 1], torch.ones(RESOLUTION[::-1], dtype=torch.float64))
    rho = torch.tensor([NORTH_RHO, SOUTH_RHO], dtype=torch.float64, requires_grad=True)
    E = torch.tensor([NORTH_EPS, SOUTH_EPS], dtype=torch.float64, requires_grad=True)
    L = sphere_closed_form(area_fractions(scene), rho, E)  # (2, 3)
    closed = share[..., 0:1] * L[0] + share[..., 1:2] * L[1]
    closed.mean().backward()
    grad = {"north.reflectance": rho.grad[0], "south.reflectance": rho.grad[1], "north_glow.emission": E.grad[0], "south_glow.emission": E.grad[1]}
    return scene, closed.detach(), grad


def gradients(scene, **options) -> dict:
    params = {n: scene.params[n].detach().clone().requires_grad_(True) for n in NAMES}
    saved = {n: scene.params[n] for n in NAMES}
    try:
        scene.params.update(params)
        ir.render(scene, progress=False, **options).mean().backward()
        return {n: params[n].grad.double() for n in NAMES}
    finally:
        scene.params.update(saved)


def test_radiosity_render_matches_the_closed_form(sphere):
    scene, closed, grad = sphere
    img = ir.render(scene, "radiosity", spp=SPP, seed=0, subdivision=1, progress=False).double()
    assert ((img.mean((0, 1)) - closed.mean((0, 1))).abs() / closed.mean((0, 1))).max() < 0.002
    got = gradients(scene, integrator="radiosity", spp=SPP, seed=0, subdivision=1)
    for n in NAMES:
        assert ((got[n] - grad[n]).abs() / grad[n].abs()).max() < 0.005, n


def test_path_tracer_agrees_within_monte_carlo_error(sphere):
    """Channel means of the path tracer (unbounded, Russian roulette) minus the closed-form image,
    within 4 standard errors (pixels are independent); its replayed gradients of the image mean
    within 4 standard errors of 4 seeds."""
    scene, closed, grad = sphere
    img = ir.render(scene, "path", spp=SPP, max_depth=-1, seed=0, progress=False).double()
    diff = (img - closed).reshape(-1, 3)
    assert (diff.mean(0).abs() < 4 * diff.std(0) / diff.shape[0] ** 0.5).all(), diff.mean(0)
    runs = [gradients(scene, integrator="path", spp=16, max_depth=-1, seed=seed) for seed in range(4)]
    for n in NAMES:
        g = torch.stack([r[n] for r in runs])
        assert ((g.mean(0) - grad[n]).abs() < 4 * g.std(0) / 2).all(), (n, g.mean(0), grad[n])
