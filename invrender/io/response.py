"""Camera response curves: how a camera turns linear exposure into the values a file stores.

A response maps linear values ``x`` (after exposure and white balance, 1.0 = the top code) to
encoded values ``y`` in [0, 1] (``encode``) and back (``decode``), both differentiable torch
functions applied elementwise to tensors of shape (..., 3) (the last axis is R, G, B; a per-channel
curve uses it):

- ``"linear"``: ``y = x`` (EXR and Radiance HDR files; unbounded above);
- ``"srgb"``: the IEC 61966-2-1 curve (8- and 16-bit PNG and JPEG files);
- ``"gamma:G"``: ``y = x^(1/G)`` for a positive G (``"gamma:2.2"``);
- a path to a CSV file, a tabulated curve (from a calibration such as Debevec's): the header
  ``value,red,green,blue`` and one row per code, ``value`` the encoded value in [0, 1], strictly
  increasing, the other columns the linear response of each channel at that code, increasing, the
  last row's 1.0 (the largest code maps to 1). Between rows both directions interpolate linearly.

:func:`response` turns a spec (a name, a path or a :class:`Response`) into a :class:`Response`;
an unknown name, a bad G, or a curve that is unreadable or not monotonic raises
:class:`~invrender.errors.ImageError` naming the spec or the file.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import torch

from invrender.errors import ImageError, did_you_mean

NAMES = ("linear", "srgb", "gamma:G", "a CSV file")
CSV_HEADER = ["value", "red", "green", "blue"]

# sRGB (IEC 61966-2-1): linear segment below these, power law above
_SRGB_LINEAR_MAX = 0.0031308
_SRGB_ENCODED_MAX = 0.04045


@dataclass(frozen=True)
class Response:
    """One camera response (see the module docstring).

    Attributes:
        name: ``"linear"``, ``"srgb"``, ``"gamma:G"`` or the CSV file's path.
        gamma: G of ``gamma:G`` (else None).
        table: a tabulated curve's (codes (K,), linear (K, 3)) float64 tensors (else None).
    """

    name: str
    gamma: float | None = None
    table: tuple | None = field(default=None, repr=False, compare=False)

    @property
    def is_linear(self) -> bool:
        return self.name == "linear"

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """Linear (..., 3) -> encoded (..., 3); differentiable. Values are clamped to [0, 1] except
        by ``linear``."""
        if self.name == "linear":
            return x
        x = x.clamp(0.0, 1.0)
        if self.name == "srgb":
            return torch.where(x <= _SRGB_LINEAR_MAX, 12.92 * x, 1.055 * x.clamp_min(_SRGB_LINEAR_MAX) ** (1 / 2.4) - 0.055)
        if self.gamma is not None:
            return x.clamp_min(torch.finfo(x.dtype).tiny) ** (1.0 / self.gamma)
        codes, linear = self.table
        return _interp_channels(x, linear.to(x), codes.to(x))

    def decode(self, y: torch.Tensor) -> torch.Tensor:
        """Encoded (..., 3) -> linear (..., 3); differentiable. Values are clamped to [0, 1] except
        by ``linear``."""
        if self.name == "linear":
            return y
        y = y.clamp(0.0, 1.0)
        if self.name == "srgb":
            return torch.where(y <= _SRGB_ENCODED_MAX, y / 12.92, ((y.clamp_min(_SRGB_ENCODED_MAX) + 0.055) / 1.055) ** 2.4)
        if self.gamma is not None:
            return y**self.gamma
        codes, linear = self.table
        return _interp_channels(y, codes.to(y), linear.to(y))

    def slope(self, y: torch.Tensor, step: float) -> torch.Tensor:
        """(..., 3) linear change per unit of encoded value at ``y``, averaged over ``[y - step/2,
        y + step/2]`` (kept inside [0, 1]): how wide one code is in linear units, over the code's
        width. ``linear``: 1."""
        if self.name == "linear":
            return torch.ones_like(y)
        lo = (y - step / 2).clamp(0.0, 1.0 - step)
        hi = lo + step
        return ((self.decode(hi) - self.decode(lo)) / step).clamp_min(1e-12)


def _interp_channels(x: torch.Tensor, xs: torch.Tensor, ys: torch.Tensor) -> torch.Tensor:
    """Piecewise-linear interpolation of (..., 3) ``x`` through the points (xs, ys) of each channel;
    ``xs`` and ``ys`` are (K,) or (K, 3), increasing along K; differentiable in ``x``."""
    K = xs.shape[0]
    xs = xs.reshape(K, -1).expand(K, 3)
    ys = ys.reshape(K, -1).expand(K, 3)
    flat = x.reshape(-1, 3)
    out = []
    for c in range(3):
        xc, xk, yk = flat[:, c], xs[:, c].contiguous(), ys[:, c].contiguous()
        i = torch.searchsorted(xk, xc.detach().contiguous()).clamp(1, K - 1)
        x0, x1, y0, y1 = xk[i - 1], xk[i], yk[i - 1], yk[i]
        t = (xc - x0) / (x1 - x0).clamp_min(1e-300)
        out.append(y0 + t * (y1 - y0))
    return torch.stack(out, dim=-1).reshape(x.shape)


def response(spec) -> Response:
    """The :class:`Response` of ``spec``: ``"linear"``, ``"srgb"``, ``"gamma:G"``, a CSV path (a
    ``str`` ending in ``.csv`` or a path object) or a Response (returned as it is)."""
    if isinstance(spec, Response):
        return spec
    if isinstance(spec, os.PathLike) or (isinstance(spec, str) and spec.lower().endswith(".csv")):
        return read_response_csv(spec)
    if not isinstance(spec, str):
        raise ImageError(f"response must be a name or a CSV path, got {type(spec).__name__}")
    name = spec.strip().lower()
    if name in ("linear", "srgb"):
        return Response(name)
    if name.startswith("gamma:"):
        try:
            g = float(name[len("gamma:") :])
        except ValueError:
            g = math.nan
        if not (math.isfinite(g) and g > 0):
            raise ImageError(f"response {spec!r}: gamma:G needs a positive number G (e.g. gamma:2.2)")
        return Response(f"gamma:{g:g}", gamma=g)
    raise ImageError(f"unknown response {spec!r}{did_you_mean(spec, NAMES)} (known: {', '.join(NAMES)})")


def _first_line(e: Exception) -> str:
    return (str(e).strip().splitlines() or [""])[0]


def read_response_csv(path) -> Response:
    """A tabulated response from the CSV file ``path`` (format: the module docstring), checked:
    the header, at least two rows, finite numbers, codes in [0, 1] strictly increasing, each
    channel increasing and ending at 1.0."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
    except OSError as e:
        raise ImageError(f"cannot read response curve {path}: {e.strerror or e}") from None
    except (UnicodeDecodeError, csv.Error) as e:  # a binary file, a NUL byte
        raise ImageError(f"response curve {path}: not a CSV text file ({e.__class__.__name__}: {_first_line(e)})") from None
    if not rows or [h.strip().lower() for h in rows[0]] != CSV_HEADER:
        raise ImageError(f"response curve {path}: the header must be {','.join(CSV_HEADER)}")
    body = [r for r in rows[1:] if any(c.strip() for c in r)]
    if len(body) < 2:
        raise ImageError(f"response curve {path}: needs at least two rows, got {len(body)}")
    try:
        data = torch.tensor([[float(c) for c in r] for r in body], dtype=torch.float64)
    except ValueError:
        raise ImageError(f"response curve {path}: every row must be four numbers value,red,green,blue") from None
    if data.shape[1] != 4 or not bool(torch.isfinite(data).all()):
        raise ImageError(f"response curve {path}: every row must be four finite numbers value,red,green,blue")
    codes, linear = data[:, 0].contiguous(), data[:, 1:].contiguous()
    if codes.min() < 0 or codes.max() > 1 or not bool((codes.diff() > 0).all()):
        raise ImageError(f"response curve {path}: value must lie in [0, 1] and increase strictly from row to row")
    bad = [CSV_HEADER[1 + c] for c in range(3) if not bool((linear[:, c].diff() > 0).all())]
    if bad:
        raise ImageError(f"response curve {path}: not monotonic: the {bad[0]} column must increase strictly from row to row")
    if float(linear.min()) < 0 or not bool(torch.allclose(linear[-1], torch.ones(3, dtype=torch.float64), atol=1e-6)):
        raise ImageError(f"response curve {path}: the linear columns must be >= 0 and 1.0 at the largest code")
    return Response(str(path), table=(codes, linear))


def write_response_csv(path, codes, linear) -> None:
    """Write a tabulated response (codes (K,), linear (K, 3)) in the format :func:`read_response_csv`
    reads, atomically."""
    from invrender.io.atomic import atomic_file

    codes = torch.as_tensor(codes, dtype=torch.float64).reshape(-1)
    linear = torch.as_tensor(linear, dtype=torch.float64).reshape(-1, 3)
    lines = [",".join(CSV_HEADER)] + [f"{float(v):.9g},{float(r):.9g},{float(g):.9g},{float(b):.9g}" for v, (r, g, b) in zip(codes, linear)]
    with atomic_file(path) as f:
        f.write(("\n".join(lines) + "\n").encode())
