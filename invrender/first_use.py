"""The work a process does once before its first render: compiling (or loading from the disk cache)
the Warp BVH's kernels (:func:`invrender.backends.warp_bvh.load`) and the Embree packet wrapper
(:mod:`invrender.backends.embree_native`). Announced and timed here.

On a fresh machine the compilers take seconds (about 12 s on 2 cores for the BVH's CPU kernels, a
few for the wrapper); from the caches (``~/.cache/warp``, ``~/.cache/invrender``) well under one. So that a
first render does not sit silent meanwhile, a compile prints one line on stderr, once per process
and thing compiled, while a render that shows progress is being set up (:func:`announcing`); and
the seconds spent are counted (:func:`seconds`), so that a render's reported speed can leave them
out (``invrender render``'s summary reports them separately).
"""

from __future__ import annotations

import contextlib
import contextvars
import sys
import threading
import time

_announce = contextvars.ContextVar("invrender_first_use_announce", default=False)
_lock = threading.Lock()
_spent = [0.0]
_announced: set[str] = set()


@contextlib.contextmanager
def announcing(on: bool):
    """Within the block (in this thread), compiles are announced on stderr when ``on`` (a render's
    ``progress``)."""
    token = _announce.set(bool(on))
    try:
        yield
    finally:
        _announce.reset(token)


@contextlib.contextmanager
def compiling(what: str, cached: bool):
    """Time the block as first-use work on ``what``; when it compiles (not ``cached``) inside
    :func:`announcing`, first say so on stderr (once per process and ``what``)."""
    if not cached and _announce.get():
        with _lock:
            fresh = what not in _announced
            _announced.add(what)
        if fresh:
            print(f"invrender: compiling {what} (first use on this machine; cached for later runs) ...", file=sys.stderr, flush=True)
    start = time.perf_counter()
    try:
        yield
    finally:
        with _lock:
            _spent[0] += time.perf_counter() - start


def seconds() -> float:
    """Seconds this process has spent so far compiling or loading kernels and wrappers."""
    with _lock:
        return _spent[0]
