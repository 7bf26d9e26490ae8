"""Levenberg-Marquardt / Gauss-Newton fits on path records (optimistix), with decorrelated residual
and Jacobian record sets, outer re-recording rounds, standard errors and checkpoints."""

from __future__ import annotations

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from tests.conftest import furnace

NAMES = ["white.reflectance", "red.reflectance", "light.emission"]


@pytest.fixture(scope="module")
def problem():
    scene = ir.load_scene("cornell_box", resolution=(24, 24))
    truth = {n: scene.params[n].clone() for n in NAMES}
    target = ir.render(scene, spp=1024, max_depth=5, seed=77, progress=False)
    with torch.no_grad():
        scene.params["white.reflectance"].fill_(0.5)
        scene.params["red.reflectance"].fill_(0.5)
        scene.params["light.emission"].fill_(5.0)
    return scene, target, truth


@pytest.mark.parametrize("solver", ["lm", "gauss_newton"])
def test_least_squares_fit_recovers_the_cornell_box(problem, solver, tmp_path):
    """Levenberg-Marquardt from grey 0.5 and emission 5; undamped Gauss-Newton (which overshoots
    from far away) from 10% off, its first round at 64 spp."""
    scene, target, truth = problem
    spp = 16
    if solver == "gauss_newton":
        scene, spp = ir.load_scene("cornell_box", resolution=(24, 24)), 64
        with torch.no_grad():
            for n in NAMES:
                scene.params[n].mul_(0.9)
    res = ir.fit(scene, target, NAMES, truth=truth, solver=solver, max_depth=5, spp=spp, rounds=4, progress=False, checkpoint=tmp_path / "ck.pt")
    assert max(res.errors.values()) < 0.1, res.errors  # a small, weakly determined problem (B channel SEs ~4%)
    for n in NAMES:  # within the reported standard errors (the rounds stop once moves are noise)
        assert bool(((res.params[n] - truth[n]).abs() < 4 * res.std_error[n]).all()), (n, res.params[n], truth[n], res.std_error[n])
    assert [h["spp"] for h in res.history] == [spp * 4**r for r in range(len(res.history))]
    assert set(res.std_error) == set(NAMES) and all(bool((v > 0).all()) for v in res.std_error.values())
    corr = res.history[-1]["correlation"]
    assert corr["channels"][0] == "white.reflectance[R]" and len(corr["matrix"]) == 3 * len(NAMES)
    assert all(abs(corr["matrix"][i][i] - 1) < 1e-9 for i in range(3 * len(NAMES)))
    from invrender.inverse.report import report_dict

    assert report_dict(res)["correlation"] == corr
    assert scene.params["light.emission"].tolist() != res.params["light.emission"].tolist()  # the input scene is left unchanged
    # a resumed fit that has all its rounds ends where the fit ended
    again = ir.fit(scene, target, NAMES, truth=truth, solver=solver, max_depth=5, spp=spp, rounds=4, progress=False, checkpoint=tmp_path / "ck.pt", resume=True)
    for n in NAMES:
        torch.testing.assert_close(again.params[n], res.params[n])


def test_bad_solver_settings_are_refused(problem):
    scene, target, _ = problem
    with pytest.raises(ParameterError, match="unknown solver 'newton'"):
        ir.fit(scene, target, NAMES, solver="newton", progress=False)
    with pytest.raises(ParameterError, match="needs a finite max_depth"):
        ir.fit(scene, target, NAMES, solver="lm", max_depth=-1, progress=False)
    with pytest.raises(ParameterError, match="relative_l2"):
        ir.fit(scene, target, NAMES, solver="lm", loss="l1", progress=False)


