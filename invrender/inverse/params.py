"""Which parameters a fit changes, and how it keeps them physical.

Each parameter's kind (:mod:`invrender.scene.kinds`) says how; both are reparametrizations, so
every value the optimizer can reach is feasible:

- [0, 1] kinds (reflectance rho, specular reflectance k_s) = sigmoid(x): they stay in (0, 1); near 0
  (and near 1) a step in x is a *relative* step in rho (resp. 1 - rho), so a dark channel such as the
  red wall's green (0.04) converges to the same relative accuracy as a bright one; and rho never
  reaches 0 exactly, where path replay's vertex adjoint ``L_rem / w`` is undefined.
- emission eps = exp(x): eps > 0, and Adam's steps are relative, so dim and bright lights converge
  alike.
"""

from __future__ import annotations

import math
import warnings

import torch

from invrender.scene.kinds import kind_of


def to_raw(name: str, value: torch.Tensor) -> torch.Tensor:
    """The unconstrained leaf the optimizer moves, from a parameter value."""
    return kind_of(name).to_raw(value)


def from_raw(name: str, raw: torch.Tensor) -> torch.Tensor:
    """The parameter value (differentiable) from the optimizer's leaf."""
    return kind_of(name).from_raw(raw)


def warn_unused(grads: dict[str, torch.Tensor]) -> None:
    """Warn about parameters with an identically zero gradient: no pixel depends on them."""
    for name, g in grads.items():
        if g is not None and not bool(g.abs().sum() > 0):
            warnings.warn(f"parameter {name} has a zero gradient: no pixel of the target depends on it", stacklevel=3)


def relative_error(value: torch.Tensor, truth: torch.Tensor) -> float:
    """Largest per-channel relative error ``|value - truth| / |truth|``."""
    denom = truth.abs().clamp_min(1e-12)
    err = ((value - truth).abs() / denom).max()
    return float(err) if math.isfinite(float(err)) else float("inf")
