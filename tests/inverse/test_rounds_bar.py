"""The least-squares rounds' progress bar: it announces "up to N rounds", predicts the time left from
the last round's parts (tracing grows 4x a round, the solve stays) and, when the rounds end early,
says after how many and stops at what it did (not at 4/5)."""

import pytest

from invrender.inverse.rounds_bar import RoundsBar, time_left


def test_time_left_grows_the_tracing_as_it_grew_and_keeps_the_solve():
    # tracing took 1 s in the last round, growing 4x a round, the solve 2 s: (4 + 2) + (16 + 2)
    assert time_left(2, 1.0, 2.0, 4.0) == pytest.approx(24.0)
    assert time_left(0, 1.0, 2.0, 4.0) == 0.0


def test_the_growth_is_measured_between_the_last_two_rounds_and_clamped():
    with RoundsBar(5, 0, "lm", enabled=False) as bar:
        bar.finish(2.0, 1.0)
        assert bar.left is None  # one round: no growth known yet, no estimate
        bar.finish(4.0, 1.0)  # grew 2x: rounds 3-5 take (8 + 1) + (16 + 1) + (32 + 1)
        assert bar.left == pytest.approx(59.0)
        bar.finish(3.0, 1.0)  # shrank (fixed costs): taken as no growth, (3 + 1) * 2
        assert bar.left == pytest.approx(8.0)
        bar.finish(30.0, 0.0)  # grew 10x: at most 4x, 120
        assert bar.left == pytest.approx(120.0)


def test_the_bar_says_up_to_n_rounds_and_shrinks_when_they_end_early(capsys):
    with RoundsBar(5, 0, "lm", enabled=True) as bar:
        for rnd in range(3):
            bar.start(rnd, 16 * 4**rnd)
            bar.finish(0.5 * 4**rnd, 1.0, loss="0.1")
        assert bar.left == pytest.approx(time_left(2, 0.5 * 16, 1.0, 4.0))
        bar.converged()
        assert bar.bar.total == bar.bar.n == bar.done == 3
    err = capsys.readouterr().err
    assert "fit (lm, up to 5 rounds)" in err and "round 3: 256 spp" in err and "s left if all 5 run" in err
    last = err.replace("\r", "\n").strip().splitlines()[-1]
    assert "fit (lm, converged after 3 of up to 5 rounds): 3/3" in last, last


def test_a_resumed_fit_starts_at_its_rounds_done(capsys):
    with RoundsBar(4, 2, "gauss_newton", enabled=True) as bar:
        assert bar.bar.n == 2
    assert "2/4" in capsys.readouterr().err
