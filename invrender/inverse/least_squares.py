"""Second-order fitting on path records: Levenberg-Marquardt / Gauss-Newton through optimistix.

The recorded images are explicit polynomials in the parameters (:mod:`invrender.estimators.records`), so
the weighted residual ``r(theta) = (I(theta) - T) / sqrt(T^2 + 0.01)`` over all views (the
``relative_l2`` weighting of ``fit``) and its exact Jacobian cost milliseconds and no tracing. The
polynomial and its Jacobian are evaluated by torch (:meth:`PathRecords.image` and
:meth:`PathRecords.jacobian`, which uses the polynomial's structure: one pass over the sparse
texel tables instead of one per variable); optimistix drives the solve in JAX (float64, which this
module switches JAX to) and reads them through ``jax.pure_callback``, zero-copy on the CPU.

**Decorrelation.** A least-squares solution on one fixed sample set is biased: the noise of the
residual and of its Jacobian are the same noise, and the normal equations ``J^T r = 0`` average
their product. Two independent record sets A and B (different seeds) remove it: the solver sees
the residual of A with the Jacobian of B (a ``jax.custom_jvp`` whose primal is A's and whose
tangent map is B's), so it solves ``J_B^T r_A = 0``, whose expectation factors.

**Constraints** by the parameter kinds' reparametrizations (sigmoid for [0, 1] kinds, exp for
emission): the solver moves unconstrained ``x``.

**Prior (Tikhonov regularization).** An environment map (a textured emission) has texels no view
sees, or sees only through a few noisy paths; their columns of the Jacobian are zero or noise, and
the solution there is whatever the start was, or noise. A :class:`Prior` adds, per channel of each
such texel, the residual ``sqrt(lambda) (v - p) / p`` (relative, like the image's weighted
residual) toward a prior value ``p`` (the fit's starting value): texels the images determine are
pulled by it negligibly, texels they cannot see stay at ``p``. ``lambda`` is the user's, or by the
default rule :data:`PRIOR_FRACTION` times the mean over the parameter's channels of the diagonal of
the data term's ``J^T J`` in relative units (each column times its value), at the round's start.

**Sensor and masks.** With a :class:`~invrender.inverse.sensor.Sensor`, view v's model is
``g_v * I_v`` (its gains times the recorded image): still a polynomial in the scene parameters,
and in the sensor's free log variables ``s`` an exponential of a linear map, so the sensor adds K
columns ``w g_v I_v A[v]`` to the Jacobian (set B's image, like every column). A target that is a
:class:`~invrender.inverse.targets.Target` brings its per-pixel weights: its residual is the
linear one times the mask and the response's inverse slope over ``sqrt(y^2 + 0.01)`` (encoded
units, relative), so masked pixels' rows are zero and change nothing.

**Uncertainty.** At the solution, the Gauss-Newton sandwich
``Cov(theta) = (J^T J)^-1 J^T diag(s^2) J (J^T J)^-1`` with ``s^2`` each residual's Monte Carlo
variance, estimated from the two independent sets (``(r_A - r_B)^2 / 2``), gives each parameter's
standard error; a near-singular ``J^T J`` names the combinations the targets cannot determine.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from invrender.estimators.records import PathRecords
from invrender.errors import NonFiniteError, ParameterError
from invrender.inverse.sensor import Sensor
from invrender.inverse.targets import Target
from invrender.scene.kinds import kind_of

SOLVERS = ("adam", "lm", "gauss_newton")
#: Gauss-Newton steps on J_B^T r_A = 0 after the solver (see solve)
REFINE_STEPS = 4
#: the default prior weight: this fraction of the mean diagonal of the data term's J^T J (relative units)
PRIOR_FRACTION = 1e-3
#: the default smoothness weight, the same way
SMOOTHNESS_FRACTION = 1e-2
#: a direction of the parameters whose standard error is above this (relative) is reported loose
LOOSE = 0.02
#: loose directions reported, at most
MAX_LOOSE = 3


def _inside(kind, value: torch.Tensor) -> torch.Tensor:
    """``value`` kept strictly inside the kind's range (sigmoids saturate at 0 and 1)."""
    if kind.reparam == "sigmoid":
        return value.clamp(1e-6, 1 - 1e-6)
    return value.clamp_min(1e-9)


@dataclass(frozen=True)
class LeastSquaresSolution:
    """One inner solve.

    Attributes:
        values: name -> float64 recovered values, shaped as recorded ((3,) or (h, w, 3)).
        identifiability: standard errors, correlations and undetermined combinations there.
        loss: mean squared weighted residual of set A at the solution.
        steps: the solver's inner steps.
        seconds: where the solve's wall time went: ``import`` (JAX and optimistix, the first
            solve of a process only), ``reduce`` (:func:`reduce_records`), ``solver`` (optimistix,
            with its compilation the first time a problem size is met), ``refine`` (the
            Gauss-Newton steps after it) and ``analyse``.
    """

    values: dict
    identifiability: Identifiability
    loss: float
    steps: int
    seconds: dict = field(default_factory=dict)

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


