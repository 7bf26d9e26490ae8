"""One linear HDR image from an exposure bracket: Debevec & Malik's response recovery and merge
(SIGGRAPH 1997), through OpenCV (``cv2.createCalibrateDebevec``, ``cv2.createMergeDebevec``).

A bracket is P >= 2 aligned 8-bit photographs of one still scene at known exposure times t_j
(seconds, or any common unit). The camera maps ``E * t`` (radiance times exposure) to a code
z = f(E t) in 0..255; the calibration recovers ``g = ln f^-1`` per channel at every code from
samples of the bracket, the merge estimates ``ln E`` per pixel as the hat-weighted mean of
``g(z_j) - ln t_j`` over the exposures.

**Scale.** The bracket fixes ``f^-1`` only up to one factor per channel (OpenCV pins code 128 at 1).
invrender divides each channel's curve by its value at code 255, so the response maps the largest
code to 1.0 (a relative linear radiance times exposure, the clipping level), and the merged image is
in the same units: a pixel of value E photographed at exposure time t reads the code whose response
is E t, and reads 255 from E t = 1 on. The absolute scale therefore rests on the curve at code 255,
which no unclipped sample reads: the calibration uses only pixels that are neither 0 nor 255 in any
image and channel (where the bracket has enough of them), and the curve's smoothness term
extrapolates the last codes. Ratios within a channel are what the bracket determines best.

Arrays here are numpy (H, W, 3) RGB, row 0 at the top; the results are torch tensors. Bad input
raises :class:`~invrender.errors.ImageError` (the images) or
:class:`~invrender.errors.ParameterError` (the exposure times, the settings) with a one-line message
naming the file or value, before any work.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from PIL import ExifTags, Image, UnidentifiedImageError

from invrender.errors import ImageError, ParameterError
from invrender.io.atomic import atomic_file

#: pixels the calibration samples (OpenCV's default is 70; more constrain the curve's ends better)
DEFAULT_SAMPLES = 128
#: weight of the curve's second-difference (smoothness) term, Debevec's lambda (OpenCV's default)
DEFAULT_SMOOTHNESS = 10.0
#: codes of an 8-bit image
LEVELS = 256
#: PIL modes of 8 bits per channel, read as RGB (grey replicated, alpha and palettes resolved)
EIGHT_BIT_MODES = ("L", "LA", "P", "PA", "RGB", "RGBA", "RGBX", "CMYK", "YCbCr")
#: the header of the response CSV
CSV_HEADER = "value,red,green,blue"


def merge_bracket(paths: Sequence[str | os.PathLike], exposures: Sequence[float] | None = None, *, samples: int = DEFAULT_SAMPLES,
                  smoothness: float = DEFAULT_SMOOTHNESS) -> tuple[torch.Tensor, torch.Tensor]:
    """Merge an exposure bracket of 8-bit image files into one linear image.

    Args:
        paths: P >= 2 image files (PNG, JPEG, TIFF, ...: 8 bits per channel), aligned, of one size.
        exposures: P exposure times (finite, > 0, not all equal), in the order of ``paths``; None
            reads each file's EXIF ``ExposureTime``.
        samples: pixels the calibration samples (at most the pixel count).
        smoothness: Debevec's lambda, the weight of the curve's smoothness term (> 0).

    Returns:
        ``(hdr, response)``: the (H, W, 3) float32 linear image, in units where code 255 starts at
        ``hdr * t = 1`` (module docstring, Scale), and the (LEVELS, 3) float32 response, the
        linear value of each code per channel, strictly increasing, 1.0 at code 255. A channel
        clipped (255) even in the shortest exposure t_min holds its lower bound ``1 / t_min`` (or
        OpenCV's estimate where that is larger): such a pixel is at least that bright, and OpenCV's
        weighted mean alone would put it below its unclipped neighbours.

    Raises:
        ImageError: a file is missing, corrupt, not 8-bit, or of another size than the first.
        ParameterError: fewer than 2 images, a count of exposures other than the count of images,
            a time that is not finite and > 0, no EXIF exposure time when none is given, or a
            recovered response that is not increasing.
    """
    images, exif = read_bracket(paths)
    times = exposure_times(paths, exposures, exif)
    return merge_images(images, times, samples=samples, smoothness=smoothness)


def read_bracket(paths: Sequence[str | os.PathLike]) -> tuple[list[np.ndarray], list[float | None]]:
    """Read P >= 2 image files as (H, W, 3) uint8 RGB arrays of one size, with each file's EXIF
    exposure time (None where it has none)."""
    if len(paths) < 2:
        raise ParameterError(f"an exposure bracket needs at least 2 images, got {len(paths)}")
    images, times = [], []
    for p in paths:
        rgb, t = _read_8bit(Path(p))
        if images and rgb.shape != images[0].shape:
            (h, w), (h0, w0) = rgb.shape[:2], images[0].shape[:2]
            raise ImageError(f"{p}: the image is {w}x{h}, but {paths[0]} is {w0}x{h0}; a bracket's images have one size")
        images.append(rgb)
        times.append(t)
    return images, times


def _read_8bit(path: Path) -> tuple[np.ndarray, float | None]:
    """One 8-bit image file -> ((H, W, 3) uint8 RGB, its EXIF exposure time or None)."""
    if not path.exists():
        raise ImageError(f"cannot read image {path}: file not found")
    if not path.is_file():
        raise ImageError(f"cannot read image {path}: not a regular file")
    try:
        with Image.open(path) as img:
            stored = _stored_mode(img)
            if img.mode not in EIGHT_BIT_MODES or "16" in stored:
                raise ImageError(f"cannot read image {path}: {_depth_of(img, stored)}; a bracket's images have 8 bits per channel "
                                 f"(OpenCV's Debevec calibration and merge take 8-bit codes only)")
            img.load()
            return np.asarray(img.convert("RGB"), dtype=np.uint8), _exif_exposure(img)
    except ImageError:
        raise
    except (UnidentifiedImageError, Image.DecompressionBombError, OSError, SyntaxError, ValueError) as e:
        reason = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise ImageError(f"cannot read image {path}: not a valid image file ({reason})") from None


def _stored_mode(img: Image.Image) -> str:
    """The raw mode the file's pixels are stored in, before PIL converts them to ``img.mode`` (a
    16-bit RGB PNG or TIFF opens as mode ``RGB`` with raw mode ``RGB;16B``/``RGB;16N``); read from
    the decoder's tile, so only before ``img.load()``. ``""`` when the decoder does not say."""
    if not img.tile:
        return ""
    args = img.tile[0].args
    raw = args if isinstance(args, str) else args[0] if isinstance(args, tuple) and args and isinstance(args[0], str) else ""
    return raw


