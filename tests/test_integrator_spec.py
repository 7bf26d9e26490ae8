"""One integrator spec everywhere: a fit given ``{"type": "path", "rr_depth": 3, "strategy":
"emitter"}`` (from Python or as ``--integrator path --set rr_depth=3 --set strategy=emitter``)
renders with those settings, observed in the integrator's traces and in the images it writes; bad
specs are one-line errors before any work, from Python and from the command line."""

import dataclasses
import json
import math

import pytest
import torch

import invrender as ir
from invrender.cli import main
from invrender.errors import ParameterError
from invrender.plugins.integrators.path import Path as PathTracer

SPEC = {"type": "path", "rr_depth": 3, "strategy": "emitter"}
FIT = dict(steps=2, spp=2, spp_final=2, progress=False)


@pytest.fixture
def traced(monkeypatch):
    """(rr_depth, strategy, max_depth) of every chunk the path tracer traces."""
    seen = []
    original = PathTracer.trace

    def spy(self, ctx, state, film):
        seen.append((self.settings.rr_depth, self.settings.strategy, self.settings.max_depth))
        return original(self, ctx, state, film)

    monkeypatch.setattr(PathTracer, "trace", spy)
    return seen


@pytest.fixture
def target(tmp_path):
    scene = ir.load_scene("cornell_box", resolution=(6, 6))
    image = ir.render(scene, spp=16, seed=7, progress=False)
    ir.write_image(tmp_path / "target.exr", image)
    return image


def test_a_fit_from_python_renders_with_the_spec_settings(target, traced):
    scene = ir.load_scene("cornell_box", resolution=(6, 6))
    result = ir.fit(scene, target, ["light.emission"], integrator=SPEC, **FIT)
    assert traced and set(traced) == {(3, "emitter", 8)}  # every trace of every step (forward, residual, replay)
    assert result.settings.integrator == SPEC


@pytest.mark.parametrize("estimator", ["autodiff", "replay"])
def test_a_fit_takes_an_integrator_object_and_the_max_depth_shortcut(target, traced, estimator):
    scene = ir.load_scene("cornell_box", resolution=(6, 6))
    ir.fit(scene, target, ["light.emission"], integrator=ir.integrators.Path(rr_depth=2, max_depth=3), estimator=estimator, **FIT)
    ir.fit(scene, target, ["light.emission"], integrator={"type": "path", "strategy": "bsdf"}, max_depth=4, estimator=estimator, **FIT)
    assert set(traced) == {(2, "mis", 3), (5, "bsdf", 4)}


def test_a_fit_from_the_command_line_renders_with_the_set_settings(tmp_path, target, traced, capsys):
    out = tmp_path / "run"
    args = ["fit", "--scene", "cornell_box", "--target", str(tmp_path / "target.exr"), "--params", "light.emission", "--out", str(out)]
    args += ["--integrator", "path", "--set", "rr_depth=3", "--set", "strategy=emitter", "--steps", "2", "--spp", "2", "--spp-final", "2", "--quiet"]
    assert main(args) == 0, capsys.readouterr().err
    assert traced and set(traced) == {(3, "emitter", 8)}
    # the final image is the recovered scene rendered with those settings, bit for bit, and not the defaults' image
    report = json.loads((out / "report.json").read_text())
    scene = ir.load_scene("cornell_box", resolution=(6, 6))
    scene.params["light.emission"] = torch.tensor(report["recovered"]["light.emission"], dtype=torch.float32)
    final = ir.read_image(out / "final.exr")
    assert torch.equal(final, ir.render(scene, SPEC, spp=8, seed=1, progress=False))
    assert not torch.equal(final, ir.render(scene, "path", spp=8, seed=1, progress=False))


