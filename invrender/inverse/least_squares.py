"""Second-order fitting on path records: Levenberg-Marquardt / Gauss-Newton through optimistix.

The recorded images are explicit polynomials in the parameters (:mod:`invrender.diff.records`), so
the weighted residual ``r(theta) = (I(theta) - T) / sqrt(T^2 + 0.01)`` over all views (the
``relative_l2`` weighting of ``fit``) and its exact Jacobian cost milliseconds and no tracing. The
polynomial is evaluated natively in JAX (in float64, which this module switches JAX to), so
optimistix differentiates and jit-compiles it.

**Decorrelation.** A least-squares solution on one fixed sample set is biased: the noise of the
residual and of its Jacobian are the same noise, and the normal equations ``J^T r = 0`` average
their product. Two independent record sets A and B (different seeds) remove it: the solver sees
the residual of A with the Jacobian of B (a ``jax.custom_jvp`` whose primal is A's and whose
tangent map is B's), so it solves ``J_B^T r_A = 0``, whose expectation factors.

**Constraints** by the parameter kinds' reparametrizations (sigmoid for [0, 1] kinds, exp for
emission): the solver moves unconstrained ``x``.

**Uncertainty.** At the solution, the Gauss-Newton sandwich
``Cov(theta) = (J^T J)^-1 J^T diag(s^2) J (J^T J)^-1`` with ``s^2`` each residual's Monte Carlo
variance, estimated from the two independent sets (``(r_A - r_B)^2 / 2``), gives each parameter's
standard error; a near-singular ``J^T J`` names the combinations the targets cannot determine.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.diff.records import PathRecords
from invrender.errors import ParameterError
from invrender.scene.kinds import kind_of

SOLVERS = ("adam", "lm", "gauss_newton")
#: Gauss-Newton steps on J_B^T r_A = 0 after the solver (see solve)
REFINE_STEPS = 4


def _inside(kind, value: torch.Tensor) -> torch.Tensor:
    """``value`` kept strictly inside the kind's range (sigmoids saturate at 0 and 1)."""
    if kind.reparam == "sigmoid":
        return value.clamp(1e-6, 1 - 1e-6)
    return value.clamp_min(1e-9)


@dataclass(frozen=True)
class LeastSquaresSolution:
    """One inner solve.

    Attributes:
        values: name -> (3,) float64 recovered values.
        identifiability: standard errors, correlations and undetermined combinations there.
        loss: mean squared weighted residual of set A at the solution.
        steps: the solver's inner steps.
    """

    values: dict
    identifiability: "Identifiability"
    loss: float
    steps: int

    @property
    def std_error(self) -> dict:
        """name -> (3,) float64 standard errors (the sandwich of the estimating equation)."""
        return self.identifiability.std_error


def _jax():
    try:
        import jax
        import jax.numpy as jnp
        import optimistix as optx
    except ImportError as e:  # pragma: no cover - a declared dependency
        raise ParameterError(f"solver 'lm' needs JAX and optimistix ({e}); pip install jax optimistix") from None
    # float64: the emission-albedo scale direction is ill-conditioned, and in float32 the solver's
    # step and cost tests are met while the normal equations are still 2% off
    jax.config.update("jax_enable_x64", True)
    return jax, jnp, optx


_RESIDUAL = None


def _decorrelated_residual():
    """The weighted residual ``fn(x, args)`` optimistix solves, built once per process (so its jit
    cache lives across calls): values of record set A, tangent map (Jacobian) of set B, through a
    ``jax.custom_jvp``. ``x`` (P, 3) unconstrained; ``args["exp"]`` (P,) 1 where a parameter is
    exp-reparametrized (emission), else sigmoid."""
    global _RESIDUAL
    if _RESIDUAL is not None:
        return _RESIDUAL
    jax, jnp, _ = _jax()

    def residual_of(x, args, which):
        V = jnp.where(args["exp"][:, None] > 0, jnp.exp(x), jax.nn.sigmoid(x))
        parts = []
        for (E, C), t, w in zip(args[which], args["T"], args["W"]):
            mono = jnp.prod(V[None, :, :] ** E[:, :, None], axis=1)  # (S, 3)
            parts.append(((jnp.einsum("sc,snc->nc", mono, C) - t) * w).reshape(-1))
        return jnp.concatenate(parts)

    @jax.custom_jvp
    def residual(x, args):
        return residual_of(x, args, "a")

    @residual.defjvp
    def _residual_jvp(primals, tangents):
        (x, args), (dx, _) = primals, tangents
        return residual_of(x, args, "a"), jax.jvp(lambda y: residual_of(y, args, "b"), (x,), (dx,))[1]  # A's values, B's Jacobian

    _RESIDUAL = residual
    return residual


