"""The least-squares rounds' progress bar: it announces "up to N rounds", predicts the time left from
the last round's parts (tracing grows 4x a round, the solve stays) and, when the rounds end early,
says after how many and stops at what it did (not at 4/5)."""

import pytest

from invrender.inverse.rounds_bar import RoundsBar, time_left


def test_time_left_grows_the_tracing_4x_a_round_and_keeps_the_solve():
    # after round 1 of 3: tracing took 1 s, the solve 2 s -> rounds 2 and 3: (4 + 2) + (16 + 2)
    assert time_left(2, 1.0, 2.0) == pytest.approx(24.0)
    assert time_left(0, 1.0, 2.0) == 0.0


def test_the_bar_says_up_to_n_rounds_and_shrinks_when_they_end_early(capsys):
    with RoundsBar(5, 0, "lm", enabled=True) as bar:
        for rnd in range(3):
            bar.start(rnd, 16 * 4**rnd)
            bar.finish(0.5, 1.0, loss="0.1")
        assert bar.left == pytest.approx(time_left(2, 0.5, 1.0))
        bar.converged()
        assert bar.bar.total == bar.bar.n == 3
    err = capsys.readouterr().err
    assert "fit (lm, up to 5 rounds)" in err and "round 3: 256 spp" in err and "s left if all 5 run" in err
    last = err.replace("\r", "\n").strip().splitlines()[-1]
    assert "converged after 3 of up to 5 rounds" in last and "3/3" in last, last


def test_a_resumed_fit_starts_at_its_rounds_done(capsys):
    with RoundsBar(4, 2, "gauss_newton", enabled=True) as bar:
        assert bar.bar.n == 2
    assert "2/4" in capsys.readouterr().err
