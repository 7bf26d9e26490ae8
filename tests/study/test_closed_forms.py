"""The furnace's random-walk gradient statistics (invrender.study.closed_forms) against the closed
forms derived by hand in docs/closed_forms.md#gradient-statistics-in-the-furnace."""

import pytest

from invrender.study.closed_forms import analog_eps_bias, furnace_walk, predict_gradient


@pytest.mark.parametrize("rho", [0.3, 0.5, 0.8])
@pytest.mark.parametrize("N", [1, 4, 16])
def test_analog_walk_matches_the_closed_forms(rho, N):
    """Per pixel, Y = Xbar - T with T = eps/(1 - rho) and D the derivative estimate; one pixel and
    the l2 weight 2/3 per component, so E[G] = (2/3) E[YD] and Var(G) = (4/9) Var(YD)."""
    eps, r = 1.7, rho
    walk = furnace_walk(rho, eps)
    T = eps / (1 - rho)
    cases = {
        ("emission", True): (eps * r / ((1 - r) ** 2 * N), eps**2 * r / (1 - r) ** 4 * (1 / N + 2 * (1 + 2 * r) / N**2 + (1 + 4 * r + r * r) / N**3)),
        ("emission", False): (0.0, eps**2 * r / (1 - r) ** 4 * (1 / N + r / N**2)),
        ("reflectance", True): (eps**2 * (1 + r) / ((1 - r) ** 3 * N), eps**4 / (1 - r) ** 6 * (r / N + (4 * r * r + 13 * r + 4) / N**2 + (r**4 + 22 * r**3 + 54 * r * r + 22 * r + 1) / (r * N**3))),
        ("reflectance", False): (0.0, eps**4 / (1 - r) ** 6 * (r / N + (r * r + 3 * r + 1) / N**2)),
    }
    for (kind, correlated), (e_yd, var_yd) in cases.items():
        p = predict_gradient(walk, kind, N, 1, T, "l2", correlated)
        assert p.truth == pytest.approx(0.0, abs=1e-12)
        assert p.mean == pytest.approx(2 / 3 * e_yd, rel=1e-9, abs=1e-12)
        assert p.variance == pytest.approx(4 / 9 * var_yd, rel=1e-9)
    assert 3 * predict_gradient(walk, "emission", N, 7, T, "l2", True).bias == pytest.approx(analog_eps_bias(rho, eps, N))


def test_roulette_settings_of_the_docs():
    """Per-path image variance Var_1 (docs/closed_forms.md#correlated-gradient-bias): unbounded with
    roulette from rr_depth R: eps^2 rho^R (1 + rho - rho^R)/(1 - rho)^2; D = 8, R = 5: 0.114 eps^2."""
    for R in (1, 2, 5):
        w = furnace_walk(0.5, 1.0, -1, R)
        assert float(w.prob.sum()) == pytest.approx(1.0, abs=1e-15)
        assert w.central(2, 0, w.x) == pytest.approx(0.5**R * (1 + 0.5 - 0.5**R) / 0.25, rel=1e-12)
    w = furnace_walk(0.5, 1.0, 8, 5)
    assert w.central(2, 0, w.x) == pytest.approx(0.11419677734375, rel=1e-12)
    assert w.mean(w.x) == pytest.approx(2 * (1 - 0.5**8), rel=1e-12)  # L_D = eps (1 - rho^D)/(1 - rho)
    assert w.mean(w.d_rho) == pytest.approx((1 - 8 * 0.5**7 + 7 * 0.5**8) / 0.25, rel=1e-12)  # dL_D/drho
    zero = furnace_walk(0.5, 1.0, 4, 5)  # no roulette within 4 terms: zero variance
    assert zero.central(2, 0, zero.x) == pytest.approx(0.0, abs=1e-15)


def test_relative_l2_is_l2_with_the_constant_weight():
    walk, T = furnace_walk(0.5, 1.0), 2.0
    a, b = (predict_gradient(walk, "reflectance", 4, 10, T, loss, True) for loss in ("l2", "relative_l2"))
    w = 1 / (T**2 + 0.01)
    assert b.mean == pytest.approx(w * a.mean) and b.variance == pytest.approx(w * w * a.variance)
