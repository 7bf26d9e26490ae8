"""Gradients of the Monte Carlo estimate: estimators against central finite differences with common
random numbers, against each other, and against the furnace's closed forms (docs/closed_forms.md#furnace)."""

import dataclasses

import pytest
import torch

import invrender as ir
from invrender.core.driver import RenderSettings
from tests.conftest import furnace

NAMES = ["red.reflectance", "white.reflectance", "light.emission"]


def weighted_loss(scene, weights, estimator=None, **kw):
    return (ir.render(scene, spp=32, max_depth=4, seed=7, estimator=estimator, progress=False, **kw) * weights).sum()


@pytest.fixture(scope="module")
def cbox_fd():
    """Central differences of a fixed random pixel weighting of the 32x32 Cornell box at max_depth 4
    (below the Russian-roulette start, so with common random numbers the estimate is a smooth
    polynomial in the parameters)."""
    scene = ir.load_scene("cornell_box", resolution=(32, 32))
    weights = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(1))
    fd = {}
    with torch.no_grad():
        for name in NAMES:
            p = scene.params[name]
            fd[name] = torch.zeros(3)
            for c in range(3):
                h = 1e-2 * max(1.0, float(p[c]))
                p[c] += h
                plus = weighted_loss(scene, weights)
                p[c] -= 2 * h
                minus = weighted_loss(scene, weights)
                p[c] += h
                fd[name][c] = (plus - minus) / (2 * h)
    return scene, weights, fd


@pytest.fixture(scope="module")
def cbox_grads(cbox_fd):
    scene, weights, _ = cbox_fd
    out = {}
    for estimator in ("autodiff", "replay"):
        for name in NAMES:
            scene.params[name].requires_grad_(True).grad = None
        weighted_loss(scene, weights, estimator).backward()
        out[estimator] = {name: scene.params[name].grad.clone() for name in NAMES}
        for name in NAMES:
            scene.params[name].requires_grad_(False).grad = None
    return out


@pytest.mark.parametrize("estimator", ["autodiff", "replay"])
def test_gradients_match_finite_differences(cbox_fd, cbox_grads, estimator):
    _, _, fd = cbox_fd
    for name in NAMES:
        rel = (cbox_grads[estimator][name] - fd[name]).abs() / fd[name].abs()
        assert (rel < 0.02).all(), (name, rel)


def test_replay_equals_autodiff(cbox_grads):
    for name in NAMES:
        assert torch.allclose(cbox_grads["replay"][name], cbox_grads["autodiff"][name], rtol=1e-4)


@pytest.mark.parametrize("estimator", ["autodiff", "replay"])
@pytest.mark.parametrize("depth", [3, 6])
def test_furnace_gradients_match_closed_form(estimator, depth):
    """L_D = eps (1 - rho^D)/(1 - rho); with cosine BSDF sampling (random_walk) the estimate and its
    gradient have zero variance, so they must hit the closed forms to 1e-4."""
    rho, eps = 0.5, 2.0
    scene = furnace(rho=rho, eps=eps, resolution=(8, 8))
    r, e = scene.params["wall.reflectance"].requires_grad_(True), scene.params["glow.emission"].requires_grad_(True)
    img = ir.render(scene, integrator="random_walk", spp=2, max_depth=depth, rr_depth=99, estimator=estimator, progress=False)
    img.mean().backward()
    dL_drho = eps * (1 - depth * rho ** (depth - 1) + (depth - 1) * rho**depth) / (1 - rho) ** 2
    dL_deps = (1 - rho**depth) / (1 - rho)
    assert torch.allclose(r.grad, torch.full((3,), dL_drho / 3), rtol=1e-4)  # mean over 3 channels
    assert torch.allclose(e.grad, torch.full((3,), dL_deps / 3), rtol=1e-4)


def test_path_tracer_furnace_gradient_mean():
    """With NEE + MIS on the tessellated sphere the gradient is noisy like the image (see
    test_furnace.py); its mean over 16x16x64 paths is held to 1e-3."""
    rho, eps, depth = 0.5, 1.0, 4
    scene = furnace(rho=rho, eps=eps)
    r = scene.params["wall.reflectance"].requires_grad_(True)
    ir.render(scene, spp=64, max_depth=depth, rr_depth=99, progress=False).mean().backward()
    dL_drho = eps * (1 - depth * rho ** (depth - 1) + (depth - 1) * rho**depth) / (1 - rho) ** 2
    assert abs(r.grad.sum().item() - dL_drho) / dL_drho < 1e-3