def test_standard_errors_are_calibrated():
    """Over 20 independent seeds (target and records), the truth lies within 2 reported standard
    errors in at least 85% of the parameter channels."""
    from invrender.estimators.records import record_paths
    from invrender.inverse.least_squares import solve

    scene = ir.load_scene("cornell_box", resolution=(12, 12))
    truth = {n: scene.params[n].detach().double().clone() for n in NAMES}
    inside = []
    for seed in range(20):
        target = ir.render(scene, spp=512, max_depth=4, seed=500 + seed, progress=False)
        a = record_paths(scene, NAMES, spp=64, max_depth=4, seed=2 * seed + 1, progress=False)
        b = record_paths(scene, NAMES, spp=64, max_depth=4, seed=2 * seed + 2, progress=False)
        sol = solve([a], [b], [target], truth)
        inside += [bool(x) for n in NAMES for x in ((sol.values[n] - truth[n]).abs() < 2 * sol.std_error[n])]
    rate = sum(inside) / len(inside)
    print(f"calibration: {rate:.1%} of {len(inside)} channels within 2 standard errors")
    assert rate >= 0.85, rate


def test_identifiability_names_the_scale_ambiguity():
    """Direct light only (max_depth 2) and the light out of view: every pixel is rho * eps * G, so
    the targets fix the products rho_c eps_c and not the scale between them; with the light in
    view (it shows eps itself) everything is determined."""
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    down = ir.Camera(origin=(0, 0.2, 1.5), target=(0, -1, 0), up=(0, 0, -1), fov=40)
    looking_down = scene.with_camera(down)
    target = ir.render(looking_down, spp=64, max_depth=2, seed=9, progress=False)
    info = ir.identifiability(looking_down, target, ["white.reflectance", "light.emission"], spp=16, max_depth=2)
    assert len(info.weak) == 3  # one scale per channel
    for combo in info.weak:
        assert {c.split("[")[0] for c in combo} == {"white.reflectance", "light.emission"}
        assert len({c.split("[")[1] for c in combo}) == 1  # the same channel of both
    assert "light.emission" in info.describe()
    seen = ir.identifiability(scene, ir.render(scene, spp=64, max_depth=2, seed=9, progress=False), ["white.reflectance", "light.emission"], spp=16, max_depth=2)
    assert seen.weak == [] and all(bool((v > 0).all()) for v in seen.std_error.values())
    with pytest.warns(UserWarning, match="do not determine these parameter combinations"):
        ir.fit(looking_down, target, ["white.reflectance", "light.emission"], solver="lm", max_depth=2, spp=16, rounds=2, progress=False)


def test_decorrelation_removes_the_fixed_sample_bias_in_the_furnace():
    """Fitting eps of the furnace (rho 0.5) to its exact radiance eps / (1 - rho) with one fixed
    sample set is biased: the image is eps * a per pixel with a the path's count of emitting
    vertices (the analog random walk: roulette from the first bounce, survival rho), and least
    squares on the same a for residual and Jacobian gives eps * E[a]^2 / E[a^2], i.e. eps / (1 + rho)
    at 1 spp (Var(n) / E[n]^2 = rho, docs/closed_forms.md#furnace): 2/3 of the truth. Residual and
    Jacobian from independent sets remove it."""
    from invrender.estimators.records import record_paths
    from invrender.inverse.least_squares import solve

    rho, eps = 0.5, 2.0
    scene = furnace(rho=rho, eps=1.0, resolution=(64, 64))
    target = torch.full((64, 64, 3), eps / (1 - rho))
    kw = dict(spp=1, max_depth=40, integrator="random_walk", rr_depth=1, progress=False)
    a = record_paths(scene, ["glow.emission"], seed=1, **kw)
    b = record_paths(scene, ["glow.emission"], seed=2, **kw)
    start = {"glow.emission": torch.ones(3, dtype=torch.float64)}
    correlated = solve([a], [a], [target], start).values["glow.emission"]
    decorrelated = solve([a], [b], [target], start).values["glow.emission"]
    assert (correlated / eps - 1 / (1 + rho)).abs().max() < 0.03, correlated
    assert (decorrelated / eps - 1).abs().max() < 0.03, decorrelated


