"""Non-finite values around a render: parameters checked before it, the image after it.

A NaN or infinite parameter value (set in place in ``scene.params``, or reached by a fit's step)
would turn every path that meets it into NaN radiance, and a NaN anywhere in an image poisons a
fit's loss and gradients. So :func:`invrender.render` refuses a scene with a non-finite parameter
before any work, naming the parameter (:func:`check_params`), and refuses to return an image with
non-finite pixels, naming how many (:func:`check_image`): a one-line error either way, never an
image that silently holds NaN. Rays with non-finite origins or directions are a different matter:
they are misses on every intersection backend (:mod:`invrender.backends.accel`).
"""

from __future__ import annotations

import torch

from invrender.errors import NonFiniteError, ParameterError


def nonfinite_params(params: dict) -> dict[str, int]:
    """name -> count of non-finite entries, for each tensor of ``params`` that has any."""
    out = {}
    for name, value in params.items():
        bad = int((~torch.isfinite(value.detach())).sum()) if torch.is_tensor(value) and value.is_floating_point() else 0
        if bad:
            out[name] = bad
    return out


def describe(params: dict, bad: dict[str, int]) -> str:
    """``'a.reflectance' (1 of 3 values)``, and the others the same way: the non-finite
    parameters ``bad`` (:func:`nonfinite_params`) of ``params``, for a message."""
    return ", ".join(f"{name!r} ({count} of {params[name].numel()} values)" for name, count in bad.items())


def check_params(params: dict, what: str = "parameter") -> None:
    """A one-line :class:`ParameterError` naming each ``params`` entry (name -> tensor) that holds
    a NaN or infinite value; ``what``: how the message calls one entry."""
    bad = nonfinite_params(params)
    if bad:
        many = len(bad) > 1
        raise ParameterError(f"{what}{'s' if many else ''} {describe(params, bad)} {'are' if many else 'is'} not finite (NaN or inf): give finite values before rendering")


def check_image(image: torch.Tensor) -> torch.Tensor:
    """``image`` ((..., H, W, 3) radiance), or a one-line :class:`NonFiniteError` with the count of
    its pixels that hold a NaN or infinite value (the parameters are finite by then:
    :func:`check_params` ran first)."""
    finite = torch.isfinite(image.detach()).all(-1)
    if bool(finite.all()):
        return image
    values = image.detach()
    nan, inf = int(torch.isnan(values).any(-1).sum()), int(torch.isinf(values).any(-1).sum())
    raise NonFiniteError(
        f"the render has {int((~finite).sum())} of {finite.numel()} pixels not finite ({nan} with NaN, {inf} with inf) although every parameter is finite: "
        "radiance beyond float32's range, a degenerate triangle, a material or emitter plugin, or the integrator produced them"
    )
