"""What the benchmark scripts measure the same way: memory of this process, and children that
report one JSON line. Imports neither invrender nor Mitsuba (``mitsuba_ref`` uses it too).

    rss_mib() -> float                        current resident set size, MiB
    peak_rss_mib() -> float                   peak resident set size (VmHWM), MiB
    print_json(result)                        a child's last word: one tagged JSON line on stdout
    run_json_child(cmd, timeout) -> dict      run a child, parse that line; ChildError when it has none
    add_json_option(parser)                   the scripts' ``--json PATH`` option
    Results(benchmark, title)                 a script's figures as tables; ``.write(path)`` saves them
                                              with the machine, date, commit and command (bench/results.py
                                              turns bench/results/*.json into docs/results.md)
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import resource
import shlex
import subprocess
import sys
from pathlib import Path

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


# --- machine-readable results (--json PATH) ---------------------------------------------------------

REPO = Path(__file__).resolve().parents[1]


def add_json_option(parser) -> None:
    """Add ``--json PATH``: write the script's figures there (bench/results/NAME.json by convention)."""
    parser.add_argument("--json", metavar="PATH", default=None,
                        help="also write the figures as JSON (machine, date, commit, command); bench/results.py reads bench/results/*.json")


def _lscpu() -> dict[str, str]:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return {}
    fields = {}
    for line in out.splitlines():
        key, _, value = line.partition(":")
        fields[key.strip()] = value.strip()
    return fields


def machine() -> dict:
    """The machine a figure was measured on: CPU model and widest vector extension (from lscpu),
    cores, memory, load average, this process's niceness, Python / torch versions."""
    cpu = _lscpu()
    flags = set(cpu.get("Flags", "").split())
    vector = next((f for f in ("avx512f", "avx2", "avx", "sse4_2") if f in flags), "unknown")
    try:
        mem_gib = round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError):
        mem_gib = None
    info = {
        "cpu": cpu.get("Model name", platform.processor() or "unknown"),
        "vector": vector,
        "cores": os.cpu_count(),
        "memory_gib": mem_gib,
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "nice": os.nice(0),
        "python": platform.python_version(),
    }
    torch = sys.modules.get("torch")
    if torch is not None:
        info["torch"] = torch.__version__
        info["cuda"] = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    return info


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


class Results:
    """A benchmark's figures as tables, written as one JSON file by ``write``.

    ``table(title, columns, note=None)`` returns the table's row list: append one list per row,
    values as printed (numbers or strings). The machine, load average and start time are taken
    when the object is made, the load average again when it is written.
    """

    def __init__(self, benchmark: str, title: str):
        self.benchmark, self.title = benchmark, title
        self.started = datetime.datetime.now(datetime.timezone.utc)
        self.machine = machine()
        self.tables: list[dict] = []
        self.notes: list[str] = []
        self.commit = _git("rev-parse", "--short", "HEAD")  # what ran: the commit and whether tracked files differed from it
        self.dirty = bool(_git("status", "--porcelain", "--untracked-files=no"))

    def table(self, title: str, columns: list[str], note: str | None = None) -> list:
        rows: list = []
        self.tables.append({"title": title, "columns": list(columns), "rows": rows, "note": note})
        return rows

    def note(self, text: str) -> None:
        self.notes.append(text)

    def markdown(self, title: str, text: str) -> None:
        """A table a script already prints as Markdown (``| a | b |`` lines); other lines become its note."""
        cells = [[c.strip() for c in line.strip().strip("|").split("|")] for line in text.splitlines() if line.strip().startswith("|")]
        cells = [row for row in cells if not all(set(c) <= set("-: ") for c in row)]  # the |---| rule
        rest = " ".join(line.strip() for line in text.splitlines() if line.strip() and not line.strip().startswith("|"))
        rows = self.table(title, cells[0] if cells else [], note=rest or None)
        rows.extend(cells[1:])

    def write(self, path: str | os.PathLike | None) -> None:
        """Write the JSON file (nothing when ``path`` is None)."""
        if path is None:
            return
        ended = datetime.datetime.now(datetime.timezone.utc)
        script = Path(sys.argv[0])
        try:
            script = script.resolve().relative_to(REPO)
        except ValueError:
            pass
        argv, skip = [], False
        for a in sys.argv[1:]:  # the command without its --json PATH
            if skip or a.startswith("--json="):
                skip = False
                continue
            if a == "--json":
                skip = True
                continue
            argv.append(a)
        niceness = self.machine.get("nice") or 0
        given = [f"{k}={shlex.quote(os.environ[k])}" for k in ("ATEN_CPU_CAPABILITY",) if os.environ.get(k)]  # read by torch at its import: part of the command
        command = " ".join([*given, ("nice " if niceness > 0 else "") + shlex.join(["python", str(script), *argv])])
        record = {
            "benchmark": self.benchmark,
            "title": self.title,
            "command": command,
            "date": self.started.strftime("%Y-%m-%d %H:%M UTC"),
            "seconds": round((ended - self.started).total_seconds(), 1),
            "commit": self.commit,
            "dirty": self.dirty,
            "machine": {**self.machine, "load_average_end": [round(x, 2) for x in os.getloadavg()]},
            "tables": self.tables,
            "notes": self.notes,
        }
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(str(path) + ".tmp")
        tmp.write_text(json.dumps(record, indent=1) + "\n")
        tmp.replace(path)
        print(f"wrote {path}")