def preload() -> None:
    """Start importing JAX and optimistix in a background thread (about 2 s, once a process), so
    that it overlaps with the work before the first solve (a fit's first records); the first
    :func:`solve` waits for it (Python's import lock), and so does the interpreter's exit. A
    failed import is raised there."""
    import threading

    def load():
        try:
            _jax()
        except ParameterError:
            pass  # said again by the solve that needs them

    # not a daemon: the interpreter waits for the import at exit. A daemon thread still inside
    # jaxlib's C++ when a failed fit ends the process is unwound by the interpreter's shutdown
    # through frames that do not allow it, and the process aborts ("FATAL: exception not
    # rethrown", exit 134) after the fit's own error message
    threading.Thread(target=load, name="invrender-jax-import", daemon=False).start()


@dataclass(frozen=True)
class _Layout:
    """How the recorded parameters map to the solver's variable rows (a constant is one row of
    three channels, a texture h * w rows), from the first record."""

    names: list[str]
    shapes: list[tuple[int, ...]]
    offsets: list[int]

    @staticmethod
    def of(records: PathRecords) -> _Layout:
        return _Layout(list(records.names), [tuple(records.record_values[n].shape) for n in records.names], records.offsets)

    def flatten(self, values: dict) -> torch.Tensor:
        """(N_var, 3) float64 rows of ``values``."""
        return torch.cat([values[n].double().reshape(-1, 3) for n in self.names])

    def unflatten(self, rows: torch.Tensor) -> dict:
        """name -> value shaped as recorded, from rows (N_var, 3)."""
        return {n: rows[a:b].reshape(shape).clone() for n, shape, a, b in zip(self.names, self.shapes, self.offsets, self.offsets[1:])}

    def _rows(self):
        return zip(self.names, self.offsets, self.offsets[1:])

    def to_raw(self, values: dict) -> torch.Tensor:
        """(N_var, 3) unconstrained rows of ``values`` (the kinds' reparametrizations)."""
        return torch.cat([kind_of(n).to_raw(values[n].double()).reshape(-1, 3) for n in self.names])

    def from_raw(self, x: torch.Tensor) -> torch.Tensor:
        """(N_var, 3) values of unconstrained rows ``x``, each kept strictly inside its range."""
        return torch.cat([_inside(kind_of(n), kind_of(n).from_raw(x[a:b])) for n, a, b in self._rows()])

    def inside(self, rows: torch.Tensor) -> torch.Tensor:
        """Value rows (N_var, 3) kept strictly inside their kinds' ranges."""
        return torch.cat([_inside(kind_of(n), rows[a:b]) for n, a, b in self._rows()])

    def labels(self) -> list[str]:
        """One label per variable channel: ``"red.reflectance[G]"``, ``"floor.reflectance[2,3][G]"``."""
        out = []
        for n, shape in zip(self.names, self.shapes):
            texels = [""] if len(shape) == 1 else [f"[{i},{j}]" for i in range(shape[0]) for j in range(shape[1])]
            out += [f"{n}{t}[{c}]" for t in texels for c in "RGB"]
        return out


def neighbour_pairs(h: int, w: int) -> torch.Tensor:
    """(P, 2) int64 flattened indices (row-major) of the neighbouring texels of an (h, w)
    latitude-longitude map: each texel with the next one in its row (wrapping around in longitude)
    and with the one below it (rows do not wrap: row 0 is the pole, row h - 1 the other)."""
    index = torch.arange(h * w).reshape(h, w)
    across = torch.stack([index.reshape(-1), torch.roll(index, -1, dims=1).reshape(-1)], dim=1) if w > 1 else torch.zeros(0, 2, dtype=torch.int64)
    down = torch.stack([index[:-1].reshape(-1), index[1:].reshape(-1)], dim=1)
    return torch.cat([across, down])


