"""Neumann-Ulam random walks: Monte Carlo estimators of the solution of ``x = a + M x``.

A walk starts in state ``i_0 = i`` and moves from state i to j with probability ``p_ij``, or ends
there with the termination probability ``t_i = 1 - sum_j p_ij``. Its weight starts at ``W_0 = 1``
and gains ``m_ij / p_ij`` with each move (docs/closed_forms.md#random-walks). Two unbiased
estimators of ``x_i = sum_k (M^k a)_i``:

- collision: ``X = sum_(k <= K) W_k a_(i_k)``, every state the walk visits scores;
- absorption: ``X = W_K a_(i_K) / t_(i_K)``, only the state where the walk ends scores.

Both need ``p_ij > 0`` wherever ``m_ij != 0`` (the absorption estimator also ``t_i > 0`` wherever
``a_i != 0``). They are unbiased when the Neumann series of |M| converges (spectral radius of |M|
below 1) and have finite variance if and only if the spectral radius of ``M^``,
``M^_ij = m_ij^2 / p_ij``, is below 1 (Ji, Mascagni and Li, SIAM J. Numer. Anal. 51(4), 2013);
:func:`variance_radius` computes it and :func:`neumann_ulam` refuses to run a walk that would have
infinite variance.

Transition probabilities (:func:`transition_matrix`):

- ``"analog"``: ``p_ij = |m_ij|``; for radiosity (``M = diag(rho) F``) the walk survives with
  ``rho_i sum_j F_ij`` and moves by form factor, every weight is 1 and ``M^ = M``;
- ``"uniform"``: the same survival ``sum_j |m_ij|``, the next state uniform among the states j with
  ``m_ij != 0``;
- a user matrix (n, n), or (C, n, n) per system.

Everything is batched over C independent systems (the colour channels) and over many walks at
once; each step is one ``torch.searchsorted`` over the cumulative rows of all systems.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from invrender.errors import ParameterError, did_you_mean

ESTIMATORS = ("collision", "absorption")
TRANSITIONS = ("analog", "uniform")


@dataclass(frozen=True)
class WalkEstimate:
    """Random-walk estimates of ``x = a + M x`` for C systems.

    Attributes:
        mean: (C, k) float64 estimate of ``x`` at each start state.
        stderr: (C, k) float64 its standard error (sample standard deviation over sqrt(walks)).
        start: (k,) int64 the start states.
        walks: walks per start state and system.
        estimator: ``"collision"`` or ``"absorption"``.
        variance_radius: (C,) float64 spectral radius of ``m_ij^2 / p_ij`` (< 1: finite variance);
            above 256 states an upper bound from power iteration (:func:`spectral_radius_bounds`).
        mean_length: mean number of moves per walk.
    """

    mean: torch.Tensor
    stderr: torch.Tensor
    start: torch.Tensor
    walks: int
    estimator: str
    variance_radius: torch.Tensor
    mean_length: float


def transition_matrix(M: torch.Tensor, transition="analog") -> torch.Tensor:
    """Transition probabilities ``p`` (C, n, n) float64 for the systems ``M`` (C, n, n).

    ``transition``: ``"analog"``, ``"uniform"`` or a matrix (n, n) or (C, n, n) (checked: finite,
    non-negative, rows summing to at most 1).
    """
    M = _systems(M)
    C, n, _ = M.shape
    if isinstance(transition, str):
        if transition not in TRANSITIONS:
            raise ParameterError(f"unknown transition {transition!r}{did_you_mean(transition, TRANSITIONS)} (known: {', '.join(TRANSITIONS)}, or a matrix)")
        m = M.abs()
        if transition == "analog":
            return m
        nonzero = m > 0
        survival = m.sum(2, keepdim=True)
        return torch.where(nonzero, survival / nonzero.sum(2, keepdim=True).clamp_min(1), 0.0)
    P = torch.as_tensor(transition, dtype=torch.float64, device=M.device)
    if P.shape not in ((n, n), (C, n, n)):
        raise ParameterError(f"transition matrix must have shape ({n}, {n}) or ({C}, {n}, {n}), got {tuple(P.shape)}")
    P = P.expand(C, n, n)
    if not bool(torch.isfinite(P).all()):
        raise ParameterError("transition matrix has non-finite entries")
    if bool((P < 0).any()):
        c, i, j = (int(x) for x in (P < 0).nonzero()[0])
        raise ParameterError(f"transition matrix has negative entries (p[{i}, {j}] = {float(P[c, i, j]):.3g}): probabilities must be >= 0")
    rows = P.sum(2)
    if bool((rows > 1 + 1e-12).any()):
        c, i = (int(x) for x in (rows > 1 + 1e-12).nonzero()[0])
        raise ParameterError(f"transition matrix row {i} sums to {float(rows[c, i]):.6g} > 1: no probability is left for the walk to end")
    return P.contiguous()


def variance_radius(M: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """(C,) spectral radius of ``M^_ij = m_ij^2 / p_ij`` (0 where ``m_ij = 0``): the walks' variance
    is finite iff it is below 1. ``M``, ``P``: (C, n, n) (:func:`spectral_radius`)."""
    return spectral_radius(_hat(_systems(M), _systems(P)))


def _hat(M: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """``M^_ij = m_ij^2 / p_ij`` (0 where ``m_ij = 0``), (C, n, n)."""
    return torch.where(M != 0, M * M / torch.where(P > 0, P, 1.0), 0.0)


#: largest n whose spectral radii are computed from all eigenvalues (above: power iteration)
EIGVALS_MAX = 256


def spectral_radius(A: torch.Tensor) -> torch.Tensor:
    """(C,) spectral radius of each of the non-negative matrices ``A`` (C, n, n) (the midpoint of
    :func:`spectral_radius_bounds`)."""
    low, high = spectral_radius_bounds(A)
    return 0.5 * (low + high)


def spectral_radius_bounds(A: torch.Tensor, iterations: int = 1000, rtol: float = 1e-6, decide: float | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Lower and upper bounds (C,), (C,) on the spectral radius of each non-negative ``A`` (C, n, n).

    Up to :data:`EIGVALS_MAX` rows both are the exact value (``torch.linalg.eigvals``). Above, power
    iteration on ``A + I`` (aperiodic, same Perron vector) with Collatz-Wielandt bounds: for any
    positive x, ``min_i (A x)_i / x_i <= rho(A) <= max_i (A x)_i / x_i``. It stops when the bounds
    agree to ``rtol``, or, with ``decide``, once (after 30 iterations) both lie on the same side of
    it.
    """
    A = A.double()
    if A.shape[-1] <= EIGVALS_MAX:
        value = torch.linalg.eigvals(A).abs().amax(-1)
        return value, value
    x = torch.ones(A.shape[:2], dtype=torch.float64, device=A.device)
    for it in range(iterations):
        y = torch.stack([torch.mv(a, v) for a, v in zip(A, x)])
        y = y + 1e-12 * y.amax(1, keepdim=True).clamp_min(1e-300)  # keeps x > 0 (moves rho by < 1e-12 n)
        ratio = y / x
        low, high = ratio.amin(1), ratio.amax(1)
        x = (y + x) / (y + x).amax(1, keepdim=True)  # the shift by I: no oscillation between cyclic classes
        done = high - low <= rtol * high
        if decide is not None and it >= 30:
            done |= (high < decide) | (low >= decide)
        if bool(done.all()):
            break
    return low, high


