"""Inverse lighting by the transport matrix: an environment map as one regularized, non-negative
linear least-squares problem (``ir.lighting.fit_map``).

**The problem.** Per colour channel, the views' pixels are ``b = A B x`` (+ the light that does not
end on the map), ``A`` (P, T) the transport matrix of the map's T texels and ``B`` (T, n) a
piecewise-constant basis of n unknowns (:class:`~invrender.estimators.map_basis.MapBasis`: the texels
themselves, or the leaves of a quadtree within a budget), estimated in two independent halves.
The fit minimizes, over ``x >= 0``,

    x^T H x - 2 g^T x + b^T b  +  lambda s [ x^T S x + mu (x - x0)^T W (x - x0) ]

with ``H = sym(A1^T A2)`` (unbiased for ``A^T A``: the plain ``Abar^T Abar`` would add the noise's
``E^T E``, a bias that shrinks the map), ``g = Abar^T b``, the first three terms together ``R(x)``,
an unbiased estimate of the residual ``||A x - b||^2`` of the exact transport
(:mod:`invrender.inverse.map_normal` accumulates them view by view). The priors are rows of the
problem: ``S`` the map's Dirichlet energy on the sphere (:func:`sphere_smoothness`, in the basis
``B^T S B``) and Tikhonov toward the start ``x0`` weighted by the unknowns' solid angles ``W``
(``mu``, default 1e-2: keeps the problem definite where smoothness alone leaves the mean free).
Both are scaled to a mean diagonal of 1 and ``s`` is the mean diagonal of ``H``, so the weight
``lambda`` is dimensionless.

**Unknowns no path reaches** (zero columns: below the floor, behind a wall) are set by the prior
alone: given the others, their best values are the prior's harmonic extension ``x_I = Q_II^-1 (p_I
- Q_IA x_A)`` (``Q`` the prior's matrix, ``p`` its pull), >= 0 whenever ``x_A`` is (``Q`` is an
M-matrix), so they are eliminated once (a sparse factorization of ``Q_II``; the reduced prior is
``Q_AA - Q_AI Q_II^-1 Q_IA``, independent of lambda) and the dense work is over the active ones.

**The weight from the data: the discrepancy principle.** The Monte Carlo noise of the images the
matrix predicts is known for any map: ``delta^2(x) = ||(A1 - A2) x||^2 / 4``. Morozov's discrepancy
principle asks the residual of ``Abar`` to equal the noise, ``||Abar x - b||^2 = delta^2(x) + P
sigma_b^2`` (``sigma_b``: the targets' own noise per pixel, 0 for exact targets); since ``||Abar x -
b||^2 = R(x) + delta^2(x)`` that is ``R(x_lambda) = P sigma_b^2``: the largest weight whose fit
explains the images down to their noise. ``R(x_lambda)`` grows with lambda, ``dR/dlambda = 2 lambda
s^2 v^T M^-1 v`` with ``v = Q x - p`` (one more pair of triangular solves), and below some weight
the regularized matrix is not definite (the noise's negative directions of ``sym(A1^T A2)``), so
the weight is the root of ``R(x_lambda) - P sigma_b^2`` found by Newton's method in log lambda
safeguarded by bisection (a Cholesky factorization per step, typically 3-6; the next channel starts
from the last one's answer). The non-negative solution is then solved at that weight by block
principal pivoting from the unconstrained solution (:func:`bounded_quadratic`). ``rule="gcv"``
minimizes generalized cross-validation instead (bench/transport_matrix.py --sweep compares them).

**What the result says.** Standard errors from the sandwich ``M^-1 (s2 H) M^-1`` (``M`` the
regularized normal matrix, ``s2`` the per-pixel variance of the residual at the solution; carried
to the eliminated unknowns through their extension), the *resolution* ``diag(M^-1 H)`` per unknown
(1: set by the images, 0: by the prior), its sum the degrees of freedom the images determine, and
the texels under 0.5 marked undetermined. One inverse of ``M`` and one product per channel.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import torch
from scipy.sparse.linalg import splu

from invrender.core.driver import one_thread
from invrender.estimators.map_basis import MapBasis, check_haar
from invrender.estimators.transport_matrix import TransportMatrix, envmap_of
from invrender.plugins.emitters.envmap import texel_solid_angles
from invrender.errors import ParameterError, did_you_mean
from invrender.inverse.targets import load_targets
from invrender.inverse.map_normal import NormalEquations, from_matrix, normal_equations
from invrender.io.maps import write_environment
from invrender.io.reports import write_json
from invrender.scene.scene import Scene
from invrender.validate import check_int

#: the rules that choose the prior's weight (``weight=None``)
RULES = ("discrepancy", "gcv")
#: the search interval of the weight, log10 (relative to the mean diagonal of H)
LOG_WEIGHT_RANGE = (-9.0, 3.0)
#: resolution below which a texel is reported undetermined
UNDETERMINED = 0.5
#: the unknowns fit_map keeps by default: maps of up to this many texels are fitted texel by texel
DEFAULT_UNKNOWNS = 3072
#: fit_map's ``rounds="auto"`` takes a second round when the first map's peak is this many times its median
SUN_RATIO = 100.0


def solver_bytes(n: int) -> int:
    """Bytes the solve takes beyond the normal equations, for n unknowns: per channel ``H``, the
    regularized matrix, its factor and inverse, the reduced prior (float64), about ``48 n^2``."""
    return 48 * n * n


def sphere_smoothness(h: int, w: int) -> sp.csr_matrix:
    """(T, T) scipy.sparse the Dirichlet energy of an (h, w) map on the sphere, ``x^T S x = sum over
    neighbouring texels of c_ij (x_i - x_j)^2``: along a row (wrapping in longitude) ``c = Omega_i /
    (s_i dphi)^2`` (``Omega_i`` the texel's solid angle, ``s_i = Omega_i / (dtheta dphi)`` its mean
    sin theta, so the pole rows, one direction each, are held together), down a column ``c = dphi
    (cos theta_i - cos theta_i+1) / dtheta^2`` (the band between the two rows)."""
    T = h * w
    omega = texel_solid_angles(h, w).numpy().reshape(h, w)[:, 0]
    dth, dph = math.pi / (h - 1), 2 * math.pi / w
    idx = np.arange(T).reshape(h, w)
    parts = []

    def edges(a, b, c):
        a, b, c = a.reshape(-1), b.reshape(-1), np.broadcast_to(c, a.shape).reshape(-1)
        parts.append((np.concatenate([a, b, a, b]), np.concatenate([a, b, b, a]), np.concatenate([c, c, -c, -c])))

    if w > 1:
        s = omega / (dth * dph)
        edges(idx, np.roll(idx, -1, axis=1), (omega / (s * dph) ** 2)[:, None])
    theta = np.arange(h) * dth
    band = dph * (np.cos(theta[:-1]) - np.cos(theta[1:])) / dth**2
    edges(idx[:-1], idx[1:], band[:, None])
    rows, cols, vals = (np.concatenate(x) for x in zip(*parts))
    return sp.coo_matrix((vals, (rows, cols)), shape=(T, T)).tocsr()  # duplicates summed


@dataclasses.dataclass
class MapFit:
    """What :func:`fit_map` recovered.

    Attributes:
        texels: (h, w, 3) float32 the map (>= 0), in the emitter's units (radiance / scale).
        stderr: (h, w, 3) standard errors of the texels (the Monte Carlo noise through the
            regularized solve; not the prior's pull).
        weight: (3,) the prior's weight lambda per channel (dimensionless: relative to the mean
            diagonal of ``A^T A``).
        rule: how the weight was chosen (``"discrepancy"``, ``"gcv"``, or ``"fixed"``).
        residual: (3,) ``||Abar x - b|| / ||b||`` per channel at the solution.
        noise: (3,) ``delta(x) / ||b||``, the Monte Carlo noise of the predicted images.
        resolution: (h, w, 3) ``diag(M^-1 H)`` clipped to [0, 1]: 1 where the images set a texel, 0
            where the prior does.
        dof: (3,) the degrees of freedom the images determine (the resolution's sum over unknowns).
        undetermined: (h, w) bool, texels whose resolution is under 0.5 in some channel.
        active: (3,) unknowns held at 0 by the bound.
        matrix: the :class:`~invrender.estimators.transport_matrix.TransportMatrix` it solved on (None
            when streamed).
        seconds: {"render": ..., "gram": ..., "solve": ...} (all rounds).
        basis: the unknowns' :class:`~invrender.estimators.map_basis.MapBasis`.
        normal: the :class:`~invrender.inverse.map_normal.NormalEquations` (solve again at other
            settings with :func:`solve_map`).
        rounds: 1, or 2 when a second transport matrix was sampled by the first round's map.
        evaluations: (3,) Cholesky factorizations the weight's search took per channel.
    """

    texels: torch.Tensor
    stderr: torch.Tensor
    weight: torch.Tensor
    rule: str
    residual: torch.Tensor
    noise: torch.Tensor
    resolution: torch.Tensor
    dof: torch.Tensor
    undetermined: torch.Tensor
    active: torch.Tensor
    matrix: TransportMatrix | None
    seconds: dict
    basis: MapBasis | None = None
    normal: NormalEquations | None = None
    rounds: int = 1
    evaluations: torch.Tensor | None = None

    def write(self, folder) -> list[Path]:
        """Write the relighting product into ``folder`` (created): ``map.exr`` the recovered map,
        ``stderr.exr`` its standard errors, ``resolution.png`` the identifiability map (each
        texel's smallest resolution over the channels, viridis: 0 dark blue, set by the prior, to
        1 yellow, set by the images) and ``fit.json`` (the weights, the rule, residual, noise,
        degrees of freedom, unknowns, rounds, seconds). Returns the paths."""
        paths = write_environment(folder, self.texels, self.stderr, self.resolution) + [Path(folder) / "fit.json"]
        floats = lambda t: [float(x) for x in t]  # noqa: E731
        write_json(paths[3], {
            "describe": self.describe(), "weight": floats(self.weight), "rule": self.rule, "residual": floats(self.residual), "noise": floats(self.noise), "dof": floats(self.dof),
            "unknowns": None if self.basis is None else self.basis.n, "texels": list(self.texels.shape[:2]), "rounds": self.rounds, "seconds": self.seconds,
        })  # fmt: skip
        return paths

    def describe(self) -> str:
        """One line: rule, weights, residual against noise, determined degrees of freedom."""
        w = ", ".join(f"{float(x):.2g}" for x in self.weight)
        r = ", ".join(f"{100 * float(x):.2f}%" for x in self.residual)
        n = ", ".join(f"{100 * float(x):.2f}%" for x in self.noise)
        T = self.texels.shape[0] * self.texels.shape[1]
        unknowns = T if self.basis is None else self.basis.n
        of = f"{unknowns} unknowns" + ("" if unknowns == T else f" for {T} texels")
        return f"prior weight {w} ({self.rule}); residual {r} against noise {n}; {', '.join(f'{float(d):.0f}' for d in self.dof)} of {of} determined per channel" + (
            f"; {self.rounds} rounds" if self.rounds > 1 else ""
        )


class _Prior:
    """The prior's matrix ``Q = smoothness S + tikhonov diag(W)`` in the basis (each scaled to a
    mean diagonal of 1) and its pull ``tikhonov W x0``, reduced onto the ``active`` unknowns: the
    others are eliminated (module docstring)."""

    def __init__(self, basis: MapBasis, tikhonov: float, smoothness: float, active: np.ndarray):
        h, w = basis.shape
        Bm = basis.matrix()
        omega = Bm.T @ texel_solid_angles(h, w).numpy()
        self.omega = omega  # (n,) each unknown's solid angle
        self.tw = tikhonov * omega / omega.mean()
        Q = sp.diags(self.tw).tocsr()
        if smoothness > 0:
            S = (Bm.T @ sphere_smoothness(h, w) @ Bm).tocsr()
            Q = Q + (smoothness / float(S.diagonal().mean())) * S
        self.a, self.i = np.flatnonzero(active), np.flatnonzero(~active)
        self.n = basis.n
        Qaa = Q[self.a][:, self.a].toarray()
        self.border = np.zeros(0, dtype=np.int64)
        self.F = np.zeros((self.i.size, 0))
        if self.i.size:
            self.lu = splu(Q[self.i][:, self.i].tocsc())
            Qia = Q[self.i][:, self.a].tocsc()
            self.border = np.unique(Qia.nonzero()[1])  # active unknowns next to eliminated ones
            if self.border.size:
                Qib = Qia[:, self.border]
                self.F = self.lu.solve(Qib.toarray())  # Q_II^-1 Q_IB (n_I, border): <= 0
                Qaa[np.ix_(self.border, self.border)] -= Qib.T @ self.F
        self.Q = torch.from_numpy(Qaa)

    def pull(self, x0: np.ndarray) -> np.ndarray:
        """p (n,) the Tikhonov pull toward x0 (n,)."""
        return self.tw * x0

    def reduced(self, p: np.ndarray) -> torch.Tensor:
        """The pull on the active unknowns with the eliminated ones at their best: ``p_A - F^T p_I``."""
        out = p[self.a].copy()
        if self.i.size and self.border.size:
            out[self.border] -= self.F.T @ p[self.i]
        return torch.from_numpy(out)

    def extend(self, xa: torch.Tensor, p: np.ndarray) -> torch.Tensor:
        """(n,) float64 all unknowns from the active ones ``xa``: the eliminated ones at
        ``Q_II^-1 p_I - F x_border``."""
        x = torch.zeros(self.n, dtype=torch.float64)
        x[torch.from_numpy(self.a)] = xa
        if self.i.size:
            xi = self.lu.solve(p[self.i])
            if self.border.size:
                xi = xi - self.F @ xa.numpy()[self.border]
            x[torch.from_numpy(self.i)] = torch.from_numpy(np.maximum(xi, 0.0))
        return x


@dataclasses.dataclass
class _Point:
    """The unconstrained solution at one weight: lambda, M's Cholesky factor, x (active), f =
    R(x) - target, dR / dlog10(lambda)."""

    lam: float
    L: torch.Tensor
    x: torch.Tensor
    f: float
    slope: float


class _Solve:
    """One channel's problem on the active unknowns at any weight (float64 torch)."""

    def __init__(self, H: torch.Tensor, Q: torch.Tensor, g: torch.Tensor, p: torch.Tensor, bb: float, scale: float, target: float):
        self.H, self.Q, self.g, self.p, self.bb, self.s, self.target = H, Q, g, p, bb, scale, target
        self.evaluations = 0

    def residual(self, x: torch.Tensor) -> float:
        """R(x): the unbiased estimate of ``||A x - b||^2``."""
        return float(x @ (self.H @ x) - 2 * self.g @ x + self.bb)

    def matrix(self, lam: float) -> torch.Tensor:
        return self.H + (lam * self.s) * self.Q

    def at(self, lam: float) -> _Point | None:
        """The unconstrained solution at ``lam`` (None where M is not positive definite)."""
        self.evaluations += 1
        L, info = torch.linalg.cholesky_ex(self.matrix(lam))
        if int(info) != 0:
            return None
        x = cholesky_solve(L, self.g + (lam * self.s) * self.p)
        v = self.Q @ x - self.p
        slope = math.log(10.0) * lam * 2 * lam * self.s * self.s * float(v @ cholesky_solve(L, v))
        return _Point(lam, L, x, self.residual(x) - self.target, slope)

    def influence(self, point: _Point) -> float:
        """tr(M^-1 H): the effective number of parameters (GCV's)."""
        Minv = torch.cholesky_inverse(point.L)
        return float(Minv.shape[0] - point.lam * self.s * float((Minv * self.Q).sum()))


