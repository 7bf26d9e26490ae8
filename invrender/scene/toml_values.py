"""Checked reading of TOML documents: the scene format's and the recipes' one-line errors.

Every check raises a :class:`~invrender.errors.SceneError` whose message names ``where`` (the file
and table) and the key, and says what was expected; callers that report another error class
(recipes raise ParameterError) convert it.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from invrender.errors import SceneError


def read_toml(path: Path, what: str) -> dict:
    """The document of the TOML file ``path``; a one-line :class:`SceneError` naming it as ``what``
    (e.g. ``"scene file"``) when it is missing, unreadable, not UTF-8 or not valid TOML."""
    try:
        return tomllib.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise SceneError(f"{what} not found: {path}") from None
    except OSError as e:
        raise SceneError(f"cannot read {what} {path}: {one_line(e.strerror or e)}") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"{path}: invalid TOML: not UTF-8 text ({one_line(e)})") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: invalid TOML: {one_line(e)}") from None

def one_line(x) -> str:
    return " ".join(str(x).split())


def show(value) -> str:
    text = repr(value)
    return one_line(text if len(text) <= 60 else text[:57] + "...")


def check_keys(doc: dict, allowed: set, where: str) -> None:
    unknown = sorted(str(k) for k in set(doc) - allowed)
    if unknown:
        raise SceneError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(allowed))})")


def table(doc: dict, key: str, where: str) -> dict:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise SceneError(f"{where}: '{key}' must be a table, got {show(value)}")
    return value


def is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def number(doc: dict, key: str, where: str, required: bool = False) -> float:
    if key not in doc and required:
        raise SceneError(f"{where}: missing required key '{key}' (a number)")
    value = doc.get(key)
    if not is_number(value):
        raise SceneError(f"{where}: '{key}' must be a number, got {show(value)}")
    return float(value)


def string(doc: dict, key: str, where: str, required: bool = False) -> str:
    if key not in doc and required:
        raise SceneError(f"{where}: missing required key '{key}' (a string)")
    value = doc.get(key)
    if not isinstance(value, str):
        raise SceneError(f"{where}: '{key}' must be a string, got {show(value)}")
    return value


def integer(doc: dict, key: str, where: str) -> int:
    value = doc.get(key)
    if not isinstance(value, int) or isinstance(value, bool):
        raise SceneError(f"{where}: '{key}' must be an integer, got {show(value)}")
    return value


def vector(doc: dict, key: str, where: str, length: int = 3, required: bool = False, scalar_ok: bool = False) -> list[float] | float:
    """``doc[key]`` as ``length`` floats; with ``scalar_ok`` one number is also accepted (returned as a float)."""
    expected = f"a number or a list of {length} numbers" if scalar_ok else f"a list of {length} numbers"
    if key not in doc and required:
        raise SceneError(f"{where}: missing required key '{key}' ({expected})")
    value = doc.get(key)
    if scalar_ok and is_number(value):
        return float(value)
    if not isinstance(value, list) or len(value) != length or not all(is_number(x) for x in value):
        raise SceneError(f"{where}: '{key}' must be {expected}, got {show(value)}")
    return [float(x) for x in value]