@dataclass(frozen=True)
class Prior:
    """Regularization of environment maps (see the module docstring), as residual rows whose Monte
    Carlo variance is zero (the prior is not sampled), one per channel:

    - Tikhonov toward prior values: ``sqrt(weight[n]) (v - p) / p`` for each texel of ``n``;
    - smoothness: ``sqrt(smoothness[n]) (v_i - v_j) / sqrt(p_i p_j)`` for each pair of
      neighbouring texels i, j (:func:`neighbour_pairs`), a relative difference that is linear in
      the values.

    Attributes:
        values: name -> prior value, shaped as recorded (> 0).
        weight: name -> Tikhonov lambda >= 0.
        smoothness: name -> smoothness mu >= 0 (textures only; missing = 0).
    """

    values: dict
    weight: dict
    smoothness: dict = field(default_factory=dict)

    def _rows(self, layout: _Layout):
        for n, a, b in layout._rows():
            if n in self.values and self.weight[n] > 0:
                yield n, a, b

    def _smooth(self, layout: _Layout):
        """(name, first row, pairs (P, 2), 1 / sqrt(p_i p_j) (P, 3)) of each smoothed texture."""
        for n, shape, a in zip(layout.names, layout.shapes, layout.offsets):
            if n in self.values and self.smoothness.get(n, 0) > 0 and len(shape) == 3:
                pairs = neighbour_pairs(shape[0], shape[1])
                p = self.values[n].double().reshape(-1, 3)
                yield n, a, pairs, (p[pairs[:, 0]] * p[pairs[:, 1]]).rsqrt()

    def residual(self, layout: _Layout, values: dict) -> torch.Tensor:
        """(M,) the prior's residual rows at ``values``."""
        parts = [(values[n].double().reshape(-1) / self.values[n].double().reshape(-1) - 1.0) * self.weight[n] ** 0.5 for n, _, _ in self._rows(layout)]
        for n, _, pairs, inv in self._smooth(layout):
            v = values[n].double().reshape(-1, 3)
            parts.append(((v[pairs[:, 0]] - v[pairs[:, 1]]) * inv).reshape(-1) * self.smoothness[n] ** 0.5)
        return torch.cat(parts) if parts else torch.zeros(0, dtype=torch.float64)

    def jacobian(self, layout: _Layout) -> torch.Tensor:
        """(M, 3 N_var) their value-space derivatives (constant)."""
        total = 3 * layout.offsets[-1]
        blocks = []
        for n, a, b in self._rows(layout):
            block = torch.zeros(3 * (b - a), total, dtype=torch.float64)
            block[:, 3 * a : 3 * b] = torch.diag(self.weight[n] ** 0.5 / self.values[n].double().reshape(-1))
            blocks.append(block)
        for n, a, pairs, inv in self._smooth(layout):
            block = torch.zeros(pairs.shape[0], 3, total, dtype=torch.float64)
            rows = torch.arange(pairs.shape[0])
            for c in range(3):
                block[rows, c, 3 * (a + pairs[:, 0]) + c] = inv[:, c] * self.smoothness[n] ** 0.5
                block[rows, c, 3 * (a + pairs[:, 1]) + c] = -inv[:, c] * self.smoothness[n] ** 0.5
            blocks.append(block.reshape(-1, total))
        return torch.cat(blocks) if blocks else torch.zeros(0, total, dtype=torch.float64)

    @staticmethod
    def by_rule(prior: dict, records: list[PathRecords], targets: list, values: dict, weight: float | None = None, smoothness: float | None = 0.0) -> "Prior":
        """The prior toward ``prior`` (name -> value) with Tikhonov ``weight`` and ``smoothness``
        for every parameter; either None: by the default rule (:data:`PRIOR_FRACTION`, resp.
        :data:`SMOOTHNESS_FRACTION`, times the mean diagonal of the data term's J^T J in relative
        units, over the parameter's channels) at ``values``."""
        fixed = {"weight": weight, "smoothness": smoothness}
        rules = {"weight": PRIOR_FRACTION, "smoothness": SMOOTHNESS_FRACTION}
        out = {key: {n: float(v) for n in prior} for key, v in fixed.items() if v is not None}
        if len(out) < 2:
            layout = _Layout.of(records[0])
            weights = _weights(targets)
            J = torch.cat([_value_jacobian(r, values, w) for r, w in zip(records, weights)])
            diag = (J * layout.flatten(values).reshape(1, -1)).pow(2).sum(0)
            mean = {n: float(diag[3 * a : 3 * b].mean()) for n, a, b in layout._rows() if n in prior}
            for key in fixed:
                out.setdefault(key, {n: rules[key] * mean[n] for n in prior})
        return Prior(prior, out["weight"], out["smoothness"])


@dataclass(frozen=True)
class _Problem:
    """One least-squares problem, evaluated by torch for the solver: set A's weighted residual and
    set B's Jacobian in the unconstrained variables (the chain rule through the reparametrization
    is applied here)."""

    layout: _Layout
    records_a: list
    records_b: list
    targets: list
    weights: list
    prior: Prior | None = None
    sensor: Sensor | None = None
    threads: int | None = None  # torch's threads in the solver's callbacks (None: as they are)

    @property
    def device(self) -> torch.device:
        """Where the records are (the residual and Jacobian are computed there, handed to the
        solver on the host)."""
        return self.records_a[0].coefficients.device

    def _split(self, x):
        """Unconstrained scene rows (N_var, 3) and sensor log variables (K,) of the solver's ``x``
        (on the records' device)."""
        flat = torch.from_numpy(np.asarray(x, dtype=np.float64)).reshape(-1).to(self.device)
        n = 3 * self.layout.offsets[-1]
        return flat[:n].reshape(-1, 3), flat[n:]

    def residual(self, x) -> np.ndarray:
        """(R,) set A's weighted residual at unconstrained ``x`` (N_var, 3) (then the sensor's K
        log variables, flat, when there is a sensor), the prior's rows last."""
        rows, s = self._split(x)
        values = self.layout.unflatten(self.layout.from_raw(rows))
        gains = _gains(self.sensor, s, len(self.targets))
        parts = [_residual(r, values, t, w, g) for r, t, w, g in zip(self.records_a, self.targets, self.weights, gains)]
        if self.prior is not None:
            parts.append(self.prior.residual(self.layout, values))
        return torch.cat(parts).cpu().numpy()

    def jacobian(self, x) -> np.ndarray:
        """(R, 3 N_var (+ K)) set B's Jacobian with respect to ``x`` (variable-major, channel-minor;
        the sensor's columns last)."""
        rows_x, s = self._split(x)
        raw = rows_x.clone().requires_grad_(True)
        with torch.enable_grad():
            rows = torch.cat([kind_of(n).from_raw(raw[a:b]) for n, a, b in self.layout._rows()])
            (dv_dx,) = torch.autograd.grad(rows.sum(), raw)  # elementwise reparametrizations
        values = self.layout.unflatten(self.layout.inside(rows.detach()))
        J = _full_jacobian(self.records_b, self.weights, values, self.sensor, s, self.prior, self.layout)
        scale = torch.cat([dv_dx.reshape(-1), torch.ones(J.shape[1] - dv_dx.numel(), dtype=torch.float64, device=J.device)])
        return (J * scale.reshape(1, -1)).cpu().numpy()