def _to_jax(t: torch.Tensor):
    jax, jnp, _ = _jax()
    return jnp.asarray(t.detach().to("cpu", torch.float64).contiguous().numpy())


def solve(
    records_a: list[PathRecords],
    records_b: list[PathRecords],
    targets: list[torch.Tensor],
    start: dict[str, torch.Tensor],
    solver: str = "lm",
    max_steps: int = 100,
    rtol: float = 1e-6,
    atol: float = 1e-9,
) -> LeastSquaresSolution:
    """Fit the recorded parameters to ``targets`` (one per view) by Levenberg-Marquardt (``"lm"``)
    or Gauss-Newton, residual from ``records_a``, Jacobian from ``records_b`` (independent seeds).

    ``start``: name -> (3,) starting values (inside each kind's range)."""
    jax, jnp, optx = _jax()
    names = list(records_a[0].names)
    kinds = [kind_of(n) for n in names]
    weights = [1.0 / (t.double() ** 2 + 0.01).sqrt().reshape(-1, 3) for t in targets]

    # every set padded to a power-of-two count of monomials (zero coefficients): the jitted solver
    # is traced once per shape, and rounds and calls with the same shapes reuse it
    size = max(1 << max(int(r.exponents.shape[0]) - 1, 1).bit_length() for r in records_a + records_b)

    def polynomial(rec: PathRecords):
        S = int(rec.exponents.shape[0])
        E = torch.zeros(size, len(names), dtype=torch.float64)
        E[:S] = rec.exponents.double()
        C = torch.zeros(size, *rec.coefficients.shape[1:], dtype=torch.float64)
        C[:S] = rec.coefficients.cpu()
        return _to_jax(E), _to_jax(C)

    args = {
        "a": [polynomial(r) for r in records_a],
        "b": [polynomial(r) for r in records_b],
        "T": [_to_jax(t.reshape(-1, 3)) for t in targets],
        "W": [_to_jax(w) for w in weights],
        "exp": _to_jax(torch.tensor([k.reparam == "exp" for k in kinds], dtype=torch.float64)),
    }
    x0 = jnp.stack([_to_jax(k.to_raw(start[n].double())) for n, k in zip(names, kinds)])
    method = optx.LevenbergMarquardt(rtol=rtol, atol=atol) if solver == "lm" else optx.GaussNewton(rtol=rtol, atol=atol)
    sol = optx.least_squares(_decorrelated_residual(), method, x0, args=args, options={"jac": "fwd"}, max_steps=max_steps, throw=False)
    x = torch.from_numpy(jax.device_get(sol.value).copy()).double()
    if not bool(torch.isfinite(x).all()):
        raise ParameterError(f"solver {solver!r} diverged (non-finite parameters); start closer or use 'lm', whose damping bounds its steps")
    values = {n: _inside(k, k.from_raw(x[p])) for p, (n, k) in enumerate(zip(names, kinds))}
    steps = int(sol.stats["num_steps"])
    # The trust region accepts steps by the decrease of |r_A|^2, which B's Jacobian does not model
    # exactly, so it stalls a little short of J_B^T r_A = 0: finish with undamped Gauss-Newton steps
    # on that equation (near the solution the problem is almost linear; a few steps suffice).
    for _ in range(REFINE_STEPS):
        J, ra = _jacobian_b_and_residual_a(records_a, records_b, targets, weights, values)
        step = torch.linalg.lstsq(J, -ra[:, None]).solution[:, 0]
        values = {n: _inside(k, values[n] + step[3 * p : 3 * p + 3]) for p, (n, k) in enumerate(zip(names, kinds))}
        if float(step.abs().max()) < 1e-10:
            break

    ident = analyse(records_a, records_b, targets, values)
    return LeastSquaresSolution(values, ident, ident.loss, steps)


def _jacobian_b_and_residual_a(records_a, records_b, targets, weights, values):
    """Value-space Jacobian (R, 3P) of set B's weighted residual and set A's residual (R,): what a
    Gauss-Newton step on ``J_B^T r_A = 0`` needs."""
    names = list(records_a[0].names)
    J = torch.cat([_value_jacobian(rec_b, values, w, names) for rec_b, w in zip(records_b, weights)])
    ra = torch.cat([_residual(rec_a, values, t, w) for rec_a, t, w in zip(records_a, targets, weights)])
    return J, ra


