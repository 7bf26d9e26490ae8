"""gradcheck(): each gradient estimator against central finite differences with common random numbers.

The objective is a fixed random weighting of the pixels, ``sum(W * I)`` with W uniform in [0, 1)
drawn from the seed, so every pixel counts and no pixel's sign cancels another's. Finite
differences re-render with the same seed (common random numbers): with ``max_depth`` below the
Russian-roulette start the estimate is then a smooth polynomial in eps and rho, and a central
difference with step ``h`` is accurate to O(h^2). The perturbed renders also build their emitters'
sampling (the choice by power, an environment map's density) and their BSDFs' sampling (a glossy
material's visible normals and pdf, which read its roughness) from the unperturbed values
(``sampling_params``), so they draw the same paths as the gradients' render: sampling depends on
emissions and roughness, and a perturbed density would move every sample. The estimate is then
``f(theta) / pdf(theta_0)`` path by path, and a central difference differentiates exactly what the
estimators do (a roughness is smooth in it, not a polynomial: still O(h^2)).

A grey parameter (roughness: one number kept as three equal channels) is one component: its three
channels move together and its gradient is their sum.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.errors import ParameterError, did_you_mean
from invrender.scene.scene import check_names
from invrender.scene.scene import Scene
from invrender.estimators import ESTIMATORS, render
from invrender.scene.kinds import kind_of


@dataclass(frozen=True)
class GradcheckRow:
    """One parameter component.

    Attributes:
        name: parameter name.
        index: component index into the flattened parameter (0-2 = R, G, B for a constant; for a
            grey parameter, the texel: its three channels together).
        fd: the central finite difference.
        gradients: estimator -> its gradient.
        rel_errors: estimator -> ``|gradient - fd| / max(|fd|, 1e-3 max_j |fd_j|)``, the max over the
            parameter's components checked (a component the image does not depend on has
            ``fd`` 0 and a gradient of float noise: measured against the parameter's scale).
    """

    name: str
    index: int
    fd: float
    gradients: dict[str, float]
    rel_errors: dict[str, float]


def gradcheck(
    scene: Scene,
    params,
    *,
    estimators=ESTIMATORS,
    spp: int = 32,
    max_depth: int = 4,
    seed: int = 0,
    integrator: str = "path",
    h: float = 1e-2,
    max_components: int = 12,
    progress: bool = False,
) -> list[GradcheckRow]:
    """Compare each estimator's gradient of ``sum(W * I)`` with central finite differences.

    Args:
        params: names (list or comma-separated string).
        estimators: which estimators to check.
        h: finite-difference step, relative to the component's magnitude (absolute below 1),
            shortened where it would leave the parameter kind's range.
        max_components: at most this many components per parameter (textures have many).
    Returns:
        one :class:`GradcheckRow` per component checked.
    """
    names = check_names(scene.params, params)
    unknown = [e for e in estimators if e not in ESTIMATORS]
    if unknown:
        raise ParameterError(f"unknown estimator {unknown[0]!r}{did_you_mean(unknown[0], ESTIMATORS)} (known: {', '.join(ESTIMATORS)})")
    if not h > 0:
        raise ParameterError(f"finite-difference step h must be positive, got {h}")
    weights = torch.rand(scene.height, scene.width, 3, generator=torch.Generator().manual_seed(seed)).to(scene.device)
    kw = dict(integrator=integrator, spp=spp, max_depth=max_depth, seed=seed, progress=progress)

    saved = {n: scene.params[n].requires_grad for n in scene.params}
    grads = {}
    try:
        for estimator in estimators:
            for n in scene.params:
                scene.params[n].requires_grad_(n in names)
                scene.params[n].grad = None
            (render(scene, estimator=estimator, **kw) * weights).sum().backward()
            grads[estimator] = {n: scene.params[n].grad.detach().reshape(-1).clone() for n in names}
    finally:
        for n, flag in saved.items():
            scene.params[n].requires_grad_(flag)
            scene.params[n].grad = None

    rows = []
    kw["sampling_params"] = {n: v.detach().clone() for n, v in scene.params.items()}
    with torch.no_grad():
        for n in names:
            kind = kind_of(n)
            group = 3 if kind.grey else 1  # a grey parameter's channels move together
            flat = scene.params[n].view(-1, group)
            first = len(rows)
            for i in range(min(flat.shape[0], max_components)):
                original = flat[i].clone()
                step = kind.fd_interval(float(original[0])) * h / kind.fd_step  # stays inside the kind's range
                flat[i] = original + step
                plus = float((render(scene, **kw) * weights).sum())
                flat[i] = original - step
                minus = float((render(scene, **kw) * weights).sum())
                flat[i] = original
                fd = (plus - minus) / (2 * step)
                g = {e: float(grads[e][n].view(-1, group)[i].sum()) for e in estimators}
                rows.append(GradcheckRow(n, i, fd, g, {}))
            # relative to the component's finite difference, or to a thousandth of the parameter's
            # largest where that is smaller: a component the image does not depend on (a normal
            # moved along itself, renormalized) has a finite difference of 0 and a gradient of float noise
            floor = max(1e-3 * max(abs(r.fd) for r in rows[first:]), 1e-12) if len(rows) > first else 1e-12
            for r in rows[first:]:
                r.rel_errors.update({e: abs(v - r.fd) / max(abs(r.fd), floor) for e, v in r.gradients.items()})
    return rows


def format_rows(rows: list[GradcheckRow]) -> str:
    """A plain-text table of gradcheck rows."""
    estimators = list(rows[0].gradients) if rows else []
    width = max([len("parameter")] + [len(r.name) for r in rows])
    head = f"{'parameter':<{width}} {'i':>3} {'finite diff':>12} " + " ".join(f"{e:>12} {'rel.err':>8}" for e in estimators)
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = " ".join(f"{r.gradients[e]:>12.6g} {r.rel_errors[e]:>8.2e}" for e in estimators)
        lines.append(f"{r.name:<{width}} {r.index:>3} {r.fd:>12.6g} {cells}")
    return "\n".join(lines)