def _depth_of(img: Image.Image, stored: str) -> str:
    """What a refused image is, for the message: 16 bits per channel, or another PIL mode."""
    return "not an 8-bit image (16 bits per channel)" if "16" in stored or "16" in img.mode else f"not an 8-bit image (PIL mode {img.mode})"


def _exif_exposure(img: Image.Image) -> float | None:
    """The EXIF ``ExposureTime`` of an opened image (in its Exif IFD, or the main one), or None."""
    exif = img.getexif()
    value = exif.get_ifd(ExifTags.IFD.Exif).get(ExifTags.Base.ExposureTime, exif.get(ExifTags.Base.ExposureTime))
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None


def exposure_times(paths: Sequence, exposures: Sequence[float] | None, exif: Sequence[float | None]) -> np.ndarray:
    """The (P,) float32 exposure times: ``exposures`` if given, else the files' EXIF times; each
    finite and > 0, and not all equal (one exposure determines no response)."""
    if exposures is None:
        missing = next((p for p, t in zip(paths, exif) if t is None), None)
        if missing is not None:
            raise ParameterError(f"{missing}: no EXIF exposure time; give the exposure times (--exposures t1,t2,...)")
        exposures, source = list(exif), "EXIF exposure time"
    else:
        exposures, source = list(exposures), "exposure time"
        if len(exposures) != len(paths):
            raise ParameterError(f"{len(exposures)} exposure times for {len(paths)} images; give one per image, in their order")
    for p, t in zip(paths, exposures):
        if isinstance(t, bool) or not (isinstance(t, numbers.Real) and math.isfinite(t) and t > 0):
            raise ParameterError(f"{p}: {source} {t!r}; expected a finite number > 0")
    times = np.asarray(exposures, dtype=np.float32)
    if not (times > 0).all() or not np.isfinite(times).all():
        raise ParameterError(f"exposure times {exposures} do not fit float32; expected finite numbers > 0")
    if np.unique(times).size < 2:
        raise ParameterError(f"every image has the exposure time {exposures[0]!r}; a bracket needs at least two different times")
    return times


