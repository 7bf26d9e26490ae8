"""What every format's checks share: is a value a number, and how an error message shows it."""

from __future__ import annotations


def is_number(x) -> bool:
    """An int or float, not a bool."""
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def one_line(x) -> str:
    """``str(x)`` with its whitespace runs (newlines too) collapsed to single spaces."""
    return " ".join(str(x).split())


def show(value) -> str:
    """``repr(value)`` on one line, cut to 60 characters: how a message quotes an input value."""
    text = repr(value)
    return one_line(text if len(text) <= 60 else text[:57] + "...")
