"""Range checks of the filters' settings: one-line errors naming the filter, setting and value."""

import math

from invrender.errors import ParameterError

#: the widest filter radius accepted, pixels (a sample then reaches (2 * 16 + 1)^2 pixels)
MAX_RADIUS = 16.0


def check_positive(filter_name: str, name: str, value, largest: float) -> float:
    """``value`` as a float in (0, largest]; a ParameterError otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not 0.0 < value <= largest:
        raise ParameterError(f"filter {filter_name!r}: {name} must be a number in (0, {largest:g}], got {value!r}")
    return float(value)


def check_finite(filter_name: str, name: str, value) -> float:
    """``value`` as a finite float; a ParameterError otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ParameterError(f"filter {filter_name!r}: {name} must be a finite number, got {value!r}")
    return float(value)
