"""solver="auto": the table of which solver a fit's parameters and settings choose, and why; the
transport-matrix route through ir.fit; Adam's plateau rule and the warnings of fits that did not
converge."""

from __future__ import annotations

import warnings

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.inverse.convergence import ConvergenceWarning, plateau
from invrender.inverse.fit import FitSettings
from invrender.inverse.solver_choice import choose_solver

CBOX = ir.load_scene("cornell_box", resolution=(8, 8))
SPECULAR = ir.load_scene("cornell_specular", resolution=(8, 8))
SKY = ir.load_scene("sky_spheres", resolution=(8, 8), map_size=(4, 8))
BIG_SKY = ir.load_scene("sky_spheres", resolution=(8, 8), map_size=(16, 32))
ALBEDOS = ["white.reflectance", "red.reflectance"]
SENSOR = ["sensor.exposure", "sensor.white_balance"]


@pytest.mark.parametrize(
    "scene, names, settings, solver, words",
    [
        (CBOX, ALBEDOS + ["light.emission"], {}, "lm", "polynomial factor of the path weights: lm on path records"),
        (CBOX, ALBEDOS + SENSOR, {}, "lm", "lm on path records"),
        (CBOX, ALBEDOS, {"rounds": 3, "spp": 8}, "lm", "lm on path records"),
        (CBOX, ALBEDOS, {"loss": "l1"}, "adam", "loss 'l1': the least-squares solvers minimize relative_l2 only"),
        (CBOX, ALBEDOS, {"control_variate": True}, "adam", "control_variate is Adam's"),
        (CBOX, ALBEDOS, {"decorrelate": False}, "adam", "decorrelate=False is Adam's"),
        (CBOX, ALBEDOS, {"max_depth": -1}, "adam", "max_depth -1 (unbounded)"),
        (CBOX, ALBEDOS, {"integrator": "radiosity"}, "adam", "integrator 'radiosity': its image is a rational function"),
        (CBOX, ALBEDOS, {"steps": 50, "lr": 0.1}, "adam", "steps, lr given: Adam's settings"),
        (CBOX, ALBEDOS, {"steps": 50, "precision": 0.01}, "lm", "lm on path records"),  # both solvers' settings: the parameters decide
        (CBOX, SENSOR, {}, "adam", "only the sensor is fitted"),
        (CBOX, ALBEDOS, {"solver": "gauss_newton"}, "gauss_newton", "solver 'gauss_newton' asked for"),
        (SPECULAR, ["glossy.roughness"], {}, "lm", "glossy.roughness is a roughness, not a polynomial factor of a path's weight: lm on re-traced renders"),
        (SPECULAR, ["glossy.roughness"] + SENSOR, {}, "adam", "lm on re-traced renders (glossy.roughness is a roughness"),
        (SKY, ["sky.emission"], {}, "transport_matrix", "sky.emission is an environment map (4x8 texels) fitted alone"),
        (SKY, ["sky.emission"], {"prior_weight": 1e-3}, "lm", "lm on path records"),
        (SKY, ["sky.emission", "floor.reflectance"], {}, "joint", "sky.emission is an environment map (4x8 texels) fitted with floor.reflectance: the images are bilinear"),
        (BIG_SKY, ["sky.emission", "floor.reflectance", "diffuse.reflectance"], {}, "joint", "the transport-matrix solve of the map alternates with lm on path records"),
        (SKY, ["sky.emission", "floor.reflectance"], {"rounds": 3}, "lm", "lm on path records"),
        (BIG_SKY, ["sky.emission", "floor.reflectance"], {"rounds": 3}, "adam", "sky.emission has 512 texels: lm's path records"),
        (SKY, ["sky.emission", "glossy.roughness"], {}, "lm", "lm on re-traced renders"),
        (SKY, ["sky.emission"], {"loss": "l2"}, "adam", "loss 'l2'"),
    ],
)
def test_auto_chooses_by_the_parameters(scene, names, settings, solver, words):
    choice = choose_solver(scene, names, FitSettings(**settings), set(settings))
    assert choice.solver == solver and words in choice.reason, choice


def test_transport_matrix_named_where_it_cannot_run():
    with pytest.raises(ParameterError, match=r"solver 'transport_matrix' fits one environment map's texels alone: 2 parameters fitted"):
        choose_solver(SKY, ["sky.emission", "floor.reflectance"], FitSettings(solver="transport_matrix"))
    with pytest.raises(ParameterError, match=r"light is an emitter of type 'area', not an environment map"):
        choose_solver(CBOX, ["light.emission"], FitSettings(solver="transport_matrix"))
    with pytest.raises(ParameterError, match="unknown solver 'newton'"):
        FitSettings(solver="newton")


