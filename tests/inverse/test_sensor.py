"""The sensor in the model: photographs as targets (JPEG round trip with exposure, white balance
and a saturating light), masks, the sensor's identifiability, and bad inputs."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.errors import ImageError, ParameterError
from invrender.inverse.convergence import ConvergenceWarning
from invrender.inverse.sensor import Sensor, synthetic_photograph
from invrender.io.response import write_response_csv

ALBEDOS = ["white.reflectance", "red.reflectance", "green.reflectance"]
SENSOR = ["sensor.exposure", "sensor.white_balance"]
EXPOSURE, WHITE_BALANCE = 0.6, (0.8, 1.0, 1.25)


def photo_problem(path, resolution=(32, 32), spp=1024, exposure=EXPOSURE, white_balance=WHITE_BALANCE, start=0.5, seed=7):
    """The round trip's problem: the Cornell box photographed as a camera would (exposure, white
    balance, the light clipped, sRGB, 8 bits, JPEG at ``path``), and the scene to fit it with, its
    albedos at ``start`` (the emission known). Returns (scene, truth): truth has every albedo."""
    scene = ir.load_scene("cornell_box", resolution=resolution)
    truth = {n: scene.params[n].clone() for n in ALBEDOS}
    synthetic_photograph(scene, path, exposure, white_balance, spp=spp, max_depth=5, seed=seed)
    with torch.no_grad():
        for n in ALBEDOS:
            scene.params[n].fill_(start)
    return scene, truth


def errors(result, truth) -> dict:
    """Signed relative errors: every albedo channel, the exposure and the white-balance gains."""
    out = {f"{n}[{c}]": float(result.params[n][i] / truth[n][i] - 1) for n in ALBEDOS for i, c in enumerate("RGB")}
    out["exposure"] = float(result.params["sensor.exposure"][0]) / EXPOSURE - 1
    for i, c in ((0, "R"), (2, "B")):
        out[f"white_balance[{c}]"] = float(result.params["sensor.white_balance"][0, i]) / WHITE_BALANCE[i] - 1
    return out


def check_round_trip(err):
    """Every albedo channel, the exposure and the white balance within 3%, and the products the
    image determines well within 1%: a channel's gain and its albedos' scale are told apart only
    through the interreflections (the scale is weakly determined), so both solvers can move a
    channel's split together (white.reflectance[B] -2.8% against white_balance[B] +2.6% in one run:
    their product within 0.3%). That split (white's R and B against their gains) may move by 4%:
    lm's white.reflectance[B] came to -2.2% .. -3.3% over seeds 0-2 with fresh records per round,
    -3.0% .. -5.3% with accumulated ones, 4 standard errors or more: the photograph's 8-bit
    quantization, not sampling noise, sets it."""
    split = {f"white.reflectance[{c}]" for c in "RB"} | {f"white_balance[{c}]" for c in "RB"}
    bad = {k: f"{100 * v:+.2f}%" for k, v in err.items() if abs(v) > (0.04 if k in split else 0.03)}
    assert not bad, bad
    for c in "RB":
        product = (1 + err[f"white.reflectance[{c}]"]) * (1 + err[f"white_balance[{c}]"]) * (1 + err["exposure"]) - 1
        assert abs(product) < 0.01, (c, product)


@pytest.fixture(scope="module")
def photo(tmp_path_factory):
    path = tmp_path_factory.mktemp("photo") / "cornell.jpg"
    scene, truth = photo_problem(path)
    return scene, truth, path


def test_round_trip_lm(photo):
    """The JPEG fitted back with ir.fit's defaults (the model's depth the photograph's): solver
    "auto" takes lm on path records, within the bounds of :func:`check_round_trip`; every albedo
    within 2.5% and every channel's gain (exposure x white balance) within 2%, or named in the
    warning of loosely determined directions with a standard error (the targets' own error, the
    8-bit quantization, included) that covers the truth within two; the light's saturated pixels
    excluded and counted; without the exclusion the same fit is far off (the clipped light reads
    as a dim one)."""
    scene, truth, path = photo
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = ir.fit(scene, path, ALBEDOS + SENSOR, max_depth=5, progress=False)
    err = errors(res, truth)
    print("auto", res.solver, len(res.history), "rounds", {k: f"{100 * v:+.2f}%" for k, v in err.items()})
    assert res.solver == "lm" and res.converged and len(res.history) == 3
    check_round_trip(err)
    loose = " ".join(str(w.message) for w in caught if issubclass(w.category, ConvergenceWarning) and "loosely" in str(w.message))
    se = {f"{n}[{c}]": float(res.std_error[n][i] / res.params[n][i]) for n in ALBEDOS for i, c in enumerate("RGB")}
    for i, c in enumerate("RGB"):
        gain = (1 + err["exposure"]) * (1 + err.get(f"white_balance[{c}]", 0.0)) - 1
        wb = float(res.std_error["sensor.white_balance"][0, i] / res.params["sensor.white_balance"][0, i])
        err[f"gain[{c}]"], se[f"gain[{c}]"] = gain, (float(res.std_error["sensor.exposure"][0] / res.params["sensor.exposure"][0]) ** 2 + wb**2) ** 0.5
    for key, e in err.items():
        if key.startswith(("exposure", "white_balance")) or abs(e) <= (0.02 if key.startswith("gain") else 0.025):
            continue
        named = key.replace("gain", "sensor.white_balance") if key != "gain[G]" else "sensor.exposure"
        assert named in loose and abs(e) < 2 * se[key], (key, e, se[key], loose)
    report = res.targets[0]
    assert report["response"] == "srgb" and report["excluded_saturated"] >= 6 and report["pixels"] == 1024
    assert res.params["sensor.white_balance"][0, 1] == 1.0 and set(res.std_error) == set(ALBEDOS + SENSOR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        biased = ir.fit(scene, path, ALBEDOS + SENSOR, solver="lm", max_depth=5, spp=16, rounds=1, progress=False, exclude_clipped=False)
    worst = max(abs(v) for v in errors(biased, truth).values())
    print("lm without the saturation mask: largest error", f"{100 * worst:.1f}%")
    assert worst > 0.2 and biased.targets[0]["excluded_saturated"] == 0


@pytest.mark.slow
def test_round_trip_adam(photo):
    """The same photograph fitted by Adam."""
    scene, truth, path = photo
    res = ir.fit(scene, path, ALBEDOS + SENSOR, solver="adam", max_depth=5, steps=300, spp=16, spp_final=64, lr=0.1, lr_sensor=0.1, progress=False)
    err = errors(res, truth)
    print("adam", {k: f"{100 * v:+.2f}%" for k, v in err.items()})
    check_round_trip(err)


@pytest.mark.parametrize("solver", ["adam", "lm"])
def test_garbage_under_a_mask_changes_nothing(solver, tmp_path):
    scene = ir.load_scene("cornell_box", resolution=(12, 12))
    target = ir.render(scene, spp=64, max_depth=3, seed=1, progress=False)
    mask = torch.ones(12, 12)
    mask[2:7, 3:9] = 0.0
    mask[9:, :] = 0.5
    garbage = target.clone()
    garbage[2:7, 3:9] = torch.rand(5, 6, 3, generator=torch.Generator().manual_seed(3)) * 0.9  # below any clipping: it counts unless masked
    with torch.no_grad():
        scene.params["white.reflectance"].fill_(0.5)
    kw = dict(max_depth=3, progress=False, solver=solver, spp=8)
    kw.update(rounds=1) if solver == "lm" else kw.update(steps=4, spp_final=8)
    names = ["white.reflectance", "sensor.exposure"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        clean = ir.fit(scene, target, names, mask=mask, **kw)
        dirty = ir.fit(scene, garbage, names, mask=mask, **kw)
        unmasked = ir.fit(scene, garbage, names, **kw)
    for n in names:
        torch.testing.assert_close(dirty.params[n], clean.params[n], rtol=1e-6, atol=1e-7)
    moved = max(float((unmasked.params[n] - clean.params[n]).abs().max()) for n in names)
    assert moved > 1e-3  # the garbage counts without the mask
    # a mask image file (white counts) and a PNG's alpha channel do the same
    from PIL import Image

    Image.fromarray((mask.numpy() * 255).astype(np.uint8), mode="L").save(tmp_path / "mask.png")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from_file = ir.fit(scene, garbage, names, mask=tmp_path / "mask.png", **kw)
    for n in names:
        torch.testing.assert_close(from_file.params[n], clean.params[n], rtol=1e-3, atol=1e-4)  # 0.5 -> 128/255


def test_identifiability_names_the_sensor_ambiguities():
    """Exposure and every emission both free: named, and a numerically undetermined direction;
    fixing either removes it; white balance against the emission's colour likewise; an lm fit
    reports it in its history and warns."""
    scene = ir.load_scene("cornell_box", resolution=(12, 12))
    target = ir.render(scene, spp=64, max_depth=3, seed=1, progress=False)
    kw = dict(spp=16, max_depth=3)
    both = ir.identifiability(scene, target, ["white.reflectance", "light.emission", "sensor.exposure"], **kw)
    assert len(both.sensor) == 1 and both.sensor[0].startswith("sensor.exposure against every emission (light.emission)")
    assert "fix the exposure" in both.sensor[0] and "or one emission" in both.sensor[0]
    assert any("sensor.exposure" in combo and any(k.startswith("light.emission") for k in combo) for combo in both.weak)
    assert "sensor.exposure against every emission" in both.describe()
    for params in (["white.reflectance", "light.emission"], ["white.reflectance", "sensor.exposure"]):
        one = ir.identifiability(scene, target, params, **kw)
        assert one.sensor == () and not any("sensor.exposure" in combo for combo in one.weak), one.describe()
    wb = ir.identifiability(scene, target, ["light.emission", "sensor.white_balance"], **kw)
    assert len(wb.sensor) == 1 and "sensor.white_balance against the emissions' colour" in wb.sensor[0]
    with pytest.warns(UserWarning, match="sensor.exposure against every emission"):
        res = ir.fit(scene, target, ["light.emission", "sensor.exposure"], solver="lm", rounds=1, progress=False, **kw)
    assert "sensor.exposure against every emission" in res.history[-1]["undetermined"]


def test_sensor_options():
    sensor = Sensor.make(3, ["sensor.exposure", "sensor.white_balance"], {"exposure": [1, 2, 3], "shared": ["white_balance"]})
    assert sensor.size == 3 + 2 and sensor.labels() == ["sensor.exposure[v0]", "sensor.exposure[v1]", "sensor.exposure[v2]", "sensor.white_balance[R]", "sensor.white_balance[B]"]
    torch.testing.assert_close(sensor.gains(sensor.to_raw())[:, 1], torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    for options, message in (
        ({"iso": 100}, "unknown sensor option 'iso'"),
        ({"white_balance": [1.2, 0.9, 1.0]}, "green gain is fixed at 1"),
        ({"exposure": -1}, "must be positive"),
        ({"shared": ["gamma"]}, "'gamma' is not"),
        ({"exposure": [1, 2]}, "one per view"),
    ):
        with pytest.raises(ParameterError, match=message):
            Sensor.make(3, [], options)


def test_bad_photo_inputs_name_the_file(tmp_path):
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    photo = tmp_path / "photo.png"
    synthetic_photograph(scene, photo, 0.6, spp=4, max_depth=2)
    names = ["white.reflectance"]
    kw = dict(progress=False, steps=1)
    with pytest.raises(ImageError, match=r"photo\.png: unknown response 'sepia'"):
        ir.fit(scene, photo, names, response="sepia", **kw)
    bent = tmp_path / "bent.csv"
    write_response_csv(bent, [0, 0.5, 1], [[0, 0, 0], [0.6, 0.5, 0.5], [0.5, 1, 1]])
    with pytest.raises(ImageError, match=r"bent\.csv: not monotonic: the red column"):
        ir.fit(scene, photo, names, response=bent, **kw)
    from PIL import Image

    Image.new("L", (9, 8), 255).save(tmp_path / "wide.png")
    with pytest.raises(ImageError, match=r"mask .*wide\.png is 9x8 but the target .*photo\.png is 8x8"):
        ir.fit(scene, photo, names, mask=tmp_path / "wide.png", **kw)
    Image.new("L", (8, 8), 0).save(tmp_path / "black.png")
    with pytest.raises(ImageError, match=r"mask .*black\.png excludes every pixel of .*photo\.png"):
        ir.fit(scene, photo, names, mask=tmp_path / "black.png", **kw)
    big = ir.load_scene("cornell_box", resolution=(10, 8))
    with pytest.raises(ImageError, match=r"photo\.png is 8x8 but the scene renders 10x8"):
        ir.fit(big, photo, names, **kw)
    with pytest.raises(ParameterError, match="unknown parameter 'sensor.iso'"):
        ir.fit(scene, photo, ["sensor.iso"], **kw)
    synthetic_photograph(scene, tmp_path / "white.png", 1000.0, spp=4, max_depth=2)
    with pytest.raises(ImageError, match=r"white\.png is saturated or 0"):
        ir.fit(scene, tmp_path / "white.png", names, **kw)


def test_cli_fits_a_photograph_with_a_mask(tmp_path, capsys):
    import json

    from PIL import Image

    from invrender.cli import main

    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    synthetic_photograph(scene, tmp_path / "photo.png", 0.6, spp=16, max_depth=2)
    Image.new("L", (8, 8), 255).save(tmp_path / "mask.png")
    argv = ["fit", "--scene", "cornell_box", "--target", str(tmp_path / "photo.png"), "--params", "white.reflectance,sensor.exposure",
            "--mask", str(tmp_path / "mask.png"), "--response", "srgb", "--steps", "2", "--spp", "2", "--spp-final", "2", "--max-depth", "2", "--quiet"]  # fmt: skip
    assert main([*argv, "--out", str(tmp_path / "run")]) == 0
    report = json.loads((tmp_path / "run" / "report.json").read_text())
    assert report["pixels"][0]["response"] == "srgb" and report["pixels"][0]["excluded_saturated"] > 0
    assert len(report["recovered"]["sensor.exposure"]) == 1
    assert main([*argv, "--response", "sepia", "--out", str(tmp_path / "bad")]) == 2
    assert "unknown response 'sepia'" in capsys.readouterr().err


def test_a_recipe_fits_with_a_mask_and_the_sensor(tmp_path):
    """A fit recipe's [photo] table: the mask (relative to the recipe) and sensor options reach the
    fit; a key it does not know is an error naming the file."""
    from PIL import Image

    from invrender.recipes import load_fit_recipe
    from invrender.study.recipe_fits import fit_recipe

    (tmp_path / "data.toml").write_text('scene = "cornell_box"\nresolution = [8, 8]\nspp = 16\nmax_depth = 2\n')
    mask = np.full((8, 8), 255, dtype=np.uint8)
    mask[:4] = 0
    Image.fromarray(mask, mode="L").save(tmp_path / "half.png")
    body = 'dataset = "data.toml"\nparams = ["white.reflectance", "sensor.exposure"]\n[fit]\nsteps = 2\nspp = 2\nspp_final = 2\nmax_depth = 2\n'
    (tmp_path / "fit.toml").write_text(body + '[photo]\nmask = "half.png"\nsensor = { exposure = 0.9 }\n')
    recipe = load_fit_recipe(tmp_path / "fit.toml")
    assert recipe.photo == {"mask": str(tmp_path / "half.png"), "sensor": {"exposure": 0.9}}
    done = fit_recipe(recipe, tmp_path / "run", progress=False)
    result = done.fits[""].result
    assert result.targets[0]["counting"] == 32 and result.initial["sensor.exposure"].tolist() == pytest.approx([0.9])
    (tmp_path / "bad.toml").write_text(body + "[photo]\niso = 100\n")
    with pytest.raises(ParameterError, match=r"bad\.toml \[photo\].*iso"):
        load_fit_recipe(tmp_path / "bad.toml")
