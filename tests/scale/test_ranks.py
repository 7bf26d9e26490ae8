"""Scale-out on torch.distributed (docs/scale.md): renders, gradients and fits split across two
torchrun processes on the CPU (gloo) equal the single-process ones."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import invrender as ir

WORKER = Path(__file__).with_name("ranks_worker.py")


def torchrun(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``torchrun --standalone --nproc-per-node 2`` with one thread per rank (as torchrun sets it)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2", *args]
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return done


@pytest.mark.slow
def test_two_process_render_equals_one_process_render(tmp_path):
    args = ["cornell_box", "--resolution", "24x20", "--spp", "16", "--seed", "3"]
    one = subprocess.run([sys.executable, "-m", "invrender", "render", *args, "--out", "one.exr", "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert one.returncode == 0, one.stderr
    done = torchrun("-m", "invrender", "render", *args, "--out", "two.exr", cwd=tmp_path)
    assert done.stderr.count("wrote") == 1  # rank 0 alone reports (and writes)
    a, b = ir.read_image(tmp_path / "one.exr"), ir.read_image(tmp_path / "two.exr")
    assert a.mean() > 0.05
    assert torch.allclose(a, b, rtol=1e-6, atol=1e-7), (a - b).abs().max()
    assert not list(tmp_path.glob(".*.tmp"))


@pytest.mark.slow
def test_python_api_inside_a_process_group(tmp_path):
    """Images, replay and autodiff gradients and a decorrelated gradient inside an initialized group
    equal one process's; a gradient study refuses with one line."""
    torchrun(str(WORKER), str(tmp_path / "ranks.pt"), cwd=tmp_path)
    got = torch.load(tmp_path / "ranks.pt", weights_only=False)
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    target = ir.render(scene, spp=32, seed=7, progress=False)
    assert torch.allclose(got["target"], target, rtol=1e-6, atol=1e-7)
    for estimator in ("replay", "autodiff"):
        rho = scene.params["red.reflectance"].requires_grad_(True)
        eps = scene.params["light.emission"].requires_grad_(True)
        image = ir.render(scene, spp=8, seed=1, estimator=estimator, progress=False)
        ((image - target) ** 2).mean().backward()
        image2, rho_grad, eps_grad = got[estimator]
        assert torch.allclose(image2, image.detach(), rtol=1e-6, atol=1e-7)
        assert torch.allclose(rho_grad, rho.grad, rtol=1e-5, atol=1e-9), (estimator, rho_grad, rho.grad)
        assert torch.allclose(eps_grad, eps.grad, rtol=1e-5, atol=1e-9), (estimator, eps_grad, eps.grad)
        assert rho.grad.abs().max() > 0
        rho.grad = eps.grad = None
        rho.requires_grad_(False)
        eps.requires_grad_(False)
    sys.path.insert(0, str(WORKER.parent))
    from ranks_worker import decorrelated

    # the fused bounce's Jacobian is summed across the ranks once (not once more as a gradient)
    assert torch.allclose(got["backpropagate"], decorrelated(scene), rtol=1e-5, atol=1e-9)
    assert "runs in one process" in got["study"]


@pytest.mark.slow
def test_two_process_fit_follows_the_one_process_trajectory(tmp_path):
    """fit's default estimator, replay (autodiff's gradients across ranks: the test above)."""
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    ir.write_image(tmp_path / "target.exr", ir.render(scene, spp=128, seed=99, progress=False))
    args = ["--scene", "cornell_box", "--target", "target.exr", "--params", "red.reflectance,light.emission", "--init", "reflectance=0.5",
            "--steps", "8", "--spp", "4", "--spp-final", "8"]  # fmt: skip
    one = subprocess.run([sys.executable, "-m", "invrender", "fit", *args, "--out", "one", "--quiet"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert one.returncode == 0, one.stderr
    torchrun("-m", "invrender", "fit", *args, "--out", "two", cwd=tmp_path)
    a = torch.load(tmp_path / "one" / "checkpoint.pt", weights_only=False)["history"]
    b = torch.load(tmp_path / "two" / "checkpoint.pt", weights_only=False)["history"]
    assert len(a) == len(b) == 8
    for sa, sb in zip(a, b):
        assert sa["loss"] == pytest.approx(sb["loss"], rel=1e-5)
        for name, value in sa["params"].items():
            assert sb["params"][name] == pytest.approx(value, rel=1e-5)
    assert a[-1]["params"]["red.reflectance"] != a[0]["params"]["red.reflectance"]  # it moved
    two = json.loads((tmp_path / "two" / "report.json").read_text())["recovered"]
    one = json.loads((tmp_path / "one" / "report.json").read_text())["recovered"]
    assert two.keys() == one.keys()
    for name, value in one.items():
        assert two[name] == pytest.approx(value, rel=1e-5)
