"""invrender fit / gradcheck / dataset from the command line: outputs, Ctrl-C and --resume, errors."""

import json

import pytest
import torch

import invrender as ir
from invrender.cli import main

DATASET = """
scene = "cornell_box"
resolution = [12, 12]
spp = 64
max_depth = 2
seed = 5
[randomize]
"red.reflectance" = [0.2, 0.8]
[set]
"light.emission" = [10, 10, 10]
[[views]]
origin = [0, 0, 3.9]
[[views]]
origin = [0.5, 0, 3.8]
"""

RECIPE = """
dataset = "data.toml"
params = ["red.reflectance"]
[init]
reflectance = 0.5
[fit]
steps = 6
spp = 2
spp_final = 2
max_depth = 2
checkpoint_every = 2
"""


@pytest.fixture
def recipe(tmp_path):
    (tmp_path / "data.toml").write_text(DATASET)
    (tmp_path / "fit.toml").write_text(RECIPE)
    return tmp_path / "fit.toml"


def test_dataset_command_writes_views_truth_manifest(tmp_path, capsys):
    (tmp_path / "data.toml").write_text(DATASET)
    assert main(["dataset", str(tmp_path / "data.toml"), "--out", str(tmp_path / "d"), "--quiet"]) == 0
    manifest = json.loads((tmp_path / "d" / "manifest.json").read_text())
    truth = json.loads((tmp_path / "d" / "truth.json").read_text())
    assert len(manifest["views"]) == 2 and manifest["randomized"] == ["red.reflectance"]
    assert truth["light.emission"] == [10.0, 10.0, 10.0] and all(0.2 <= v <= 0.8 for v in truth["red.reflectance"])
    assert ir.read_image(tmp_path / "d" / "view_01.exr").shape == (12, 12, 3)
    assert (tmp_path / "d" / "view_00.png").exists()


PHOTOGRAPH = """
[photograph]
exposure = [0.5, 2.0]
white_balance = [0.8, 2.0, 1.0]
format = "png"
bits = 16
"""


def test_a_photograph_dataset_writes_the_camera_files_and_the_sensor_truth(tmp_path):
    """``[photograph]``: each view's target is the photograph (16-bit PNG here) of its linear
    render (kept as view_NN.exr), the truth holds the sensor per view with the white balance
    normalized to green = 1 (its green gain moved into the exposure), and load_dataset gives the
    photographs as paths, which fit reads with their bit depth; the file's codes are the sensor
    applied to the radiance."""
    from invrender.inverse.sensor import photograph
    from invrender.io.images import read_photo
    from invrender.recipes import load_dataset, make_dataset

    (tmp_path / "data.toml").write_text(DATASET + PHOTOGRAPH)
    make_dataset(tmp_path / "data.toml", tmp_path / "d", progress=False)
    truth = json.loads((tmp_path / "d" / "truth.json").read_text())
    assert truth["sensor.exposure"] == [1.0, 4.0] and truth["sensor.white_balance"] == [[0.4, 1.0, 0.5]] * 2
    _, targets, cameras, _ = load_dataset(tmp_path / "d")
    assert targets == [str(tmp_path / "d" / f"view_{i:02d}.png") for i in range(2)] and len(cameras) == 2
    radiance = ir.read_image(tmp_path / "d" / "view_01.exr")
    photo = read_photo(targets[1])
    assert photo.bits == 16
    expected = photograph(radiance, 4.0, (0.4, 1.0, 0.5))
    assert float((photo.values - expected).abs().max()) <= 0.5 / 65535 + 1e-6


@pytest.mark.parametrize(
    "table, words",
    [
        ('exposure = -1', "'exposure' must be a positive number or one per view (2)"),
        ('exposure = [1, 2, 3]', "'exposure' must be a positive number or one per view (2)"),
        ('white_balance = [1, 0, 1]', "'white_balance' must be positive [r, g, b] gains"),
        ('response = "log"', "unknown response"),
        ('format = "jpg"\nbits = 16', "'format' must be \"jpg\" (8 bits)"),
        ('quality = 0', "'quality' must be an integer in [1, 100]"),
        ('iso = 100', "iso"),
    ],
)
def test_bad_photograph_tables_are_one_line_errors(table, words, tmp_path):
    from invrender.errors import ParameterError
    from invrender.recipes import load_dataset_recipe

    (tmp_path / "data.toml").write_text(DATASET + "[photograph]\n" + table + "\n")
    with pytest.raises(ParameterError) as e:
        load_dataset_recipe(tmp_path / "data.toml")
    assert words in str(e.value) and "[photograph]" in str(e.value) and "\n" not in str(e.value)


