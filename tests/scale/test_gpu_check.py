"""bench/gpu_check.py: its CPU smoke test (the CPU against itself) lists and passes every check, and
without warp-lang it skips the Warp checks, saying why; on a CUDA machine the real check passes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "bench" / "gpu_check.py"
CHECKS = ["render_torch", "render_warp", "kernels", "grad_replay", "grad_replay_torch", "grad_autodiff", "records", "fit_lm", "fit_adam", "process_group"]
#: a child in which warp-lang, embreex and pyrender cannot be imported (as on the GPU machine, which has no Warp;
#: run() also takes its compiler away, so that Embree's packets do not build)
BLOCKED = "import runpy, sys\nfor m in ('warp', 'embreex', 'pyrender'):\n    sys.modules[m] = None\nsys.argv = sys.argv[1:]\nrunpy.run_path(sys.argv[0], run_name='__main__')"


def run(tmp_path: Path, *args: str, blocked: bool = False) -> tuple[subprocess.CompletedProcess, dict]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    if blocked:
        env["CXX"] = "/nonexistent/c++"  # and no compiler for Embree's packets: no Embree at all
    env.pop("INVRENDER_KERNELS", None)
    head = [sys.executable, "-c", BLOCKED] if blocked else [sys.executable]
    done = subprocess.run([*head, str(SCRIPT), "--out", str(tmp_path), *args], capture_output=True, text=True, env=env, timeout=600)
    summary = json.loads((tmp_path / "gpu_check.json").read_text()) if (tmp_path / "gpu_check.json").exists() else {}
    return done, summary


@pytest.mark.slow
@pytest.mark.warp
def test_cpu_smoke_test_runs_every_check(tmp_path):
    done, summary = run(tmp_path, "--device", "cpu", "--quick")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    checks = {c["name"]: c for c in summary["checks"]}
    assert list(checks) == CHECKS
    assert all(c["status"] == "passed" for c in checks.values()), [(c["name"], c.get("reason")) for c in checks.values()]
    for c in checks.values():  # every result compared, within its tolerance
        assert c["results"] and all(r["ok"] and r["error"] <= r["tolerance"] for r in c["results"].values() if "ok" in r), c
    assert checks["kernels"]["results"]["uniforms_vs_torch (on cpu)"]["error"] == 0  # bit for bit
    assert checks["kernels"]["results"]["camera_samples_vs_torch (on cpu)"]["error"] == 0
    assert set(checks["grad_replay"]["results"]) >= {"grad light.emission (vs cpu)", "grad red.reflectance (vs cpu)"}
    assert checks["fit_lm"]["results"]["error vs truth"]["device"] < 0.5  # it moved towards the truth from grey 0.5 / emission 5
    rows = {r["renderer"]: r for r in summary["throughput"]["rows"]}
    assert {"invrender path (torch)", "invrender path (warp)"} <= set(rows) and all(r["mpaths_per_s"] > 0 for r in rows.values())
    assert summary["skipped"] == [{"name": "throughput Mitsuba cuda_ad_rgb", "reason": "needs --device cuda (this run: cpu)"}]
    assert summary["failed"] == [] and summary["device"] == "cpu"
    assert "10 passed, 0 failed, 1 skipped" in done.stdout


def test_without_warp_the_warp_checks_are_skipped_with_the_reason(tmp_path):
    """The kernels check needs no Warp (the compiled bounce is Dr.Jit's): it runs."""
    done, summary = run(tmp_path, "--device", "cpu", "--quick", "--only", "render_torch,render_warp,kernels,throughput", blocked=True)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    status = {c["name"]: (c["status"], c.get("reason")) for c in summary["checks"]}
    why = "warp-lang is not installed (pip install warp-lang)"
    assert status == {"render_torch": ("passed", None), "render_warp": ("skipped", why), "kernels": ("passed", None)}
    skipped = {s["name"]: s["reason"] for s in summary["skipped"]}
    assert skipped["throughput warp"] == why and skipped["throughput embree"] == "embreex is not installed (pip install embreex)"
    assert f"skipped render_warp: {why}" in done.stdout


def test_bad_arguments_exit_2(tmp_path):
    done, _ = run(tmp_path, "--device", "cpu", "--only", "render_torch,nonsense")
    assert done.returncode == 2 and "unknown check(s) nonsense" in done.stderr
    if not torch.cuda.is_available():
        done, _ = run(tmp_path, "--device", "cuda")
        assert done.returncode == 2 and "torch sees no CUDA device here" in done.stderr


@pytest.mark.cuda
def test_gpu_check_passes_on_cuda(tmp_path):
    done, summary = run(tmp_path, "--device", "cuda", "--quick")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert summary["failed"] == [] and [c["name"] for c in summary["checks"]] == CHECKS