def _residual(rec: PathRecords, values: dict, target: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """(N * 3,) one view's weighted residual ``(I - T) w``."""
    return ((rec.image(values).reshape(-1, 3) - target.double().reshape(-1, 3)) * w).reshape(-1)


def _jacobian_and_residuals(records_a, records_b, targets, weights, values):
    """Value-space Jacobians (R, 3P) of set B's and set A's weighted residuals, and both sets'
    residuals (R,)."""
    names = list(records_a[0].names)
    blocks, blocks_a, ra, rb = [], [], [], []
    for rec_a, rec_b, t, w in zip(records_a, records_b, targets, weights):
        ra.append(_residual(rec_a, values, t, w))
        rb.append(_residual(rec_b, values, t, w))
        blocks.append(_value_jacobian(rec_b, values, w, names))
        blocks_a.append(_value_jacobian(rec_a, values, w, names))
    return torch.cat(blocks), torch.cat(blocks_a), torch.cat(ra), torch.cat(rb)


def _value_jacobian(rec: PathRecords, values: dict, w: torch.Tensor, names: list[str]) -> torch.Tensor:
    """(N * 3, 3P) derivatives of one view's weighted residual with respect to every parameter
    channel (channel c of a pixel depends on channel c of a parameter only)."""
    jac = rec.jacobian(values)
    cols = []
    for n in names:
        d = jac[n].reshape(-1, 3) * w
        for c in range(3):
            col = torch.zeros_like(d)
            col[:, c] = d[:, c]
            cols.append(col.reshape(-1))
    return torch.stack(cols, dim=1)


@dataclass(frozen=True)
class Identifiability:
    """What the targets determine about the parameters, from the Gauss-Newton matrix ``J^T J``.

    Attributes:
        std_error: name -> (3,) standard errors at the evaluated values.
        correlation: (3P, 3P) correlation matrix of the parameter channels.
        channels: the 3P channel labels (``"red.reflectance[G]"``).
        weak: combinations the targets cannot determine: each a dict channel label -> weight (a unit
            vector in relative units, largest weights only), for every direction along which the
            column-scaled ``J^T J`` has an eigenvalue below ``threshold`` times its largest.
        loss: mean squared weighted residual of record set A at the evaluated values.
    """

    std_error: dict
    correlation: torch.Tensor
    channels: list[str]
    weak: list[dict]
    loss: float

    def describe(self) -> str:
        """One line per undetermined combination (empty when everything is determined)."""
        return "; ".join(" + ".join(f"{w:+.2f} {c}" for c, w in combo.items()) for combo in self.weak)


def analyse(records_a: list[PathRecords], records_b: list[PathRecords], targets: list[torch.Tensor], values: dict, threshold: float = 1e-6) -> Identifiability:
    """Standard errors, correlations and undetermined combinations at ``values``.

    The standard errors are the sandwich of the estimating equation ``J_B^T r_A = 0``, whose
    variance has the residual's noise seen through J (``s^2`` per residual, from the two sets) and
    the Jacobian's own noise times the residual (``dJ^T diag(r_A^2) dJ``, ``dJ = (J_A - J_B)/sqrt 2``)."""
    names = list(records_a[0].names)
    weights = [1.0 / (t.double() ** 2 + 0.01).sqrt().reshape(-1, 3) for t in targets]
    J, J_a, ra, rb = _jacobian_and_residuals(records_a, records_b, targets, weights, values)
    # relative units: each column scaled by its parameter value, so eps and rho compare
    scale = torch.cat([values[n].double() for n in names])
    Js = J * scale[None, :]
    JtJ = Js.T @ Js
    norms = JtJ.diagonal().clamp_min(1e-300).sqrt()
    normalized = JtJ / (norms[:, None] * norms[None, :])
    eigenvalues, vectors = torch.linalg.eigh(normalized)
    labels = [f"{n}[{c}]" for n in names for c in "RGB"]
    weak = []
    for lam, v in zip(eigenvalues.tolist(), vectors.T):
        if lam < threshold * float(eigenvalues.max()):
            order = torch.argsort(v.abs(), descending=True)
            combo = {labels[i]: float(v[i]) for i in order.tolist() if abs(float(v[i])) > 0.2}
            weak.append(combo)
    s2 = (ra - rb) ** 2 / 2
    dJ = (J_a - J) / 2**0.5
    inv = torch.linalg.pinv(J.T @ J)
    cov = inv @ ((J.T * s2) @ J + (dJ.T * ra**2) @ dJ) @ inv
    se = cov.diagonal().clamp_min(0).sqrt()
    corr = cov / (se[:, None] * se[None, :]).clamp_min(1e-300)
    return Identifiability({n: se[3 * p : 3 * p + 3].clone() for p, n in enumerate(names)}, corr, labels, weak, float((ra**2).mean()))
