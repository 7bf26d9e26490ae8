"""The README's examples run as written: every ```python block (in one child process, in order,
sharing one namespace, in a temporary folder) and every ```bash line (``invrender ...`` as
``python -m invrender ...``, in the same folder) of the sections below.

The README states each example's time on 2 cores; to keep this test at about a minute, a few
numbers are made smaller through :data:`SMALLER`, a table of textual replacements, each of which must
match the README (so the README cannot drift from what is tested without this test failing).
``INVRENDER_README_AS_WRITTEN=1`` runs them unchanged and prints each example's seconds: the check
of the times the README states. The install and quick-start commands are checked by test_docs.py
(they are CI's own, and the quick start's render runs there at 8x8).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
#: the README's sections whose examples run here
SECTIONS = ["Render from Python", "Fit materials and lights to images", "Study a gradient estimator"]
#: smaller numbers for the test: (section, the README's text, the text run instead)
SMALLER = [
    ("Render from Python", "resolution=(64, 64)", "resolution=(16, 16)"),
    ("Fit materials and lights to images", 'resolution=(32, 32), map_size=(16, 32)', 'resolution=(16, 16), map_size=(16, 32)'),
    ("Study a gradient estimator", "spp=[4, 16], trials=50)", "spp=[1, 4], trials=4, reference_spp=8, reference_repeats=2, pixel_maps=False)"),
    ("Study a gradient estimator", 'study.summary("path/replay/correlated", 4,', 'study.summary("path/replay/correlated", 1,'),
    ("Study a gradient estimator", "--spp 4,16 --trials 50 --out", "--spp 1,2 --trials 4 --resolution 4x4 --target-spp 16 --reference-spp 8 --reference-repeats 2 --no-pixel-maps --out"),
    ("Study a gradient estimator", "invrender variance furnace\n", "invrender variance furnace --trials 4 --spp 1,2 --resolution 4x4\n"),
]
#: what the examples must have computed, checked after the block whose text holds the key
CHECKS = {
    'res = ir.fit(scene, target, ["red.reflectance", "light.emission"])': [
        # the fit started away from the truth and came back to it
        'assert (scene.params["red.reflectance"] - truth.params["red.reflectance"]).abs().max() > 0.2',
        'assert res.solver == "lm" and res.converged, (res.solver, res.solver_reason)',
        'assert (res.params["red.reflectance"] - truth.params["red.reflectance"]).abs().max() < 0.05, res.params',
        'assert ((res.params["light.emission"] / truth.params["light.emission"]) - 1).abs().max() < 0.1, res.params',
    ],
    "print(relit.mean((0, 1)) / true.mean((0, 1)) - 1)": [
        'assert (start.params["sky.emission"] == 1).all() and not (sky.params["sky.emission"] == 1).all()',
        "assert float((relit.mean((0, 1)) / true.mean((0, 1)) - 1).abs().max()) < 0.03, relit.mean((0, 1)) / true.mean((0, 1))",
    ],
    "synthetic_photograph(": [
        'assert (start.params["white.reflectance"] == 0.5).all()',
        'assert abs(float(res.params["sensor.exposure"][0]) / 0.8 - 1) < 0.1, res.params',
        'assert (res.params["white.reflectance"] / truth.params["white.reflectance"] - 1).abs().max() < 0.1, res.params',
    ],
}
AS_WRITTEN = os.environ.get("INVRENDER_README_AS_WRITTEN") == "1"


def _section(text: str, title: str) -> str:
    match = re.search(rf"(?ms)^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text)
    assert match, f"README.md has no '## {title}' section"
    return match.group(1)


def _examples(kind: str) -> list[tuple[str, str]]:
    """(section, code) of each ```kind block of the run sections, in order, made smaller unless
    INVRENDER_README_AS_WRITTEN=1; every replacement must match its section."""
    text = README.read_text()
    blocks = []
    for title in SECTIONS:
        body = _section(text, title)
        for old, new in [(old, new) for section, old, new in SMALLER if section == title]:
            assert old in body, f"test_readme.SMALLER: {old!r} is no longer in README.md's '{title}': update the table"
            if not AS_WRITTEN:
                body = body.replace(old, new)
        blocks += [(title, code) for code in re.findall(rf"(?ms)^```{kind}\n(.*?)^```", body)]
    return blocks


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}


def _driver(blocks: list[tuple[str, str]]) -> str:
    """A script that runs the blocks in one namespace, then their CHECKS, and reports each one's seconds."""
    lines = ["import json, time", "ns, seconds = {}, []"]
    for i, (title, code) in enumerate(blocks):
        checks = [c for key, cs in CHECKS.items() if key in code for c in cs]
        lines += [
            "clock = time.perf_counter()",
            f"exec(compile({code!r}, {f'README.md, {title}, python block {i + 1}'!r}, 'exec'), ns)",
            f"exec({chr(10).join(checks)!r}, ns)" if checks else "",
            f"seconds.append(({title!r}, {i + 1}, time.perf_counter() - clock))",
        ]
    lines.append("print('SECONDS ' + json.dumps(seconds))")
    return "\n".join(lines)


def test_every_check_belongs_to_a_block():
    code = "\n".join(c for _, c in _examples("python"))
    for key in CHECKS:
        assert key in code, f"test_readme.CHECKS: no README block holds {key!r}"


@pytest.mark.slow
def test_python_examples_run(tmp_path):
    blocks = _examples("python")
    assert len(blocks) >= 5, f"expected the README's python examples, found {len(blocks)}"
    (tmp_path / "readme_examples.py").write_text(_driver(blocks))
    done = subprocess.run([sys.executable, "readme_examples.py"], cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, done.stderr[-3000:]
    seconds = json.loads(done.stdout.split("SECONDS ")[-1])
    assert len(seconds) == len(blocks)
    print("\n".join(f"{title}, block {i}: {s:.1f} s" for title, i, s in seconds))
    assert (tmp_path / "out.exr").stat().st_size > 0 and (tmp_path / "photo.jpg").stat().st_size > 0


def _cli_lines() -> list[str]:
    lines = []
    for _, code in _examples("bash"):
        lines += [line.strip() for line in code.replace("\\\n", " ").splitlines() if line.strip() and not line.lstrip().startswith("#")]
    return lines


@pytest.mark.slow
def test_cli_examples_run(tmp_path):
    lines = _cli_lines()
    assert any(line.startswith("invrender fit ") and "--init" in line for line in lines), "the README's CLI fit starts at the truth (no --init)"
    for line in lines:
        args = shlex.split(line.split(" #")[0])
        assert args[0] == "invrender", f"README.md's example {line!r} is not an invrender command"
        clock = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "invrender", *args[1:]], cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f"{line}: {done.stderr.strip()[-1500:]}"
        print(f"{time.perf_counter() - clock:.1f} s: {line}")
    fit = json.loads((tmp_path / "runs" / "fit" / "report.json").read_text())  # from --init's start to the built-in's values
    assert fit["initial"]["red.reflectance"] == pytest.approx([0.3] * 3) and fit["initial"]["light.emission"] == pytest.approx([10.0] * 3)
    assert fit["recovered"]["red.reflectance"] == pytest.approx([0.5701, 0.0430, 0.0444], abs=0.03)
    assert fit["recovered"]["light.emission"] == pytest.approx([18.387, 13.987, 6.754], rel=0.05)
    assert (tmp_path / "runs" / "variance" / "furnace" / "check.md").is_file()
