"""Writing what a run leaves for people: text, JSON and matplotlib figures, each atomically
(temp file + rename: never a half-written file; inside a process group, rank 0 only)."""

from __future__ import annotations

import json

from invrender.io.atomic import atomic_file


def write_text(path, text: str) -> None:
    """Atomically write ``text`` (UTF-8) to ``path``."""
    with atomic_file(path) as f:
        f.write(text.encode("utf-8"))


def write_json(path, data: dict) -> None:
    """Atomically write ``data`` as indented JSON."""
    write_text(path, json.dumps(data, indent=2) + "\n")


def save_figure(fig, path) -> None:
    """Write a matplotlib figure to the PNG ``path`` atomically, then close it."""
    import matplotlib.pyplot as plt

    try:
        with atomic_file(path) as f:
            fig.savefig(f, format="png", dpi=110)
    finally:
        plt.close(fig)


__all__ = ["save_figure", "write_json", "write_text"]
