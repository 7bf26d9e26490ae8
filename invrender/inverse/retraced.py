"""Least squares on re-traced renders: Levenberg-Marquardt for parameters path records cannot represent.

**Which path a least-squares fit takes** (:func:`~invrender.estimators.records.record_obstacle`): on
path records (:mod:`invrender.inverse.least_squares`) when every fitted scene parameter is a
polynomial factor of the path weights (its kind's ``polynomial``, and its material's
``not_polynomial`` gives no reason); otherwise, when any one is not (a ``roughness``; a rough
plastic's ``reflectance`` or ``specular_reflectance``, whose value sums two lobes; the emission of
an environment map or constant sky beside another emitter infinitely far away, whose radiances add
along every ray that leaves the scene), the whole fit runs here, every unknown's
Jacobian column from forward-mode renders. There is no mixing: one rule, one path per fit.

**The residual and its Jacobian.** Round r of a fit traces at ``spp``; at the round's start values
``theta_0`` every render of the round holds its sampling there (``sampling_params``: visible
normals and pdfs of the detached roughness, emitters' choice by power) and traces without Russian
roulette (``rr_depth = -1``; least-squares fits have a finite ``max_depth``), so with fixed seeds
each render is ``f(theta) / pdf(theta_0)`` path by path: an unbiased estimate for every
``theta``, smooth in it, as a path record is at its record point. The residual is the
``relative_l2`` one of the record solver (``least_squares._weights``: a Target's mask and
response too), from renders of seed A; the Jacobian from renders of an independent seed B
(decorrelated: the solver solves ``J_B^T r_A = 0``, see least_squares.py). Its columns are
forward-mode derivatives (``torch.autograd.forward_ad``) of B's render, one render per group of
columns: an RGB parameter's three channels act on their own image channels only (the assumption
the record solver's block structure makes too), so a tangent of ones on all three gives its three
columns in one render; a grey parameter (a roughness: one number in three equal channels) is one
column; a texture takes one render per texel (at most :data:`MAX_RENDERS` per view in all).

**The iteration** is a small damped Gauss-Newton loop in torch on the value-space unknowns
(Marquardt's diagonal damping :data:`DAMPING` for ``"lm"``, none for ``"gauss_newton"``): each
step solves the linearization with B's Jacobian and A's residual, so its fixed point is
``J_B^T r_A = 0``; a step may bring a value at most :data:`MAX_FACTOR` closer to a bound of its
kind's range (no value leaves it), is taken back and damped where it multiplies ``|r_A|^2`` by
more than :data:`GROWTH`, and is lengthened (2x, 4x, 8x) while ``|r_A|^2`` falls (Gauss-Newton
undershoots along a roughness: the highlight's response to alpha is far from linear). There is no
strict descent test: ``|r_A|^2`` of renders sampled at ``theta_0`` grows with their variance away
from ``theta_0``, so its minimum lies between ``theta_0`` and the solution; a descent test would
hold the fit back there. A trial step costs one render per view (the residual), an accepted one
the Jacobian's renders too. optimistix's solvers (used on records) linearize at every trial point
and accept steps by the decrease of that biased cost; here each linearization is several renders.
The round ends when no unknown moves by more than :data:`XTOL` of itself, or after
:data:`MAX_STEPS` steps; the next round resamples at the estimate with 4x the samples.

**Uncertainty**: at the solution the Jacobian of set A too (the same renders at seed A), and the
record solver's sandwich and undetermined combinations (``least_squares.sandwich``,
``weak_combinations``) on ``J_A``, ``J_B``, ``r_A``, ``r_B``.

**Cost** per round and view: the Jacobian's renders (one per RGB or grey parameter, one per texel
of a texture) and one residual render per trial step (1-4 per step), and the Jacobian of set A
once at the end; a forward-mode render costs about 1.1-1.5 plain ones.
"""

from __future__ import annotations

import dataclasses
import math

import torch
import torch.autograd.forward_ad as fwAD

from invrender.estimators import render
from invrender.estimators.records import record_obstacle
from invrender.errors import ParameterError
from invrender.inverse.least_squares import Identifiability, LeastSquaresSolution, _gains, _linear, _weights, sandwich, weak_combinations
from invrender.inverse.sensor import Sensor
from invrender.scene.kinds import kind_of
from invrender.scene.scene import Scene

