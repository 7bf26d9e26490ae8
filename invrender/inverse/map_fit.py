"""Inverse lighting by the transport matrix: an environment map as one regularized, non-negative
linear least-squares problem (``ir.lighting.fit_map``).

**The problem.** Per colour channel, the views' pixels are ``b = A L`` (+ the light that does not
end on the map), ``A`` (P, T) the transport matrix of the map's T texels
(:func:`invrender.diff.transport_matrix.transport_matrix`), estimated in two independent halves
``A1``, ``A2``. The fit minimizes, over texels ``x >= 0``,

    x^T H x - 2 g^T x + b^T b  +  lambda s [ x^T S x + mu (x - x0)^T W (x - x0) ]

with ``H = sym(A1^T A2)`` (unbiased for ``A^T A``: the plain ``Abar^T Abar`` would add the noise's
``E^T E``, a bias that shrinks the map), ``g = Abar^T b`` (``Abar`` the halves' mean), the first
three terms together ``R(x)``, an unbiased estimate of the residual ``||A x - b||^2`` of the exact
transport. The priors are rows of the problem: ``S`` the smoothness of the map on the sphere (its
Dirichlet energy ``int |grad L|^2 dOmega`` on the texel grid, neighbours along each row wrapping in
longitude and down each column, each difference weighted by the solid angle it spans:
:func:`sphere_smoothness`) and Tikhonov toward the start ``x0`` weighted by the texels' solid angles
``W`` (``mu``, default 1e-2: keeps the problem definite where smoothness alone leaves the mean
free). Both are scaled to a mean diagonal of 1 and ``s`` is the mean diagonal of ``H``, so the
weight ``lambda`` is dimensionless.

**The weight from the data: the discrepancy principle.** The Monte Carlo noise of the images the
matrix predicts is known for any map: ``delta^2(x) = ||(A1 - A2) x||^2 / 4`` (the variance of the
halves' mean). Morozov's discrepancy principle asks the residual of ``Abar`` to equal the noise,
``||Abar x - b||^2 = delta^2(x) + P sigma_b^2`` (``sigma_b``: the targets' own noise per pixel, 0
for exact targets); since ``||Abar x - b||^2 = R(x) + delta^2(x)`` that is ``R(x_lambda) = P
sigma_b^2``: the largest weight whose fit explains the images down to their noise. ``R(x_lambda)``
grows with lambda, and below some weight the regularized matrix is not even definite (the noise's
negative directions of ``sym(A1^T A2)`` outweigh the prior), so the weight is the smallest at which
both hold, found by bisection in log lambda on the unconstrained solutions (a Cholesky
factorization each, to 0.05 decades), and the non-negative solution is then solved at that
weight (block principal pivoting on the normal equations: :func:`bounded_quadratic`).

**What the result says.** Standard errors from the sandwich ``M^-1 (s2 H) M^-1`` (``M`` the
regularized normal matrix, ``s2`` the per-pixel variance of the residual at the solution), the
*resolution* ``diag(M^-1 H)`` per texel (1: set by the images, 0: by the prior), its sum the
degrees of freedom the images determine, and the texels under 0.5 marked undetermined.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import torch

from invrender.diff.transport_matrix import TransportMatrix, envmap_of, transport_matrix
from invrender.emitters.envmap import texel_solid_angles
from invrender.errors import ParameterError
from invrender.inverse.fit import load_targets
from invrender.scene.scene import Scene

#: the rules that choose the prior's weight (fit_map's ``weight=None``)
RULES = ("discrepancy",)
#: the search interval of the weight, log10 (relative to the mean diagonal of H)
LOG_WEIGHT_RANGE = (-9.0, 3.0)
#: resolution below which a texel is reported undetermined
UNDETERMINED = 0.5


def solver_bytes(texels: int) -> int:
    """Bytes the solve takes beyond the transport matrix: per channel ``H``, the regularized matrix
    and its factor, the prior, two T x T work arrays (float64), about ``48 T^2``."""
    return 48 * texels * texels


def sphere_smoothness(h: int, w: int) -> np.ndarray:
    """(T, T) float64 the Dirichlet energy of an (h, w) map on the sphere, ``x^T S x = sum over
    neighbouring texels of c_ij (x_i - x_j)^2``: along a row (wrapping in longitude) ``c = Omega_i /
    (s_i dphi)^2`` (``Omega_i`` the texel's solid angle, ``s_i = Omega_i / (dtheta dphi)`` its mean
    sin theta, so the pole rows, one direction each, are held together), down a column ``c = dphi
    (cos theta_i - cos theta_i+1) / dtheta^2`` (the band between the two rows)."""
    T = h * w
    omega = texel_solid_angles(h, w).numpy().reshape(h, w)[:, 0]
    dth, dph = math.pi / (h - 1), 2 * math.pi / w
    S = np.zeros((T, T))
    idx = np.arange(T).reshape(h, w)

    def edges(a, b, c):
        a, b, c = a.reshape(-1), b.reshape(-1), np.broadcast_to(c, a.shape).reshape(-1)
        np.add.at(S, (a, a), c)
        np.add.at(S, (b, b), c)
        np.add.at(S, (a, b), -c)
        np.add.at(S, (b, a), -c)

    if w > 1:
        s = omega / (dth * dph)
        edges(idx, np.roll(idx, -1, axis=1), (omega / (s * dph) ** 2)[:, None])
    theta = np.arange(h) * dth
    band = dph * (np.cos(theta[:-1]) - np.cos(theta[1:])) / dth**2
    edges(idx[:-1], idx[1:], band[:, None])
    return S


@dataclasses.dataclass
class MapFit:
    """What :func:`fit_map` recovered.

    Attributes:
        texels: (h, w, 3) float32 the map (>= 0), in the emitter's units (radiance / scale).
        stderr: (h, w, 3) standard errors of the texels (the Monte Carlo noise through the
            regularized solve; not the prior's pull).
        weight: (3,) the prior's weight lambda per channel (dimensionless: relative to the mean
            diagonal of ``A^T A``).
        rule: how the weight was chosen (``"discrepancy"``, or ``"fixed"``).
        residual: (3,) ``||Abar x - b|| / ||b||`` per channel at the solution.
        noise: (3,) ``delta(x) / ||b||``, the Monte Carlo noise of the predicted images.
        resolution: (h, w, 3) ``diag(M^-1 H)``: 1 where the images set a texel, 0 where the prior does.
        dof: (3,) the degrees of freedom the images determine (the resolution's sum).
        undetermined: (h, w) bool, texels whose resolution is under 0.5 in some channel.
        active: (3,) texels held at 0 by the bound.
        matrix: the :class:`~invrender.diff.transport_matrix.TransportMatrix` it solved on.
        seconds: {"render": ..., "solve": ...}.
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

    def describe(self) -> str:
        """One line: rule, weights, residual against noise, determined degrees of freedom."""
        w = ", ".join(f"{float(x):.2g}" for x in self.weight)
        r = ", ".join(f"{100 * float(x):.2f}%" for x in self.residual)
        n = ", ".join(f"{100 * float(x):.2f}%" for x in self.noise)
        T = self.texels.shape[0] * self.texels.shape[1]
        return f"prior weight {w} ({self.rule}); residual {r} against noise {n}; {', '.join(f'{float(d):.0f}' for d in self.dof)} of {T} texels determined per channel"


@dataclasses.dataclass
class _Channel:
    """One channel's normal equations: ``H`` (T, T), ``g`` (T,), ``bb``, the channel's halves
    (P, T) and row weights (P,) for the noise, the count ``n`` of the rows that count."""

    H: torch.Tensor
    g: torch.Tensor
    bb: float
    halves: tuple[torch.Tensor, torch.Tensor]
    weight: torch.Tensor
    n: int

    @property
    def scale(self) -> float:
        return float(self.H.diagonal().mean()) if self.n else 0.0

    def residual(self, x: torch.Tensor) -> float:
        """R(x): the unbiased estimate of ``||A x - b||^2``."""
        return float(x @ (self.H @ x) - 2 * self.g @ x + self.bb)

    def noise(self, x: torch.Tensor) -> float:
        """delta^2(x) = ||(A1 - A2) x||^2 / 4 (rows weighted)."""
        x = x.float()
        return 0.25 * float(((self.halves[0] @ x - self.halves[1] @ x).double().square() * self.weight).sum())


def _channels(tm: TransportMatrix, b: torch.Tensor, weight: torch.Tensor) -> list[_Channel]:
    """The normal equations per channel from the halves, over the pixels some path links to the
    map (others carry no information on it), rows weighted by ``sqrt(weight)`` (P, 3)."""
    A1, A2 = tm.halves
    out = []
    for c in range(3):
        rows = (((A1[c] != 0).any(1) | (A2[c] != 0).any(1)) & (weight[:, c] > 0)).nonzero()[:, 0]
        r = weight[rows, c].sqrt()[:, None]
        a1, a2 = A1[c].index_select(0, rows) * r, A2[c].index_select(0, rows) * r
        bc = (b[rows, c] * r[:, 0]).double()
        G = (a1.T @ a2).double()
        H = 0.5 * (G + G.T)
        g = (0.5 * ((a1.T @ bc.float()) + (a2.T @ bc.float()))).double()
        out.append(_Channel(H, g, float(bc.square().sum()), (A1[c], A2[c]), weight[:, c].double(), int(rows.numel())))
        del a1, a2
    return out


def _prior(h: int, w: int, tikhonov: float, smoothness: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(Q (T, T), W (T,)): the prior's matrix ``smoothness S + tikhonov diag(W)``, each scaled to
    a mean diagonal of 1, and the Tikhonov weights W (so the prior's pull is ``tikhonov W x0``)."""
    T = h * w
    W = texel_solid_angles(h, w)
    W = W / W.mean()
    Q = torch.zeros(T, T, dtype=torch.float64)
    if smoothness > 0:
        S = torch.from_numpy(sphere_smoothness(h, w))
        Q += (smoothness / float(S.diagonal().mean())) * S
    Q.diagonal().add_(tikhonov * W)
    return Q, tikhonov * W


class _Solve:
    """Solutions of one channel at any weight (float64 torch: its LAPACK shares torch's threads):
    the unconstrained one by Cholesky and the non-negative one."""

    def __init__(self, ch: _Channel, Q: torch.Tensor, q: torch.Tensor, x0: torch.Tensor):
        self.ch, self.Q, self.pull = ch, Q, q * x0
        self.s = ch.scale

    def factor(self, lam: float) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(M, its lower Cholesky factor or None where M is not positive definite)."""
        M = self.ch.H + (lam * self.s) * self.Q
        L, info = torch.linalg.cholesky_ex(M)
        return M, (L if int(info) == 0 else None)

    def rhs(self, lam: float) -> torch.Tensor:
        return self.ch.g + (lam * self.s) * self.pull

    def unconstrained(self, lam: float) -> torch.Tensor | None:
        _, L = self.factor(lam)
        return None if L is None else cholesky_solve(L, self.rhs(lam))

    def discrepancy(self, lam: float, target: float) -> float:
        """R(x_lambda) - target (-inf where the regularized matrix is not definite: too small)."""
        x = self.unconstrained(lam)
        return -math.inf if x is None else self.ch.residual(x) - target

    def nonnegative(self, lam: float) -> tuple[torch.Tensor, torch.Tensor]:
        """(x >= 0, the Cholesky factor of M): the bounded solution at ``lam``."""
        M, L = self.factor(lam)
        if L is None:
            raise ParameterError(f"the regularized normal matrix is not positive definite at prior weight {lam:.3g}: raise the weight or the samples per pixel")
        return bounded_quadratic(M, self.rhs(lam), L), L


def cholesky_solve(L: torch.Tensor, r: torch.Tensor) -> torch.Tensor:
    """``M^-1 r`` (T,) for M's lower Cholesky factor ``L``, by two triangular solves (an order of
    magnitude faster than ``torch.cholesky_solve`` on one right-hand side)."""
    y = torch.linalg.solve_triangular(L, r[:, None], upper=False)
    return torch.linalg.solve_triangular(L.T, y, upper=True)[:, 0]


def bounded_quadratic(M: torch.Tensor, r: torch.Tensor, L: torch.Tensor | None = None, max_iter: int = 100) -> torch.Tensor:
    """argmin over x >= 0 of ``x^T M x - 2 r^T x`` (M (T, T) positive definite, r (T,)): non-negative
    least squares in normal-equation form by block principal pivoting (Kim and Park, "Fast
    nonnegative matrix factorization: an active-set-like method and comparisons", SIAM J. Sci.
    Comput. 33(6), 2011; Portugal, Judice and Vicente 1994): all infeasible variables exchanged
    between the free and the bound set at once, a single one (the last) when that stops reducing
    their count. ``L``: M's Cholesky factor, reused for the first, unconstrained solve."""
    T = r.shape[0]
    x = cholesky_solve(L, r) if L is not None else torch.linalg.solve(M, r)
    if bool((x >= 0).all()):
        return x
    free = torch.ones(T, dtype=torch.bool)
    best, chances = T + 1, 3
    for _ in range(max_iter):
        x = torch.zeros_like(r)
        f = free.nonzero()[:, 0]
        if f.numel():
            x[f] = cholesky_solve(torch.linalg.cholesky(M[f][:, f]), r[f])  # a principal submatrix of M: definite
        y = M @ x - r  # half the gradient: >= 0 on the bound set at the optimum
        bad = (free & (x < 0)) | (~free & (y < -1e-12 * r.abs().max().clamp_min(1e-300)))
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
    raise ParameterError(f"the non-negative solve did not converge in {max_iter} exchanges")


def _choose_weight(solve: _Solve, target: float, hint: float | None = None, tol: float = 0.05) -> float:
    """log10 of the discrepancy principle's weight: the smallest lambda (within
    :data:`LOG_WEIGHT_RANGE`, to ``tol`` decades) at which the regularized matrix ``H + lambda s Q``
    is positive definite and the residual ``R(x_lambda)`` reaches ``target``. Both hold from some
    weight on (below the first the noise's negative directions of ``sym(A1^T A2)`` outweigh the
    prior; the residual grows with the weight), so it is one bisection. ``hint``: a close guess
    (another channel's answer) that narrows it."""

    def enough(t: float) -> bool:
        return solve.discrepancy(10.0**t, target) >= 0

    lo, hi = LOG_WEIGHT_RANGE
    if hint is not None and not enough(hint - 0.25) and enough(hint + 0.25):
        lo, hi = hint - 0.25, hint + 0.25
    elif enough(lo):
        return lo
    elif not enough(hi):
        return hi
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if enough(mid):
            hi = mid
        else:
            lo = mid
    return hi


def solve_map(
    tm: TransportMatrix,
    targets: list[torch.Tensor],
    *,
    start=None,
    weight: float | None = None,
    smoothness: float = 1.0,
    tikhonov: float = 1e-2,
    target_noise: float = 0.0,
    masks: list[torch.Tensor] | None = None,
    stderr: bool = True,
) -> MapFit:
    """The non-negative regularized least-squares map of the transport matrix ``tm`` for
    ``targets`` (one (H, W, 3) linear image per view, as ``tm.views``); module docstring.

    Args:
        start: x0 (h, w, 3), the Tikhonov prior's centre (default: every texel the targets' mean
            over the matrix's mean row sum, a flat map of the right brightness).
        weight: the prior's weight lambda (dimensionless); None: the discrepancy principle's.
        smoothness, tikhonov: the two priors' relative weights (>= 0; tikhonov > 0).
        target_noise: the targets' own noise, a standard deviation per pixel and channel (0: exact).
        masks: per view (H, W) pixel weights in [0, 1] (None: every pixel counts).
        stderr: compute standard errors and the resolution (two T^3 products per channel).
    """
    clock = time.perf_counter()
    h, w = tm.shape
    T = h * w
    if len(targets) != len(tm.views):
        raise ParameterError(f"{len(targets)} target(s) for a transport matrix of {len(tm.views)} view(s): give one target per view")
    for i, (t, (H_, W_)) in enumerate(zip(targets, tm.views)):
        if tuple(t.shape) != (H_, W_, 3):
            raise ParameterError(f"target {i} is {tuple(t.shape)}, its view renders {H_} x {W_} x 3")
        if not bool(torch.isfinite(t).all()):
            raise ParameterError(f"target {i} contains NaN or Inf values")
    for name, value, low in (("smoothness", smoothness, 0.0), ("tikhonov", tikhonov, 0.0), ("target_noise", target_noise, 0.0)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= low):
            raise ParameterError(f"fit_map {name} must be a finite number >= {low:g}, got {value!r}")
    if tikhonov <= 0:
        raise ParameterError(f"fit_map tikhonov must be > 0 (it keeps the problem definite where smoothness leaves the map's mean free), got {tikhonov!r}")
    if weight is not None and not (isinstance(weight, (int, float)) and math.isfinite(weight) and weight > 0):
        raise ParameterError(f"fit_map weight must be a number > 0 or None (the discrepancy principle), got {weight!r}")
    b = torch.cat([t.detach().float().reshape(-1, 3) for t in targets])
    if tm.offset is not None:
        b = b - tm.offset
    pixel_weight = torch.ones_like(b) if masks is None else torch.cat([m.float().reshape(-1, 1).expand(-1, 3) for m in masks])
    channels = _channels(tm, b, pixel_weight)
    if start is None:
        Abar_rows = 0.5 * (tm.halves[0].sum(2) + tm.halves[1].sum(2))  # (3, P): each pixel under a map of ones
        level = [float(b[:, c].sum() / Abar_rows[c].sum().clamp_min(1e-30)) for c in range(3)]
        x0 = torch.tensor(level, dtype=torch.float64).expand(T, 3).clone()
    else:
        x0 = torch.as_tensor(start, dtype=torch.float64).reshape(-1, 3)
        if x0.shape[0] != T:
            raise ParameterError(f"start must be {h} x {w} x 3, got {tuple(torch.as_tensor(start).shape)}")
    Q, q = _prior(h, w, tikhonov, smoothness)
    texels, se, res = (torch.zeros(T, 3, dtype=torch.float64) for _ in range(3))
    weights, residual, noise, dof = (torch.zeros(3, dtype=torch.float64) for _ in range(4))
    active = torch.zeros(3, dtype=torch.int64)
    hint = None
    for c, ch in enumerate(channels):
        if ch.scale <= 0:  # no pixel sees the map in this channel: the prior alone
            texels[:, c] = x0[:, c]
            weights[c] = math.inf
            continue
        solve = _Solve(ch, Q, q, x0[:, c])
        if weight is None:
            hint = _choose_weight(solve, ch.n * target_noise**2, hint)
            lam = 10.0**hint
        else:
            lam = weight
        x, L = solve.nonnegative(lam)
        texels[:, c], weights[c] = x, lam
        d2 = ch.noise(x)
        residual[c] = math.sqrt(max(ch.residual(x) + d2, 0.0) / max(ch.bb, 1e-300))
        noise[c] = math.sqrt(d2 / max(ch.bb, 1e-300))
        active[c] = int((x <= 0).sum())
        if stderr:
            Minv = torch.cholesky_inverse(L)
            R = Minv @ ch.H  # the resolution matrix
            s2 = (d2 + ch.n * target_noise**2) / ch.n  # per-pixel variance of the residual
            se[:, c] = (s2 * (R * Minv).sum(1)).clamp_min(0.0).sqrt()  # diag(M^-1 H M^-1), M symmetric
            res[:, c] = R.diagonal()
            dof[c] = float(R.diagonal().sum())
    resolution = res.float().reshape(h, w, 3)
    return MapFit(
        texels=texels.float().reshape(h, w, 3),
        stderr=se.float().reshape(h, w, 3),
        weight=weights,
        rule="fixed" if weight is not None else "discrepancy",
        residual=residual,
        noise=noise,
        resolution=resolution,
        dof=dof,
        undetermined=(resolution < UNDETERMINED).any(2) if stderr else torch.zeros(h, w, dtype=torch.bool),
        active=active,
        matrix=tm,
        seconds={"render": tm.seconds, "solve": time.perf_counter() - clock},
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
    smoothness: float = 1.0,
    tikhonov: float = 1e-2,
    target_noise: float = 0.0,
    mask=None,
    start=None,
    stderr: bool = True,
    memory_mb: float | None = None,
    progress: bool = False,
) -> MapFit:
    """The map of the envmap ``emitter`` of ``scene`` that reproduces ``targets`` (an image or a
    list, one per camera of ``cameras``) seen through the scene's known objects: the transport
    matrix (:func:`~invrender.diff.transport_matrix.transport_matrix`, two halves of ``spp`` samples
    per pixel, sampled by the scene's current map) and its non-negative regularized solve
    (:func:`solve_map`: ``weight`` None chooses the prior's weight by the discrepancy principle).
    The scene's current map fixes the map's size and the sampling; ``start`` (default: a flat map
    of the targets' brightness) is the Tikhonov prior's centre. Refused before any work, in one
    line with the figure, when the matrix and the solve (``24 P T + 48 T^2`` bytes) exceed
    ``memory_mb`` (default: 90% of the memory available)."""
    envmap_of(scene, emitter)
    views = load_targets(scene, targets, cameras, mask=mask)
    current = scene.params[f"{emitter}.emission"]
    T = int(current.shape[0]) * int(current.shape[1])
    tm = transport_matrix(
        scene, emitter, cameras=cameras, integrator=integrator, spp=spp, max_depth=max_depth, seed=seed, memory_mb=memory_mb, extra_bytes=solver_bytes(T), progress=progress,
    )  # fmt: skip
    masks = None if all(t.plain for _, t in views) else [t.mask for _, t in views]
    return solve_map(tm, [t.linear for _, t in views], start=start, weight=weight, smoothness=smoothness, tikhonov=tikhonov, target_noise=target_noise, masks=masks, stderr=stderr)
