"""Model studies: one fit recipe, several variants (path, utah, utah + eps0), one table."""

import json

import pytest
import torch

from invrender.cli import main
from invrender.errors import ParameterError
from invrender.recipes import apply_init, load_fit_recipe
from invrender.scene import load_scene
from invrender.scene.scene import AMBIENT

DATASET = """
scene = "cornell_box"
resolution = [16, 16]
spp = 256
max_depth = 8
seed = 2
[set]
"white.reflectance" = [0.8, 0.7, 0.6]
"light.emission" = [15, 12, 8]
"""

STUDY = """
dataset = "data.toml"
params = ["white.reflectance", "light.emission"]
[init]                      # start at the truth: a model that explains the target stays there
"white.reflectance" = [0.8, 0.7, 0.6]
"light.emission" = [15, 12, 8]
[fit]
steps = 12
spp = 8
spp_final = 8
lr = 0.05
lr_emission = 0.05
[[variants]]
label = "path"
[[variants]]
label = "utah"
integrator = "utah"
[[variants]]
label = "utah + eps0"
integrator = "utah"
params = ["ambient.emission"]
init = { "ambient.emission" = 0.2 }
"""


def test_study_writes_a_table_and_shows_the_utah_bias(tmp_path, capsys):
    """From the truth, the path model stays within a few percent; utah, which lacks the
    interreflected light of the (path-traced) target, has to brighten white and the light."""
    (tmp_path / "data.toml").write_text(DATASET)
    (tmp_path / "study.toml").write_text(STUDY)
    out = tmp_path / "run"
    assert main(["fit", str(tmp_path / "study.toml"), "--out", str(out), "--quiet"]) == 0
    table = (out / "study.md").read_text()
    assert table.splitlines()[0] == "| parameter | truth | path | utah | utah + eps0 |"
    assert "ambient.emission R" in table and table in capsys.readouterr().out
    data = json.loads((out / "study.json").read_text())
    for folder in ("path", "utah", "utah_eps0"):
        assert (out / folder / "report.json").is_file() and (out / folder / "final.exr").is_file()
    errors = data["errors"]
    assert max(abs(e["path"]) for e in errors.values()) < 0.05
    assert errors["light.emission G"]["utah"] > 0.05  # the missing interreflection, put into eps
    assert data["variants"]["utah"]["integrator"] == "utah"
    assert set(data["recovered"]) == {"ambient.emission R", "ambient.emission G", "ambient.emission B"}


def test_variant_errors(tmp_path):
    (tmp_path / "data.toml").write_text(DATASET)
    bad = STUDY.replace('label = "utah"\n', 'label = "utah"\ncolour = 1\n')
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(ParameterError, match="unknown key 'colour'"):
        load_fit_recipe(tmp_path / "bad.toml")
    (tmp_path / "nolabel.toml").write_text(STUDY.replace('label = "path"\n', 'integrator = "path"\n'))
    with pytest.raises(ParameterError, match="label"):
        load_fit_recipe(tmp_path / "nolabel.toml")


def test_apply_init_starts_an_ambient_term_and_names_win_over_kinds():
    scene = load_scene("cornell_box", resolution=(4, 4))
    names = ["red.reflectance", "white.reflectance", "light.emission", AMBIENT]
    apply_init(scene, names, {"red.reflectance": 0.3, "reflectance": 0.5, "emission": 5.0, AMBIENT: 0.1})
    assert torch.allclose(scene.params["red.reflectance"], torch.full((3,), 0.3))
    assert torch.allclose(scene.params["white.reflectance"], torch.full((3,), 0.5))
    assert torch.allclose(scene.params["light.emission"], torch.full((3,), 5.0))
    assert torch.allclose(scene.params[AMBIENT], torch.full((3,), 0.1))  # not 5: eps0 is not an emitter
