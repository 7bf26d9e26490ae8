"""The optional packages of the backends: imported where used, never at ``import invrender``.

``warp-lang`` (the fused kernels and the ``warp`` intersection backend) and ``embreex`` (the
``embree`` backend) speed a render up but are not needed for one: the ``torch`` backend and the
kernels' torch expressions compute the same images. A path that picks a backend by default falls
back to torch when its package is missing and says so once (:func:`note_once`); a path that names
the package's backend gets a one-line :class:`~invrender.errors.MissingPackageError` naming the
package and its install command (:func:`require`).
"""

from __future__ import annotations

import importlib
import sys
import threading
from types import ModuleType

from invrender.errors import MissingPackageError

#: module name -> pip package name
PIP_NAMES = {"warp": "warp-lang", "embreex": "embreex", "pyrender": "pyrender"}

_found: dict[str, ModuleType | None] = {}
_noted: set[str] = set()
_lock = threading.Lock()


def find(module: str) -> ModuleType | None:
    """The imported ``module``, or None when it cannot be imported (not installed, blocked, or a
    broken install whose native library fails to load); tried once per process."""
    with _lock:
        if module not in _found:
            try:
                _found[module] = importlib.import_module(module)
            except (ImportError, OSError):
                _found[module] = None
        return _found[module]


def install_hint(module: str) -> str:
    """``'pip install <package>'`` for a module name of :data:`PIP_NAMES`."""
    return f"pip install {PIP_NAMES.get(module, module)}"


def require(module: str, needed_for: str, otherwise: str = "") -> ModuleType:
    """``module``, imported; a one-line :class:`MissingPackageError` naming it, what needs it, its
    install command and ``otherwise`` (what to do instead) when it cannot be imported."""
    found = find(module)
    if found is None:
        instead = f" (or {otherwise})" if otherwise else ""
        raise MissingPackageError(f"{needed_for} needs the {PIP_NAMES.get(module, module)} package, which is not installed: {install_hint(module)}{instead}")
    return found


def note_once(message: str) -> None:
    """Print ``invrender: note: message`` on stderr, the first time only."""
    with _lock:
        if message in _noted:
            return
        _noted.add(message)
    print(f"invrender: note: {message}", file=sys.stderr)
