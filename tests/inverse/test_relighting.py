"""Relighting as a product (invrender/inverse/relighting.py): ``invrender fit`` of an environment
map writes the map, its standard errors, its identifiability and a labelled figure of the views
relit, held-out ones included; bad input is one line; ``ir.lighting.relight`` puts the recovered
map into another scene in one call."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest
import torch
from PIL import Image

import invrender as ir
from invrender.cli import main
from invrender.errors import ParameterError
from invrender.scene.camera import Camera
from invrender.scene.formats.cameras import write_transforms

HIDDEN = {"type": "path", "hide_emitters": True}
MAP = (16, 32)  # sky_spheres' own map size, which --scene sky_spheres takes


def view(azimuth: float) -> Camera:
    a = math.radians(azimuth)
    return Camera(origin=(4.2 * math.sin(a), 0.35, 4.2 * math.cos(a)), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Four 10 x 10 views of sky_spheres (background hidden) written as a transforms.json with
    their renders as the images, and the true map as an EXR."""
    folder = tmp_path_factory.mktemp("sky")
    truth = ir.load_scene("sky_spheres", resolution=(10, 10))
    cams = [view(a) for a in (0, 120, 240, 60)]
    images = [folder / f"view_{i}.exr" for i in range(len(cams))]
    for i, (cam, path) in enumerate(zip(cams, images)):
        ir.write_image(path, ir.render(truth.with_camera(cam), HIDDEN, spp=128, max_depth=2, seed=i, progress=False))
    write_transforms(folder / "transforms.json", cams, (10, 10), images)
    ir.write_image(folder / "truth.exr", truth.params["sky.emission"])
    return folder


FIT = ["fit", "--scene", "sky_spheres", "--params", "sky.emission", "--init", "sky.emission=1", "--integrator", "path", "--set", "hide_emitters=true", "--max-depth", "2", "--spp-final", "16", "--quiet"]


