"""The furnace's gradient statistics in closed form, for ``random_walk`` (docs/closed_forms.md#gradient-statistics-in-the-furnace).

In the furnace (a closed Lambertian enclosure, grey albedo rho, emission eps, every ray landing on an
emitting wall) the ``random_walk`` integrator's path is fixed by one number: how many vertices m it
emits at. Cosine sampling makes every sample weight exactly rho, so the throughput before vertex k is
a known number ``beta_k`` (rho^k divided by the roulette survival probabilities so far), and

    X   = eps sum_{k<m} beta_k            (the path's radiance)
    dX/deps = X / eps,   dX/drho = eps sum_{k<m} (k / rho) beta_k

(the roulette probabilities are detached: vertex k carries rho k times). :func:`furnace_walk`
enumerates m with its probability under the renderer's roulette rule, for any ``max_depth`` and
``rr_depth``, so every moment below is an exact finite sum (the tail beyond 1e-17 of probability
mass, weighted by the moment's growth, is dropped).

A pixel averages N independent paths. With ``Y = Xbar - T`` (T the target) and ``D`` the pixel's
derivative estimate, the per-component gradient of ``l2`` (the mean over the 3P values of the image)
is ``G = (2/(3P)) sum_p Y_p D_p``; ``relative_l2`` weighs it by ``1/(T^2 + 0.01)``. Pixels are
independent and alike, so ``E[G] = (2w/3) E[Y D]`` and ``Var(G) = (4 w^2 / (9P)) Var(Y D)``, with:

- correlated (Y and D from the same paths): ``E[YD] = c11/N + delta mu_D`` and
  ``E[Y^2 D^2] = mu_D^2 c20/N + 2 mu_D c21/N^2 + c22/N^3 + (N-1)/N^3 (c20 c02 + 2 c11^2)
  + 2 delta (2 mu_D c11/N + c12/N^2) + delta^2 (mu_D^2 + c02/N)``;
- decorrelated (Y from independent paths): ``E[YD] = delta mu_D`` and
  ``E[Y^2 D^2] = (c20/N + delta^2)(mu_D^2 + c02/N)``;

``c_ab`` the central moments ``E[(X - mu_X)^a (dX - mu_D)^b]`` of one path, ``delta = mu_X - T``.
The true gradient (of the loss at the expected image) is ``(2w/3) delta mu_D``; the correlated
gradient's bias is ``(2w/3) c11 / N``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.errors import ParameterError

#: losses with a closed form here: dl/dI affine in I with a constant weight in the furnace
CLOSED_FORM_LOSSES = ("l2", "relative_l2")


@dataclass(frozen=True)
class FurnaceWalk:
    """The ``random_walk`` estimator in the furnace, one path at a time.

    Attributes:
        prob: (M,) float64 probability that a path emits at exactly m = 1 .. M vertices.
        x: (M,) its radiance X.
        d_eps: (M,) dX/deps.
        d_rho: (M,) dX/drho.
    """

    prob: torch.Tensor
    x: torch.Tensor
    d_eps: torch.Tensor
    d_rho: torch.Tensor

    def derivative(self, kind: str) -> torch.Tensor:
        """(M,) the path's derivative with respect to a parameter of ``kind`` (``"emission"`` or ``"reflectance"``)."""
        if kind == "emission":
            return self.d_eps
        if kind == "reflectance":
            return self.d_rho
        raise ParameterError(f"the furnace's closed forms cover emission and reflectance, not {kind!r}")

    def mean(self, values: torch.Tensor) -> float:
        return float((self.prob * values).sum())

    def central(self, a: int, b: int, d: torch.Tensor) -> float:
        """``E[(X - mu_X)^a (d - mu_d)^b]`` for one path."""
        return float((self.prob * (self.x - self.mean(self.x)) ** a * (d - self.mean(d)) ** b).sum())