def _union_coefficients(records: list[PathRecords], exponents: torch.Tensor) -> list[torch.Tensor]:
    """Each record's coefficients (S_u, N, 3) on the monomials ``exponents`` (S_u, P) (a
    superset of each record's; a monomial a record lacks has coefficient 0 there)."""
    out = []
    for r in records:
        index = {tuple(e): i for i, e in enumerate(exponents.tolist())}
        rows = torch.tensor([index[tuple(e)] for e in r.exponents.tolist()], dtype=torch.int64, device=r.coefficients.device)
        out.append(r.coefficients.new_zeros(exponents.shape[0], *r.coefficients.shape[1:]).index_copy_(0, rows, r.coefficients))
    return out


#: the fewest rows a channel of a view a reduced problem is padded to (reduce_records)
MIN_BUCKET = 256


def _bucket(n: int) -> int:
    """``n`` rounded up to a power of two, at least :data:`MIN_BUCKET`: problem sizes the solver's
    compiled function is reused for (the rounds' monomial counts grow a little with their samples:
    the Cornell box's 2S + 1 goes from about 120 to 160, one bucket)."""
    return max(MIN_BUCKET, 1 << (n - 1).bit_length())


def reduce_records(records_a: list[PathRecords], records_b: list[PathRecords], targets: list, weights: list):
    """The same least-squares problem in a few rows per view instead of one per pixel (records
    without texel terms only): per view and channel, an orthonormal basis Q (N, K) of the span of
    the weighted coefficient images of both sets and the weighted target, ``[w C_A, w C_B, w T]``
    (K = 2 S + 1 columns over the union of their S monomials). Set A's weighted residual
    ``w (g C_A m - T)`` (any gains g) lies in that span, and so does every column of set B's
    Jacobian, so ``Q^T r_A`` has the norm of ``r_A`` and ``(Q^T J_B)^T Q^T r_A = J_B^T r_A``,
    ``(Q^T J_B)^T Q^T J_B = J_B^T J_B``: the solver's steps, costs and stopping tests are those of
    the full problem, each evaluation costs O(K S) instead of O(N S). Returns records whose
    "pixels" are the K rows (coefficients ``Q^T w C``), padded to :func:`_bucket` rows with zeros,
    their targets ``Q^T w T`` as (1, K, 3) and weights of 1."""
    red_a, red_b, red_t, red_w = [], [], [], []
    for a, b, t, w in zip(records_a, records_b, targets, weights):
        exponents = torch.unique(torch.cat([a.exponents, b.exponents]), dim=0)
        ca, cb = _union_coefficients([a, b], exponents)
        S, N = exponents.shape[0], ca.shape[1]
        w = w.to(ca.device, torch.float64)  # (N, 3)
        y = _linear(t).double().reshape(-1, 3).to(ca.device) * w
        K = _bucket(min(N, 2 * S + 1))
        qa, qb, qt = ca.new_zeros(S, K, 3), ca.new_zeros(S, K, 3), ca.new_zeros(K, 3)
        for c in range(3):
            M = torch.cat([(ca[:, :, c] * w[:, c]).T, (cb[:, :, c] * w[:, c]).T, y[:, c : c + 1]], dim=1)  # (N, 2S + 1)
            Q = torch.linalg.qr(M).Q[:, :K]  # (N, min(N, 2S + 1))
            k = Q.shape[1]
            qa[:, :k, c] = (Q.T @ M[:, :S]).T
            qb[:, :k, c] = (Q.T @ M[:, S : 2 * S]).T
            qt[:k, c] = Q.T @ y[:, c]
        for src, dst, coef in ((a, red_a, qa), (b, red_b, qb)):
            dst.append(dataclasses.replace(src, exponents=exponents, coefficients=coef, resolution=(K, 1), texel_exponents=None, texel_terms=()))
        red_t.append(qt.reshape(1, K, 3))
        red_w.append(torch.ones(K, 3, dtype=torch.float64, device=ca.device))
    return red_a, red_b, red_t, red_w


#: problems being solved, by handle: the jitted residual reads them through ``jax.pure_callback``
_PROBLEMS: dict[int, _Problem] = {}
_RESIDUAL = None


def _decorrelated_residual():
    """The weighted residual ``fn(x, args)`` optimistix solves, built once per process (its jit
    cache is reused by every solve of the same size): values of record set A, tangent map
    (Jacobian) of set B, through a ``jax.custom_jvp`` whose primal and Jacobian are computed by
    torch (``jax.pure_callback``). ``args["handle"]`` names the problem in ``_PROBLEMS``;
    ``args["r"]`` is a zero array shaped like the residual."""
    global _RESIDUAL
    if _RESIDUAL is not None:
        return _RESIDUAL
    jax, jnp, _ = _jax()

    def call(method, shape, x, handle):
        def host(x, handle):
            problem = _PROBLEMS[int(handle)]
            if problem.threads is not None:
                torch.set_num_threads(problem.threads)  # per thread (OpenMP): this is one of XLA's
            return getattr(problem, method)(np.array(x, dtype=np.float64))

        return jax.pure_callback(host, jax.ShapeDtypeStruct(shape, jnp.float64), x, handle, vmap_method="sequential")

    @jax.custom_jvp
    def residual(x, args):
        return call("residual", args["r"].shape, x, args["handle"])

    @residual.defjvp
    def _residual_jvp(primals, tangents):
        (x, args), (dx, _) = primals, tangents
        J = call("jacobian", (args["r"].shape[0], x.size), x, args["handle"])  # depends on x only: once per linearization
        return residual(x, args), J @ dx.reshape(-1)

    _RESIDUAL = residual
    return residual


