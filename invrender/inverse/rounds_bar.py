"""The progress bar of a least-squares fit's rounds (:func:`invrender.inverse.fit.fit` with
``solver="lm"`` or ``"gauss_newton"``), honest about what it will do.

Rounds may end early (once converged), so the bar announces "up to N rounds" and, when they end,
says after how many and shrinks its total to what was done. Round r samples ``spp * 4^r`` paths a
pixel, so rounds are not alike: tqdm's rate (rounds per second so far) would predict the rest from
the first, cheap round (and its one-off imports). The time left is instead predicted from the last
two rounds: the part of a round that grows with its samples (tracing the records, or the whole
round on re-traced renders) grew by ``g`` from the one before to the last (``g`` clamped to
[1, 4]: small renders are dominated by fixed costs, large ones by the samples) and is taken to
grow so on; the rest (the solve) to stay as it was:

    left = sum over the rounds j still to run of (grows * g^(j - last) + stays)

which assumes every round up to N runs (an upper estimate when the rounds stop early). After one
round there is no ``g`` yet, and no estimate.
"""

from __future__ import annotations

import sys

from tqdm.auto import tqdm

#: how much more each round samples than the one before (spp * 4^r): the most its tracing grows
GROWTH = 4


def time_left(rounds_left: int, grows: float, stays: float, growth: float) -> float:
    """Seconds the ``rounds_left`` rounds still to run take, predicted from the last round's
    ``grows`` seconds (times ``growth`` per further round) and ``stays`` seconds (module docstring)."""
    return sum(grows * growth**j + stays for j in range(1, rounds_left + 1))


class RoundsBar:
    """A tqdm bar over ``rounds`` rounds, ``done`` of them done already (a resumed fit).

    Use as a context manager; :meth:`start` before a round (its spp shown), :meth:`finish` after it
    (with the seconds its parts took and a postfix of the round's numbers), :meth:`converged` when
    the rounds end before ``rounds``.
    """

    def __init__(self, rounds: int, done: int, solver: str, enabled: bool):
        self.rounds, self.solver, self.done = rounds, solver, done  # done: counted here, as a disabled tqdm does not
        self.bar = tqdm(
            total=rounds, initial=done, disable=not enabled, desc=f"fit ({solver}, up to {rounds} round{'s' if rounds != 1 else ''})", file=sys.stderr, dynamic_ncols=True,
            bar_format="{desc}: {n_fmt}/{total_fmt} |{bar}| {elapsed}{postfix}",
        )  # fmt: skip
        self.numbers: dict = {}
        self.grew: list[float] = []  # each finished round's seconds that grow with its samples
        self.left: float | None = None

    def __enter__(self) -> "RoundsBar":
        return self

    def __exit__(self, *exc) -> None:
        self.bar.close()

    def _show(self, now: str) -> None:
        left = "" if self.left is None else f", about {self.left:.0f} s left if all {self.rounds} run"
        self.bar.set_postfix_str(", ".join([now + left, *(f"{k}={v}" for k, v in self.numbers.items())]))

    def start(self, rnd: int, spp: int) -> None:
        """Round ``rnd`` (0-based) begins, at ``spp`` samples a pixel."""
        self._show(f"round {rnd + 1}: {spp} spp")

    def finish(self, grows: float, stays: float, **numbers) -> None:
        """A round ended: ``grows`` of its seconds scale with its samples, ``stays`` do not;
        ``numbers`` (loss, inner steps, ...) are shown until the next round ends."""
        self.bar.update(1)
        self.done += 1
        self.numbers = numbers
        self.grew.append(grows)
        if len(self.grew) >= 2:
            growth = min(max(self.grew[-1] / max(self.grew[-2], 1e-9), 1.0), GROWTH)
            self.left = time_left(self.rounds - self.done, grows, stays, growth)
        self._show(f"{self.done} done")

    def converged(self) -> None:
        """The rounds end here, before ``rounds``: the bar's total becomes the rounds done."""
        self.bar.total = self.done
        self.bar.set_description_str(f"fit ({self.solver}, converged after {self.done} of up to {self.rounds} rounds)", refresh=False)
        self.left = None
        self._show("done")
