"""A recursive control variate for the images a fit takes ``dl/dI`` at (Nicolet, Rousselle, Novak,
Keller, Jakob and Mueller, "Recursive Control Variates for Inverse Rendering", SIGGRAPH 2023).

Consecutive fit steps render nearly the same image. At step i, with seed ``s_i``, render the image
at the new parameters and, with the *same* random numbers, at the previous ones:

    a_i = I(theta_i; s_i),   b_i = I(theta_(i-1); s_i),   F_i = a_i + alpha_i (F_(i-1) - b_i)

``theta_i`` is fixed before step i's numbers are drawn, so ``E[a_i] = I(theta_i)`` and ``E[b_i] =
I(theta_(i-1))``, and by induction ``F_(i-1)``'s error has mean zero: ``F_i`` is unbiased for any
weight ``alpha_i`` chosen before step i's numbers are drawn (its errors are correlated across steps,
as any recursive estimate's). ``a_i - alpha_i b_i`` cancels most of ``a_i``'s noise when the step is
small, and ``F_(i-1)`` brings the average of the earlier steps.

With ``s^2`` a single render's variance, ``d^2`` the variance of ``a_i - b_i`` (noise of the change)
and ``V`` that of ``F_(i-1)``,

    Var(F_i) = alpha^2 V + (1 - alpha)^2 s^2 + alpha d^2,    minimal at  alpha = (s^2 - d^2/2) / (V + s^2)

(``Cov(a, b) = s^2 - d^2/2``). Each quantity is one number per colour channel (the image mean): ``s^2``
from two independent renders at the first step (scaled as 1/spp when spp changes), ``d^2`` the
previous step's (so that ``alpha_i`` does not depend on step i's numbers), ``V`` carried by the
recursion. Early steps move far (large ``d^2``: alpha near 0, plain renders); as the fit settles,
alpha grows and the image's variance drops to a fraction of one render's.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

#: largest weight: keeps the recursion forgetting (an alpha of 1 never lets old noise go)
ALPHA_MAX = 0.98


class RecursiveControlVariate:
    """The recursive estimate of one view's image across fit steps.

    ``render(values, seed, spp)`` must return the (H, W, 3) image at parameter ``values`` with the
    random numbers of ``seed`` (no gradient needed). State (all per colour channel, (3,) float64):
    ``s2`` one render's variance at ``spp``, ``V`` the variance of ``F``, ``d2`` the last step's
    difference variance; ``F`` (H, W, 3) float64 the current estimate, ``values`` its parameters.
    """

    def __init__(self, render: Callable[[dict, int, int], torch.Tensor]):
        self.render = render
        self.F: torch.Tensor | None = None
        self.values: dict | None = None
        self.s2 = self.V = self.d2 = None
        self.spp = 0
        self.alpha = 0.0

    def __call__(self, values: dict, seed: int, spp: int) -> torch.Tensor:
        """The control-variate estimate (H, W, 3) float32 of the image at ``values``."""
        a = self.render(values, seed, spp).double()
        if self.F is None:
            # s^2 from two independent renders (the second seed is one no step uses: seeds are even)
            a2 = self.render(values, seed + 1_000_000_007, spp).double()
            self.s2 = ((a - a2) ** 2).mean((0, 1)) / 2
            self.F, self.V, self.d2, self.spp, self.alpha = (a + a2) / 2, self.s2 / 2, self.s2, spp, 0.0
        else:
            if spp != self.spp:
                self.s2, self.spp = self.s2 * self.spp / spp, spp
            b = self.render(self.values, seed, spp).double()
            # the weight from what was known before this step's numbers (the previous d^2)
            alpha = ((self.s2 - self.d2 / 2) / (self.V + self.s2)).clamp(0.0, ALPHA_MAX)
            self.d2 = ((a - b) ** 2).mean((0, 1))
            self.F = a + alpha * (self.F - b)
            self.V = alpha**2 * self.V + (1 - alpha) ** 2 * self.s2 + alpha * self.d2
            self.alpha = float(alpha.mean())
        self.values = {k: v.detach().clone() for k, v in values.items()}
        return self.F.float()

    @property
    def variance_ratio(self) -> float:
        """Var(F) / Var(one render), channel mean: what the control variate buys now."""
        return float((self.V / self.s2).mean()) if self.s2 is not None else 1.0

    def state(self) -> dict:
        """What a checkpoint keeps to continue exactly."""
        return {"F": self.F, "values": self.values, "s2": self.s2, "V": self.V, "d2": self.d2, "spp": self.spp, "alpha": self.alpha}

    def load(self, state: dict) -> None:
        for key, value in state.items():
            setattr(self, key, value)