#: forward-mode renders per view for one Jacobian, at most (a texture needs one per texel)
MAX_RENDERS = 64
#: Levenberg-Marquardt steps per round, at most
MAX_STEPS = 8
#: Marquardt damping of solver "lm" (times the diagonal of J^T J); "gauss_newton": none
DAMPING = 1e-3
#: a step brings a value at most this factor closer to a bound of its kind's range (0, 1 or
#: infinity): the round's sampling is held at its start, so its renders grow noisier the further
#: they move (the next round resamples), and no value leaves its range
MAX_FACTOR = 4.0
#: a step is taken back (and damped) where it multiplies |r_A|^2 by more than this
GROWTH = 4.0
#: a round's iteration ends when no unknown moved by more than this fraction of itself
XTOL = 5e-3


@dataclasses.dataclass(frozen=True)
class Unknowns:
    """The scalar unknowns of the fitted parameters, in value space: per parameter and texel its
    three channels, or one number for a grey kind (a roughness).

    Attributes:
        names: the fitted scene parameters.
        shapes: their shapes ((3,) or (h, w, 3)).
    """

    names: list
    shapes: list

    @staticmethod
    def of(values: dict) -> "Unknowns":
        return Unknowns(list(values), [tuple(v.shape) for v in values.values()])

    def channels(self, i: int) -> int:
        return 1 if kind_of(self.names[i]).grey else 3

    def texels(self, i: int) -> int:
        return math.prod(self.shapes[i][:-1]) if len(self.shapes[i]) == 3 else 1

    @property
    def offsets(self) -> list[int]:
        out = [0]
        for i in range(len(self.names)):
            out.append(out[-1] + self.texels(i) * self.channels(i))
        return out

    def vector(self, values: dict) -> torch.Tensor:
        """(P,) float64 unknowns of ``values`` (name -> value)."""
        return torch.cat([values[n].double().reshape(-1, 3)[:, : self.channels(i)].reshape(-1) for i, n in enumerate(self.names)])

    def values(self, u: torch.Tensor) -> dict:
        """name -> float64 value shaped as the parameter, of the unknowns ``u`` (P,)."""
        o = self.offsets
        return {n: u[o[i] : o[i + 1]].reshape(-1, self.channels(i)).expand(-1, 3).reshape(self.shapes[i]).clone() for i, n in enumerate(self.names)}

    def bounded(self, u: torch.Tensor, du: torch.Tensor) -> torch.Tensor:
        """``u + du`` with each unknown brought at most :data:`MAX_FACTOR` closer to a bound of its
        kind's range (below: 0; above: 1 for the sigmoid kinds, none for the exp kinds)."""
        o = self.offsets
        parts = []
        for i, n in enumerate(self.names):
            a, d = u[o[i] : o[i + 1]], du[o[i] : o[i + 1]]
            hi = 1.0 - (1.0 - a) / MAX_FACTOR if kind_of(n).reparam == "sigmoid" else a * MAX_FACTOR
            parts.append(torch.minimum(torch.maximum(a + d, a / MAX_FACTOR), hi))
        return torch.cat(parts)

    def labels(self) -> list[str]:
        """One label per unknown: ``"metal.roughness"``, ``"red.reflectance[G]"``, ``"floor.reflectance[2,3][G]"``."""
        out = []
        for i, (n, shape) in enumerate(zip(self.names, self.shapes)):
            texels = [""] if len(shape) == 1 else [f"[{a},{b}]" for a in range(shape[0]) for b in range(shape[1])]
            out += [f"{n}{t}" for t in texels] if self.channels(i) == 1 else [f"{n}{t}[{c}]" for t in texels for c in "RGB"]
        return out

    def renders(self) -> list[tuple[int, int]]:
        """(parameter index, texel) of each forward-mode render of a Jacobian."""
        return [(i, t) for i in range(len(self.names)) for t in range(self.texels(i))]


def check(scene: Scene, names: list[str], sensor: Sensor, what: str) -> None:
    """One-line errors (naming ``what``: ``"solver 'lm'"``, ``"identifiability"``) for what a
    re-traced fit cannot do: fit the sensor, or more than
    :data:`MAX_RENDERS` forward-mode renders per Jacobian (textures: one per texel)."""
    why = record_obstacle(scene, names)
    normals = [n for n in names if kind_of(n).adam_only]
    if normals:
        raise ParameterError(f"{what} on re-traced renders cannot follow {normals[0]}, a shading normal (forward-mode renders do not turn the shading frame): fit it with solver 'adam'")
    if sensor.size:
        raise ParameterError(f"{what} on re-traced renders ({why}) cannot fit the sensor's exposure or white balance; fix them (sensor options) or use solver 'adam'")
    count = Unknowns.of({n: scene.params[n] for n in names}).renders()
    if len(count) > MAX_RENDERS:
        raise ParameterError(
            f"{what} on re-traced renders ({why}) takes one forward-mode render per texel: "
            f"{', '.join(names)} need {len(count)} per Jacobian, at most {MAX_RENDERS}; fit fewer texels or use solver 'adam'"
        )