def test_render_and_the_cli_render_agree_on_set_settings(tmp_path, capsys):
    out = tmp_path / "a.exr"
    code = main(["render", "cornell_box", "--resolution", "8x6", "--spp", "2", "--set", "rr_depth=1", "--set", "hemisphere=uniform", "--max-depth", "3", "--out", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    scene = ir.load_scene("cornell_box", resolution=(8, 6))
    assert torch.equal(ir.read_image(out), ir.render(scene, {"type": "path", "rr_depth": 1, "hemisphere": "uniform", "max_depth": 3}, spp=2, progress=False))


def test_radiosity_settings_are_reachable_from_the_cli(tmp_path, capsys):
    out = tmp_path / "r.exr"
    code = main(["render", "cornell_box", "--integrator", "radiosity", "--set", "patches=64", "--set", "rays=32", "--set", "final_gather=false",
                 "--resolution", "4x4", "--spp", "1", "--out", str(out), "--quiet"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    scene = ir.load_scene("cornell_box", resolution=(4, 4))
    assert torch.equal(ir.read_image(out), ir.render(scene, {"type": "radiosity", "patches": 64, "rays": 32}, spp=1, progress=False))


def test_help_lists_every_integrator_with_its_settings(capsys):
    with pytest.raises(SystemExit):
        main(["render", "--help"])
    text = capsys.readouterr().out
    for name in ir.integrators.INTEGRATORS:
        assert f"  {name}: " in text
    assert "final_gather = False" in text and "strategy = 'mis'" in text and "rr_depth = 5" in text


BAD_SPECS = [
    ({"integrator": {"type": "path", "rr_depth": -5}}, "rr_depth must be >= 1, or -1"),
    ({"integrator": {"type": "path", "bogus": 1}}, "has no setting 'bogus'"),
    ({"integrator": {"rr_depth": 3}}, "needs a 'type' key"),
    ({"integrator": "nope"}, "unknown integrator 'nope'"),
    ({"integrator": "pth"}, r"unknown integrator 'pth' \(did you mean 'path'\?\) \(known: "),
    ({"integrator": {"type": "path", "max_dept": 3}}, r"integrator 'path' has no setting 'max_dept' \(did you mean 'max_depth'\?\)"),
    ({"stesp": 3}, r"unknown fit setting 'stesp' \(did you mean 'steps'\?\)"),
    ({"integrator": {"type": "path", "strategy": "mys"}}, r"unknown strategy 'mys' \(did you mean 'mis'\?\)"),
    ({"integrator": {"type": "path", "strategy": 3}}, "unknown strategy"),
    ({"integrator": {"type": "path", "max_depth": 10**9}}, "max_depth must be <="),
    ({"integrator": {"type": "path", "max_depth": 4}, "max_depth": 5}, "differ"),
    ({"max_depth": -2}, "max_depth must be >= 1, or -1"),
    ({"lr": math.nan}, "lr must be finite"),
    ({"spp": 10**12}, "spp must be <="),
    ({"steps": True}, "steps must be an integer"),
]


@pytest.mark.parametrize("settings, words", BAD_SPECS)
def test_bad_fit_specs_are_one_line_errors_before_any_work(settings, words, monkeypatch):
    from invrender.inverse import fit as fit_module

    monkeypatch.setattr(fit_module, "load_views", lambda *a, **k: pytest.fail("worked before checking the settings"))
    with pytest.raises(ParameterError, match=words) as e:
        ir.fit(ir.load_scene("cornell_box", resolution=(4, 4)), torch.zeros(4, 4, 3), ["light.emission"], progress=False, **settings)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(spp=10**12), "spp must be <="),
        (dict(integrator={"type": "path", "rr_depth": 0}), "rr_depth must be >= 1"),
        (dict(max_depth=-3), "max_depth must be >= 1, or -1"),
        (dict(memory_mb=math.nan), "memory_mb must be finite"),
        (dict(spp=2**30), "paths, more than"),  # 64x64 x 2^30 spp: more paths than any machine finishes
    ],
)
def test_bad_render_settings_are_one_line_errors(kwargs, words, monkeypatch):
    from invrender.plugins.integrators import base

    monkeypatch.setattr(base.Integrator, "context", lambda *a, **k: pytest.fail("worked before checking the settings"))
    scene = ir.load_scene("cornell_box", resolution=(64, 64)) if kwargs.get("spp") == 2**30 else ir.load_scene("cornell_box", resolution=(4, 4))
    with pytest.raises(ParameterError, match=words) as e:
        ir.render(scene, **{"spp": 1, **kwargs}, progress=False)
    assert "\n" not in str(e.value)


def test_a_resolution_no_machine_holds_is_refused_before_rendering(monkeypatch):
    from invrender.plugins.integrators import base

    monkeypatch.setattr(base.Integrator, "context", lambda *a, **k: pytest.fail("worked before checking the resolution"))
    with pytest.raises(ParameterError, match="resolution width must be <= 65536"):
        ir.load_scene("cornell_box", resolution=(10**6, 10**6))  # refused where the scene is made
    scene = dataclasses.replace(ir.load_scene("cornell_box"), resolution=(10**6, 10**6))  # and where it is rendered
    with pytest.raises(ParameterError, match="resolution width must be <= 65536"):
        ir.render(scene, spp=1, progress=False)


@pytest.mark.parametrize(
    "args, words",
    [
        (["render", "--set", "rr_depth=abc"], "setting rr_depth must be int, got 'abc'"),
        (["render", "--set", "bogus=1"], "has no setting 'bogus'"),
        (["render", "--set", "rr_depth"], "--set expects KEY=VALUE"),
        (["render", "--set", "strategy=sideways"], "unknown strategy 'sideways'"),
        (["render", "--set", "max_depth=-2"], "max_depth must be >= 1, or -1"),
        (["render", "--max-depth", "3", "--set", "max_depth=4"], "max_depth is given twice"),
        (["render", "--integrator", "utah", "--set", "rr_depth=2"], "integrator 'utah' has no setting 'rr_depth'"),
        (["render", "--integrator", "radiosity", "--set", "tolerance=nan"], "tolerance"),
        (["render", "--spp", str(10**12)], "spp must be <="),
        (["render", "--resolution", "1000000x1000000"], "resolution width must be <= 65536"),
        (["fit", "--scene", "cornell_box", "--target", "t.exr", "--params", "light.emission", "--out", "run", "--set", "rr_depth=-4"], "rr_depth must be >= 1"),
        (["fit", "--scene", "cornell_box", "--target", "t.exr", "--params", "light.emission", "--out", "run", "--integrator", "nope"], "unknown integrator 'nope'"),
        (["fit", "--scene", "cornell_box", "--target", "t.exr", "--params", "light.emission", "--out", "run", "--spp", str(10**12)], "spp must be <="),
        (["fit", "--scene", "cornell_box", "--target", "t.exr", "--params", "light.emission", "--out", "run", "--lr", "nan"], "lr must be finite"),
        (["ablation", "--out", "run", "--set", "hemisphere=square"], "hemisphere"),
        (["gradcheck", "--set", "rr_depth=0"], "rr_depth must be >= 1"),
    ],
)
def test_bad_specs_on_the_command_line_are_one_line_errors(args, words, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    if args[0] == "fit":
        ir.write_image(tmp_path / "t.exr", torch.zeros(4, 4, 3))
    before = set(tmp_path.iterdir())
    if args[0] in ("render", "gradcheck") and "--resolution" not in args:
        args = args + ["--resolution", "4x4"]
    try:
        code = main(args)
    except SystemExit as e:  # argparse's own errors (a --resolution it cannot read)
        code = e.code
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("invrender: error:") and words in lines[0], err
    assert "Traceback" not in err
    assert set(tmp_path.iterdir()) == before  # nothing written


def test_a_recipe_takes_an_integrator_table(tmp_path):
    from invrender.recipes import load_fit_recipe

    dataset = tmp_path / "d.toml"
    dataset.write_text('scene = "cornell_box"\nresolution = [4, 4]\nspp = 4\n')
    recipe = tmp_path / "r.toml"
    recipe.write_text(f'dataset = "{dataset.name}"\nparams = ["light.emission"]\n[fit]\nintegrator = {{ type = "path", rr_depth = 3, strategy = "emitter" }}\n')
    assert load_fit_recipe(recipe).settings["integrator"] == SPEC
    recipe.write_text(f'dataset = "{dataset.name}"\nparams = ["light.emission"]\n[fit]\nintegrator = {{ type = "path", rr_depth = -7 }}\n')
    with pytest.raises(ParameterError, match=r"r.toml \[fit\]: .*rr_depth must be >= 1") as e:
        load_fit_recipe(recipe)
    assert "\n" not in str(e.value)


def test_study_and_ablation_take_specs():
    from invrender.ablation import VARIANTS
    from invrender.study import GradientConfig, fit_settings

    config = GradientConfig(integrator={"type": "random_walk", "rr_depth": 2})
    assert config.label == "random_walk/replay/decorrelated/rr_depth=2"
    assert fit_settings("path/replay/decorrelated/rr_depth=3/strategy=emitter")["integrator"] == SPEC
    variant = next(v for v in VARIANTS if v.name == "emitter_only")
    assert variant.integrator_spec({"type": "path", "rr_depth": 3}) == SPEC
