"""The built-in furnace check: measured gradient bias and variance against the closed forms of
docs/closed_forms.md#gradient-statistics-in-the-furnace, under the settings where they hold."""

import pytest

from invrender.errors import ParameterError
from invrender.study.closed_forms import analog_eps_bias
from invrender.study import parse_config
from invrender.study.furnace import furnace_check, has_closed_form

ANALOG = "random_walk/autodiff/{}/max_depth=-1/rr_depth=1"


@pytest.fixture(scope="module")
def check():
    configs = [ANALOG.format("correlated"), ANALOG.format("decorrelated"), "path/autodiff/correlated"]
    return furnace_check(configs, spp=(1, 4), trials=120, resolution=(16, 16), progress=False)


@pytest.mark.slow
def test_correlated_bias_and_variance_of_the_analog_walk(check):
    """Bias 2 eps rho/((1-rho)^2 N) of dl/deps (4 and 1 at N = 1, 4), its rho analogue, and the
    variances, each within 3.5 standard errors."""
    rows = [r for r in check.rows if r.config == ANALOG.format("correlated")]
    assert len(rows) == 4
    for r in rows:
        if r.parameter == "glow.emission":
            assert r.predicted_mean - r.truth == pytest.approx(analog_eps_bias(0.5, 1.0, r.spp))
        assert abs(r.mean_z) < 3.5, r
        assert abs(r.variance_z) < 3.5, r


@pytest.mark.slow
def test_decorrelated_bias_is_zero(check):
    for r in check.rows:
        if r.config == ANALOG.format("decorrelated"):
            assert r.truth == 0.0 and r.predicted_mean == 0.0
            assert abs(r.mean) < 3.5 * r.mean_se, r
            assert abs(r.variance_z) < 3.5, r


@pytest.mark.slow
def test_path_defaults_are_far_less_biased_than_the_textbook_form(check):
    """path at max_depth 8, rr_depth 5: no closed form, its bias is measured only: over 10x below."""
    for r in check.rows:
        if r.config == "path/autodiff/correlated" and r.parameter == "glow.emission":
            assert r.predicted_mean is None and r.predicted_variance is None
            assert 0 < r.bias < analog_eps_bias(0.5, 1.0, r.spp) / 10, r
    assert "random_walk" in check.table() and check.worst_z() < 3.5


def test_integrators_without_an_exact_gradient_are_refused():
    with pytest.raises(ParameterError, match="not of 'utah'"):
        furnace_check(["utah/replay/correlated"], trials=2, progress=False)
    with pytest.raises(ParameterError, match="closed form"):
        furnace_check(loss="l1", trials=2, progress=False)


def test_which_configurations_have_closed_forms():
    """Only the random walk with independent paths: antithetic pairs share their random numbers."""
    assert has_closed_form(parse_config("random_walk/autodiff/correlated/max_depth=6/rr_depth=2/sampler=independent"))
    assert not has_closed_form(parse_config("random_walk/replay/correlated/sampler=antithetic"))
    assert not has_closed_form(parse_config("path/replay/decorrelated"))
