"""What native libraries print while they read a file, caught so that it becomes part of one error line.

OpenEXR's C core and libpng (inside OpenCV) report a corrupt file by writing to the process's
standard error (file descriptor 2) themselves, before the Python call returns or raises; OpenCV's
own logger does the same. Python's ``contextlib.redirect_stderr`` cannot catch those writes (they
bypass ``sys.stderr``), so :func:`native_output` points descriptor 2 (and, as for OpenEXR's Python
binding, ``sys.stdout``) at a temporary file for the duration of one read and hands back the lines
written there: the reader puts the last of them into its one-line :class:`~invrender.errors.ImageError`
on failure and drops them on success.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
import threading

#: one capture at a time: descriptor 2 is the process's, not a thread's
_LOCK = threading.Lock()


@contextlib.contextmanager
def native_output():
    """Capture descriptor 2 and ``sys.stdout`` during the block; yields a list that holds, once the
    block has ended (normally or by an exception), the non-empty lines written there, oldest first.

    Where descriptor 2 cannot be duplicated (a process started without one), only ``sys.stdout``
    is captured."""
    lines: list[str] = []
    printed = io.StringIO()
    with _LOCK:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        try:
            saved = os.dup(2)
        except OSError:
            saved = None
        with tempfile.TemporaryFile() as sink:
            if saved is not None:
                os.dup2(sink.fileno(), 2)
            try:
                with contextlib.redirect_stdout(printed):
                    yield lines
            finally:
                if saved is not None:
                    os.dup2(saved, 2)
                    os.close(saved)
                sink.seek(0)
                text = sink.read().decode("utf-8", errors="replace") + "\n" + printed.getvalue()
                lines.extend(line.strip() for line in text.splitlines() if line.strip())


def last_line(lines: list[str], default: str) -> str:
    """The last line a native library printed (its final word on the failure), or ``default``."""
    return lines[-1] if lines else default


__all__ = ["last_line", "native_output"]