def test_fit_cli_writes_the_relighting_product(dataset, tmp_path):
    """Three views fitted, the fourth held out: map.exr and stderr.exr are the map's shape, finite
    and >= 0, resolution.png one pixel a texel, in [0, 1] set by the images along the seen band; the
    figure's panels (4 maps, 4 views x target and relit) on a 4-column grid; report.json's
    relighting errors per view, by its number in the file, the held-out one within a few percent
    on the channel means; the map's error against --truth."""
    out = tmp_path / "run"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # texels no view sees
        assert main(FIT + ["--cameras", str(dataset / "transforms.json"), "--held-out", "3", "--truth", f"sky.emission={dataset / 'truth.exr'}", "--out", str(out)]) == 0
    recovered, stderr = ir.read_image(out / "map.exr"), ir.read_image(out / "stderr.exr")
    assert recovered.shape == stderr.shape == (*MAP, 3)
    assert bool(torch.isfinite(recovered).all() and torch.isfinite(stderr).all()) and float(recovered.min()) >= 0 and float(stderr.max()) > 0
    resolution = np.asarray(Image.open(out / "resolution.png"))
    assert resolution.shape == (*MAP, 3) and (resolution[-1] == (68, 1, 84)).all()  # the nadir row, below the floor: viridis' 0, set by the prior
    assert resolution[:, :, 1].max() > 10  # brighter where the views see the map (three 10 x 10 views determine few of 512 texels)
    assert Image.open(out / "relighting.png").size[0] > 4 * Image.open(out / "relighting.png").size[1] / 3  # 4 columns, 3 rows
    assert ir.read_image(out / "heldout.exr").shape == (10, 10, 3) and (out / "final_02.exr").exists() and not (out / "final_03.exr").exists()
    report = json.loads((out / "report.json").read_text())
    assert report["solver"] == "transport_matrix" and report["held_out"]["views"] == [3]
    assert list(report["relighting"]) == ["view 0 (fitted)", "view 1 (fitted)", "view 2 (fitted)", "view 3 (held out)"]
    held = report["relighting"]["view 3 (held out)"]
    assert max(abs(m) for m in held["channel_means"]) < 0.05 and 0 < held["rmse"] < 0.4, held
    assert report["truth"]["sky.emission"] == ir.read_image(dataset / "truth.exr").tolist() and report["relative_error"]["sky.emission"] > 0
    torch.testing.assert_close(recovered, torch.tensor(report["recovered"]["sky.emission"]))


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--target", "{d}/view_0.exr", "--held-out", "1"], "--held-out names views of --cameras (0-based, in the file's order): give --cameras"),
        (["--cameras", "{d}/transforms.json", "--held-out", "4"], "--held-out 4: {d}/transforms.json has 4 views (0 to 3)"),
        (["--cameras", "{d}/transforms.json", "--held-out", "0", "1", "2", "3"], "--held-out leaves none of the 4 views"),
        (["--cameras", "{d}/transforms.json", "--target", "{d}/view_0.exr", "{d}/view_1.exr", "{d}/view_2.exr", "--held-out", "3"], "--target: 3 image(s) for the 4 views of {d}/transforms.json: give one per view, the held-out ones too"),
        (["--cameras", "{d}/transforms.json", "--truth", "sky.emission"], "--truth expects NAME=VALUE, NAME=R,G,B or NAME=IMAGE, got 'sky.emission'"),
        (["--cameras", "{d}/transforms.json", "--truth", "sky.emission=1,2"], "--truth sky.emission: cannot read image 1,2"),
    ],
)
def test_fit_cli_bad_held_out_or_truth_is_one_line(dataset, tmp_path, capsys, extra, words):
    extra = [e.format(d=dataset) for e in extra]
    assert main(FIT + extra + ["--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words.format(d=dataset) in err[0], err
    assert not (tmp_path / "o" / "report.json").exists()


def test_held_out_views_need_an_environment_map_fit(dataset, tmp_path, capsys):
    """Held-out views are relit under a recovered map: with another parameter it is refused before
    the fit (nothing written)."""
    args = [a if a != "sky.emission" else "floor.reflectance" for a in FIT if a != "--init" and a != "sky.emission=1"]
    assert main(args + ["--cameras", str(dataset / "transforms.json"), "--held-out", "3", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "held-out views are relit under a recovered environment map" in err[0] and not (tmp_path / "o").exists()


@pytest.fixture(scope="module")
def fitted():
    """ir.fit of sky_spheres' 8 x 16 map from two 10 x 10 views: a FitResult of the transport matrix."""
    truth = ir.load_scene("sky_spheres", resolution=(10, 10), map_size=(8, 16))
    cams = [view(0), view(180)]
    targets = [ir.render(truth.with_camera(c), HIDDEN, spp=128, max_depth=2, seed=i, progress=False) for i, c in enumerate(cams)]
    flat = truth.with_params({"sky.emission": torch.ones(8, 16, 3)}, detach=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = ir.fit(flat, targets, ["sky.emission"], cameras=cams, integrator=HIDDEN, max_depth=2, spp_final=16, progress=False)
    assert res.solver == "transport_matrix" and res.resolution["sky.emission"].shape == (8, 16, 3)
    return res


def test_relight_renders_another_scene_under_the_recovered_map_in_one_call(fitted, tmp_path):
    """A scene with an environment map of another size gets the recovered map: its render equals,
    to the bit, that of the scene built with that map; a scene without one (the Cornell box) gets
    it added as a new emitter with the fitted emitter's constants, and the light coming in through
    its open side brightens it; a map file written by the fit relights the same way."""
    recovered = fitted.params["sky.emission"]
    other = ir.load_scene("sky_spheres", resolution=(8, 8), map_size=(4, 8), subdivisions=2)
    relit = ir.lighting.relight(other, fitted)
    assert relit.params["sky.emission"].shape == (8, 16, 3) and other.params["sky.emission"].shape == (4, 8, 3)  # the input is left alone
    built = ir.load_scene("sky_spheres", resolution=(8, 8), map_size=(8, 16), subdivisions=2, sky=recovered)
    torch.testing.assert_close(ir.render(relit, HIDDEN, spp=8, max_depth=2, seed=5, progress=False), ir.render(built, HIDDEN, spp=8, max_depth=2, seed=5, progress=False), rtol=0, atol=0)

    box = ir.load_scene("cornell_box", resolution=(8, 8))
    lit = ir.lighting.relight(box, fitted)
    assert lit.emitters == (*box.emitters, "sky") and lit.emitter_spec(len(box.emitters)) == fitted.scene.emitter_spec(fitted.scene.emitters.index("sky"))
    torch.testing.assert_close(lit.params["sky.emission"], recovered)
    dark, bright = (ir.render(s, spp=32, max_depth=2, seed=1, progress=False).mean() for s in (box, lit))
    assert bool(torch.isfinite(bright)) and float(bright) > 1.2 * float(dark)

    ir.write_image(tmp_path / "map.exr", recovered)
    from_file = ir.lighting.relight("cornell_box", tmp_path / "map.exr")
    torch.testing.assert_close(from_file.params["sky.emission"], recovered)


def test_relight_names_what_it_cannot_use(fitted):
    box = ir.load_scene("cornell_box", resolution=(8, 8))
    sky = ir.load_scene("sky_spheres", resolution=(8, 8), map_size=(4, 8))
    with pytest.raises(ParameterError, match=r"cornell_box has no environment map 'skye' \(environment maps: none\)"):
        ir.lighting.relight(box, fitted, emitter="skye")
    with pytest.raises(ParameterError, match=r"no environment map 'skye' \(did you mean 'sky'\?\)"):
        ir.lighting.relight(sky, fitted, emitter="skye")
    with pytest.raises(ParameterError, match=r"relight takes the lighting of a scene with one environment map; cornell_box has 0"):
        ir.lighting.relight(sky, box)
    with pytest.raises(ParameterError, match=r"relight: the map must be \(h, w, 3\)"):
        ir.lighting.relight(sky, torch.ones(3))
    with pytest.raises(ParameterError, match="relight takes a FitResult, a MapFit"):
        ir.lighting.relight(sky, 3.0)