def test_fit_recipe_writes_report_plot_render_checkpoint_and_resumes(recipe, tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    assert main(["fit", str(recipe), "--out", str(out), "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["steps"] == 6 and set(report) >= {"initial", "recovered", "truth", "relative_error", "settings"}
    assert report["initial"]["red.reflectance"] == pytest.approx([0.5] * 3)
    for name in ("loss.png", "final_00.exr", "final_01.exr", "final_00.png", "final_01.png", "checkpoint.pt"):
        assert (out / name).exists(), name

    import invrender.inverse.fit as fit_module

    original, calls = fit_module._view_loss, {"n": 0}

    def interrupt_at_step_3(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2 * 3 + 1:  # two views per step
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(fit_module, "_view_loss", interrupt_at_step_3)
    out2 = tmp_path / "run2"
    assert main(["fit", str(recipe), "--out", str(out2), "--quiet"]) == 130
    assert not (out2 / "report.json").exists() and (out2 / "checkpoint.pt").exists()
    monkeypatch.setattr(fit_module, "_view_loss", original)
    assert main(["fit", str(recipe), "--out", str(out2), "--resume", "--quiet"]) == 0
    resumed = json.loads((out2 / "report.json").read_text())
    assert resumed["recovered"] == report["recovered"]


@pytest.mark.slow
def test_lm_fit_of_a_texture_writes_the_correlation_figure(tmp_path, capsys):
    """``--solver lm`` on a textured parameter: per-texel values and standard errors in the report,
    one correlation matrix channel per texel and colour, and correlation.png beside loss.png."""
    scene = ir.load_scene("forward/textured_floor.toml", resolution=(12, 12))
    ir.write_image(tmp_path / "t.exr", ir.render(scene, spp=256, max_depth=3, progress=False))
    out = tmp_path / "run"
    argv = ["fit", "--scene", "forward/textured_floor.toml", "--target", str(tmp_path / "t.exr"), "--params", "floor.reflectance", "--solver", "lm"]
    assert main([*argv, "--rounds", "1", "--spp", "16", "--max-depth", "3", "--out", str(out), "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert torch.tensor(report["recovered"]["floor.reflectance"]).shape == (4, 4, 3)
    assert torch.tensor(report["std_error"]["floor.reflectance"]).shape == (4, 4, 3)
    assert len(report["correlation"]["channels"]) == 48 and report["correlation"]["channels"][5] == "floor.reflectance[0,1][B]"
    assert (out / "correlation.png").stat().st_size > 1000 and (out / "loss.png").exists()


def test_fit_from_scene_and_target(tmp_path, capsys):
    target = tmp_path / "t.exr"
    ir.write_image(target, ir.render(ir.load_scene("cornell_box", resolution=(8, 8)), spp=16, max_depth=2, progress=False))
    code = main(["fit", "--scene", "cornell_box", "--target", str(target), "--params", "light.emission", "--init", "emission=5",
                 "--steps", "3", "--spp", "2", "--spp-final", "2", "--max-depth", "2", "--out", str(tmp_path / "o"), "--quiet"])  # fmt: skip
    assert code == 0
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["initial"]["light.emission"] == [5.0, 5.0, 5.0] and "truth" not in report


@pytest.mark.parametrize(
    "args, words",
    [
        (["fit", "--scene", "cornell_box", "--params", "light.emission"], "needs a recipe"),
        (["fit", "--scene", "cornell_box", "--target", "missing.exr", "--params", "light.emission"], "not found"),
        (["fit", "nope.toml"], "recipe not found"),
        (["fit", "--scene", "cornell_box", "--target", "T", "--params", "lamp.emission"], "unknown parameter"),
        (["fit", "--scene", "cornell_box", "--target", "T", "--params", "light.emission", "--init", "emission=a,b"], "--init expects"),
        (["fit", "--scene", "cornell_box", "--target", "T", "--params", "light.emission", "--loss", "l3"], "unknown loss"),
        (["fit", "--scene", "cornell_box", "--target", "T", "--params", "light.emission", "--resume"], "cannot resume"),
        (["fit", "--scene", "cornell_box", "--target", "N", "--params", "light.emission"], "NaN"),
    ],
)
def test_fit_bad_input_one_line_exit_2(args, words, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    ir.write_image("T.exr", torch.ones(8, 8, 3))
    import numpy as np
    import OpenEXR

    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, {"RGB": np.full((8, 8, 3), np.nan, dtype=np.float32)}) as f:
        f.write("N.exr")
    args = [a.replace("T", "T.exr") if a == "T" else a.replace("N", "N.exr") if a == "N" else a for a in args]
    code = main(args + ["--out", "out", "--quiet", "--steps", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0], err


def test_gradcheck_command(capsys):
    code = main(["gradcheck", "cornell_box", "--params", "light.emission", "--resolution", "8x8", "--spp", "4", "--max-depth", "2", "--tolerance", "0.02"])
    out = capsys.readouterr().out
    assert code == 0 and "light.emission" in out and "replay" in out and "largest relative error" in out
    rows = ir.gradcheck(ir.load_scene("cornell_box", resolution=(8, 8)), ["red.reflectance"], spp=4, max_depth=3)
    assert len(rows) == 3 and all(r.rel_errors["replay"] < 0.02 for r in rows)


def test_every_shipped_recipe_parses_and_names_real_parameters():
    """Each optimize/ recipe and its dataset load, and every fitted and randomized name is a
    parameter of the dataset's scene (with its initial values applied) or of the sensor."""
    from pathlib import Path

    from invrender.recipes import apply_init, check_fit_recipe, dataset_scene, load_fit_recipe

    root = Path(__file__).resolve().parents[2]
    recipes = sorted((root / "optimize").glob("*.toml"))
    assert any(p.name == "cornell_specular.toml" for p in recipes)
    for path in recipes:
        recipe = load_fit_recipe(path)
        scene = dataset_scene(recipe.dataset)
        assert set(recipe.dataset.randomize) <= set(scene.params), path
        names = recipe.params + [n for v in recipe.variants for n in v.params]
        apply_init(scene, names, recipe.init)
        from invrender.inverse.sensor import is_sensor

        assert {n for n in recipe.params if not is_sensor(n)} <= set(scene.params), path
        check_fit_recipe(recipe)  # what a fit checks before its dataset is rendered passes too


def test_every_fit_setting_has_a_flag():
    import dataclasses

    from invrender.cli import FIT_OPTIONS, build_parser
    from invrender.inverse.fit import FitSettings

    assert {f.name for f in dataclasses.fields(FitSettings)} == {name for name, _, _ in FIT_OPTIONS}
    args = build_parser().parse_args(["fit", "--out", "x", "--decorrelate", "false", "--lr-final", "0.1", "--checkpoint-every", "5", "--beta2", "0.9"])
    assert (args.decorrelate, args.lr_final, args.checkpoint_every, args.beta2) == (False, 0.1, 5, 0.9)


def test_gradcheck_command_with_another_integrator(capsys):
    args = ["gradcheck", "cornell_specular", "--integrator", "whitted", "--ambient", "0.05", "--resolution", "8x8", "--spp", "4", "--max-depth", "3"]
    code = main(args + ["--params", "mirror.specular_reflectance,ambient.emission", "--tolerance", "0.02"])
    out = capsys.readouterr().out
    assert code == 0 and "mirror.specular_reflectance" in out and "ambient.emission" in out


def test_a_fit_recipe_with_a_bad_sensor_is_refused_before_its_dataset_is_rendered(recipe, tmp_path):
    """An invalid ``[photo] sensor`` white balance: one line naming the recipe, exit 2, and no
    dataset (nor anything else) written to the output folder (it used to be refused only after
    the dataset was rendered into it)."""
    from tests.conftest import refused

    recipe.write_text(RECIPE + '[photo]\nsensor = { white_balance = [1, 2, 3] }\n')
    line = refused(tmp_path, "fit", str(recipe), "--quiet")
    assert line == f"invrender: error: {recipe} [photo] sensor: sensor option white_balance: the green gain is fixed at 1 (the common scale is the exposure's)"


@pytest.mark.parametrize(
    "extra, words",
    [
        ('[photo]\nsensor = { shared = ["gain"] }\n', "[photo] sensor: sensor option shared: 'gain' is not 'exposure' or 'white_balance'"),
        ('[photo]\nmask = "small.png"\n', "[photo]: mask " + "{tmp}/small.png is 5x5 but the target view 0 of the dataset is 12x12"),
        ('[photo]\nmask = "nope.png"\n', "[photo]: cannot read image {tmp}/nope.png: file not found"),
        ('[photo]\nresponse = "gama:2"\n', "[photo]: view 0 of the dataset: unknown response 'gama:2'"),
        ('[[variants]]\nlabel = "more"\nparams = ["red.reflectanse"]\n', "variant 'more' params: unknown parameter 'red.reflectanse' (did you mean 'red.reflectance'?)"),
        ('[[variants]]\nlabel = "hot"\ninit = { "light.emission" = -1 }\n', "variant 'hot' [init]: light.emission: emission eps must be >= 0"),
    ],
)
def test_every_fit_recipe_input_is_checked_before_anything_is_written(recipe, tmp_path, capsys, extra, words):
    from PIL import Image

    Image.new("L", (5, 5), 255).save(tmp_path / "small.png")
    body = RECIPE.replace("[init]", extra + "[init]") if extra.startswith("[photo]") else RECIPE + extra
    recipe.write_text(body)
    code = main(["fit", str(recipe), "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith(f"invrender: error: {recipe}") and words.format(tmp=tmp_path) in err[0], err
    assert not (tmp_path / "run").exists()


def test_init_takes_the_sensor_names_params_takes(tmp_path, capsys):
    """``--init sensor.exposure=0.5``: the sensor's starting value (it used to be refused as an
    unknown parameter although --params takes the name); a recipe's [init] likewise."""
    target = tmp_path / "t.png"
    ir.write_image(target, torch.full((8, 8, 3), 0.2))
    code = main(["fit", "--scene", "cornell_box", "--target", str(target), "--params", "white.reflectance,sensor.exposure", "--init", "sensor.exposure=0.5",
                 "--init", "sensor.white_balance=0.9,1,1.1", "--steps", "1", "--spp", "1", "--max-depth", "1", "--out", str(tmp_path / "o"), "--quiet"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["initial"]["sensor.exposure"] == pytest.approx([0.5])
    from invrender.recipes import split_init

    assert split_init({"sensor.exposure": 0.5, "reflectance": 0.3}, {"shared": ["exposure"]}) == ({"reflectance": 0.3}, {"shared": ["exposure"], "exposure": 0.5})


def test_a_target_whose_square_overflows_is_refused(tmp_path, capsys):
    """A finite target too large for a float32 loss (a corrupt EXR's 1e24): one line naming it."""
    ir.write_image(tmp_path / "huge.exr", torch.full((8, 8, 3), 1e24))
    code = main(["fit", "--scene", "cornell_box", "--target", str(tmp_path / "huge.exr"), "--params", "light.emission", "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and f"{tmp_path / 'huge.exr'} has a value of 1e+24, beyond 1.845e+19" in err[0], err
    assert not (tmp_path / "o").exists()


def test_lm_on_one_of_two_skies_is_refused_before_tracing_naming_both(tmp_path):
    """``fit --solver lm`` of one envmap beside another: the radiances add along escaping rays, so
    path records cannot hold the map and the fit takes re-traced renders, whose Jacobian needs one
    render per texel: refused before any tracing, naming the parameter and the other sky."""
    from tests.conftest import refused

    ir.write_image(tmp_path / "a.exr", torch.full((8, 16, 3), 0.5))
    ir.write_image(tmp_path / "b.exr", torch.full((4, 8, 3), 0.2))
    ir.write_image(tmp_path / "t.exr", torch.full((8, 8, 3), 0.3))
    scene = tmp_path / "skies.toml"
    scene.write_text('[camera]\norigin = [3, 2.5, 3.5]\n[materials.m]\nreflectance = 0.5\n[[shapes]]\ntype = "cube"\nmaterial = "m"\n'
                     '[emitters.sky]\ntype = "envmap"\nemission_texture = "a.exr"\n[emitters.sky2]\ntype = "envmap"\nemission_texture = "b.exr"\n')  # fmt: skip
    line = refused(tmp_path, "fit", "--scene", str(scene), "--target", str(tmp_path / "t.exr"), "--params", "sky.emission", "--solver", "lm", "--quiet")
    assert "sky.emission: emitter 'sky' shares the rays that leave the scene with the other emitter(s) infinitely far away (sky2)" in line
    assert "takes one forward-mode render per texel: sky.emission need 128 per Jacobian, at most 64" in line