def solve(
    records_a: list[PathRecords],
    records_b: list[PathRecords],
    targets: list[torch.Tensor],
    start: dict[str, torch.Tensor],
    solver: str = "lm",
    max_steps: int = 100,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    prior: Prior | None = None,
    sensor: Sensor | None = None,
    ambiguities: list[str] = (),
) -> LeastSquaresSolution:
    """Fit the recorded parameters to ``targets`` (one per view: linear (H, W, 3) tensors or
    :class:`~invrender.inverse.targets.Target`) by Levenberg-Marquardt (``"lm"``) or Gauss-Newton,
    residual from ``records_a``, Jacobian from ``records_b`` (independent seeds).

    ``start``: name -> starting value shaped as recorded ((3,), or (h, w, 3) for a texture),
    inside each kind's range, and the sensor's values (``sensor.exposure`` (V,), ...) where there
    is one. ``prior``: Tikhonov rows added to the objective (:class:`Prior`). ``sensor``: the
    views' exposure and white balance (:mod:`invrender.inverse.sensor`), its free variables
    solved for with the rest; ``ambiguities``: its named scale ambiguities, reported in the
    solution's identifiability."""
    clock = time.perf_counter()
    jax, jnp, optx = _jax()
    seconds = {"import": time.perf_counter() - clock}
    dense = not any(r.texel_terms for r in list(records_a) + list(records_b))
    threads = torch.get_num_threads()
    if dense:
        # a reduced problem is a few thousand numbers: on several threads each operation would
        # cost more in OpenMP's start and spin (and, on a busy machine, in waiting for cores) than
        # in arithmetic (a 256x80 product 8 ms on 2 threads of a loaded 2-core machine, 0.02 ms on one)
        torch.set_num_threads(1)
    try:
        return _solve(jax, jnp, optx, dense, records_a, records_b, targets, start, solver, max_steps, rtol, atol, prior, sensor, ambiguities, seconds)
    finally:
        torch.set_num_threads(threads)


def _solve(jax, jnp, optx, dense, records_a, records_b, targets, start, solver, max_steps, rtol, atol, prior, sensor, ambiguities, seconds: dict) -> LeastSquaresSolution:
    """:func:`solve`, on the reduced problem where ``dense`` (no texel terms); adds its phases'
    wall times to ``seconds``."""
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[name] = now - clock
        clock = now

    layout = _Layout.of(records_a[0])
    weights = _weights(targets)
    sensor = sensor if sensor is not None and sensor.active else None
    # without texel terms the solver and the refinement see the problem in a few rows a view
    # (reduce_records: the same steps); the analysis below uses every pixel
    problem = _Problem(layout, *reduce_records(records_a, records_b, targets, weights), prior, sensor, 1) if dense else _Problem(layout, records_a, records_b, targets, weights, prior, sensor)
    lap("reduce")
    handle = id(problem)
    _PROBLEMS[handle] = problem
    extra = prior.residual(layout, start).numel() if prior is not None else 0
    s0 = sensor.to_raw(start) if sensor is not None else torch.zeros(0, dtype=torch.float64)
    try:
        args = {"handle": jnp.asarray(handle, dtype=jnp.int64), "r": jnp.zeros(sum(_linear(t).numel() for t in problem.targets) + extra)}
        method = optx.LevenbergMarquardt(rtol=rtol, atol=atol) if solver == "lm" else optx.GaussNewton(rtol=rtol, atol=atol)
        raw0 = layout.to_raw(start)
        x0 = jnp.asarray(raw0.cpu().numpy() if sensor is None else torch.cat([raw0.reshape(-1), s0]).cpu().numpy())
        sol = optx.least_squares(_decorrelated_residual(), method, x0, args=args, options={"jac": "fwd"}, max_steps=max_steps, throw=False)
        x = torch.from_numpy(jax.device_get(sol.value).copy()).double()
    finally:
        del _PROBLEMS[handle]
    rows, s = problem._split(x.numpy())
    if not bool(torch.isfinite(x).all()):
        bad = [repr(n) for n, a, b in layout._rows() if not bool(torch.isfinite(rows[a:b]).all())] + (["the sensor's values"] if not bool(torch.isfinite(s).all()) else [])
        raise NonFiniteError(f"solver {solver!r} diverged: {', '.join(bad)} not finite after {int(sol.stats['num_steps'])} steps; start closer or use 'lm', whose damping bounds its steps")
    flat = layout.from_raw(rows)
    n = flat.numel()
    steps = int(sol.stats["num_steps"])
    lap("solver")
    # The trust region accepts steps by the decrease of |r_A|^2, which B's Jacobian does not model
    # exactly, so it stalls a little short of J_B^T r_A = 0: finish with undamped Gauss-Newton steps
    # on that equation (near the solution the problem is almost linear; a few steps suffice).
    for _ in range(REFINE_STEPS):
        values = layout.unflatten(flat)
        J = _full_jacobian(problem.records_b, problem.weights, values, sensor, s, prior, layout)
        ra = _all_residuals(problem.records_a, problem.targets, problem.weights, values, sensor, s, prior, layout)
        step = torch.linalg.lstsq(J, -ra[:, None]).solution[:, 0]
        flat = layout.inside(flat + step[:n].reshape(-1, 3))
        s = s + step[n:]
        if float(step.abs().max()) < 1e-10:
            break
    values = layout.unflatten(flat)
    lap("refine")
    ident = analyse(records_a, records_b, targets, values, prior=prior, sensor=sensor, sensor_raw=s, ambiguities=ambiguities)
    if sensor is not None:
        values.update({k: v.detach() for k, v in sensor.values(s).items()})
    lap("analyse")
    return LeastSquaresSolution(values, ident, ident.loss, steps, seconds)