def retrace_integrator(model) -> dict:
    """The integrator spec of a re-traced fit's renders: the fit's, without Russian roulette."""
    settings = dataclasses.asdict(model.settings)
    if "rr_depth" in settings:
        settings["rr_depth"] = -1
    return {"type": model.name, **settings}


@dataclasses.dataclass
class _Renders:
    """The renders of one round: every view at seeds A and B, sampling held at ``frozen``."""

    scenes: list
    unknowns: Unknowns
    frozen: dict
    integrator: dict
    spp: int
    seeds: list  # per view (seed A, seed B)
    sampler: str

    def _params(self, scene: Scene, values: dict) -> dict:
        params = {n: v.detach() for n, v in scene.params.items()}
        params.update({n: values[n].to(params[n].dtype) for n in values})
        return params

    def image(self, v: int, values: dict, half: int, tangent=None):
        """View ``v``'s (N, 3) float64 render of set ``half`` at ``values``; with ``tangent``
        (name, tensor): (render, its forward-mode derivative along the tangent)."""
        scene = self.scenes[v]
        kw = dict(spp=self.spp, seed=self.seeds[v][half], sampler=self.sampler, progress=False, sampling_params=self.frozen)
        params = self._params(scene, values)
        if tangent is None:
            with torch.no_grad():
                return render(dataclasses.replace(scene, params=params), self.integrator, **kw).double().reshape(-1, 3)
        name, t = tangent
        with torch.no_grad(), fwAD.dual_level():
            params[name] = fwAD.make_dual(params[name], t.to(params[name]))
            primal, tan = fwAD.unpack_dual(render(dataclasses.replace(scene, params=params), self.integrator, **kw))
            primal = primal.double().reshape(-1, 3).clone()
            tan = torch.zeros_like(primal) if tan is None else tan.double().reshape(-1, 3).clone()
        return primal, tan

    def jacobian(self, v: int, values: dict, half: int, w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """View ``v``'s value-space Jacobian (N * 3, P) of its weighted residual (``w``: the
        weights times the view's gains, (N, 3)) from set ``half``, and that set's image (N, 3)."""
        U = self.unknowns
        o = U.offsets
        image, columns = None, torch.zeros(w.shape[0], 3, o[-1], dtype=torch.float64)
        for i, t in U.renders():
            name, shape = U.names[i], U.shapes[i]
            tangent = torch.zeros(shape, dtype=torch.float64).reshape(-1, 3)
            tangent[t] = 1.0
            image, d = self.image(v, values, half, (name, tangent.reshape(shape)))
            d = d * w
            base = o[i] + t * U.channels(i)
            if U.channels(i) == 1:
                columns[:, :, base] = d
            else:
                for c in range(3):
                    columns[:, c, base + c] = d[:, c]
        return columns.reshape(-1, o[-1]), image


def _problem(scenes, targets, start, model, spp, seeds, sampler, sensor):
    """The round's renders, and its residual(values, half) (R,) and jacobian(values, half) ((R, P), residual)."""
    U = Unknowns.of(start)
    weights = _weights(targets)
    gains = _gains(sensor if sensor is not None and sensor.active else None, torch.zeros(0, dtype=torch.float64), len(targets))
    wg = [w if g is None else w * g for w, g in zip(weights, gains)]
    renders = _Renders(scenes, U, {n: v.detach().float().clone() for n, v in start.items()}, retrace_integrator(model), spp, seeds, sampler)

    def residual(values: dict, half: int = 0, images=None) -> torch.Tensor:
        parts = []
        for v, target in enumerate(targets):
            image = images[v] if images is not None else renders.image(v, values, half)
            if gains[v] is not None:
                image = image * gains[v]
            parts.append(((image - _linear(target).double().reshape(-1, 3)) * weights[v]).reshape(-1))
        return torch.cat(parts)

    def jacobian(values: dict, half: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(R, P) value-space Jacobian of set ``half`` and its residual (R,)."""
        blocks, images = zip(*(renders.jacobian(v, values, half, wg[v]) for v in range(len(targets))))
        return torch.cat(blocks), residual(values, images=list(images))

    return renders, residual, jacobian


def solve(scenes: list[Scene], targets: list, start: dict, *, model, spp: int, seeds: list, sampler: str = "stratified", sensor: Sensor | None = None,
          solver: str = "lm", max_steps: int = MAX_STEPS, threshold: float = 1e-6) -> LeastSquaresSolution:  # fmt: skip
    """One round: fit the scene parameters ``start`` (name -> value at the round's start, inside
    each kind's range) to ``targets`` (one per view in ``scenes``: tensors or Targets) on
    re-traced renders of the integrator ``model`` at ``spp``, view v's residual from seed
    ``seeds[v][0]`` and its Jacobian from ``seeds[v][1]`` (module docstring). ``sensor``: fixed
    gains only (none fitted)."""
    U = Unknowns.of(start)
    renders, residual, jacobian = _problem(scenes, targets, start, model, spp, seeds, sampler, sensor)
    u = U.vector(start)
    values = U.values(u)
    r = residual(values)
    J, r_b = jacobian(values, 1)
    floor = DAMPING if solver == "lm" else 0.0
    cost, lam, steps = float(r @ r), floor, 0
    for steps in range(1, max_steps + 1):
        H, g = J.T @ J, J.T @ r
        D = torch.diag(H.diagonal().clamp_min(1e-12 * float(H.diagonal().max()) + 1e-300))
        u_new = U.bounded(u, -(torch.linalg.lstsq(H + lam * D, g[:, None]).solution[:, 0]))
        values_new = U.values(u_new)
        r_new = residual(values_new)
        cost_new = float(r_new @ r_new)
        if not math.isfinite(cost_new) or cost_new > GROWTH * cost:
            lam = max(10.0 * lam, 1e-2)  # a step the linearization got badly wrong: damp it
            continue
        du = u_new - u
        for t in (2.0, 4.0, 8.0):  # Gauss-Newton undershoots along a roughness: go further while |r_A|^2 falls
            if cost_new >= cost:
                break
            u_far = U.bounded(u, t * du)
            r_far = residual(U.values(u_far))
            if not float(r_far @ r_far) < cost_new:
                break
            u_new, values_new, r_new, cost_new = u_far, U.values(u_far), r_far, float(r_far @ r_far)
        moved = float(((u_new - u).abs() / u.abs().clamp_min(1e-6)).max())
        u, values, r, cost, lam = u_new, values_new, r_new, cost_new, floor
        J, r_b = jacobian(values, 1)
        if moved < XTOL:
            break
    ident = _identify(U, values, J, r_b, jacobian(values, 0), threshold)  # set A's renders once: r_A is r
    return LeastSquaresSolution(values, ident, ident.loss, steps)


def _identify(U: Unknowns, values: dict, J_b, r_b, set_a, threshold: float) -> Identifiability:
    """The record solver's sandwich and undetermined combinations on both sets' Jacobians and residuals."""
    J_a, r_a = set_a
    labels = U.labels()
    groups = [torch.arange(J_b.shape[1])]
    if all(U.channels(i) == 3 for i in range(len(U.names))):  # channels never mix without a grey unknown
        groups = [torch.arange(c, J_b.shape[1], 3) for c in range(3)]
    weak = weak_combinations(J_b * U.vector(values)[None, :], labels, groups, threshold)
    se, corr = sandwich(J_b, J_a, r_a, r_b)
    return Identifiability(U.values(se), corr, labels, weak, float((r_a**2).mean()))


def analyse(scenes: list[Scene], targets: list, values: dict, *, model, spp: int, seeds: list, sampler: str = "stratified", sensor: Sensor | None = None,
            threshold: float = 1e-6) -> Identifiability:  # fmt: skip
    """Standard errors, correlations and undetermined combinations at ``values`` (name -> value)
    from forward-mode renders of both seeds (``seeds[v]``: view v's (A, B)), without fitting: what
    ``ir.identifiability`` gives for parameters path records cannot represent."""
    U = Unknowns.of(values)
    renders, residual, jacobian = _problem(scenes, targets, values, model, spp, seeds, sampler, sensor)
    values = U.values(U.vector(values))
    J_b, r_b = jacobian(values, 1)
    return _identify(U, values, J_b, r_b, jacobian(values, 0), threshold)

