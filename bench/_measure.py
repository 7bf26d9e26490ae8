"""What the benchmark scripts measure the same way: memory of this process, and children that
report one JSON line. Imports neither invrender nor Mitsuba (``mitsuba_ref`` uses it too).

    rss_mib() -> float                        current resident set size, MiB
    peak_rss_mib() -> float                   peak resident set size (VmHWM), MiB
    print_json(result)                        a child's last word: one tagged JSON line on stdout
    run_json_child(cmd, timeout) -> dict      run a child, parse that line; ChildError when it has none
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys

_JSON_TAG = "BENCH_JSON "


def _status_mib(field: str) -> float | None:
    """``VmRSS`` / ``VmHWM`` of this process from /proc/self/status, MiB (None where unavailable)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024  # kB
    except OSError:
        pass
    return None


def rss_mib() -> float:
    """Current resident set size of this process, MiB."""
    value = _status_mib("VmRSS")
    return peak_rss_mib() if value is None else value


def peak_rss_mib() -> float:
    """Peak resident set size of this process, MiB.

    ``VmHWM`` (the high-water mark of this program's own address space) rather than ``ru_maxrss``:
    on Linux ``ru_maxrss`` survives fork + exec, so a child started by a parent that already holds
    torch and a rendered target would report at least the parent's RSS. ``ru_maxrss`` only where
    /proc is missing.
    """
    value = _status_mib("VmHWM")
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 if value is None else value  # KiB on Linux


class ChildError(RuntimeError):
    """A child ended without its JSON line; ``str()`` is one line, ``stdout`` / ``stderr`` its output."""

    def __init__(self, reason: str, stdout: str = "", stderr: str = ""):
        super().__init__(reason)
        self.stdout, self.stderr = stdout, stderr


def print_json(result: dict) -> None:
    """Print ``result`` as the tagged JSON line ``run_json_child`` looks for (after any other output)."""
    sys.stdout.flush()
    print(_JSON_TAG + json.dumps(result), flush=True)


def run_json_child(cmd: list[str], timeout: float) -> dict:
    """Run ``cmd`` (a fresh process, so its memory figures are its own) and return the last JSON
    line it printed with ``print_json``. Raises ChildError on a timeout or when there is no such line."""
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise ChildError(f"timeout after {timeout:g} s") from None
    for line in reversed(proc.stdout.splitlines()):
        if line.startswith(_JSON_TAG):
            return json.loads(line[len(_JSON_TAG) :])
    why = "killed (out of memory?)" if proc.returncode in (-9, 137) else f"exit {proc.returncode}"
    tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or [""]
    raise ChildError(f"{why}: {tail[0][:160]}", proc.stdout, proc.stderr)