def _weights(targets: list) -> list[torch.Tensor]:
    """(N, 3) float64 residual weights per view: the ``relative_l2`` weighting (a
    :class:`~invrender.inverse.targets.Target`'s own, with its mask and response)."""
    return [(t.relative_weight() if isinstance(t, Target) else 1.0 / (t.double() ** 2 + 0.01).sqrt()).reshape(-1, 3) for t in targets]


def _linear(target) -> torch.Tensor:
    """The linear (H, W, 3) target of a tensor or a Target."""
    return target.linear if isinstance(target, Target) else target


def _gains(sensor: Sensor | None, s: torch.Tensor, views: int) -> list:
    """Per view its (3,) float64 gains, or None without a sensor."""
    if sensor is None:
        return [None] * views
    g = sensor.gains(s.double())
    return [g[v] for v in range(views)]


def _all_residuals(records, targets, weights, values, sensor, s, prior, layout) -> torch.Tensor:
    """(R,) every view's weighted residual of ``records``, then the prior's rows."""
    gains = _gains(sensor, s, len(targets))
    parts = [_residual(r, values, t, w, g) for r, t, w, g in zip(records, targets, weights, gains)]
    if prior is not None:
        parts.append(prior.residual(layout, values))
    return torch.cat(parts)


def _full_jacobian(records, weights, values, sensor, s, prior, layout) -> torch.Tensor:
    """(R, 3 N_var + K) value-space Jacobian of ``records``' weighted residuals (the scene's
    columns, then the sensor's log-variable columns), then the prior's rows (zero in the sensor's)."""
    gains = _gains(sensor, s, len(records))
    A = sensor.A if sensor is not None else None
    blocks = []
    for v, (r, w, g) in enumerate(zip(records, weights, gains)):
        J = _value_jacobian(r, values, w if g is None else w * g)
        if sensor is not None:
            J = torch.cat([J, _sensor_jacobian(r, values, w, g, A[v])], dim=1)
        blocks.append(J)
    if prior is not None:
        Jp = prior.jacobian(layout)
        blocks.append(torch.cat([Jp, torch.zeros(Jp.shape[0], blocks[0].shape[1] - Jp.shape[1], dtype=torch.float64)], dim=1))
    return torch.cat(blocks)


