"""Configuration spec strings of gradient studies: parsing, canonical labels, early errors."""

import pytest

from invrender.errors import ParameterError
from invrender.study import GradientConfig, parse_config, parse_configs


def test_spec_parts_in_any_order_and_canonical_label():
    c = parse_config("correlated/rr_depth=1/random_walk/max_depth=-1")
    assert c == GradientConfig("random_walk", "replay", "correlated", (("max_depth", -1), ("rr_depth", 1)))
    assert c.label == "random_walk/replay/correlated/max_depth=-1/rr_depth=1"
    assert parse_config(c.label) == c
    assert parse_config("autodiff") == GradientConfig("path", "autodiff", "decorrelated")


def test_render_keywords_and_backpropagate_settings():
    c = parse_config("path/autodiff/decorrelated/rr_depth=2/backend=torch")
    assert c.render_kwargs() == {"integrator": "path", "estimator": "autodiff", "backend": "torch", "rr_depth": 2}
    integrator, settings = c.integrator_and_settings(spp=8, seed=3)
    assert integrator.settings.rr_depth == 2 and settings.backend == "torch" and (settings.spp, settings.seed) == (8, 3)


def test_roulette_does_not_change_the_model():
    """Configurations that differ in the estimator, the pairing or rr_depth share a reference."""
    models = {parse_config(s).model for s in ("path/replay/correlated", "path/autodiff/decorrelated/rr_depth=1")}
    assert models == {GradientConfig("path", "replay", "decorrelated")}
    assert parse_config("path/max_depth=4").model not in models


def test_pairing_options_go_to_the_pairing_not_the_render():
    c = parse_config("path/autodiff/control_variate/cv_steps=3/sampler=antithetic")
    assert c.pairing_options == {"cv_steps": 3, "cv_step": 0.01}  # the default step filled in
    assert c.render_kwargs() == {"integrator": "path", "estimator": "autodiff", "sampler": "antithetic"}
    assert c.model == GradientConfig("path", "replay", "decorrelated")  # the sampler and the chain do not change the expected image


@pytest.mark.parametrize(
    "spec, words",
    [
        ("path/replay/bogus", "unknown part 'bogus'"),
        ("path/decorrelated/cv_steps=4", "belongs to the control_variate pairing"),
        ("path/control_variate/cv_steps=0", "cv_steps must be an integer >= 1"),
        ("path/control_variate/cv_step=-0.1", "cv_step must be a number >= 0"),
        ("path/sampler=sobol", "unknown sampler 'sobol'"),
        ("path/random_walk", "two integrators"),
        ("path/rr_depth=", "KEY=VALUE"),
        ("path/rr_depth=1/rr_depth=2", "given twice"),
        ("path/spp=4", "set by the study"),
        ("path/no_such_setting=1", "has no setting 'no_such_setting'"),
        ("random_walk/rr_depth=0", "rr_depth must be"),
        ("", "spec string"),
    ],
)
def test_bad_specs_are_one_line_errors(spec, words):
    with pytest.raises(ParameterError, match=words) as e:
        parse_config(spec)
    assert "\n" not in str(e.value)


def test_a_configuration_given_twice():
    with pytest.raises(ParameterError, match="given twice"):
        parse_configs("path/correlated,correlated/path/replay")
    with pytest.raises(ParameterError, match="no configurations"):
        parse_configs([])
