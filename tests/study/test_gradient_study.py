"""gradient_study on small images with fixed seeds: the estimators agree sample for sample, the
per-pixel contributions add up to the gradient, outputs are written, bad input fails before work."""

import json
import math

import pytest
import torch

import invrender as ir
from invrender.errors import ImageError, ParameterError
from invrender.study import gradients, parse_config, setup
from invrender.study.loss_gradients import Objective
from invrender.study.output import COLUMNS, write_study
from invrender.study.plots import plot_study
from invrender.study.statistics import log_slope, moments
from invrender.study.trials import gradient_sample, pixel_contributions

PARAMS = ["red.reflectance", "light.emission"]


@pytest.fixture(scope="module")
def cbox8():
    return ir.load_scene("cornell_box", resolution=(8, 8))


@pytest.fixture(scope="module")
def study(cbox8):
    configs = ["path/replay/correlated", "path/autodiff/correlated", "path/replay/decorrelated", "path/autodiff/decorrelated/rr_depth=2"]
    return ir.gradient_study(cbox8, PARAMS, configs, spp=[1, 4], trials=4, target_spp=64, reference_spp=16, reference_repeats=3, progress=False)


def test_replay_and_autodiff_give_the_same_samples(study):
    """The same estimate differentiated two ways: identical statistics for the same seeds."""
    for pairing in ("correlated",):
        for n in study.spp:
            a, b = study.run(f"path/replay/{pairing}", n).samples, study.run(f"path/autodiff/{pairing}", n).samples
            assert torch.allclose(a, b, rtol=1e-4, atol=1e-9), (a, b)
            assert not torch.equal(a[0], a[1])  # distinct seeds per trial


def test_references_are_shared_by_model_and_bias_is_mean_minus_reference(study):
    refs = study.references
    assert refs["path/replay/correlated"] is refs["path/autodiff/decorrelated/rr_depth=2"]  # roulette is unbiased
    s = study.summary("path/replay/correlated", 4, "component")
    assert torch.allclose(s.bias, s.moments.mean - refs["path/replay/correlated"].samples.mean(0))
    assert bool((s.bias_se > s.moments.std_error).all())  # the reference's error is included
    p = study.summary("path/replay/correlated", 4, "parameter")
    assert torch.allclose(p.moments.mean, torch.stack([s.moments.mean[:3].sum(), s.moments.mean[3:].sum()]))
    assert torch.allclose(p.efficiency, 1 / (p.moments.variance * p.seconds))


def test_pixel_contributions_add_up_to_the_gradient(cbox8):
    """Forward mode gives dI/dt per pixel; with the same dl/dI the pixels' contributions sum to the
    reverse-mode gradient, channel by channel, for either pairing."""
    scene = cbox8.with_params(detach=True)
    for n in PARAMS:
        scene.params[n].requires_grad_(True)
    target = torch.full((8, 8, 3), 0.3)
    for spec in ("path/replay/correlated", "path/autodiff/decorrelated"):
        objective = Objective(scene, target, "relative_l2")
        g, _, _ = gradient_sample(objective, PARAMS, parse_config(spec), 2, 6)
        for k, name in enumerate(PARAMS):
            c = pixel_contributions(objective, name, parse_config(spec), 2, 6)
            assert torch.allclose(c.sum((0, 1)), g[3 * k : 3 * k + 3], rtol=1e-4, atol=1e-10), (spec, name)


def test_pixel_maps_and_outputs(study, tmp_path):
    corr, decorr, roulette = study.pixel_maps  # replay and autodiff share a map; rr_depth changes the estimate
    assert decorr.configs == ("path/replay/decorrelated",) and roulette.configs == ("path/autodiff/decorrelated/rr_depth=2",)
    assert corr.configs == ("path/replay/correlated", "path/autodiff/correlated") and corr.spp == 1
    assert corr.variance.shape == (8, 8) and corr.total > 0
    paths = write_study(study, tmp_path) + plot_study(study, tmp_path)
    assert {p.name for p in paths} == {"results.csv", "results.json", "samples.pt", "variance.png", "bias.png", "pixel_variance.png"}
    lines = (tmp_path / "results.csv").read_text().splitlines()
    assert lines[0].split(",") == list(COLUMNS)
    assert len(lines) == 1 + len(study.configs) * len(study.spp) * (2 + 6)  # 2 parameter sums + 6 components
    data = json.loads((tmp_path / "results.json").read_text())
    assert set(data["slopes"]) == {c.label for c in study.configs} and len(data["pixel_maps"]) == 3
    saved = torch.load(tmp_path / "samples.pt")
    assert torch.equal(saved["runs"]["path/replay/correlated @ 4"]["samples"], study.run("path/replay/correlated", 4).samples)


def test_statistics():
    x = torch.tensor([[1.0, 2.0], [3.0, 2.0], [5.0, 2.0]])
    m = moments(x)
    assert m.mean.tolist() == [3.0, 2.0] and m.variance.tolist() == [4.0, 0.0]
    assert m.std_error[0] == pytest.approx((4 / 3) ** 0.5)
    slope, se = log_slope([1, 2, 4, 8], [8.0, 4.0, 2.0, 1.0], [0.8, 0.4, 0.2, 0.1])
    # log y has standard error 0.1 everywhere: se = 0.1 / sqrt(sum (log x - mean)^2) = 0.1 / (sqrt(5) ln 2)
    assert slope == pytest.approx(-1.0) and se == pytest.approx(0.1 / (5**0.5 * math.log(2)))
    assert log_slope([1, 2, 4], [4.0, 2.1, 0.9])[0] == pytest.approx(-1.07, abs=0.01)  # unweighted


@pytest.mark.parametrize(
    "kwargs, error, words",
    [
        (dict(spp=[]), ParameterError, "spp list is empty"),
        (dict(spp=[4, 0]), ParameterError, "spp must be positive"),
        (dict(trials=1), ParameterError, "trials must be >= 2"),
        (dict(configs=["path/replay/sideways"]), ParameterError, "unknown part 'sideways'"),
        (dict(configs=["glossy_walk/replay"]), ParameterError, "unknown part 'glossy_walk'"),
        (dict(params=["red.reflectance", "blue.reflectance"]), ParameterError, "unknown parameter 'blue.reflectance'"),
        (dict(loss="ssim"), ParameterError, "unknown loss 'ssim'"),
        (dict(at=-1.0), ParameterError, "at must be a positive factor"),
        (dict(at=3.0), ParameterError, "red.reflectance"),  # rho * 3 leaves [0, 1]
        (dict(pixel_param="white.reflectance"), ParameterError, "not one of the studied"),
        (dict(target=torch.zeros(4, 4, 3)), ImageError, "4x4"),
    ],
)
def test_bad_input_fails_before_any_rendering(cbox8, monkeypatch, kwargs, error, words):
    def no_work(*a, **k):
        raise AssertionError("rendered before checking the input")

    monkeypatch.setattr(gradients, "gradient_sample", no_work)
    monkeypatch.setattr(setup, "render", no_work)  # the study target is rendered in study.setup
    args = {"params": PARAMS, **kwargs}
    with pytest.raises(error, match=words) as e:
        ir.gradient_study(cbox8, args.pop("params"), progress=False, **args)
    assert "\n" not in str(e.value)