def test_textured_reflectance_gradient_matches_autodiff():
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    with torch.no_grad():
        scene.params["white.reflectance"] = scene.params["white.reflectance"].expand(4, 4, 3).clone()
    tex = scene.params["white.reflectance"].requires_grad_(True)
    grads = []
    for estimator in ("autodiff", "replay"):
        tex.grad = None
        ir.render(scene, spp=8, max_depth=3, estimator=estimator, progress=False).sum().backward()
        grads.append(tex.grad.clone())
    assert grads[0].abs().sum() > 0 and torch.allclose(grads[0], grads[1], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("kept", [True, False])
def test_a_chunk_whose_passes_diverge_is_traced_again_by_one_bounce(monkeypatch, kept):
    """The primal pass runs the fused bounce (compiled) and the adjoint pass the torch bounce; where
    float rounding makes them decide a path differently (a roulette draw), the adjoint pass's
    queries differ from the primal's: that chunk's primal pass is traced again by the torch bounce,
    and the gradient is the one of passes that agree (seen on the specular box at 128^2, 64 spp,
    which failed with an error before)."""
    from invrender.backends.accel import QueriesDiverged, RepeatedQueries
    from invrender.estimators import backpropagate
    from invrender.plugins.integrators import make_integrator

    scene = ir.load_scene("cornell_specular", resolution=(16, 16))
    name = "glossy.specular_reflectance"  # not a Lambertian colour: replayed by the adjoint pass
    weights = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(2))

    def gradient() -> torch.Tensor:
        p = scene.params[name].detach().clone().requires_grad_(True)
        work = dataclasses.replace(scene, params={**scene.params, name: p})
        if kept:  # the forward pass keeps each path's radiance and shadow-ray answers
            (ir.render(work, spp=8, seed=3, estimator="replay", progress=False, chunk_paths=700) * weights).sum().backward()
        else:  # a decorrelated gradient: replay traces the primal pass itself
            backpropagate(work, weights, make_integrator("path"), RenderSettings(spp=8, seed=3, progress=False, chunk_paths=700), "replay")
        return p.grad

    expected = gradient()
    answer, diverged = RepeatedQueries._answer, []

    def diverging(self, kind, n, ask):
        if self._next == 2 and not diverged:  # the first repeated trace takes another turn at its third query
            diverged.append(kind)
            raise QueriesDiverged("diverged")
        return answer(self, kind, n, ask)

    monkeypatch.setattr(RepeatedQueries, "_answer", diverging)
    got = gradient()
    assert diverged and float(expected.abs().max()) > 0
    assert (got - expected).abs().max() <= 1e-4 * expected.abs().max()


@pytest.mark.parametrize("scene_name, integrator", [("cornell_box", "path"), ("cornell_specular", "whitted")])
def test_replay_reuses_the_forward_pass_radiance(monkeypatch, scene_name, integrator):
    """``loss(render(...)).backward()`` with replay skips the primal pass when the forward pass kept
    each path's radiance: the same gradient as tracing it again (paths that split included), and
    fewer traces."""
    from invrender.estimators import replay
    from invrender.plugins.integrators import INTEGRATORS

    scene = ir.load_scene(scene_name, resolution=(16, 16))
    weights = torch.rand(16, 16, 3, generator=torch.Generator().manual_seed(2))
    name = scene.materials[0] + ".reflectance"
    traces = []
    cls = INTEGRATORS[integrator]
    original = cls.trace
    monkeypatch.setattr(cls, "trace", lambda self, ctx, state, film: (traces.append(type(film).__name__), original(self, ctx, state, film))[1])
    grads = {}
    for share in (replay.KEEP_SHARE, 0.0):
        monkeypatch.setattr(replay, "KEEP_SHARE", share)
        traces.clear()
        p = scene.params[name].requires_grad_(True)
        p.grad = None
        (ir.render(scene, integrator, spp=8, seed=3, estimator="replay", progress=False, chunk_paths=700) * weights).sum().backward()
        grads[share] = (p.grad.clone(), list(traces))
        p.requires_grad_(False).grad = None
    kept, retraced = grads[replay.KEEP_SHARE], grads[0.0]
    assert kept[0].abs().max() > 0  # the same gradient, up to the float32 rounding of the kept radiances
    assert (kept[0] - retraced[0]).abs().max() <= 1e-5 * retraced[0].abs().max()
    chunks = -(-16 * 16 * 8 // 700)
    assert kept[1].count("PathFilm") == chunks and kept[1].count("AdjointFilm") == chunks  # forward + adjoint
    assert retraced[1].count("PathFilm") == chunks and retraced[1].count("Film") == chunks  # + the plain forward
