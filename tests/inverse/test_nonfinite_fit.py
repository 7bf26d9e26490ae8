"""A fit that meets a non-finite value stops with one line naming it and the step, keeps its last
good state in the checkpoint (from which it resumes), and the CLI exits 2; a NaN starting value is
refused before any render; a failed ``lm`` fit ends with its own error, not with an abort in the
JAX import thread. Fits run in child processes (a regression could kill the interpreter)."""

from __future__ import annotations

import math
import re
import subprocess
import sys

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from tests.transport.test_nonfinite import ROOT, run_child, survived

FIT_CHILD = """
    import json, math, sys
    import torch
    import invrender as ir
    from invrender.inverse import fit as F

    folder = sys.argv[1]
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    target = ir.render(scene, spp=4, progress=False)
    start = scene.with_params({"light.emission": [5.0, 5.0, 5.0]})
    kw = dict(steps=6, spp=2, checkpoint_every=2, progress=False)
    out = {}

    def stopped(case, **settings):
        checkpoint = f"{folder}/{case}.pt"
        try:
            ir.fit(start, target, ["light.emission"], checkpoint=checkpoint, **{**kw, **settings})
        except ir.InvRenderError as e:
            state = torch.load(checkpoint, weights_only=False)
            value = F.P.from_raw("light.emission", state["raw"]["light.emission"])
            out[case] = {"error": [type(e).__name__, str(e)], "step": state["step"], "history": len(state["history"]), "value": value.tolist()}

    # a learning rate that overflows exp(): Adam's update is undone, the starting values kept
    stopped("overflow", lr_emission=1e37)
    resumed = ir.fit(start, target, ["light.emission"], checkpoint=f"{folder}/overflow.pt", resume=True, lr_emission=0.15, steps=2)
    out["resumed"] = [len(resumed.history), resumed.params["light.emission"].tolist()]

    # NaN radiance from step 3 on (a plugin gone wrong): the loss is NaN, the state after step 2 kept
    render, calls = F.render, [0]
    def nan_from_step_3(*args, **kwargs):
        calls[0] += 1
        image = render(*args, **kwargs)
        return image * math.nan if calls[0] >= 3 else image
    F.render = nan_from_step_3
    stopped("loss")
    F.render = render

    # a NaN gradient at step 4
    backpropagate, calls = F.backpropagate, [0]
    def nan_gradient(scene, grad_image, *args, **kwargs):
        calls[0] += 1
        backpropagate(scene, grad_image * (math.nan if calls[0] == 4 else 1.0), *args, **kwargs)
    F.backpropagate = nan_gradient
    stopped("gradient")
    print(json.dumps(out))
"""


def test_a_fit_stops_at_a_non_finite_step_and_keeps_its_last_good_state(tmp_path):
    out = survived(run_child(FIT_CHILD, str(tmp_path)))
    kept = f"is kept in checkpoint {tmp_path}"

    kind, message = out["overflow"]["error"]
    assert kind == "NonFiniteError"
    assert message == (
        "fit stopped at step 1: Adam's step made parameter 'light.emission' (3 values) not finite (learning rate too large?); "
        f"the last good state (the starting values) {kept}/overflow.pt"
    )
    assert out["overflow"]["step"] == 0 and out["overflow"]["history"] == 0
    assert out["overflow"]["value"] == pytest.approx([5.0] * 3, rel=1e-6)  # the update undone
    steps, value = out["resumed"]
    assert steps == 2 and all(math.isfinite(v) and v > 0 for v in value)  # the kept state resumes

    kind, message = out["loss"]["error"]
    assert kind == "NonFiniteError" and message == f"fit stopped at step 3: the loss is nan; the last good state (after step 2) {kept}/loss.pt"
    assert out["loss"]["step"] == 2 and out["loss"]["history"] == 2 and all(math.isfinite(v) for v in out["loss"]["value"])

    kind, message = out["gradient"]["error"]
    assert message == f"fit stopped at step 4: the gradient of parameter 'light.emission' (3 values) is not finite; the last good state (after step 3) {kept}/gradient.pt"
    assert out["gradient"]["step"] == 3 and out["gradient"]["history"] == 3  # newer than the periodic checkpoint of step 2


def test_cli_fit_exits_2_with_one_line(tmp_path):
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    ir.write_image(tmp_path / "target.exr", ir.render(scene, spp=2, progress=False))
    command = [sys.executable, "-m", "invrender", "fit", "--scene", "cornell_box", "--resolution", "8x8", "--target", str(tmp_path / "target.exr")]
    command += ["--params", "light.emission", "--init", "light.emission=5", "--lr-emission", "1e37", "--steps", "3", "--spp", "1", "--out", str(tmp_path / "run"), "--quiet"]
    proc = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.startswith("invrender:")]
    assert len(lines) == 1 and re.match(r"invrender: error: fit stopped at step 1: Adam's step made parameter 'light.emission' \(\d values?\) not finite .*checkpoint.pt$", lines[0])
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)
    assert state["step"] == 0 and bool(torch.isfinite(state["raw"]["light.emission"]).all())
    assert not (tmp_path / "run" / "report.json").exists()


def test_a_nan_starting_value_is_refused_before_any_render():
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    with torch.no_grad():
        scene.params["light.emission"][0] = math.inf
    with pytest.raises(ParameterError, match=r"^parameter 'light.emission' \(1 of 3 values\) is not finite"):
        ir.fit(scene, torch.zeros(8, 8, 3), ["red.reflectance"], steps=1, progress=False)


#: a failed lm fit ends the process while the JAX import (started early by preload) may still be
#: inside jaxlib: as a daemon thread it was unwound there and the process aborted (exit 134)
PRELOAD_CHILD = """
    import sys, time
    from invrender.inverse.least_squares import preload

    preload()
    while "jaxlib" not in sys.modules:
        time.sleep(0.001)
    time.sleep(float(sys.argv[1]))
    print("invrender: error: the fit failed", file=sys.stderr)
    sys.exit(2)
"""


def test_exit_during_the_jax_import_is_the_fit_s_own():
    proc = run_child(PRELOAD_CHILD, "0.02")
    assert proc.returncode == 2 and proc.stderr.strip().splitlines()[-1] == "invrender: error: the fit failed", proc.stderr[-2000:]


def test_a_diverged_least_squares_round_keeps_the_rounds_before_it(tmp_path, monkeypatch):
    from invrender.errors import NonFiniteError
    from invrender.inverse import fit as F

    solve, rounds = F._solve_on_records, [0]

    def diverging(*args, **kwargs):
        rounds[0] += 1
        if rounds[0] == 2:
            raise NonFiniteError("solver 'lm' diverged: 'light.emission' not finite after 3 steps; start closer")
        return solve(*args, **kwargs)

    monkeypatch.setattr(F, "_solve_on_records", diverging)
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    target = ir.render(scene, spp=4, progress=False)
    with pytest.raises(NonFiniteError) as info:
        ir.fit(scene, target, ["light.emission"], solver="lm", rounds=3, spp=2, max_depth=2, checkpoint=tmp_path / "ck.pt", progress=False)
    assert str(info.value) == (
        "fit stopped at round 2: solver 'lm' diverged: 'light.emission' not finite after 3 steps; start closer; "
        f"the last good state (after round 1) is kept in checkpoint {tmp_path / 'ck.pt'}"
    )
    state = torch.load(tmp_path / "ck.pt", weights_only=False)
    assert state["step"] == 1 and len(state["history"]) == 1
