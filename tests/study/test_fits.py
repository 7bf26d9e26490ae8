"""Fit studies: configurations mapped onto fit settings (refused when a fit cannot express them),
time to a threshold from a fit's history, and ``invrender variance --fits``."""

import json
import math

import pytest
import torch

import invrender as ir
from invrender.cli import main
from invrender.errors import ParameterError
from invrender.study.fits import FitRun, fit_settings, fit_study


@pytest.mark.parametrize(
    "spec, settings",
    [
        ("path/replay/decorrelated", {"integrator": "path", "estimator": "replay", "decorrelate": True}),
        ("random_walk/autodiff/correlated/max_depth=4", {"integrator": "random_walk", "estimator": "autodiff", "decorrelate": False, "max_depth": 4}),
        ("path/replay/control_variate/sampler=antithetic", {"integrator": "path", "estimator": "replay", "decorrelate": True, "control_variate": True, "sampler": "antithetic"}),
        # the integrator's own settings go into the fit's integrator spec (issue 18: a fit can set them)
        ("path/replay/decorrelated/rr_depth=2/hemisphere=uniform", {"integrator": {"type": "path", "rr_depth": 2, "hemisphere": "uniform"}, "estimator": "replay", "decorrelate": True}),
    ],
)
def test_configurations_map_onto_fit_settings(spec, settings):
    assert fit_settings(spec) == settings


@pytest.mark.parametrize(
    "spec, words",
    [
        ("path/replay/decorrelated/memory_mb=64", "option 'memory_mb' has no fit setting"),
        ("path/replay/decorrelated/backend=torch", "option 'backend' has no fit setting"),
        ("path/replay/control_variate/cv_steps=4", "cv_steps does not apply to a fit"),
    ],
)
def test_what_a_fit_cannot_express_is_refused(spec, words):
    with pytest.raises(ParameterError, match=words) as e:
        fit_settings(spec)
    assert "\n" not in str(e.value)


def test_time_to_a_threshold_first_reached_and_settled():
    error = torch.tensor([[0.5], [0.015], [0.03], [0.009], [0.012], [0.008], [0.005]], dtype=torch.float64)
    run = FitRun("c", 0, {}, torch.arange(1.0, 8.0, dtype=torch.float64), error, torch.zeros(7), torch.full((7,), 4), 1.0, {})
    assert run.reached(0.02) == 1 and run.settled(0.02) == 3 and run.time_to(0.02) == 2.0 and run.time_to(0.02, settled=True) == 4.0
    assert run.reached(0.01) == 3 and run.settled(0.01) == 5
    assert run.reached(0.001) is None and math.isinf(run.time_to(0.001))


def test_a_small_fit_study(tmp_path):
    scene = ir.load_scene("cornell_box", resolution=(6, 6))
    configs = ["path/replay/decorrelated", "path/autodiff/control_variate/sampler=antithetic"]
    study = fit_study(scene, ["light.emission"], configs, repeats=2, steps=4, spp=2, spp_final=4, target_spp=32, progress=False)
    assert [(r.config, r.repeat) for r in study.runs] == [(configs[0], 0), (configs[1], 0), (configs[0], 1), (configs[1], 1)]  # interleaved
    assert study.runs[1].settings["control_variate"] and study.runs[1].settings["sampler"] == "antithetic"
    run = study.runs[0]
    assert run.errors.shape == (4, 1) and bool((run.seconds[1:] >= run.seconds[:-1]).all())
    assert run.errors[0, 0] < 0.5  # started at half the emission, one step made
    assert study.start["light.emission"] == pytest.approx([v / 2 for v in study.truth["light.emission"]])
    summary = study.summary(configs[0])
    finals = [float(r.error[-1]) for r in study.runs_of(configs[0])]
    assert summary["repeats"] == 2 and summary["final_error"] == pytest.approx(sum(finals) / 2)  # the median of two


def test_fit_study_checks_before_any_work(monkeypatch):
    from invrender.study import fits

    def no_work(*a, **k):
        raise AssertionError("worked before checking the input")

    monkeypatch.setattr(fits, "fit", no_work)
    monkeypatch.setattr(fits, "study_target", no_work)
    scene = ir.load_scene("cornell_box", resolution=(4, 4))
    for kwargs, words in (
        ({"configs": ["path/replay/decorrelated", "path/replay/decorrelated/rr_depth=0"]}, "rr_depth"),
        ({"settings": {"sampler": "independent"}}, "set by each configuration"),
        ({"settings": {"lr": -1.0}}, "lr must be positive"),
        ({"repeats": 0}, "repeats must be positive"),
        ({"at": -2.0}, "at must be a positive factor"),
    ):
        with pytest.raises(ParameterError, match=words):
            fit_study(scene, ["light.emission"], progress=False, **kwargs)


def test_cli_fits_write_tables_and_figure(tmp_path, capsys):
    out = tmp_path / "fits"
    args = ["variance", "cornell_box", "--fits", "--params", "light.emission", "--resolution", "4x4", "--steps", "3", "--fit-spp", "2",
            "--target-spp", "16", "--configs", "path/replay/decorrelated,path/replay/decorrelated/sampler=antithetic", "--quiet", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    stdout = capsys.readouterr().out
    assert "to 1% settled" in stdout and "path/replay/decorrelated/sampler=antithetic" in stdout
    assert {p.name for p in out.iterdir()} == {"fits.csv", "fits_summary.csv", "fits.json", "fits.png"}
    lines = (out / "fits.csv").read_text().splitlines()
    assert lines[0] == "config,repeat,step,spp,seconds,loss,error,error light.emission" and len(lines) == 1 + 2 * 3
    data = json.loads((out / "fits.json").read_text())
    assert data["fit_settings"]["path/replay/decorrelated/sampler=antithetic"]["sampler"] == "antithetic" and data["settings"]["spp_final"] == 2


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--fits", "--trials", "5"], "--trials applies to gradient studies"),
        (["--steps", "5"], "--steps applies to fits only"),
        (["--fits", "--configs", "path/replay/decorrelated/memory_mb=64"], "option 'memory_mb' has no fit setting"),
        (["--fits", "--fit-spp", "4,8,16"], "one or two values"),
    ],
)
def test_cli_fits_bad_input_is_one_line(extra, words, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code = main(["variance", "cornell_box", "--params", "light.emission", "--resolution", "4x4", "--out", "out", *extra])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and words in err, err
    assert not any(tmp_path.iterdir())
