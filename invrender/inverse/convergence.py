"""When a fit has converged, and the one-line warning when it has not.

**Adam's plateau.** Adam's loss is a Monte Carlo estimate, so a fall is only one when it stands
out of the loss's own noise. Over the steps at ``spp_final`` (the second half of the steps: the
loss of the first half is noisier and still falling fast), the rule compares the mean loss of the
last ``window`` steps, ``m_1``, with that of the ``window`` steps before, ``m_0``: the relative
improvement ``d = (m_0 - m_1) / m_1``. The loss's noise per step, ``sigma``, is measured from its
step-to-step fluctuation (``std(l_t - l_t-1) / sqrt 2``: a slow trend cancels in the differences),
so ``d`` has the standard error ``e = sigma sqrt(2 / window) / m_1``. The plateau is reached when
``d < max(PLATEAU_SIGNIFICANCE e, PLATEAU_TOLERANCE)``: the loss no longer falls by more than its
noise can hide (or by 0.1%, for a loss without noise). A fit whose steps run out first warns
(:class:`ConvergenceWarning`), with the last improvement against its noise and the gradient norm.

**Least-squares rounds** converge when no channel moved significantly and ``precision`` is met
(``fit.py``); stopped by the round cap instead, they warn with the last move and the precision
reached. Either way, directions the standard errors leave loose (above 2% relative:
``least_squares.loose_directions``) are named in a warning with their standard errors.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

#: the plateau: the last window's improvement below this many of its standard errors ...
PLATEAU_SIGNIFICANCE = 2.0
#: ... or below this relative improvement
PLATEAU_TOLERANCE = 1e-3


class ConvergenceWarning(UserWarning):
    """A fit ended on its cap of steps or rounds before its stopping rule was met, or the targets
    determine a direction of the parameters only loosely."""


@dataclass(frozen=True)
class Plateau:
    """The plateau rule at the end of a run of losses.

    Attributes:
        reached: whether the last window's improvement is below the threshold.
        improvement: ``d``, the relative fall of the mean loss from the window before to the last.
        noise: ``e``, its standard error from the loss's fluctuation.
    """

    reached: bool
    improvement: float
    noise: float


def plateau(losses, window: int) -> Plateau | None:
    """The plateau rule (module docstring) on the last ``2 window`` of ``losses`` (a sequence of
    floats); None when there are fewer, or ``window`` is 0."""
    if window <= 0 or len(losses) < 2 * window:
        return None
    before, last = losses[-2 * window : -window], losses[-window:]
    m0, m1 = sum(before) / window, sum(last) / window
    diffs = [b - a for a, b in zip(losses[-2 * window : -1], losses[-2 * window + 1 :])]
    mean_diff = sum(diffs) / len(diffs)
    sigma = math.sqrt(sum((d - mean_diff) ** 2 for d in diffs) / max(len(diffs) - 1, 1) / 2)
    scale = abs(m1) if m1 != 0 else 1.0
    d, e = (m0 - m1) / scale, sigma * math.sqrt(2 / window) / scale
    return Plateau(d < max(PLATEAU_SIGNIFICANCE * e, PLATEAU_TOLERANCE), d, e)


def adam_losses(history: list[dict], steps: int) -> list[float]:
    """The losses of Adam's steps at ``spp_final`` (the second half of ``steps``)."""
    return [h["loss"] for h in history if h["step"] > steps // 2]


def check_adam(history: list[dict], steps: int, window: int, adam_only: bool = False) -> bool | None:
    """Whether an Adam fit's history ends on a plateau (None: ``window`` 0, no rule); warns in one
    line when it does not: steps run, the last improvement against its noise, the gradient norm,
    and what to try (``adam_only``: a fitted parameter only Adam fits, so more steps alone)."""
    if window <= 0:
        return None
    p = plateau(adam_losses(history, steps), window)
    if p is not None and p.reached:
        return True
    grad = history[-1].get("grad_norm") if history else None
    where = (
        f"the loss still fell {100 * p.improvement:.2g}% over the last {window} steps (noise {100 * p.noise:.2g}%)"
        if p is not None
        else f"too few steps at spp_final to measure a plateau (2 x plateau_window = {2 * window} needed)"
    )
    norm = f", gradient norm {grad:.3g}" if grad is not None else ""
    advice = "give more steps" if adam_only else "give more steps, or solver 'auto' / 'lm'"
    warnings.warn(f"Adam did not converge in {len(history)} steps: {where}{norm}; {advice}", ConvergenceWarning, stacklevel=4)
    return False


def check_least_squares(history: list[dict], solver: str, rounds: int, precision: float | None, move: float) -> bool:
    """Whether a least-squares fit's last round converged; warns in one line when the rounds ran
    out first (the last round's move in standard errors against ``move``, the precision reached),
    and when the targets leave directions loose (each with its standard errors)."""
    last = history[-1] if history else {}
    converged = bool(last.get("converged", False))
    if last.get("loose"):
        warnings.warn(f"{solver}: the targets determine these directions only loosely (one standard error along each): {last['loose']}", ConvergenceWarning, stacklevel=4)
    if converged or not history:
        return converged
    why = [f"the last round moved a channel by {last.get('moved_in_std_errors', float('nan')):.2g} standard errors (converged below {move})"]
    if precision is not None:
        worst = max(max(se / max(abs(v), 1e-12) for se, v in zip(_flat(last["std_error"][n]), _flat(last["params"][n]))) for n in last["std_error"])
        why.append(f"the largest relative standard error is {100 * worst:.2g}% (precision {100 * precision:.2g}% asked)")
    warnings.warn(f"{solver} did not converge in {len(history)} of {rounds} rounds: {'; '.join(why)}; give more rounds", ConvergenceWarning, stacklevel=4)
    return False


def _flat(x) -> list[float]:
    """A nested list of numbers, flattened."""
    return [y for v in x for y in _flat(v)] if isinstance(x, list) else [x]
