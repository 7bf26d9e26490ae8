"""The path tracer's sampling choices (docs/sampling.md): every strategy estimates the same image,
the better ones with less noise, and gradients and path records work with each of them.

- Means: channel means over seeds within 4 standard errors (of the strategy and of the reference
  together) of a high-spp render, for MIS / BSDF-only / emitter-only, uniform hemisphere sampling
  and no roulette, on the Cornell box and on the specular Cornell box (mirror, glass, glossy: the
  emitter-only strategy must still count emitters seen through delta lobes).
- Noise: MIS at least as good as the better single strategy (Cornell box: emitter samples carry
  nearly all of it, MIS matches them; forward/mis_plates.toml: each single strategy fails
  somewhere, MIS beats both), and BSDF-only far worse than either on the Cornell box.
"""

from __future__ import annotations

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError

VARIANTS = {
    "mis": {},
    "bsdf": {"strategy": "bsdf"},
    "emitter": {"strategy": "emitter"},
    "uniform": {"hemisphere": "uniform"},
    "emitter+uniform": {"strategy": "emitter", "hemisphere": "uniform"},
    "no_roulette": {"rr_depth": -1},
}


def reference(scene, spp=2048, parts=4):
    """A high-spp render (H, W, 3) float64 and the standard error (3,) of its channel means."""
    images = torch.stack([ir.render(scene, spp=spp // parts, seed=1000 + k, progress=False).double() for k in range(parts)])
    means = images.mean((1, 2))
    return images.mean(0), means.std(0) / parts**0.5


def renders(scene, options, spp=16, seeds=8):
    return torch.stack([ir.render(scene, spp=spp, seed=s, progress=False, **options).double() for s in range(seeds)])


@pytest.fixture(scope="module")
def cbox16():
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    return scene, *reference(scene)


@pytest.mark.parametrize("name", list(VARIANTS))
def test_every_strategy_has_the_same_mean(cbox16, name):
    scene, ref, ref_se = cbox16
    images = renders(scene, VARIANTS[name])
    means = images.mean((1, 2))
    se = (means.var(0) / means.shape[0] + ref_se**2).sqrt()
    z = (means.mean(0) - ref.mean((0, 1))) / se
    assert (z.abs() < 4).all(), f"{name}: z = {z.tolist()}"


@pytest.mark.parametrize("name", ["bsdf", "emitter"])
def test_strategies_agree_through_mirrors_glass_and_glossy(name):
    scene = ir.load_scene("cornell_specular", resolution=(8, 8), subdivisions=2)
    mis = renders(scene, {}, spp=32, seeds=6).mean((1, 2))
    other = renders(scene, VARIANTS[name], spp=32, seeds=6).mean((1, 2))
    se = (mis.var(0) / 6 + other.var(0) / 6).sqrt()
    z = (other.mean(0) - mis.mean(0)) / se
    assert (z.abs() < 4).all(), f"{name}: z = {z.tolist()}"


def test_mis_is_at_least_as_good_as_the_better_single_strategy(cbox16):
    """Cornell box (measured 16x16, 8 x 16 spp: MSE 0.0083 MIS, 0.0083 emitter, 0.052 BSDF)."""
    scene, ref, _ = cbox16
    mse = {name: float(((renders(scene, VARIANTS[name]) - ref) ** 2).mean()) for name in ("mis", "bsdf", "emitter")}
    assert mse["mis"] <= 1.02 * min(mse["bsdf"], mse["emitter"]), mse
    assert mse["bsdf"] > 3 * mse["mis"], mse


def test_mis_beats_both_single_strategies_where_each_fails():
    """forward/mis_plates.toml: a glossy floor reflecting a large panel (emitter samples fail), a wall
    lit by a tiny lamp (BSDF samples fail); measured at 16x16: MSE 0.024 MIS, 0.060 emitter, 0.48 BSDF."""
    scene = ir.load_scene("forward/mis_plates.toml", resolution=(12, 12))
    ref, _ = reference(scene, spp=2048)
    mse = {name: float(((renders(scene, VARIANTS[name], seeds=4) - ref) ** 2).mean()) for name in ("mis", "bsdf", "emitter")}
    assert mse["mis"] < 0.7 * mse["emitter"] and mse["mis"] < 0.2 * mse["bsdf"], mse


def test_cosine_sampling_is_exact_in_the_furnace_and_uniform_is_unbiased():
    """Closed furnace, rho 0.5, eps 1, max_depth 4: L = eps (1 - rho^4) / (1 - rho) = 1.875.
    Cosine-weighted BSDF sampling has zero variance (weight rho); uniform hemisphere sampling
    (weight 2 rho cos) is unbiased but noisy (docs/closed_forms.md, hemisphere integrals)."""
    scene = ir.load_scene("furnace", resolution=(16, 16), rho=0.5, eps=1.0)
    exact = 1.875
    cosine = ir.render(scene, "random_walk", spp=4, max_depth=4, progress=False).double()
    torch.testing.assert_close(cosine, torch.full_like(cosine, exact), rtol=1e-5, atol=0)
    uniform = ir.render(scene, "random_walk", spp=64, max_depth=4, hemisphere="uniform", progress=False).double()
    pixel_means = uniform.mean(-1).reshape(-1)
    assert pixel_means.std() > 0.01
    assert abs(pixel_means.mean() - exact) < 4 * pixel_means.std() / pixel_means.numel() ** 0.5


def test_bsdf_strategy_is_the_random_walk_sample_for_sample(cbox16):
    scene = cbox16[0]
    a = ir.render(scene, "path", spp=4, strategy="bsdf", progress=False)
    b = ir.render(scene, "random_walk", spp=4, progress=False)
    torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-7)


def test_no_roulette_ends_paths_at_max_depth_only():
    """Without roulette every path keeps every term up to max_depth: the random walk in the furnace
    (cosine sampling, weight rho) gives the truncated series exactly; with roulette it is noisy."""
    scene = ir.load_scene("furnace", resolution=(4, 4), rho=0.9, eps=1.0)
    exact = (1 - 0.9**12) / (1 - 0.9)
    img = ir.render(scene, "random_walk", spp=2, max_depth=12, rr_depth=-1, progress=False).double()
    torch.testing.assert_close(img, torch.full_like(img, exact), rtol=1e-5, atol=0)
    rouletted = ir.render(scene, "random_walk", spp=2, max_depth=12, rr_depth=2, progress=False).double()
    assert float((rouletted - exact).abs().max()) > 0.1


@pytest.mark.parametrize("name", ["bsdf", "emitter", "uniform", "no_roulette"])
def test_replay_equals_autodiff_with_each_strategy(cbox16, name):
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    target = torch.rand(8, 8, 3, generator=torch.Generator().manual_seed(0))
    grads = {}
    for estimator in ("autodiff", "replay"):
        params = {k: v.detach().clone().requires_grad_(True) for k, v in scene.params.items()}
        scene.params.update(params)
        image = ir.render(scene, spp=4, max_depth=4, estimator=estimator, progress=False, **VARIANTS[name])
        ((image - target) ** 2).sum().backward()
        grads[estimator] = {k: v.grad.clone() for k, v in params.items()}
    for k in grads["autodiff"]:
        torch.testing.assert_close(grads["replay"][k], grads["autodiff"][k], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("name", ["bsdf", "emitter", "uniform", "no_roulette"])
def test_path_records_follow_each_strategy(cbox16, name):
    """A record at the scene's values is the render of the same seed, whatever the strategy."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    records = ir.record_paths(scene, ["red.reflectance", "light.emission"], spp=4, max_depth=4, progress=False, **VARIANTS[name])
    image = ir.render(scene, spp=4, max_depth=4, progress=False, **VARIANTS[name])
    torch.testing.assert_close(records.image().float(), image, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"strategy": "nee"}, "unknown strategy 'nee' \\(known: mis, bsdf, emitter\\)"),
        ({"hemisphere": "cos"}, "unknown hemisphere sampling 'cos' \\(did you mean 'cosine'\\?\\) \\(known: cosine, uniform\\)"),
        ({"rr_depth": 0}, "rr_depth must be >= 1, or -1 for no Russian roulette, got 0"),
        ({"rr_depth": -1, "max_depth": -1}, "max_depth -1 \\(unbounded\\) needs Russian roulette"),
        ({"integrator": "random_walk", "strategy": "bsdf"}, "integrator 'random_walk' has no setting 'strategy'"),
        ({"integrator": "distributed", "strategy": "bsdf"}, "integrator 'distributed' samples emitters its own way"),
        ({"integrator": "whitted", "hemisphere": "uniform"}, "integrator 'whitted' has no setting 'hemisphere'"),
    ],
)
def test_bad_choices_are_one_line_errors(kwargs, message):
    scene = ir.load_scene("cornell_box", resolution=(4, 4))
    with pytest.raises(ParameterError, match=message) as info:
        ir.render(scene, spp=1, progress=False, **kwargs)
    assert "\n" not in str(info.value)