def cholesky_solve(L: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """``M^-1 r`` (T,) for M's lower Cholesky factor ``L``, by two triangular solves (an order of
    magnitude faster than ``torch.cholesky_solve`` on one right-hand side)."""
    y = torch.linalg.solve_triangular(L, r[:, None], upper=False)
    return torch.linalg.solve_triangular(L.T, y, upper=True)[:, 0]


def sparse_quadratic(M: torch.Tensor, r: torch.Tensor, C, details: np.ndarray, mu, x: torch.Tensor, iterations: int = 500, tol: float = 1e-5) -> torch.Tensor:
    """argmin over x >= 0 of ``x^T M x - 2 r^T x + 2 mu ||(C x)_details||_1`` by ADMM (Boyd et al.,
    "Distributed optimization and statistical learning via the alternating direction method of
    multipliers", 2011, section 6): C (T, n) scipy.sparse the Haar coefficients of the unknowns
    (:meth:`~invrender.estimators.map_basis.MapBasis.haar`, ``C^T C`` diagonal), ``details`` (T,)
    bool the rows penalized. Each round: the non-negative quadratic
    ``(M + rho C^T C) x = r + rho C^T (z - u)`` (:func:`bounded_quadratic`, one Cholesky factor for
    all rounds), the details soft-thresholded by ``mu / rho``, the scaled dual updated; stops when
    the primal and dual residuals fall under ``tol`` relative to the coefficients. ``x``: the
    start (the solve without the L1 term)."""
    Ct = C.T.tocsr()
    counts = torch.from_numpy(np.asarray(C.multiply(C).sum(0)).ravel())
    rho = float(M.diagonal().mean()) / max(float(counts.mean()), 1e-30)
    Mr = M + torch.diag(rho * counts)
    L = torch.linalg.cholesky(Mr)
    to_t = lambda v: torch.from_numpy(np.asarray(v, dtype=np.float64).ravel())  # noqa: E731
    z = to_t(C @ x.numpy())
    u = torch.zeros_like(z)
    threshold = torch.as_tensor(mu, dtype=torch.float64) / rho  # a number, or one per row
    penalized = torch.from_numpy(details)
    for _ in range(iterations):
        x = bounded_quadratic(Mr, r + rho * to_t(Ct @ (z - u).numpy()), L)
        cx = to_t(C @ x.numpy())
        v = cx + u
        z_next = torch.where(penalized, v.sign() * (v.abs() - threshold).clamp_min(0.0), v)
        primal = float((cx - z_next).norm())
        dual = rho * float(to_t(Ct @ (z_next - z).numpy()).norm())
        u, z = v - z_next, z_next
        size = max(float(cx.norm()), float(z.norm()), 1e-300)
        if primal <= tol * size and dual <= tol * rho * max(float(to_t(Ct @ u.numpy()).norm()), size):
            break
    return x


def bounded_quadratic(M: torch.Tensor, r: torch.Tensor, L: torch.Tensor | None = None, max_iter: int = 100, x: torch.Tensor | None = None) -> torch.Tensor:
    """argmin over x >= 0 of ``x^T M x - 2 r^T x`` (M (T, T) positive definite, r (T,)): non-negative
    least squares in normal-equation form by block principal pivoting (Kim and Park, "Fast
    nonnegative matrix factorization: an active-set-like method and comparisons", SIAM J. Sci.
    Comput. 33(6), 2011; Portugal, Judice and Vicente 1994): all infeasible variables exchanged
    between the free and the bound set at once, a single one (the last) when that stops reducing
    their count. It starts from the unconstrained solution ``x`` (or solves it with M's Cholesky
    factor ``L``): where most unknowns are interior, few exchanges follow."""
    T = r.shape[0]
    if x is None:
        x = cholesky_solve(L, r) if L is not None else torch.linalg.solve(M, r)
    free = torch.ones(T, dtype=torch.bool)
    best, chances = T + 1, 3
    tol = 1e-12 * float(r.abs().max().clamp_min(1e-300))
    for _ in range(max_iter):
        y = M @ x - r  # half the gradient: >= 0 on the bound set at the optimum, 0 on the free one
        bad = (free & (x < 0)) | (~free & (y < -tol))
        count = int(bad.sum())
        if count == 0:
            return x.clamp_min(0.0)
        if count < best:
            best, chances = count, 3
            free = free ^ bad
        elif chances > 0:
            chances -= 1
            free = free ^ bad
        else:  # the backup rule: exchange only the last infeasible variable
            free[bad.nonzero()[-1, 0]] ^= True
        x = torch.zeros_like(r)
        f = free.nonzero()[:, 0]
        if f.numel():
            x[f] = cholesky_solve(torch.linalg.cholesky(M[f][:, f]), r[f])  # a principal submatrix of M: definite
    raise ParameterError(f"the non-negative solve did not converge in {max_iter} exchanges")


def _discrepancy(solve: _Solve, hint: float | None = None, tol: float = 0.02) -> _Point:
    """The discrepancy principle's point: the root in t = log10 lambda (within
    :data:`LOG_WEIGHT_RANGE`) of ``R(x_lambda) - target`` by Newton steps, bisection where a step
    leaves the bracket or M is not definite; the smallest weight of the range where the residual
    is above the target already, the largest where it never gets there."""
    lo, hi = LOG_WEIGHT_RANGE
    best: _Point | None = None  # the point of the smallest t known to reach the target
    # another channel's answer, a little above: the root often lies just above the weight where M
    # stops being definite, and a start on the definite side keeps Newton's steps in the bracket
    t = min(max(0.0 if hint is None else hint + 2 * tol, lo), hi)
    for _ in range(60):
        point = solve.at(10.0**t)
        if point is None or point.f < 0:
            lo = t
        else:
            hi, best = t, point
        step = None
        if point is not None and point.slope > 0:
            step = -point.f / point.slope
            if abs(step) < tol:
                return point
        if hi - lo < tol:
            break
        if step is not None and lo < t + step < hi:
            t = t + step
        elif best is None:  # nothing reaches the target yet: climb, no bisection toward the range's end
            t = min(t + 0.5, 0.5 * (t + hi) if hi - t < 1.0 else t + 0.5)
        else:
            t = 0.5 * (lo + hi)
    if best is not None:
        return best
    point = solve.at(10.0 ** LOG_WEIGHT_RANGE[1])  # the residual stays under the target: the largest weight
    if point is None:
        raise ParameterError(f"the regularized normal matrix is not positive definite even at prior weight 1e{LOG_WEIGHT_RANGE[1]:g}: raise the samples per pixel")
    return point


def _gcv(solve: _Solve, D: torch.Tensor, rows: int, tol: float = 0.05) -> _Point:
    """Generalized cross-validation's point: the weight minimizing ``rows ||Abar x - b||^2 / (rows -
    tr(M^-1 H))^2`` over :data:`LOG_WEIGHT_RANGE` (a grid of half decades, then golden section)."""

    def score(t: float) -> tuple[float, _Point | None]:
        point = solve.at(10.0**t)
        if point is None:
            return math.inf, None
        rss = point.f + solve.target + float(point.x @ (D @ point.x))
        return rows * rss / max(rows - solve.influence(point), 1e-9) ** 2, point

    grid = np.arange(LOG_WEIGHT_RANGE[0], LOG_WEIGHT_RANGE[1] + 1e-9, 0.5)
    scores = [score(float(t))[0] for t in grid]
    k = int(np.argmin(scores))
    if not math.isfinite(scores[k]):
        raise ParameterError("the regularized normal matrix is not positive definite at any weight: raise the samples per pixel")
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    g = (math.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = score(c)[0], score(d)[0]
    while b - a > tol:
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = score(c)[0]
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = score(d)[0]
    return score(0.5 * (a + b))[1] or solve.at(10.0 ** grid[k])


def _leaf_start(start, basis: MapBasis, omega: np.ndarray) -> np.ndarray:
    """(n, 3) the start map (h, w, 3) in the basis: each leaf's solid-angle-weighted mean."""
    h, w = basis.shape
    x0 = torch.as_tensor(start, dtype=torch.float64)
    if x0.numel() != h * w * 3:
        raise ParameterError(f"start must be {h} x {w} x 3, got {tuple(x0.shape)}")
    texel = texel_solid_angles(h, w).numpy()[:, None] * x0.reshape(-1, 3).numpy()
    return (basis.matrix().T @ texel) / omega[:, None]


def _check_solve(weight, rule, smoothness, tikhonov, target_noise, sparsity, shape: tuple[int, int] | None = None) -> None:
    """A one-line :class:`ParameterError` for a solve setting out of range (and, with the map's
    ``shape``, for a sparsity prior on a map that is not 2^k x 2^l): before any render."""
    for name, value, low in (("smoothness", smoothness, 0.0), ("tikhonov", tikhonov, 0.0), ("target_noise", target_noise, 0.0), ("sparsity", sparsity, 0.0)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= low):
            raise ParameterError(f"fit_map {name} must be a finite number >= {low:g}, got {value!r}")
    if tikhonov <= 0:
        raise ParameterError(f"fit_map tikhonov must be > 0 (it keeps the problem definite where smoothness leaves the map's mean free), got {tikhonov!r}")
    if weight is not None and not (isinstance(weight, (int, float)) and math.isfinite(weight) and weight > 0):
        raise ParameterError(f"fit_map weight must be a number > 0 or None (the rule's), got {weight!r}")
    if rule not in RULES:
        raise ParameterError(f"fit_map rule must be one of {', '.join(RULES)}, got {rule!r}{did_you_mean(str(rule), RULES)}")
    if sparsity > 0 and shape is not None:
        check_haar(*shape)


def solve_map(
    source,
    targets: list[torch.Tensor] | None = None,
    *,
    start=None,
    weight: float | None = None,
    rule: str = "discrepancy",
    smoothness: float = 1.0,
    tikhonov: float = 1e-2,
    target_noise: float = 0.0,
    masks: list[torch.Tensor] | None = None,
    stderr: bool = True,
    sparsity: float = 0.0,
) -> MapFit:
    """The non-negative regularized least-squares map (module docstring) of ``source``: a
    :class:`~invrender.estimators.transport_matrix.TransportMatrix` with its ``targets`` (one (H, W, 3)
    linear image per view) and ``masks`` (per view (H, W) pixel weights in [0, 1]; None: every
    pixel counts), or :class:`~invrender.inverse.map_normal.NormalEquations` (a fit's ``normal``:
    the targets are in them already).

    Args:
        start: x0 (h, w, 3), the Tikhonov prior's centre (default: every texel the targets' mean
            over the matrix's mean row sum, a flat map of the right brightness).
        weight: the prior's weight lambda (dimensionless); None: the ``rule``'s.
        rule: ``"discrepancy"`` (Morozov's, on the known noise) or ``"gcv"``.
        smoothness, tikhonov: the two priors' relative weights (>= 0; tikhonov > 0).
        target_noise: the targets' own noise, a standard deviation per pixel and channel (0: exact).
        stderr: compute standard errors and the resolution (an inverse and a product per channel).
        sparsity: the weight of an L1 prior on the map's Haar details (:func:`sparse_quadratic`;
            dimensionless, relative to the prior's weight at the targets' brightness; 0: none), for
            a sun: the map's height and width must be powers of 2. The weight rule, the standard
            errors and the resolution are those of the problem without it.
    """
    clock = time.perf_counter()
    _check_solve(weight, rule, smoothness, tikhonov, target_noise, sparsity)
    if isinstance(source, TransportMatrix):
        if targets is None:
            raise ParameterError("solve_map of a transport matrix needs its targets, one per view")
        tm, normal = source, from_matrix(source, [torch.as_tensor(t) for t in targets], masks)
    elif isinstance(source, NormalEquations):
        tm, normal = None, source
    else:
        raise ParameterError(f"solve_map solves a TransportMatrix or NormalEquations, got {type(source).__name__}")
    basis = normal.basis
    h, w = basis.shape
    n = basis.n
    active = np.zeros(n, dtype=bool)
    for c in range(3):
        active |= (normal.Gm[c].diagonal() > 0).numpy()
    prior = _Prior(basis, tikhonov, smoothness, active)
    x0 = np.broadcast_to(normal.flat.numpy(), (n, 3)).copy() if start is None else _leaf_start(start, basis, prior.omega)
    a = torch.from_numpy(prior.a)
    if sparsity > 0:  # the Haar coefficients of the reached unknowns (refused here for a map not 2^k x 2^l)
        haar, details = basis.haar()
        haar = haar[:, prior.a]
    x_all, se, res = (torch.zeros(n, 3, dtype=torch.float64) for _ in range(3))
    weights, residual, noise, dof = (torch.zeros(3, dtype=torch.float64) for _ in range(4))
    bound = torch.zeros(3, dtype=torch.int64)
    evaluations = torch.zeros(3, dtype=torch.int64)
    hint = None
    # single-threaded: the solve is a chain of many small LAPACK calls (triangular solves, the
    # inverse of a factor), each of which synchronizes the whole OpenMP team; on a machine shared
    # with other work a descheduled thread stalls every one (measured on 2 loaded cores, n = 1300:
    # a triangular solve 0.2 s with 2 threads, 0.8 ms with 1; cholesky_inverse 2.3 s against 0.05 s)
    with one_thread():
        for c in range(3):
            p = prior.pull(x0[:, c])
            H = normal.H(c, a)
            scale = float((normal.Gm[c].diagonal().double() - normal.D[c].diagonal().double()).sum()) / n
            if scale <= 0 or not a.numel():  # no pixel sees the map in this channel: the prior alone
                x_all[:, c] = prior.extend(torch.zeros(a.numel(), dtype=torch.float64), p) if a.numel() else torch.from_numpy(x0[:, c])
                weights[c] = math.inf
                continue
            D = normal.D[c][a][:, a].double()
            rows = int(normal.rows[c])
            solve = _Solve(H, prior.Q, normal.g[c][a], prior.reduced(p), float(normal.bb[c]), scale, rows * target_noise**2)
            if weight is not None:
                point = solve.at(weight)
                if point is None:
                    raise ParameterError(f"the regularized normal matrix is not positive definite at prior weight {weight:.3g}: raise the weight or the samples per pixel")
            elif rule == "gcv":
                point = _gcv(solve, D, rows)
            else:
                point = _discrepancy(solve, hint)
                hint = math.log10(point.lam)
            evaluations[c] = solve.evaluations
            M = solve.matrix(point.lam)
            xa = bounded_quadratic(M, solve.g + (point.lam * scale) * solve.p, point.L, x=point.x)
            if sparsity > 0:
                mu = sparsity * point.lam * scale * float(normal.flat[c])
                xa = sparse_quadratic(M, solve.g + (point.lam * scale) * solve.p, haar, details, mu, xa)
            x_all[:, c] = prior.extend(xa, p)
            weights[c] = point.lam
            d2 = float(xa @ (D @ xa))
            bb = max(float(normal.bb[c]), 1e-300)
            residual[c] = math.sqrt(max(solve.residual(xa) + d2, 0.0) / bb)
            noise[c] = math.sqrt(d2 / bb)
            bound[c] = int((x_all[:, c] <= 0).sum())
            if stderr:
                Minv = torch.cholesky_inverse(point.L)
                R = (Minv.float() @ H.float()).double()  # the resolution matrix M^-1 H
                s2 = (d2 + rows * target_noise**2) / max(rows, 1)  # per-pixel variance of the residual
                se[a, c] = (s2 * (R * Minv).sum(1)).clamp_min(0.0).sqrt()  # diag(M^-1 H M^-1), M symmetric
                # clipped to [0, 1]: H is unbiased but noisy and can be indefinite, and a prior weight
                # near the edge of definiteness turned the noise's negative directions into
                # negative resolutions (a "-41 of 512 determined" at 2 x 64 spp)
                res[a, c] = R.diagonal().clamp(0.0, 1.0)
                dof[c] = float(res[a, c].sum())
                if prior.i.size and prior.border.size:  # the eliminated unknowns: x_I = ... - F x_border
                    bo = torch.from_numpy(prior.border)
                    cov = s2 * (R[bo] @ Minv[:, bo])
                    F = torch.from_numpy(prior.F)
                    se[torch.from_numpy(prior.i), c] = ((F @ cov) * F).sum(1).clamp_min(0.0).sqrt()
            del D
    resolution = basis.expand(res).float().reshape(h, w, 3)
    return MapFit(
        texels=basis.expand(x_all).float().reshape(h, w, 3),
        stderr=basis.expand(se).float().reshape(h, w, 3),
        weight=weights,
        rule="fixed" if weight is not None else rule,
        residual=residual,
        noise=noise,
        resolution=resolution,
        dof=dof,
        undetermined=(resolution < UNDETERMINED).any(2) if stderr else torch.zeros(h, w, dtype=torch.bool),
        active=bound,
        matrix=tm,
        seconds={"render": normal.seconds["render"], "gram": normal.seconds["gram"], "solve": time.perf_counter() - clock},
        basis=basis,
        normal=normal,
        evaluations=evaluations,
    )


def fit_map(
    scene: Scene,
    targets,
    emitter: str = "sky",
    *,
    cameras=None,
    integrator="path",
    spp: int = 64,
    max_depth: int | None = 3,
    seed: int = 0,
    weight: float | None = None,
    rule: str = "discrepancy",
    smoothness: float = 1.0,
    tikhonov: float = 1e-2,
    target_noise: float = 0.0,
    sparsity: float = 0.0,
    mask=None,
    start=None,
    stderr: bool = True,
    unknowns: int = DEFAULT_UNKNOWNS,
    rounds="auto",
    pilot_spp: int | None = None,
    memory_mb: float | None = None,
    progress: bool = False,
) -> MapFit:
    """The map of the envmap ``emitter`` of ``scene`` that reproduces ``targets`` (an image or a
    list, one per camera of ``cameras``) seen through the scene's known objects: the normal
    equations of its transport matrix streamed view by view
    (:func:`~invrender.inverse.map_normal.normal_equations`, two halves of ``spp`` samples per
    pixel, sampled by the scene's current map) and their non-negative regularized solve
    (:func:`solve_map`: ``weight`` None chooses the prior's weight by ``rule``).

    The unknowns are the map's texels when there are at most ``unknowns`` of them, else the blocks
    of a quadtree (:class:`~invrender.estimators.map_basis.MapBasis`). ``rounds``: 2 renders the matrix
    again sampled by the first round's map (plus a tenth of its mean, so no direction is left
    unsampled), with the quadtree refined where that map has its power (a sun); ``"auto"`` does so
    when the basis is coarser than the texels or the first map's peak is over
    :data:`SUN_RATIO` x its median. Where a second round follows whatever the first finds (2, or
    ``"auto"`` with a basis coarser than the texels) the first is a pilot that only chooses the
    second's sampling and basis, traced at ``pilot_spp`` per half (default ``spp // 4``, at least
    1). The scene's current map fixes the map's size and the first
    round's sampling; ``start`` (default: a flat map of the targets' brightness) is the Tikhonov
    prior's centre. Refused before any work, in one line with the figure, when a view's halves,
    the normal equations and the solve (``24 P_v n + 72 n^2`` bytes) exceed ``memory_mb``
    (default: 90% of the memory available)."""
    envmap_of(scene, emitter)
    if rounds not in (1, 2, "auto"):
        raise ParameterError(f"fit_map rounds must be 1, 2 or 'auto', got {rounds!r}")
    views = load_targets(scene, targets, cameras, mask=mask)
    current = scene.params[f"{emitter}.emission"]
    h, w = int(current.shape[0]), int(current.shape[1])
    basis = MapBasis.uniform(h, w, unknowns)
    masks = None if all(t.plain for _, t in views) else [t.mask for _, t in views]
    linear = [t.linear for _, t in views]
    second = rounds == 2 or (rounds == "auto" and not basis.is_texels)  # whatever the first round finds
    pilot_spp = max(1, spp // 4) if pilot_spp is None else pilot_spp
    check_int("fit_map ", "pilot_spp", pilot_spp, 1)
    render = {"integrator": integrator, "max_depth": max_depth, "progress": progress}
    _check_solve(weight, rule, smoothness, tikhonov, target_noise, sparsity, (h, w))  # before any render
    settings = {"start": start, "weight": weight, "rule": rule, "smoothness": smoothness, "tikhonov": tikhonov, "target_noise": target_noise, "stderr": stderr, "sparsity": sparsity}

    def round_(basis: MapBasis, seed: int, spp: int, sampling_map=None) -> MapFit:
        normal = normal_equations(scene, emitter, linear, cameras=cameras, masks=masks, basis=basis, memory_mb=memory_mb, extra_bytes=solver_bytes(basis.n), seed=seed, sampling_map=sampling_map, spp=spp, **render)
        return solve_map(normal, **settings)

    fit = round_(basis, seed, pilot_spp if second else spp)
    if second or (rounds == "auto" and _has_sun(fit)):
        first = fit.texels.reshape(-1, 3)
        sampling = first + 0.1 * first.mean(0)
        fine = basis.refined(first, unknowns) if not basis.is_texels else basis
        last = round_(fine, seed + 1, spp, sampling.reshape(h, w, 3))
        last.seconds = {k: fit.seconds[k] + last.seconds[k] for k in last.seconds}
        last.rounds = 2
        fit = last
    return fit


def _has_sun(fit: MapFit) -> bool:
    """The first round's map has a peak over :data:`SUN_RATIO` x its median (over the texels the
    images determine): a sun, whose columns a map-independent sampling leaves noisy."""
    lum = fit.texels.mean(2)[~fit.undetermined] if bool((~fit.undetermined).any()) else fit.texels.mean(2).reshape(-1)
    median = float(lum.median())
    return median > 0 and float(lum.max()) > SUN_RATIO * median