def merge_images(images: Sequence[np.ndarray], times: np.ndarray, *, samples: int = DEFAULT_SAMPLES,
                 smoothness: float = DEFAULT_SMOOTHNESS) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`merge_bracket` on P (H, W, 3) uint8 RGB arrays of one size and their (P,) exposure
    times (checked by :func:`read_bracket` and :func:`exposure_times`)."""
    import cv2  # lazily: only merging needs it

    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise ParameterError(f"samples {samples!r}: expected an integer >= 1")
    if not (math.isfinite(smoothness) and smoothness > 0):
        raise ParameterError(f"smoothness {smoothness!r}: expected a finite number > 0")
    times = np.ascontiguousarray(times, dtype=np.float32)
    response = calibrate(np.stack(images), times, samples, smoothness)
    bgr = [np.ascontiguousarray(image[..., ::-1]) for image in images]
    curve = np.ascontiguousarray(response[:, None, ::-1])  # (256, 1, 3) BGR, as OpenCV keeps it
    hdr = np.ascontiguousarray(cv2.createMergeDebevec().process(bgr, times, curve)[..., ::-1], dtype=np.float32)
    shortest = int(np.argmin(times))
    clipped = images[shortest] == LEVELS - 1  # (H, W, 3): beyond the range of every exposure
    hdr[clipped] = np.maximum(hdr[clipped], np.float32(1.0 / times[shortest]))
    return torch.from_numpy(hdr), torch.from_numpy(response)


def calibrate(stack: np.ndarray, times: np.ndarray, samples: int, smoothness: float) -> np.ndarray:
    """Debevec's response of a (P, H, W, 3) uint8 bracket: (LEVELS, 3) float32, strictly increasing,
    1.0 at the top code.

    The samples are the ``samples`` pixels, from a grid of up to four times as many, with the fewest
    clipped readings (0 or 255, over images and channels; ties in a fixed shuffled order, so they
    spread over the image): a clipped reading says only that the value is beyond the range, and as
    an equation it pulls the curve's ends. They go to OpenCV as a 1 x N strip, whose grid sampling
    (``random=False``) then takes every pixel once.
    """
    import cv2

    p, h, w, _ = stack.shape
    n = min(samples, h * w)
    grid = min(4 * n, h * w)
    cols = max(1, min(w, round(math.sqrt(grid * w / h))))
    rows = max(1, min(h, math.ceil(grid / cols)))
    ys, xs = np.meshgrid(np.unique(np.linspace(0, h - 1, rows).round().astype(int)), np.unique(np.linspace(0, w - 1, cols).round().astype(int)), indexing="ij")
    candidates = stack[:, ys.ravel(), xs.ravel(), :]  # (P, N, 3)
    clipped = ((candidates == 0) | (candidates == LEVELS - 1)).sum(axis=(0, 2))
    shuffled = np.random.default_rng(0).permutation(clipped.size)
    chosen = np.sort(shuffled[np.argsort(clipped[shuffled], kind="stable")[:n]])
    strip = [np.ascontiguousarray(candidates[j, chosen][None, :, ::-1]) for j in range(p)]
    curve = cv2.createCalibrateDebevec(chosen.size, float(smoothness), False).process(strip, times)
    raw = curve[:, 0, ::-1].astype(np.float64)
    with np.errstate(all="ignore"):
        response = np.ascontiguousarray(raw / raw[-1], dtype=np.float32)
    for c, name in enumerate(("red", "green", "blue")):
        steps = np.diff(response[:, c])
        if not (np.isfinite(response[:, c]).all() and (response[:, c] > 0).all() and (steps > 0).all()):
            code = int(np.argmax(~(steps > 0))) + 1
            raise ParameterError(f"the response recovered from the bracket does not increase ({name} channel, code {code}): the images do not determine it "
                                 f"there; add images, spread the exposure times, or raise the smoothness")
    return response


def response_csv(response: torch.Tensor | np.ndarray) -> str:
    """The text of a response CSV: the header ``value,red,green,blue``, then one row per code: the
    encoded value code / (N - 1) in [0, 1] (the shortest decimal that reads back as that float64)
    and the linear response of each channel (9 significant digits: float32 exactly).

    Raises:
        ParameterError: ``response`` is not (N, 3) with N >= 2, finite, > 0, strictly increasing
            per channel and 1.0 at the last code.
    """
    r = np.asarray(torch.as_tensor(response).detach().cpu(), dtype=np.float64)
    if r.ndim != 2 or r.shape[1] != 3 or r.shape[0] < 2:
        raise ParameterError(f"a response is (N, 3) with N >= 2 codes, got shape {r.shape}")
    if not (np.isfinite(r).all() and (r > 0).all() and (np.diff(r, axis=0) > 0).all() and (r[-1] == 1.0).all()):
        raise ParameterError("a response is finite, > 0, strictly increasing per channel and 1.0 at the last code")
    values = np.arange(r.shape[0]) / (r.shape[0] - 1)
    lines = [CSV_HEADER] + [f"{v!r},{a:.9g},{b:.9g},{c:.9g}" for v, (a, b, c) in zip(values.tolist(), r)]
    return "\n".join(lines) + "\n"


def write_response_csv(path: str | os.PathLike, response: torch.Tensor | np.ndarray) -> None:
    """Write a (N, 3) response (:func:`response_csv`) to ``path``, atomically."""
    text = response_csv(response)
    with atomic_file(path) as f:
        f.write(text.encode("utf-8"))


def response_figure(response: torch.Tensor | np.ndarray, title: str = "camera response (Debevec)"):
    """A matplotlib figure of a (N, 3) response: the linear value of each code per channel, on a
    linear and a logarithmic axis."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = np.asarray(torch.as_tensor(response).detach().cpu(), dtype=np.float64)
    values = np.arange(r.shape[0]) / (r.shape[0] - 1)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, scale in zip(axes, ("linear", "log")):
        for c, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            ax.plot(values, r[:, c], color=colour, label=("red", "green", "blue")[c])
        ax.set_yscale(scale)
        ax.set_xlabel("encoded value (code / 255)")
        ax.set_ylabel("linear response (1 at the top code)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend()
    fig.suptitle(title)
    fig.tight_layout()
    return fig


__all__ = ["CSV_HEADER", "DEFAULT_SAMPLES", "DEFAULT_SMOOTHNESS", "merge_bracket", "merge_images", "read_bracket", "response_csv", "response_figure",
           "write_response_csv"]
