"""The command line answers at once: ``--help``, every command's ``--help`` and mistyped names
(command, scene, scene file, integrator) import no torch (nor numpy, nor any plugin), exit 0 / 2,
and suggest the closest name; ``import invrender`` is lazy yet the whole API is there; the
registries import their built-in plugins on first use; the help texts' static catalog is the live
library's."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import invrender as ir
from invrender.cli import COMMANDS
from invrender.cli.generate_catalog import CATALOG, source

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}

#: what the help and the checks of names must not import
HEAVY = ("torch", "numpy", "warp", "trimesh", "cv2", "matplotlib", "PIL", "invrender.scene", "invrender.core", "invrender.backends", "invrender.plugins", "invrender.estimators")

#: runs invrender.cli.main on each argv of sys.argv[1] (JSON) and reports exit codes, outputs and heavy modules
DRIVER = r"""
import contextlib, io, json, sys
from invrender.cli import main
results = []
for argv in json.loads(sys.argv[1]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as e:
            code = e.code
    results.append({"code": code, "out": out.getvalue(), "err": err.getvalue()})
print(json.dumps({"results": results, "heavy": [m for m in json.loads(sys.argv[2]) if m in sys.modules]}))
"""


def drive(cases: list[list[str]], cwd) -> tuple[list[dict], list[str]]:
    run = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(cases), json.dumps(HEAVY)], capture_output=True, text=True, env=ENV, cwd=cwd, timeout=120)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    return out["results"], out["heavy"]


def test_help_and_bad_names_answer_without_torch(tmp_path):
    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "cornell_far.toml").write_text("")
    names = [c.__name__.rsplit(".", 1)[1] for c in COMMANDS]
    helps = [["--help"]] + [[name, "--help"] for name in names]
    bad = [
        ["render", "cornel_box"], ["gradcheck", "cornel_box"], ["variance", "furnac", "--out", "o"], ["ablation", "cornell_bx", "--out", "o"],
        ["fit", "--scene", "cornel_box", "--target", "t.exr", "--params", "a", "--out", "o"], ["render", "scenes/cornel_far.toml"],
        ["render", "--integrator", "pth"], ["rendr"], ["render", "--resolution", "64by64"],
    ]  # fmt: skip
    results, heavy = drive(helps + bad, tmp_path)
    assert heavy == [], f"--help and bad names imported {heavy}"
    for argv, r in zip(helps, results):
        assert r["code"] == 0 and r["out"].startswith("usage: invrender"), (argv, r)
    render_help = results[1 + names.index("render")]["out"]
    assert "whitted: Whitted ray tracing" in render_help and "rr_depth = 5" in render_help and "cornell_specular" in render_help
    assert "--lr-final" in results[1 + names.index("fit")]["out"]
    errors = [r["err"] for r in results[len(helps) :]]
    assert all(r["code"] == 2 for r in results[len(helps) :]) and all(e.startswith("invrender: error: ") and e.count("\n") == 1 for e in errors), errors
    for e in errors[:5]:
        assert "unknown scene" in e and ("(did you mean 'cornell_box'?)" in e or "(did you mean 'furnace'?)" in e), e
    assert "scene file not found: scenes/cornel_far.toml (did you mean 'cornell_far.toml'?)" in errors[5]
    assert "unknown integrator 'pth' (did you mean 'path'?)" in errors[6]
    assert "unknown command 'rendr' (did you mean 'render'?)" in errors[7]
    assert not (tmp_path / "o").exists()


def test_import_is_lazy_and_the_registries_load_their_plugins(tmp_path):
    child = r"""
import sys
import invrender as ir
assert "torch" not in sys.modules and "invrender.registry" not in sys.modules, sorted(m for m in sys.modules if m.startswith("invrender"))
assert set(ir.__all__) <= set(dir(ir))
from invrender.registry import EMITTERS, INTEGRATORS, MATERIALS
mine = type("Mine", (), {"type_name": "diffuse"})
MATERIALS.register(mine)                   # the built-ins are imported first: a user's plugin shadows one
assert MATERIALS["diffuse"] is mine and "glossy" in MATERIALS and "envmap" in EMITTERS and "whitted" in INTEGRATORS
from invrender import fit, Camera
assert ir.io.read_image is ir.read_image   # the subpackages, as attributes, as before
assert callable(fit) and ir.integrators.Whitted is INTEGRATORS["whitted"] and ir.materials.Glossy is MATERIALS["glossy"]
print("OK")
"""
    run = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=300)
    assert run.returncode == 0 and run.stdout.strip() == "OK", run.stderr[-3000:]


def test_a_render_to_a_tensor_loads_no_image_codec(tmp_path):
    """A render (and a replayed gradient) that writes no file imports none of the image codecs
    (kornia, OpenEXR, Pillow: about 2 s and 25 MiB of a first render in a fresh process, and of
    a gradient's memory increment), yet ``ir.io.read_image`` is there when asked for."""
    child = r"""
import sys
import torch
import invrender as ir
scene = ir.load_scene("cornell_box", resolution=(8, 8))
scene.params["white.reflectance"].requires_grad_(True)
ir.render(scene, spp=1, estimator="replay", progress=False).sum().backward()
codecs = [m for m in ("kornia", "OpenEXR", "PIL") if m in sys.modules]
assert not codecs, codecs
assert callable(ir.io.read_image) and callable(ir.io.write_image) and "kornia" in sys.modules
print("OK")
"""
    run = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, env=ENV, cwd=tmp_path, timeout=300)
    assert run.returncode == 0 and run.stdout.strip() == "OK", run.stderr[-3000:]


def test_every_api_name_resolves():
    assert all(getattr(ir, name) is not None for name in ir.__all__)
    assert ir.baseline.__name__ == "invrender.baseline" and ir.lighting.fit_sh is not None
    try:
        ir.no_such_name
    except AttributeError as e:
        assert "no_such_name" in str(e)
    else:
        raise AssertionError("ir.no_such_name resolved")


def test_the_catalog_is_the_live_library():
    assert CATALOG.read_text() == source(), "invrender/cli/catalog.py is stale: run python -m invrender.cli.generate_catalog"
