"""The furnace: a closed Lambertian enclosure with uniform rho and eps (docs/closed_forms.md#furnace).

Radiance everywhere is ``eps (1 - rho^D) / (1 - rho)`` with D Neumann terms and ``eps / (1 - rho)``
unbounded. Cosine-weighted BSDF sampling at fixed depth is a zero-variance estimator here, so the
random walk must hit the closed form to float precision in every pixel.
"""

import pytest
import torch

import invrender as ir
from tests.conftest import furnace


def truncated(eps, rho, depth):
    return eps * (1 - rho**depth) / (1 - rho)


@pytest.mark.parametrize("depth", [1, 2, 3, 5])
def test_random_walk_fixed_depth_is_exact_in_every_pixel(depth):
    img = ir.render(furnace(rho=0.5, eps=1.0), integrator="random_walk", spp=4, max_depth=depth, rr_depth=99, progress=False)
    expected = truncated(1.0, 0.5, depth)
    assert (img - expected).abs().max().item() / expected < 1e-4


def test_random_walk_per_term_images_are_eps_rho_to_the_k():
    rho, eps = 0.7, 2.0
    terms = ir.render(furnace(rho=rho, eps=eps), integrator="random_walk", spp=2, max_depth=6, rr_depth=99, terms=True, progress=False)
    assert terms.shape == (6, 16, 16, 3)
    for k in range(6):
        assert torch.allclose(terms[k], torch.full_like(terms[k], eps * rho**k), rtol=1e-5)


def test_path_fixed_depth_mean():
    """NEE + MIS is not zero-variance on a tessellated sphere (the geometry term varies between
    flat triangles), so the path tracer is held to its image mean: 32x32x64 paths give a standard
    error of about 2e-4 relative, the bound is 1e-3."""
    img = ir.render(furnace(rho=0.5, eps=1.0, resolution=(32, 32)), spp=64, max_depth=4, rr_depth=99, progress=False)
    expected = truncated(1.0, 0.5, 4)
    assert abs(img.mean().item() - expected) / expected < 1e-3
    assert (img - expected).abs().max().item() / expected < 0.05  # no pixel far off


@pytest.mark.parametrize("integrator", ["path", "random_walk"])
def test_unbounded_russian_roulette_reaches_eps_over_one_minus_rho(integrator):
    """Per-path variance is eps^2 rho/(1-rho)^2 = 2 (rho = 0.5); 32x32x128 paths give a standard
    error of 0.2% of eps/(1-rho) = 2, so 1% is a 5-sigma bound."""
    img = ir.render(furnace(rho=0.5, eps=1.0, resolution=(32, 32)), integrator=integrator, spp=128, max_depth=-1, rr_depth=1, progress=False)
    assert abs(img.mean().item() - 2.0) / 2.0 < 0.01


def test_unbounded_terms_sum_to_image():
    scene = furnace(rho=0.5, eps=1.0)
    full = ir.render(scene, spp=16, max_depth=-1, rr_depth=2, seed=3, progress=False)
    terms = ir.render(scene, spp=16, max_depth=-1, rr_depth=2, seed=3, terms=True, progress=False)
    assert terms.shape[0] > 4
    assert torch.allclose(terms.sum(0), full, rtol=1e-5, atol=1e-6)


def test_terms_nothing_reached_are_images_of_zeros():
    """A tiny view where no camera ray sees the light: max_depth 1 gives one (zero) term image,
    not an error, and max_depth 3 three, whichever terms the paths reached."""
    scene = ir.load_scene("cornell_box", resolution=(4, 4))
    one = ir.render(scene, spp=2, max_depth=1, terms=True, progress=False)
    assert one.shape == (1, 4, 4, 3)
    assert ir.render(scene, spp=2, max_depth=3, terms=True, progress=False).shape == (3, 4, 4, 3)