def test_rounds_accumulate_their_records_and_a_resumed_fit_re_records_them(problem, tmp_path, monkeypatch):
    """Round r traces only its new samples (spp 4, then 12, 48, ... a pixel per set, one seed per
    set) and solves on every sample so far; the rounds stop (the nested rounds' move test); a fit
    stopped after two rounds and resumed re-records their passes at their record points and ends
    exactly where the uninterrupted fit does."""
    from invrender.estimators import records

    scene, target, truth = problem
    traced = []
    real = records.record_paths
    monkeypatch.setattr(records, "record_paths", lambda *a, **k: traced.append((k["spp"], k["first_sample"], k["seed"])) or real(*a, **k))
    kw = dict(truth=truth, solver="lm", max_depth=5, spp=4, rounds=6, progress=False)
    whole = ir.fit(scene, target, NAMES, **kw)
    rounds = len(whole.history)
    assert whole.history[-1]["converged"] and rounds < 6, [h["moved_in_std_errors"] for h in whole.history]
    assert max(whole.errors.values()) < 0.1, whole.errors
    assert [h["spp"] for h in whole.history] == [4 * 4**r for r in range(rounds)]
    passes = [(4, 0)] + [(3 * 4**r, 4**r) for r in range(1, rounds)]
    assert traced == [(n, a, s) for n, a in passes for s in (0, 1)]  # A and B, each its own seed
    ck = tmp_path / "ck.pt"
    ir.fit(scene, target, NAMES, checkpoint=ck, **{**kw, "rounds": 2})
    traced.clear()
    again = ir.fit(scene, target, NAMES, checkpoint=ck, resume=True, **kw)
    assert traced == [(n, a, s) for n, a in passes for s in (0, 1)]
    for n in NAMES:
        torch.testing.assert_close(again.params[n], whole.params[n], rtol=0, atol=0)


def test_the_reduced_problem_has_the_normal_equations_of_every_pixel():
    """reduce_records: at any values, set A's residual keeps its norm and set B's Jacobian gives
    the same J_B^T r_A and J_B^T J_B as the full per-pixel problem (with a sensor's gains too), in
    a few rows a channel."""
    from invrender.estimators.records import record_paths
    from invrender.inverse.least_squares import _full_jacobian, _Layout, _residual, _weights, reduce_records

    scene = ir.load_scene("cornell_box", resolution=(12, 12))
    target = ir.render(scene, spp=32, max_depth=7, seed=5, progress=False)
    a = record_paths(scene, NAMES, spp=1, max_depth=7, seed=1, progress=False)
    b = record_paths(scene, NAMES, spp=6, max_depth=7, seed=2, progress=False)
    assert a.exponents.shape != b.exponents.shape or not a.exponents.equal(b.exponents)  # the union is needed
    w = _weights([target])
    ra_, rb_, rt, rw = reduce_records([a], [b], [target], w)
    assert ra_[0].coefficients.shape[1] == 256 and rt[0].shape == (1, 256, 3)
    layout = _Layout.of(a)
    g = torch.tensor([1.3, 0.9, 1.1], dtype=torch.float64)
    for seed in range(2):
        values = {n: torch.rand(3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64) * 0.8 + 0.1 for n in NAMES}
        full_r, red_r = _residual(a, values, target, w[0], g), _residual(ra_[0], values, rt[0], rw[0], g)
        full_J = _full_jacobian([b], w, values, None, None, None, layout)
        red_J = _full_jacobian(rb_, rw, values, None, None, None, layout)
        torch.testing.assert_close(red_r.norm(), full_r.norm(), rtol=1e-10, atol=0)
        torch.testing.assert_close(red_J.T @ _residual(ra_[0], values, rt[0], rw[0]), full_J.T @ _residual(a, values, target, w[0]), rtol=1e-9, atol=1e-12)
        torch.testing.assert_close(red_J.T @ red_J, full_J.T @ full_J, rtol=1e-9, atol=1e-12)
