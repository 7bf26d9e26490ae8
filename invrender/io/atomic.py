"""Atomic file writes: a failure never leaves a half-written output behind (docs/architecture.md#errors-are-part-of-the-interface)."""

from __future__ import annotations

import contextlib
import io
import os
import secrets
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from invrender.io.ranks import is_main


@contextlib.contextmanager
def atomic_file(path) -> Iterator[BinaryIO]:
    """Open a temporary file beside ``path`` for binary writing; when the block succeeds it replaces
    ``path``, when it raises the temporary file is removed and ``path`` is left as it was.

    Missing parent directories are created. The file is made with ``open(..., "xb")`` rather than
    ``tempfile.mkstemp``, whose mode 0600 the output would keep: it honours the umask like any file.

    Inside a torch.distributed group only rank 0 writes (every rank holds the same results): the
    other ranks' writes go to a buffer that is dropped.
    """
    if not is_main():
        yield io.BytesIO()
        return
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
    try:
        with open(tmp, "xb") as f:
            yield f
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