def check_walk(M: torch.Tensor, a: torch.Tensor, P: torch.Tensor, estimator: str) -> torch.Tensor:
    """Refuse a walk that would be biased or have infinite variance; return the (C,) variance radius.

    Raises:
        ParameterError: one line naming the problem: ``p_ij = 0`` where ``m_ij != 0``; the
            series of |M| diverging; the spectral radius of ``m_ij^2 / p_ij`` at or above 1 (named
            with its value and channel); ``t_i = 0`` where ``a_i != 0`` for the absorption estimator.
    """
    if estimator not in ESTIMATORS:
        raise ParameterError(f"unknown random-walk estimator {estimator!r}{did_you_mean(estimator, ESTIMATORS)} (known: {', '.join(ESTIMATORS)})")
    missing = (M != 0) & (P <= 0)
    if bool(missing.any()):
        c, i, j = (int(x) for x in missing.nonzero()[0])
        raise ParameterError(f"transition probability p[{i}, {j}] is 0 where m[{i}, {j}] = {float(M[c, i, j]):.3g} is not: the walk would be biased")
    low, high = spectral_radius_bounds(M.abs(), decide=1.0)
    if bool((high >= 1).any()):
        c = int(high.argmax())
        raise ParameterError(f"the Neumann series diverges: spectral radius of |M| {_radius(low[c], high[c])} in {_channel(c, M.shape[0])}")
    low, radius = spectral_radius_bounds(_hat(M, P), decide=1.0)
    if bool((radius >= 1).any()):
        c = int(radius.argmax())
        raise ParameterError(
            f"transition probabilities give the random walk infinite variance: spectral radius of m_ij^2/p_ij {_radius(low[c], radius[c])} "
            f"in {_channel(c, M.shape[0])}"
        )
    if estimator == "absorption":
        t = 1.0 - P.sum(2)
        stuck = (t <= 0) & (a != 0)
        if bool(stuck.any()):
            c, i = (int(x) for x in stuck.nonzero()[0])
            raise ParameterError(f"the absorption estimator needs a termination probability > 0 where a != 0: row {i} of the transition matrix sums to 1")
    return radius


