"""Fit targets as the objective sees them: linear values, per-pixel weights, excluded pixels.

A target is a tensor or an image file (:func:`invrender.io.images.read_photo`: PNG 8/16-bit,
JPEG, EXR, HDR). Its encoded values ``y`` are decoded by its camera response
(:mod:`invrender.io.response`; default ``srgb`` for 8- and 16-bit files, ``linear`` for float files
and tensors) to the linear target ``T = decode(y)``, which the model image ``g_v * I_v``
(:mod:`invrender.inverse.sensor`) is compared with.

**Where the comparison happens.** In linear space, each residual weighted by the inverse slope of
the response at the target (``1 / decode'(y)``, averaged over one code): to first order that is the
residual in the file's encoded units, where the noise of an 8-bit photo (quantization, JPEG) is
roughly uniform, so every pixel weighs by how precisely the file states it; and unlike encoding
the render, it keeps the model linear in the render (a Monte Carlo render's noise enters
unbiased, and path records stay polynomials for the least-squares solvers). ``relative_l2`` does
not divide an encoded target's residuals further (:meth:`Target.norm`): uniform noise makes the
plain encoded residual the maximum-likelihood choice (on the JPEG round trip of
tests/inverse/test_sensor.py dividing by ``y^2 + 0.01`` as for linear images doubled the errors
of the dark blue channel), and the curve's compression of highlights already weighs dark pixels
up as the relative weighting does. For a linear target all of this is the plain comparison.

**Pixels that count.** A per-pixel weight in [0, 1]: the user's mask (an image, a tensor, or the
target's own alpha channel), times the automatic exclusion of an integer file's clipped pixels:
*saturated* (any channel at or above :data:`SATURATION` of the top code; the lamp) and *dark*
(any channel at code 0). Excluded pixels weigh 0 in every objective (losses, path-record
residuals and Jacobians, identifiability), so what they hold changes nothing.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import torch

from invrender.errors import ImageError, ParameterError
from invrender.io.images import read_mask, read_photo
from invrender.io.response import Response, response as make_response
from invrender.scene.scene import Scene
from invrender.validate import FLOAT32_MAX

#: the largest target value a fit takes: the square root of float32's largest, so that a residual's
#: square stays finite
LARGEST_TARGET = math.sqrt(FLOAT32_MAX)
#: an integer file's pixel is saturated when a channel is at or above this fraction of the top code
#: (250 of 255: the codes just below the top are where clipping and JPEG ringing meet)
SATURATION = 0.98
#: Target.excluded codes
SATURATED, DARK = 1, 2


@dataclass(frozen=True)
class Target:
    """One view's target.

    Attributes:
        label: the file, or ``"target i"``.
        linear: (H, W, 3) float32 decoded target T.
        encoded: (H, W, 3) float32 values as stored (= ``linear`` for a linear target).
        weight: (H, W, 3) float32 mask times the inverse response slope: turns a linear residual
            into encoded units; 0 where a pixel does not count.
        mask: (H, W) float32 pixel weights in [0, 1] (user mask times the automatic exclusion).
        response: the response that decoded it.
        saturated: pixels excluded as saturated.
        dark: pixels excluded at code 0.
        plain: a linear target with every pixel counting (the losses' plain formulas apply).
        excluded: (H, W) int8 why a pixel was excluded automatically: 0 not (it counts by
            ``mask``), :data:`SATURATED`, :data:`DARK`; None where nothing was.
    """

    label: str
    linear: torch.Tensor
    encoded: torch.Tensor
    weight: torch.Tensor
    mask: torch.Tensor
    response: Response
    saturated: int = 0
    dark: int = 0
    plain: bool = True
    excluded: torch.Tensor | None = None

    def to(self, device) -> "Target":
        move = {k: getattr(self, k).to(device) for k in ("linear", "encoded", "weight", "mask")}
        return Target(self.label, response=self.response, saturated=self.saturated, dark=self.dark, plain=self.plain, excluded=self.excluded, **move)

    def pixels_image(self) -> torch.Tensor:
        """(H, W, 3) linear RGB in [0, 1] showing which pixels count: the target (clipped to 1)
        times each pixel's mask weight, pixels excluded as saturated in red, at 0 in blue, pixels the
        user's mask leaves out dark grey."""
        m = self.mask.cpu()[..., None]
        image = self.linear.cpu().clamp(0.0, 1.0) * m + (1.0 - m) * 0.02
        if self.excluded is not None:
            for code, colour in ((SATURATED, (1.0, 0.0, 0.0)), (DARK, (0.0, 0.2, 1.0))):
                image[self.excluded.cpu() == code] = torch.tensor(colour)
        return image

    def relative_weight(self) -> torch.Tensor:
        """(H, W, 3) float64 the least-squares residual weight: ``relative_l2`` in the target's
        units, ``weight / norm``."""
        if self.plain:
            return 1.0 / (self.linear.double() ** 2 + 0.01).sqrt()
        return self.weight.double() / self.norm().double()

    def norm(self) -> torch.Tensor:
        """(H, W, 3) what ``relative_l2`` divides a residual by: ``sqrt(T^2 + 0.01)`` for a linear
        target; 1 for an encoded one, whose response already weighs the residuals in encoded units
        (where its noise is uniform, and where the curve's compression of highlights does what the
        relative weighting does for linear images)."""
        if self.response.is_linear:
            return (self.linear**2 + 0.01).sqrt()
        return torch.ones_like(self.linear)

    def report(self) -> dict:
        """What the fit used of this target, as plain data."""
        H, W = self.mask.shape
        return {
            "target": self.label, "response": self.response.name, "pixels": H * W,
            "excluded_saturated": self.saturated, "excluded_dark": self.dark,
            "counting": float(self.mask.sum()),
        }  # fmt: skip


def _per_view(value, n: int, what: str) -> list:
    if isinstance(value, (list, tuple)):
        if len(value) != n:
            raise ParameterError(f"{len(value)} {what}s for {n} target(s): give one per target (None where there is none)")
        return list(value)
    return [value] * n


def make_target(t, label: str, size: tuple[int, int], mask=None, response=None, exclude: bool = True) -> Target:
    """The :class:`Target` of ``t`` (an (H, W, 3) tensor or an image path) for a view rendering
    ``size`` = (width, height), with ``mask`` (None: the file's alpha, if any; a path; an (H, W)
    tensor in [0, 1]), ``response`` (None: the file's default) and the automatic exclusion of
    clipped pixels (``exclude``). Every check raises a one-line error naming the file."""
    photo = read_photo(t) if isinstance(t, (str, os.PathLike)) else None
    values = photo.values if photo is not None else torch.as_tensor(t, dtype=torch.float32).detach()
    if values.ndim != 3 or values.shape[2] != 3:
        raise ImageError(f"{label} must be an (H, W, 3) RGB image, got shape {tuple(values.shape)}")
    if not torch.isfinite(values).all():
        raise ImageError(f"{label} contains NaN or Inf values")
    if values.numel() and float(values.abs().max()) > LARGEST_TARGET:
        raise ImageError(f"{label} has a value of {float(values.abs().max()):.4g}, beyond {LARGEST_TARGET:.4g}: its residual's square would overflow float32 "
                         f"(a corrupt file, or radiance in other units)")
    if bool((values < 0).any()):
        raise ImageError(f"{label} has negative radiance (minimum {float(values.min()):.4g}); a target is linear radiance >= 0")
    W, H = size
    if tuple(values.shape[:2]) != (H, W):
        raise ImageError(f"{label} is {values.shape[1]}x{values.shape[0]} but the scene renders {W}x{H} (set the scene's resolution to the target's)")
    spec = response if response is not None else (photo.default_response if photo is not None else "linear")
    try:
        resp = make_response(spec)
    except ImageError as e:
        raise ImageError(f"{label}: {e}") from None
    bits = photo.bits if photo is not None else None
    if not resp.is_linear and bits is None and float(values.max()) > 1.0:
        raise ImageError(f"{label} has values above 1 (maximum {float(values.max()):.4g}) but response {resp.name!r} encodes values in [0, 1]")
    linear = resp.decode(values.double()).float()
    # the user's mask
    weights = torch.ones(H, W)
    mask_label = label
    if mask is None and photo is not None and photo.alpha is not None:
        weights = photo.alpha.float()
        mask_label = f"{label}'s alpha channel"
    elif mask is not None:
        mask_label = str(mask) if isinstance(mask, (str, os.PathLike)) else f"the mask of {label}"
        weights = read_mask(mask) if isinstance(mask, (str, os.PathLike)) else torch.as_tensor(mask, dtype=torch.float32).detach()
        if weights.ndim == 3 and weights.shape[2] == 1:
            weights = weights[..., 0]
        if weights.ndim != 2 or tuple(weights.shape) != (H, W):
            shape = f"{weights.shape[1]}x{weights.shape[0]}" if weights.ndim == 2 else f"shape {tuple(weights.shape)}"
            raise ImageError(f"mask {mask_label} is {shape} but the target {label} is {W}x{H}")
        if not bool(torch.isfinite(weights).all()) or float(weights.min()) < 0 or float(weights.max()) > 1:
            raise ImageError(f"mask {mask_label}: weights must lie in [0, 1]")
    if not bool((weights > 0).any()):
        raise ImageError(f"mask {mask_label} excludes every pixel of {label}")
    # the automatic exclusion of clipped pixels (integer files)
    saturated = dark = 0
    excluded = None
    if exclude and bits is not None:
        top = 2**bits - 1
        sat = (values >= SATURATION).any(-1)
        low = (values * top < 0.5).any(-1) & ~sat
        saturated, dark = int(sat.sum()), int(low.sum())
        weights = weights * (~(sat | low)).float()
        excluded = (sat.to(torch.int8) * SATURATED + low.to(torch.int8) * DARK) if saturated + dark else None
        if not bool((weights > 0).any()):
            raise ImageError(f"every counting pixel of {label} is saturated or 0 ({saturated} saturated, {dark} at 0): nothing left to fit")
    step = 1.0 / (2**bits - 1) if bits is not None else 1e-3
    slope = resp.slope(values.double(), step).float()
    plain = resp.is_linear and bool((weights == 1).all())
    weight = weights[..., None] / slope
    return Target(label, linear, values.float(), weight, weights, resp, saturated, dark, plain, excluded)


def make_targets(targets: list, labels: list[str], sizes: list[tuple[int, int]], mask=None, response=None, exclude: bool = True) -> list[Target]:
    """One :class:`Target` per view: ``mask`` and ``response`` are one for every view or a list
    with one per view (None entries: the defaults)."""
    n = len(targets)
    masks, responses = _per_view(mask, n, "mask"), _per_view(response, n, "response")
    return [make_target(t, lab, size, m, r, exclude) for t, lab, size, m, r in zip(targets, labels, sizes, masks, responses)]


def load_views(scene: Scene, target, cameras) -> list[tuple[Scene, torch.Tensor]]:
    """(scene seen by each camera, its linear target image (H, W, 3)) per view, every target checked
    as ``fit`` checks them (file readable, finite, non-negative, the scene's size; one camera each;
    files decoded by their default response)."""
    return [(view_scene, t.linear) for view_scene, t in load_targets(scene, target, cameras)]


def load_targets(scene: Scene, target, cameras, *, mask=None, response=None, exclude_clipped: bool = True) -> list[tuple[Scene, Target]]:
    """(scene seen by each camera, its :class:`~invrender.inverse.targets.Target`) per view, with
    ``mask``, ``response`` and ``exclude_clipped`` as :func:`fit` takes them."""
    targets = list(target) if isinstance(target, (list, tuple)) else [target]
    if not targets:
        raise ParameterError("no target was given: an (H, W, 3) image, a file, or a list of them (one per camera)")
    if cameras is not None and len(cameras) != len(targets):
        raise ParameterError(f"{len(targets)} target(s) but {len(cameras)} camera(s): give one camera per target")
    if cameras is None and len(targets) > 1:
        raise ParameterError("several targets need one camera each (cameras=[...])")
    view_scenes = [scene.with_camera(cameras[i]) if cameras is not None else scene for i in range(len(targets))]
    labels = [str(t) if isinstance(t, (str, os.PathLike)) else f"target {i}" for i, t in enumerate(targets)]
    made = make_targets(targets, labels, [(v.width, v.height) for v in view_scenes], mask=mask, response=response, exclude=exclude_clipped)
    return [(v, t.to(scene.device)) for v, t in zip(view_scenes, made)]
