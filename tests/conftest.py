"""Shared fixtures: small scenes, CPU only, fixed seeds."""

import pytest
import torch

import invrender as ir

torch.set_num_threads(1)  # pytest -n 2 runs two workers on the two cores


def pytest_collection_modifyitems(config, items):
    """Tests marked ``cuda`` are skipped where torch sees no CUDA device, those marked ``warp``
    where warp-lang cannot be imported (a GPU machine without Warp)."""
    from invrender.backends import packages

    missing = {"cuda": None if torch.cuda.is_available() else "needs a CUDA device",
               "warp": None if packages.find("warp") else "needs warp-lang (pip install warp-lang)"}  # fmt: skip
    for item in items:
        for mark, reason in missing.items():
            if reason and item.get_closest_marker(mark) is not None:
                item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture(scope="session")
def cbox32():
    return ir.load_scene("cornell_box", resolution=(32, 32))


def furnace(rho=0.5, eps=1.0, resolution=(16, 16)):
    return ir.load_scene("furnace", resolution=resolution, rho=rho, eps=eps)


def refused(tmp_path, *args: str, out: str = "out"):
    """Run ``python -m invrender *args --out tmp_path/out`` in a child process (so that what native
    libraries write to descriptor 2 is seen too) and check a refusal: exit status 2, stderr exactly
    one line ``invrender: error: ...``, nothing on stdout and nothing left at ``out``. Returns
    that line."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-m", "invrender", *args, "--out", str(tmp_path / out)], cwd=repo, capture_output=True, text=True, timeout=300)
    lines = done.stderr.splitlines()
    assert done.returncode == 2 and len(lines) == 1 and lines[0].startswith("invrender: error: "), (done.returncode, done.stderr)
    assert done.stdout == "" and not (tmp_path / out).exists(), (done.stdout, list((tmp_path / out).rglob("*")) if (tmp_path / out).exists() else None)
    return lines[0]
