"""Statistics of independent gradient samples: mean, variance and their standard errors, bias, and
the slope of variance against samples per pixel.

Notation: T trials (independent seeds) of a C-component gradient, ``x_t``.

- mean ``m = (1/T) sum x_t``, standard error ``sqrt(s^2 / T)``;
- variance ``s^2 = 1/(T - 1) sum (x_t - m)^2``, and its standard error from the fourth central
  moment ``m4``: ``Var(s^2) ~ (m4 - s^4 (T - 3)/(T - 1)) / T`` (no normality assumed: gradient
  samples are heavy-tailed at low spp). For normal samples it is ``s^2 sqrt(2/(T - 1))``, so ~200
  trials give a 10% relative error;
- bias against a reference ``r`` with standard error ``e_r``: ``m - r``, standard error
  ``sqrt(e_m^2 + e_r^2)``;
- efficiency ``1 / (s^2 t)``, t the mean seconds per gradient: the inverse of the variance reached
  per second of computation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class Moments:
    """Sample statistics of T draws of a K-vector.

    Attributes:
        mean: (K,) float64.
        std_error: (K,) standard error of the mean.
        variance: (K,) unbiased sample variance of one draw.
        variance_se: (K,) standard error of ``variance``.
        count: T.
    """

    mean: torch.Tensor
    std_error: torch.Tensor
    variance: torch.Tensor
    variance_se: torch.Tensor
    count: int


def moments(samples: torch.Tensor) -> Moments:
    """:class:`Moments` of ``samples`` (T, K), T >= 2."""
    x = samples.double()
    T = x.shape[0]
    mean = x.mean(0)
    centred = x - mean
    variance = (centred**2).sum(0) / (T - 1)
    m4 = (centred**4).mean(0)
    variance_se = ((m4 - variance**2 * (T - 3) / (T - 1)).clamp_min(0) / T).sqrt()
    return Moments(mean, (variance / T).sqrt(), variance, variance_se, T)


def log_slope(x: list[float], y: list[float], y_se: list[float] | None = None) -> tuple[float, float]:
    """Slope of ``log y`` against ``log x`` by (weighted) least squares, with its standard error.

    ``y_se``: standard errors of ``y``; the weight of a point is ``(y / y_se)^2`` (the inverse
    variance of ``log y``). Without them (or with one of them 0) the fit is unweighted and the
    error comes from the residuals. Needs two or more points with ``y > 0``; NaN otherwise.
    """
    points = [(math.log(a), math.log(b), (s / b if s is not None else 0.0)) for a, b, s in zip(x, y, y_se or [None] * len(x)) if b > 0]
    if len(points) < 2:
        return math.nan, math.nan
    lx = torch.tensor([p[0] for p in points], dtype=torch.float64)
    ly = torch.tensor([p[1] for p in points], dtype=torch.float64)
    sigma = torch.tensor([p[2] for p in points], dtype=torch.float64)
    weighted = bool((sigma > 0).all())
    w = 1 / sigma**2 if weighted else torch.ones_like(lx)
    xm = (w * lx).sum() / w.sum()
    ym = (w * ly).sum() / w.sum()
    sxx = (w * (lx - xm) ** 2).sum()
    if float(sxx) == 0:
        return math.nan, math.nan
    slope = (w * (lx - xm) * (ly - ym)).sum() / sxx
    if weighted:
        se = (1 / sxx).sqrt()
    elif len(points) > 2:
        residual = ly - ym - slope * (lx - xm)
        se = ((residual**2).sum() / (len(points) - 2) / sxx).sqrt()
    else:
        se = torch.tensor(math.nan)
    return float(slope), float(se)
