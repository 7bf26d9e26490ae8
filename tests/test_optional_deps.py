"""invrender without its optional accelerators: warp-lang, drjit, embreex and pyrender blocked, and no
C++ compiler for Embree's packets.

A child process makes every import of ``warp``, ``drjit``, ``embreex`` and ``pyrender`` fail (``sys.modules[name]
= None`` before ``import invrender``, as on a machine where they are not installed) and then renders
with the torch backend, differentiates, runs an ``lm`` fit and asks for each missing package's path.
The image must equal, to float rounding, the one this process renders with the same seed and backend
with Dr.Jit in place: the bounce's lane functions evaluated as eager torch are their reference (the
fused bounce and the camera samples need no Warp: only the warp backend asks for it).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

import invrender as ir

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys
for name in ("warp", "embreex", "pyrender", "drjit"):
    sys.modules[name] = None
import torch
import invrender as ir
from invrender.errors import BaselineError, MissingPackageError

torch.set_num_threads(1)
out = {"file": ir.__file__}
scene = ir.load_scene("cornell_box", resolution=(12, 12))
img = ir.render(scene, spp=4, max_depth=3, seed=5, progress=False)      # default backend: embree missing -> torch
out["image"] = img.flatten().tolist()

p = scene.params["red.reflectance"]
p.requires_grad_(True)
loss = ir.render(scene, spp=4, max_depth=3, seed=5, progress=False).square().mean()
loss.backward()
out["grad"] = p.grad.tolist()
p.requires_grad_(False)

truth = scene.params["red.reflectance"].clone()
target = ir.render(scene, spp=256, max_depth=3, seed=9, progress=False)
with torch.no_grad():
    scene.params["red.reflectance"].fill_(0.5)
res = ir.fit(scene, target, ["red.reflectance"], solver="lm", max_depth=3, spp=16, rounds=2, progress=False)
out["lm"] = res.params["red.reflectance"].tolist()
out["truth"] = truth.tolist()

errors = {}
for backend in ("embree", "warp"):
    try:
        ir.render(scene, spp=1, backend=backend, progress=False)
    except MissingPackageError as e:
        errors[backend] = str(e)
from invrender.baseline import pyrender_render
try:
    pyrender_render(scene)
except BaselineError as e:
    errors["pyrender"] = str(e)
out["errors"] = errors
from invrender.cli import main
out["cli_rc"] = main(["render", "cornell_box", "--backend", "warp", "--resolution", "4x4", "--spp", "1", "--out", sys.argv[1]])
out["blocked"] = {name: sys.modules.get(name, 0) is None for name in ("warp", "embreex", "pyrender", "drjit")}
print("RESULT " + json.dumps(out))
"""


@pytest.mark.slow
def test_invrender_works_without_warp_embree_and_pyrender(tmp_path):
    # no compiler either: the embree backend's packets (invrender.backends.embree_native) do not build
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYOPENGL_PLATFORM": "egl", "OMP_NUM_THREADS": "1", "CXX": "/nonexistent/c++"}
    env.pop("INVRENDER_KERNELS", None)
    run = subprocess.run([sys.executable, "-c", CHILD, str(tmp_path / "x.exr")], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(next(line for line in run.stdout.splitlines() if line.startswith("RESULT "))[7:])
    assert Path(out["file"]).resolve().is_relative_to(ROOT)
    assert out["blocked"] == {"warp": True, "embreex": True, "pyrender": True, "drjit": True}

    # the fallbacks are said once each, on one line
    notes = [line for line in run.stderr.splitlines() if line.startswith("invrender: note: ")]
    assert len(notes) == 2, run.stderr
    assert any("drjit is not installed: the bounce runs as eager torch" in n and "pip install drjit" in n for n in notes)
    assert not any("warp-lang" in n for n in notes)  # nothing but the warp backend needs it
    assert any("embreex is not installed: intersecting with the torch backend" in n for n in notes)

    # the same image as here, compiled by Dr.Jit, same seed and backend
    scene = ir.load_scene("cornell_box", resolution=(12, 12))
    here = ir.render(scene, spp=4, max_depth=3, seed=5, backend="torch", progress=False)
    assert float(here.mean()) > 0.01
    torch.testing.assert_close(torch.tensor(out["image"]).view_as(here), here, rtol=1e-5, atol=1e-6)

    grad = torch.tensor(out["grad"])
    assert bool(torch.isfinite(grad).all()) and float(grad.abs().min()) > 0  # the red wall is seen in every channel

    lm, truth = torch.tensor(out["lm"]), torch.tensor(out["truth"])
    assert float((lm - truth).abs().max()) < 0.02, (lm, truth)  # from 0.5 to (0.57, 0.04, 0.04) within 0.02

    errors = out["errors"]
    assert set(errors) == {"embree", "warp", "pyrender"}
    assert all("\n" not in e for e in errors.values())
    assert "needs the embreex package, which is not installed: pip install embreex" in errors["embree"]
    assert "needs the warp-lang package, which is not installed: pip install warp-lang" in errors["warp"]
    assert "needs the pyrender package, which is not installed: pip install pyrender" in errors["pyrender"]
    assert out["cli_rc"] == 2
    cli = [line for line in run.stderr.splitlines() if line.startswith("invrender: error: ")]
    assert len(cli) == 1 and "pip install warp-lang" in cli[0]
