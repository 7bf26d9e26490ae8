"""The integrator interface: a registry filled by subclassing, validated settings, the pre-pass hook
and the default chunked driver, usable by integrators written outside the package."""

from __future__ import annotations

import dataclasses

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.plugins.integrators import INTEGRATORS, DepthSettings, Integrator, make_integrator
from invrender.plugins.integrators.vertex import next_vertex


def test_registry_holds_the_ladder():
    assert set(INTEGRATORS) >= {"random_walk", "path", "utah", "whitted", "distributed"}
    for name, cls in INTEGRATORS.items():
        assert cls.name == name and cls.summary
    assert make_integrator("utah").terms_kept == 2
    assert make_integrator("utah", max_depth=1).terms_kept == 1
    path = ir.integrators.Path(max_depth=3)
    assert make_integrator(path) is path
    with pytest.raises(ParameterError, match="settings max_depth given beside an integrator object"):
        make_integrator(path, max_depth=4)
    with pytest.raises(dataclasses.FrozenInstanceError):
        path.settings.max_depth = 5


def test_a_new_integrator_registers_once_and_runs_its_pre_pass_once_per_render():
    calls = []

    class FirstHitAlbedo(Integrator):
        """Term 0 = the diffuse albedo at the first hit, scaled by what the pre-pass computed."""

        name = "test_first_hit_albedo"
        Settings = DepthSettings
        summary = "a test integrator"

        def prepare(self, ctx):
            calls.append(1)
            return dataclasses.replace(ctx, extra=torch.tensor(2.0))

        def trace(self, ctx, state, film):
            state, s = next_vertex(ctx, state, film, 0)
            if s is not None:
                sp = ctx.shading_point(s, -state.d)
                film.add(0, state.pixel, ctx.extra * ctx.materials.diffuse_reflectance(sp))

    try:
        assert INTEGRATORS["test_first_hit_albedo"] is FirstHitAlbedo
        scene = ir.load_scene("cornell_box", resolution=(8, 8))
        img = ir.render(scene, "test_first_hit_albedo", spp=4, max_depth=1)
        assert len(calls) == 1  # once per render, not per chunk or worker
        centre = img[4, 4]  # the back wall: white
        torch.testing.assert_close(centre, 2 * scene.params["white.reflectance"])
        with pytest.raises(ParameterError, match="has no setting 'rr_depth'"):
            ir.render(scene, "test_first_hit_albedo", rr_depth=2)
        # differentiable through the default driver, by both estimators
        scene.params["white.reflectance"].requires_grad_(True)
        for estimator in ("autodiff", "replay"):
            scene.params["white.reflectance"].grad = None
            ir.render(scene, "test_first_hit_albedo", spp=4, estimator=estimator).sum().backward()
            assert float(scene.params["white.reflectance"].grad.min()) > 0
    finally:
        INTEGRATORS.pop("test_first_hit_albedo", None)


def test_a_render_that_cannot_fit_in_memory_is_refused_before_work(monkeypatch, tmp_path, capsys):
    from invrender.cli import main
    from invrender.core import driver

    monkeypatch.setattr(driver, "available_memory_bytes", lambda: 10 * 2**20)  # 10 MiB left
    scene = ir.load_scene("cornell_box", resolution=(4, 4))
    ir.render(scene, spp=1, max_depth=1)  # small renders still run
    with pytest.raises(ParameterError, match=r"a 2000x2000 render needs .* GiB for its films .* more than the 0.0 GiB available"):
        ir.render(ir.load_scene("cornell_box", resolution=(2000, 2000)), spp=1)
    out = tmp_path / "big.exr"
    assert main(["render", "--resolution", "2000x2000", "--spp", "1", "--out", str(out)]) == 2
    assert "lower the resolution" in capsys.readouterr().err and not out.exists()