def neumann_ulam(
    M: torch.Tensor,
    a: torch.Tensor,
    transition="analog",
    estimator: str = "collision",
    walks: int = 1000,
    seed: int = 0,
    start: torch.Tensor | None = None,
    max_steps: int = 100000,
) -> WalkEstimate:
    """Estimate the solutions of ``x_c = a_c + M_c x_c`` by random walks, after checking that they
    are unbiased with finite variance (:func:`check_walk`).

    Args:
        M: (C, n, n) or (n, n) the systems' matrices.
        a: (C, n) or (n,) their right-hand sides.
        transition: ``"analog"``, ``"uniform"`` or a matrix (see :func:`transition_matrix`).
        estimator: ``"collision"`` or ``"absorption"``.
        walks: walks per start state and system.
        seed: seed of the walks' random numbers.
        start: (k,) int64 start states; None = every state.
        max_steps: a walk still going after this many moves is an error.
    Returns:
        a :class:`WalkEstimate` (mean and standard error per system and start state).
    """
    M = _systems(M)
    C, n, _ = M.shape
    a = torch.as_tensor(a, dtype=torch.float64, device=M.device).detach()
    a = a.expand(C, n) if a.ndim == 1 else a
    if a.shape != (C, n):
        raise ParameterError(f"right-hand side must have shape ({n},) or ({C}, {n}), got {tuple(a.shape)}")
    if isinstance(walks, bool) or not isinstance(walks, int) or walks < 2:
        raise ParameterError(f"walks must be an integer >= 2, got {walks!r}")
    P = transition_matrix(M, transition)
    radius = check_walk(M, a, P, estimator)
    start = torch.arange(n, device=M.device) if start is None else torch.as_tensor(start, dtype=torch.int64, device=M.device)
    t = (1.0 - P.sum(2)).clamp_min(0.0)  # (C, n) termination probabilities
    # one sorted table for all systems: row r = c n + i holds r + cumsum(p_i1, ..., p_in, t_i)
    cdf = torch.cat([P, t[:, :, None]], dim=2).reshape(C * n, n + 1).cumsum(1)
    cdf[:, -1] = 1.0
    table = (cdf + torch.arange(C * n, device=M.device, dtype=torch.float64)[:, None]).reshape(-1)
    ratio = torch.where(P > 0, M / torch.where(P > 0, P, 1.0), 0.0).reshape(-1)  # m_ij / p_ij
    a_flat, t_flat = a.reshape(-1), t.reshape(-1)

    k = start.shape[0]
    walker = torch.arange(C * k * walks, device=M.device)
    channel = walker // (k * walks)
    row = channel * n + start[(walker // walks) % k]  # c n + state
    score = torch.zeros(walker.shape[0], dtype=torch.float64, device=M.device)
    weight = torch.ones_like(score)
    if estimator == "collision":
        score += a_flat[row]
    gen = torch.Generator(device="cpu").manual_seed(seed)
    alive = walker
    moves = 0
    for _ in range(max_steps):
        u = torch.rand(alive.shape[0], generator=gen, dtype=torch.float64).to(M.device)
        pos = torch.searchsorted(table, row + u, right=True)
        j = (pos - row * (n + 1)).clamp(0, n)  # n = the walk ends here
        ends = j == n
        if estimator == "absorption":
            done = ends.nonzero()[:, 0]
            score.index_add_(0, alive[done], weight[done] * a_flat[row[done]] / t_flat[row[done]])
        go = (~ends).nonzero()[:, 0]
        alive, row, j, weight = alive[go], row[go], j[go], weight[go]
        moves += alive.shape[0]
        if not alive.shape[0]:
            break
        weight = weight * ratio[row * n + j]
        row = (row // n) * n + j
        if estimator == "collision":
            score.index_add_(0, alive, weight * a_flat[row])
    else:
        raise ParameterError(f"random walks still going after max_steps = {max_steps} moves: raise max_steps or end walks sooner")
    score = score.reshape(C, k, walks)
    return WalkEstimate(
        mean=score.mean(2),
        stderr=score.std(2) / math.sqrt(walks),
        start=start,
        walks=walks,
        estimator=estimator,
        variance_radius=radius,
        mean_length=moves / score.numel(),
    )


def _systems(M) -> torch.Tensor:
    M = torch.as_tensor(M, dtype=torch.float64).detach()
    if M.ndim == 2:
        M = M[None]
    if M.ndim != 3 or M.shape[1] != M.shape[2]:
        raise ParameterError(f"system matrix must have shape (n, n) or (C, n, n), got {tuple(M.shape)}")
    return M


def _radius(low: torch.Tensor, high: torch.Tensor) -> str:
    """A spectral radius known to lie in [low, high], high >= 1, for a message."""
    if float(low) == float(high):
        return f"is {float(low):.4g} >= 1"
    if float(low) >= 1:
        return f"is at least {float(low):.4g} >= 1"
    return f"lies in [{float(low):.4g}, {float(high):.4g}], not certainly below 1"


def _channel(c: int, count: int) -> str:
    return f"channel {'RGB'[c]}" if count == 3 else f"system {c}"


__all__ = [
    "WalkEstimate", "neumann_ulam", "transition_matrix", "variance_radius", "spectral_radius", "spectral_radius_bounds", "check_walk",
    "ESTIMATORS", "TRANSITIONS",
]  # fmt: skip