def test_fit_says_which_solver_and_converges(tmp_path, capsys):
    """ir.fit's default on two albedos: lm on records, said on stderr and in the result; an envmap
    alone: the transport matrix, wrapped as a FitResult (a resumed fit returns it as it was)."""
    truth = ir.load_scene("cornell_box", resolution=(12, 12))
    target = ir.render(truth, spp=256, max_depth=3, seed=1, progress=False)
    start = truth.with_params({n: torch.full((3,), 0.5) for n in ALBEDOS})
    res = ir.fit(start, target, ALBEDOS, max_depth=3, spp=16, truth={n: truth.params[n] for n in ALBEDOS})
    assert res.solver == "lm" and res.settings.solver == "lm" and "lm on path records" in res.solver_reason
    assert res.converged is True and max(res.errors.values()) < 0.05, res.errors
    assert "fit: solver lm: every parameter is a polynomial factor" in capsys.readouterr().err

    sky = ir.load_scene("sky_spheres", resolution=(12, 12), map_size=(3, 4))
    hidden = {"type": "path", "hide_emitters": True}
    sky_target = ir.render(sky, hidden, spp=256, max_depth=2, seed=3, progress=False)
    flat = sky.with_params({"sky.emission": torch.ones(3, 4, 3)})
    kw = dict(integrator=hidden, max_depth=2, progress=False, checkpoint=tmp_path / "map.pt")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # texels no view sees
        res = ir.fit(flat, sky_target, ["sky.emission"], **kw)
        again = ir.fit(flat, sky_target, ["sky.emission"], resume=True, **kw)
    assert res.solver == "transport_matrix" and res.converged is True and len(res.history) == 1
    assert res.params["sky.emission"].shape == (3, 4, 3) and bool((res.params["sky.emission"] >= 0).all())
    assert res.std_error["sky.emission"].shape == (3, 4, 3) and "prior weight" in res.history[0]["transport_matrix"]
    relit = ir.render(res.scene, hidden, spp=256, max_depth=2, seed=3, progress=False)
    assert abs(float(relit.mean() / sky_target.mean()) - 1) < 0.03
    torch.testing.assert_close(again.params["sky.emission"], res.params["sky.emission"])


def test_plateau_rule():
    """A falling loss is no plateau; noise around a constant is; a fall smaller than the noise is."""
    g = torch.Generator().manual_seed(0)
    noise = (0.01 * torch.randn(40, generator=g)).tolist()
    assert not plateau([1.0 - 0.01 * t for t in range(40)], 20).reached  # 20% down over a window
    flat = plateau([1.0 + e for e in noise], 20)
    assert flat.reached and 0.001 < flat.noise < 0.01, flat  # noise 1% a step: about 0.3% on the mean
    assert plateau([1.0 - 0.0001 * t + e for t, e in enumerate(noise)], 20).reached  # 0.2% fall, hidden by the noise
    assert plateau([1.0] * 39, 20) is None and plateau([1.0] * 40, 0) is None


def test_adam_stops_on_its_plateau_or_warns():
    """Adam on one emission: with many steps it stops on the plateau (before the cap, converged);
    with few it warns in one line with the improvement and the gradient norm."""
    truth = ir.load_scene("cornell_box", resolution=(8, 8))
    target = ir.render(truth, spp=256, max_depth=2, seed=1, progress=False)
    start = truth.with_params({"light.emission": torch.full((3,), 5.0)})
    kw = dict(solver="adam", max_depth=2, spp=4, spp_final=4, plateau_window=10, progress=False)
    res = ir.fit(start, target, ["light.emission"], steps=400, **kw)
    assert res.converged is True and 40 <= len(res.history) < 400, len(res.history)
    assert res.solver_reason == "solver 'adam' asked for" and "grad_norm" in res.history[-1]
    with pytest.warns(ConvergenceWarning, match=r"Adam did not converge in 6 steps: too few steps at spp_final .*gradient norm \d"):
        short = ir.fit(start, target, ["light.emission"], steps=6, **kw)
    assert short.converged is False
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConvergenceWarning)
        off = ir.fit(start, target, ["light.emission"], steps=6, **{**kw, "plateau_window": 0})
    assert off.converged is None and len(off.history) == 6


def test_lm_on_its_round_cap_warns():
    truth = ir.load_scene("cornell_box", resolution=(8, 8))
    target = ir.render(truth, spp=256, max_depth=2, seed=1, progress=False)
    start = truth.with_params({"white.reflectance": torch.full((3,), 0.5)})
    with pytest.warns(ConvergenceWarning, match=r"lm did not converge in 1 of 1 rounds: the last round moved a channel by .* standard errors \(converged below 2.5\); give more rounds"):
        res = ir.fit(start, target, ["white.reflectance"], solver="lm", rounds=1, max_depth=2, spp=8, progress=False)
    assert res.converged is False
    with pytest.warns(ConvergenceWarning, match=r"the largest relative standard error is .*% \(precision 0.01% asked\)"):
        ir.fit(start, target, ["white.reflectance"], solver="lm", rounds=1, precision=1e-4, max_depth=2, spp=8, progress=False)
