"""A scene file's render settings (``scene.defaults``: a Mitsuba ``<integrator>`` and ``<sampler>``)
are the defaults of ``ir.render``, fits, studies and ``invrender render``; a setting given wins
and the file's is reported as overridden."""

import warnings

import pytest
import torch

import invrender as ir
from invrender.cli import main
from invrender.estimators.defaults import SettingOverridden, fit_settings, scene_integrator
from invrender.inverse.fit import FitSettings
from invrender.study.configs import GradientConfig

SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="{depth}"/>{extra}</integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 2.5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
    </sensor>
    <shape type="cube"><boolean name="flip_normals" value="true"/><bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.8, 0.8"/></bsdf>
        <transform name="to_world"><scale value="3"/></transform></shape>
    <shape type="sphere"><transform name="to_world"><scale value="0.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.6, 0.7"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="90"/><translate y="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="10, 10, 10"/></emitter></shape>
</scene>
"""


def scene_file(tmp_path, depth=6, spp=3, extra='<integer name="rr_depth" value="-1"/>'):
    path = tmp_path / f"d{depth}.xml"
    path.write_text(SCENE.format(depth=depth, spp=spp, extra=extra))
    return path


def quiet_render(scene, **kw):
    """A render that must not warn about overridden settings."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", SettingOverridden)
        return ir.render(scene, progress=False, **kw)


def test_file_depth_and_spp_are_the_defaults(tmp_path):
    scene = ir.load_scene(scene_file(tmp_path))
    assert scene.defaults == {"integrator": "path", "max_depth": 6, "rr_depth": -1, "spp": 3}
    image = quiet_render(scene)
    assert torch.equal(image, quiet_render(scene, integrator="path", max_depth=6, spp=3))
    assert torch.equal(image, quiet_render(scene, max_depth=6))  # the same as the file's: nothing to report
    assert torch.equal(image, quiet_render(scene, integrator={"type": "path", "max_depth": 6}, spp=3))
    assert torch.equal(image, quiet_render(scene, integrator="path"))  # the file's integrator keeps its settings
    # not the invrender defaults (max_depth 8, 64 spp): in this closed box without roulette every
    # path lives to the file's depth (terms=True gives one image per term reached)
    assert quiet_render(scene, terms=True).shape[0] == 6 and quiet_render(scene, integrator=ir.integrators.Path(max_depth=8, rr_depth=-1), terms=True, spp=3).shape[0] == 8
    assert not torch.equal(image, quiet_render(scene, integrator=ir.integrators.Path(max_depth=8, rr_depth=-1), spp=3))
    assert not torch.equal(image, quiet_render(scene, max_depth=6, spp=64))


def test_explicit_setting_wins_and_says_so(tmp_path):
    scene = ir.load_scene(scene_file(tmp_path))
    with pytest.warns(SettingOverridden, match=r"scene 'd6': max_depth=3 overrides the file's max_depth 6") as record:
        image = ir.render(scene, max_depth=3, progress=False)
    assert len(record) == 1
    assert torch.equal(image, quiet_render(scene, integrator=ir.integrators.Path(max_depth=3, rr_depth=-1), spp=3))
    with pytest.warns(SettingOverridden, match=r"integrator 'random_walk' replaces the file's 'path' and its settings \(max_depth 6, rr_depth -1\)"):
        ir.render(scene, "random_walk", progress=False)
    spec, overridden = scene_integrator(scene, {"type": "path", "rr_depth": 2}, {"max_depth": 4})
    assert spec == {"type": "path", "max_depth": 4, "rr_depth": 2}
    assert overridden == ["rr_depth=2 overrides the file's rr_depth -1", "max_depth=4 overrides the file's max_depth 6"]
    # spp changes the noise only: taken, not warned about
    assert quiet_render(scene, spp=1).shape == (6, 8, 3)


def test_fit_and_study_take_the_file_integrator(tmp_path):
    scene = ir.load_scene(scene_file(tmp_path, extra='<integer name="rr_depth" value="2"/>'))
    settings = fit_settings(scene, {"steps": 3})
    assert FitSettings(**settings).model.settings.max_depth == 6 and FitSettings(**settings).model.settings.rr_depth == 2
    assert FitSettings(**settings).spp == FitSettings().spp  # a fit's spp schedule is its own
    with pytest.warns(SettingOverridden, match="max_depth=3 overrides the file's max_depth 6"):
        settings = fit_settings(scene, {"max_depth": 3})
    assert FitSettings(**settings).model.settings.max_depth == 3 and FitSettings(**settings).model.settings.rr_depth == 2
    assert fit_settings(ir.load_scene("cornell_box"), {"steps": 3}) == {"steps": 3}
    # a study's gradient renders take the same integrator as its forward renders
    config = GradientConfig()
    assert config.integrator_and_settings(1, 0, scene)[0].settings.max_depth == 6
    assert config.integrator_and_settings(1, 0)[0].settings.max_depth == 8


def test_fit_renders_at_the_file_depth(tmp_path):
    scene = ir.load_scene(scene_file(tmp_path, depth=2))
    target = quiet_render(scene, spp=4)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SettingOverridden)
        result = ir.fit(scene, target, [next(k for k in scene.params if k.endswith(".reflectance"))], steps=1, spp=1, spp_final=1, progress=False)
    assert result.settings.model.settings.max_depth == 2


def test_cli_honours_the_file_and_reports_overrides(tmp_path, capsys):
    path = scene_file(tmp_path)
    out = tmp_path / "o.exr"
    assert main(["render", str(path), "--out", str(out), "--seed", "1"]) == 0
    err = capsys.readouterr().err
    assert ", 3 spp," in err and "overrides" not in err
    scene = ir.load_scene(path)
    expected = quiet_render(scene, seed=1)
    assert torch.allclose(ir.read_image(out), expected)
    assert main(["render", str(path), "--out", str(out), "--max-depth", "3", "--spp", "2"]) == 0
    err = capsys.readouterr().err
    assert "max_depth=3 overrides the file's max_depth 6" in err and "--spp overrides the file's 3 spp" in err
    with pytest.warns(SettingOverridden):
        expected = ir.render(scene, max_depth=3, spp=2, progress=False)
    assert torch.allclose(ir.read_image(out), expected)


@pytest.mark.parametrize("name", ["cornell_box", "furnace"])
def test_builtin_scenes_unchanged(name):
    scene = ir.load_scene(name, resolution=(8, 8))
    assert scene.defaults == {}
    image = quiet_render(scene, spp=2)
    assert torch.equal(image, quiet_render(scene, integrator="path", spp=2))
    assert torch.equal(quiet_render(scene), quiet_render(scene, integrator=ir.integrators.Path(), spp=64))