def furnace_walk(rho: float, eps: float, max_depth: int = -1, rr_depth: int = 1) -> FurnaceWalk:
    """Enumerate the furnace's ``random_walk`` paths under the renderer's rules: vertex k emits
    ``eps beta_k``; after it (if ``k + 1 < max_depth`` or unbounded) beta is multiplied by rho and,
    once ``k + 1 >= rr_depth``, the path survives with ``q = min(beta, 0.95)`` and beta is divided by q
    (``invrender.core.context.russian_roulette``); ``rr_depth = -1``: no roulette."""
    if not 0 < rho < 1:
        raise ParameterError(f"the furnace's closed forms need 0 < rho < 1, got {rho}")
    if max_depth == -1 and (rr_depth == -1 or rr_depth > 1000):
        raise ParameterError("an unbounded walk needs Russian roulette (1 <= rr_depth <= 1000)")
    prob, x, d_eps, d_rho = [], [], [], []
    alive, beta, total, total_rho = 1.0, 1.0, 0.0, 0.0
    k = 0
    while True:
        total += eps * beta  # vertex k emits
        total_rho += eps * beta * k / rho
        if max_depth != -1 and k + 1 >= max_depth:
            end = alive  # the last term kept: every remaining path ends here
        else:
            beta *= rho  # cosine-sampled Lambertian weight
            q = min(beta, 0.95) if rr_depth != -1 and k + 1 >= rr_depth else 1.0
            end = alive * (1 - q)
            beta /= q
        prob.append(end)
        x.append(total)
        d_eps.append(total / eps)
        d_rho.append(total_rho)
        alive -= end
        k += 1
        # stop when what is left cannot matter to a fourth moment (X grows like k, dX/drho like k^2)
        if alive <= 0 or (max_depth == -1 and alive * (k + 1) ** 8 < 1e-17) or k > 100_000:
            break
    return FurnaceWalk(*(torch.tensor(v, dtype=torch.float64) for v in (prob, x, d_eps, d_rho)))


@dataclass(frozen=True)
class GradientPrediction:
    """Closed-form statistics of one gradient component.

    Attributes:
        mean: expected gradient.
        variance: variance of one gradient.
        truth: the gradient of the loss at the expected image (what an unbiased estimator averages to).
    """

    mean: float
    variance: float
    truth: float

    @property
    def bias(self) -> float:
        return self.mean - self.truth

    def scaled(self, k: float) -> GradientPrediction:
        """The same for ``k`` times the component (e.g. the sum of 3 identical channels: k = 3)."""
        return GradientPrediction(k * self.mean, k * k * self.variance, k * self.truth)


def predict_gradient(walk: FurnaceWalk, kind: str, spp: int, pixels: int, target: float, loss: str, correlated: bool) -> GradientPrediction:
    """Mean and variance of one component of the loss gradient with respect to a parameter of ``kind``.

    Args:
        walk: from :func:`furnace_walk`.
        spp: N, samples per pixel.
        pixels: P, pixels of the image.
        target: T, the target's (constant) radiance.
        loss: ``"l2"`` or ``"relative_l2"``.
        correlated: the same paths give ``dl/dI`` and the derivative (else independent ones).
    """
    if loss not in CLOSED_FORM_LOSSES:
        raise ParameterError(f"no closed form for the {loss!r} loss (closed forms: {', '.join(CLOSED_FORM_LOSSES)})")
    d = walk.derivative(kind)
    N = spp
    mu_d = walk.mean(d)
    delta = walk.mean(walk.x) - target
    c = {(a, b): walk.central(a, b, d) for a, b in ((2, 0), (1, 1), (0, 2), (2, 1), (1, 2), (2, 2))}
    if correlated:
        e_yd = c[1, 1] / N + delta * mu_d
        e_y2d2 = (
            mu_d**2 * c[2, 0] / N + 2 * mu_d * c[2, 1] / N**2 + c[2, 2] / N**3 + (N - 1) / N**3 * (c[2, 0] * c[0, 2] + 2 * c[1, 1] ** 2)
            + 2 * delta * (2 * mu_d * c[1, 1] / N + c[1, 2] / N**2) + delta**2 * (mu_d**2 + c[0, 2] / N)
        )  # fmt: skip
    else:
        e_yd = delta * mu_d
        e_y2d2 = (c[2, 0] / N + delta**2) * (mu_d**2 + c[0, 2] / N)
    w = 1.0 if loss == "l2" else 1.0 / (target**2 + 0.01)
    return GradientPrediction(
        mean=2 * w / 3 * e_yd,
        variance=4 * w**2 / (9 * pixels) * (e_y2d2 - e_yd**2),
        truth=2 * w / 3 * delta * mu_d,
    )


def furnace_radiance(rho: float, eps: float) -> float:
    """``L = eps / (1 - rho)``: the furnace's exact radiance (all Neumann terms)."""
    return eps / (1 - rho)


def analog_eps_bias(rho: float, eps: float, spp: int) -> float:
    """The textbook form: the correlated ``l2`` (mse) gradient's bias with respect to eps, summed over
    the three channels, for the analog walk (``random_walk``, ``max_depth=-1``, ``rr_depth=1``):
    ``2 eps rho / ((1 - rho)^2 N)``."""
    return 2 * eps * rho / ((1 - rho) ** 2 * spp)

