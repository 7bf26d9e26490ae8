"""Checks of settings values: one-line :class:`~invrender.errors.ParameterError` s naming the
setting, the value and what was expected.

The settings dataclasses (render, integrator, fit settings) call these from ``__post_init__``, so a
value is checked where a spec is parsed, whichever entry point (Python, a recipe, the CLI) gave it,
and before any work starts. This module sits at the bottom of the package's layers: it imports
only :mod:`invrender.errors`.
"""

from __future__ import annotations

import math
import typing

from invrender.errors import ParameterError, did_you_mean

#: most samples one pixel may take: the counter-based sampler's sample index is 32 bits
MAX_SPP = 2**32 - 1
#: most pixels an image may have: the sampler's pixel index is 32 bits (65536 x 65535 at most)
MAX_PIXELS = 2**32 - 1
#: longest side of an image, pixels
MAX_SIDE = 2**16
#: most camera paths one render may trace (about 10^12: days of work on any machine today)
MAX_PATHS = 2**40
#: the largest finite float32: every value a render computes with is a float32, so a number beyond
#: it (a light's scale of 1e39) is an infinity there, whatever it was in the scene file
FLOAT32_MAX = 3.4028234663852886e38
#: largest finite depth (Neumann terms kept); deeper truncations are indistinguishable from -1
MAX_DEPTH = 10_000


def check_int(owner: str, name: str, value, low: int | None = None, high: int | None = None) -> None:
    """A :class:`ParameterError` unless ``value`` is an int (not a bool) in ``[low, high]``.
    ``owner`` prefixes ``name`` in the message (e.g. ``"fit setting "``)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ParameterError(f"{owner}{name} must be an integer, got {value!r}")
    if low is not None and value < low:
        raise ParameterError(f"{owner}{name} must be {'positive' if low == 1 else f'>= {low}'}, got {value}")
    if high is not None and value > high:
        raise ParameterError(f"{owner}{name} must be <= {high}, got {value if value < 10**15 else f'{value:.3g}'}")


def check_depth(owner: str, name: str, value, minus_one: str | None = "unbounded") -> None:
    """A depth: an int in ``[1, MAX_DEPTH]``, or -1 where ``minus_one`` says what -1 means
    (``"unbounded"``; None = -1 is not allowed)."""
    check_int(owner, name, value)
    if value == -1 and minus_one:
        return
    alternative = f", or -1 for {minus_one}" if minus_one else ""
    if value < 1:
        raise ParameterError(f"{owner}{name} must be >= 1{alternative}, got {value}")
    if value > MAX_DEPTH:
        raise ParameterError(f"{owner}{name} must be <= {MAX_DEPTH}{alternative}, got {value}")


def check_float(owner: str, name: str, value, low: float | None = None, high: float | None = None, *, positive: bool = False) -> None:
    """A :class:`ParameterError` unless ``value`` is a finite real number (an int or a float, not
    a bool) in ``[low, high]`` (``> 0`` with ``positive``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{owner}{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ParameterError(f"{owner}{name} must be finite, got {value!r}")
    if positive and not value > 0:
        raise ParameterError(f"{owner}{name} must be positive, got {value!r}")
    if low is not None and value < low:
        raise ParameterError(f"{owner}{name} must be >= {low:g}, got {value!r}")
    if high is not None and value > high:
        raise ParameterError(f"{owner}{name} must be <= {high:g}, got {value!r}")


def check_choice(owner: str, name: str, value, choices) -> None:
    """A :class:`ParameterError` unless ``value`` is one of ``choices`` (strings)."""
    if not isinstance(value, str) or value not in choices:
        hint = did_you_mean(value, choices) if isinstance(value, str) else ""
        raise ParameterError(f"unknown {owner}{name} {value!r}{hint} (known: {', '.join(choices)})")


def check_bool(owner: str, name: str, value) -> None:
    """A :class:`ParameterError` unless ``value`` is True or False."""
    if not isinstance(value, bool):
        raise ParameterError(f"{owner}{name} must be true or false, got {value!r}")


def check_resolution(width, height, where: str = "resolution") -> None:
    """An image size a machine can hold: positive ints, each side at most :data:`MAX_SIDE`,
    at most :data:`MAX_PIXELS` pixels."""
    for name, value in (("width", width), ("height", height)):
        check_int(f"{where} ", name, value, 1, MAX_SIDE)
    if width * height > MAX_PIXELS:
        raise ParameterError(f"{where} {width}x{height} has more than {MAX_PIXELS} pixels")


def check_paths(width: int, height: int, spp: int) -> None:
    """A render of ``width x height`` pixels at ``spp`` samples a machine can finish: at most
    :data:`MAX_PATHS` camera paths."""
    check_resolution(width, height)
    if width * height * spp > MAX_PATHS:
        raise ParameterError(
            f"a {width}x{height} render at {spp} spp traces {width * height * spp:.3g} paths, more than the {MAX_PATHS:.3g} "
            "one render may trace: lower spp or the resolution"
        )


def type_names(annotation) -> list[str]:
    """The type names of a dataclass field's annotation, whether the annotation is a string (a
    module with ``from __future__ import annotations``) or the types themselves: ``"int | None"``,
    ``int | None`` and ``Optional[int]`` all give ``["int", "None"]``."""
    if isinstance(annotation, str):
        return [name.strip() for name in annotation.split("|")]
    if annotation is None or annotation is type(None):
        return ["None"]
    args = typing.get_args(annotation)
    if args:
        return [name for arg in args for name in type_names(arg)]
    return [getattr(annotation, "__name__", str(annotation))]


#: the torch device types invrender renders on
DEVICE_TYPES = ("cpu", "cuda")


def check_device(device) -> None:
    """A :class:`ParameterError` unless ``device`` (a string; torch.device objects pass) names a
    device invrender renders on: ``cpu``, ``cuda`` or ``cuda:N`` (torch's own error for other
    strings is a long list of every device type it knows)."""
    if not isinstance(device, str):
        return
    kind, sep, index = device.partition(":")
    if kind not in DEVICE_TYPES or (sep and (kind != "cuda" or not index.isdigit())):
        raise ParameterError(f"unknown device {device!r}{did_you_mean(kind, DEVICE_TYPES)} (cpu, cuda or cuda:N)")