def _sensor_jacobian(rec: PathRecords, values: dict, w: torch.Tensor, g: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
    """(N * 3, K) derivatives of one view's weighted residual ``w (g I - T)`` with respect to the
    sensor's log variables (``A``: (3, K), d log g / d s)."""
    gI = (rec.image(values).reshape(-1, 3) * g * w)  # (N, 3)
    return (gI[:, :, None] * A[None]).reshape(-1, A.shape[1])


def _residual(rec: PathRecords, values: dict, target, w: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
    """(N * 3,) one view's weighted residual ``(g I - T) w`` (``g``: the view's gains, or none)."""
    image = rec.image(values).reshape(-1, 3)
    if g is not None:
        image = image * g
    return ((image - _linear(target).double().reshape(-1, 3)) * w).reshape(-1)


def _jacobian_and_residuals(records_a, records_b, targets, weights, values, sensor=None, s=None):
    """Value-space Jacobians (R, 3 N_var (+ K)) of set B's and set A's weighted residuals, and both
    sets' residuals (R,)."""
    gains = _gains(sensor, s, len(targets))
    ra = torch.cat([_residual(r, values, t, w, g) for r, t, w, g in zip(records_a, targets, weights, gains)])
    rb = torch.cat([_residual(r, values, t, w, g) for r, t, w, g in zip(records_b, targets, weights, gains)])
    J = _full_jacobian(records_b, weights, values, sensor, s, None, None)
    J_a = _full_jacobian(records_a, weights, values, sensor, s, None, None)
    return J, J_a, ra, rb


def _value_jacobian(rec: PathRecords, values: dict, w: torch.Tensor) -> torch.Tensor:
    """(N * 3, 3 N_var) derivatives of one view's weighted residual with respect to every variable
    channel (channel c of a pixel depends on channel c of a variable only)."""
    cols = []
    for jac in rec.jacobian(values).values():
        d = jac.reshape(jac.shape[0] * jac.shape[1], -1, 3) * w[:, None, :]  # (N, rows of the parameter, 3)
        block = torch.zeros(d.shape[0], 3, d.shape[1], 3, dtype=d.dtype)
        for c in range(3):
            block[:, c, :, c] = d[:, :, c]
        cols.append(block.reshape(d.shape[0] * 3, -1))
    return torch.cat(cols, dim=1)


@dataclass(frozen=True)
class Identifiability:
    """What the targets determine about the parameters, from the Gauss-Newton matrix ``J^T J``.

    Attributes:
        std_error: name -> standard errors at the evaluated values, shaped as the parameter.
        correlation: (3 N_var, 3 N_var) correlation matrix of the variable channels (a texture
            has one variable per texel).
        channels: the 3 N_var channel labels (``"red.reflectance[G]"``, ``"floor.reflectance[2,3][G]"``).
        weak: combinations the targets cannot determine: each a dict channel label -> weight (a unit
            vector in relative units, largest weights only), for every direction along which the
            column-scaled ``J^T J`` has an eigenvalue below ``threshold`` times its largest.
        loss: mean squared weighted residual of record set A at the evaluated values.
        sensor: the sensor's named scale ambiguities.
        loose: the combinations of two channels or more the standard errors leave loosest, where
            their spread is above :data:`LOOSE` of the values (relative units; sensor channels in log units), loosest
            first, at most :data:`MAX_LOOSE` (the covariance's eigenvectors): each a dict of
            ``std_error`` (along the direction), ``weights`` (channel label -> weight of the unit
            vector, largest weights only) and ``channel_std_error`` (those channels' relative
            standard errors).
        monte_carlo_std_error: name -> the standard errors of the Monte Carlo noise alone (the
            targets' own error left out; None: the same as ``std_error``): the spread of two
            rounds' estimates against the same targets.
    """

    std_error: dict
    correlation: torch.Tensor
    channels: list[str]
    weak: list[dict]
    loss: float
    sensor: list[str] = ()
    loose: list = ()
    monte_carlo_std_error: dict | None = None

    def describe(self) -> str:
        """One line per undetermined combination (empty when everything is determined): the
        sensor's scale ambiguities first (named, with what resolves them), then the numerical ones."""
        return "; ".join(list(self.sensor) + [" + ".join(f"{w:+.2f} {c}" for c, w in combo.items()) for combo in self.weak])

    def describe_loose(self) -> str:
        """The :attr:`loose` directions in one line (empty when there are none)."""
        return "; ".join(
            f"{100 * d['std_error']:.3g}% along " + " ".join(f"{w:+.2f} {c}" for c, w in d["weights"].items())
            + " (standard errors " + ", ".join(f"{c} {100 * e:.3g}%" for c, e in d["channel_std_error"].items()) + ")"
            for d in self.loose
        )  # fmt: skip

    @property
    def undetermined(self) -> bool:
        """Whether anything is undetermined (a sensor ambiguity or a weak combination)."""
        return bool(self.weak) or bool(self.sensor)


def analyse(
    records_a: list[PathRecords], records_b: list[PathRecords], targets: list, values: dict, threshold: float = 1e-6,
    prior: Prior | None = None, sensor: Sensor | None = None, sensor_raw: torch.Tensor | None = None,
    ambiguities: list[str] = (),
) -> Identifiability:  # fmt: skip
    """Standard errors, correlations and undetermined combinations at ``values``.

    The standard errors are the sandwich of the estimating equation ``J_B^T r_A = 0``, whose
    variance has the residual's noise seen through J (``s^2`` per residual, from the two sets) and
    the Jacobian's own noise times the residual (``dJ^T diag(r_A^2) dJ``, ``dJ = (J_A - J_B)/sqrt 2``).
    With a ``prior`` its rows enter the estimating equation (noise-free: a texel the prior alone
    holds has standard error 0, the Monte Carlo error of an estimate that is the prior); the
    undetermined combinations are those of the images alone, the prior left out. ``loss`` is the
    images' residual only.

    With a ``sensor`` (its free log variables at ``sensor_raw``, default its starting values) its
    columns join the analysis (the standard errors of ``sensor.exposure`` and
    ``sensor.white_balance`` come out beside the scene's), and the channels are analysed together
    (an exposure couples them). ``ambiguities``: the sensor's named scale ambiguities
    (:meth:`~invrender.inverse.sensor.Sensor.ambiguities`), reported as they are."""
    layout = _Layout.of(records_a[0])
    weights = _weights(targets)
    sensor = sensor if sensor is not None and sensor.active else None
    s = (sensor_raw if sensor_raw is not None else sensor.to_raw()) if sensor is not None else torch.zeros(0, dtype=torch.float64)
    J, J_a, ra, rb = _jacobian_and_residuals(records_a, records_b, targets, weights, values, sensor, s)
    loss = float((ra**2).mean())
    # relative units: each column scaled by its parameter value, so eps and rho compare (the
    # sensor's columns are per log value already)
    scale = torch.cat([layout.flatten(values).reshape(-1), torch.ones(J.shape[1] - 3 * layout.offsets[-1], dtype=torch.float64)])
    labels = layout.labels() + (sensor.labels() if sensor is not None else [])
    # channels never mix (J^T J is block diagonal): one eigenproblem per channel; an exposure
    # couples them: one for all
    groups = [torch.arange(c, 3 * layout.offsets[-1], 3) for c in range(3)] if sensor is None or sensor.size == 0 else [torch.arange(J.shape[1])]
    weak = weak_combinations(J * scale[None, :], labels, groups, threshold)
    if prior is not None:
        Jp, rp = prior.jacobian(layout), prior.residual(layout, values)
        Jp = torch.cat([Jp, torch.zeros(Jp.shape[0], J.shape[1] - Jp.shape[1], dtype=torch.float64)], dim=1)
        J, J_a, ra, rb = torch.cat([J, Jp]), torch.cat([J_a, Jp]), torch.cat([ra, rp]), torch.cat([rb, rp])
    # the targets' own error (a photograph's quantization, a render's noise) is in the residual's
    # mean square, (r_A^2 + r_B^2) / 2 = the Monte Carlo variance + r_A r_B, on the image rows
    images = torch.zeros_like(ra, dtype=torch.bool)
    images[: len(ra) - (len(rp) if prior is not None else 0)] = True
    se, corr = sandwich(J, J_a, ra, rb, torch.where(images, (ra**2 + rb**2) / 2, (ra - rb) ** 2 / 2))
    se_mc, _ = sandwich(J, J_a, ra, rb)
    n = 3 * layout.offsets[-1]

    def by_name(se: torch.Tensor) -> dict:
        out = layout.unflatten(se[:n].reshape(-1, 3))
        if sensor is not None:
            out.update(sensor.std_error(sensor.values(s), se[n:]))
        return out

    loose = loose_directions(se / scale, corr, labels)
    return Identifiability(by_name(se), corr, labels, weak, loss, tuple(ambiguities), loose, by_name(se_mc))


def weak_combinations(Js: torch.Tensor, labels: list[str], groups: list[torch.Tensor], threshold: float = 1e-6) -> list[dict]:
    """The combinations a column-scaled Jacobian ``Js`` (R, P) cannot determine: for each group of
    columns (indices), every eigenvector of its normalized ``J^T J`` whose eigenvalue is below
    ``threshold`` times the largest, as a dict label -> weight (weights above 0.2 only)."""
    JtJ = Js.T @ Js
    norms = JtJ.diagonal().clamp_min(1e-300).sqrt()
    normalized = JtJ / (norms[:, None] * norms[None, :])
    weak = []
    for cols in groups:
        eigenvalues, vectors = torch.linalg.eigh(normalized[cols][:, cols])
        for lam, v in zip(eigenvalues.tolist(), vectors.T):
            if lam < threshold * float(eigenvalues.max()):
                order = torch.argsort(v.abs(), descending=True)
                weak.append({labels[int(cols[i])]: float(v[i]) for i in order.tolist() if abs(float(v[i])) > 0.2})
    return weak


def sandwich(J: torch.Tensor, J_a: torch.Tensor, ra: torch.Tensor, rb: torch.Tensor, s2: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Standard errors (P,) and correlations (P, P) of the solution of ``J^T r_A = 0`` from two
    independent sets' Jacobians ``J`` (B's, the one solved with) and ``J_a`` (R, P) and residuals
    ``ra``, ``rb`` (R,): the sandwich ``(J^T J)^-1 (J^T diag(s^2) J + dJ^T diag(r_A^2) dJ)
    (J^T J)^-1`` with ``s^2`` (R,) each residual's variance (default ``(r_A - r_B)^2 / 2``, the
    Monte Carlo noise alone) and ``dJ = (J_A - J_B) / sqrt 2`` (see :func:`analyse`)."""
    if s2 is None:
        s2 = (ra - rb) ** 2 / 2
    dJ = (J_a - J) / 2**0.5
    inv = torch.linalg.pinv(J.T @ J)
    cov = inv @ ((J.T * s2) @ J + (dJ.T * ra**2) @ dJ) @ inv
    se = cov.diagonal().clamp_min(0).sqrt()
    return se, cov / (se[:, None] * se[None, :]).clamp_min(1e-300)


def loose_directions(rel_se: torch.Tensor, corr: torch.Tensor, labels: list[str]) -> list:
    """The directions of the relative covariance ``diag(rel_se) corr diag(rel_se)`` (P channels)
    whose standard error is above :data:`LOOSE` and that combine two channels or more, loosest
    first, at most :data:`MAX_LOOSE` (:attr:`Identifiability.loose`: the unit vector's weights
    above 0.2, its sign such that the largest is positive)."""
    cov = torch.nan_to_num(rel_se[:, None] * corr * rel_se[None, :])
    eigenvalues, vectors = torch.linalg.eigh(cov)
    out = []
    for lam, v in zip(reversed(eigenvalues.tolist()), reversed(list(vectors.T))):
        if lam <= LOOSE**2 or len(out) == MAX_LOOSE:
            break
        v = v * torch.sign(v[v.abs().argmax()])
        order = torch.argsort(v.abs(), descending=True)
        big = [int(i) for i in order.tolist() if abs(float(v[i])) > 0.2]
        if len(big) < 2:  # one channel's own imprecision (its standard error says it), not a combination
            continue
        out.append({"std_error": lam**0.5, "weights": {labels[i]: float(v[i]) for i in big}, "channel_std_error": {labels[i]: float(rel_se[i]) for i in big}})
    return out
