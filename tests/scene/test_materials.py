"""Material types and the thin-lens camera in TOML scene files: what loads, and the one-line errors."""

from __future__ import annotations

import pytest
import torch

import invrender as ir
from invrender.cli import main
from invrender.errors import InvRenderError, ParameterError, SceneError
from invrender.scene.kinds import KINDS, kind_of
from invrender.scene.materials import MATERIAL_TYPES, Material

SCENE = """
[camera]
origin = [0, 0, 3]
{camera}

[materials.floor]
{floor}

[materials.chrome]
type = "mirror"
specular_reflectance = [0.9, 0.8, 0.7]

[materials.glass]
type = "dielectric"
ior = 1.33

[materials.brushed]
type = "glossy"
roughness = 0.3
specular_reflectance = 0.5

[emitters.lamp]
emission = 5

[[shapes]]
type = "rectangle"
material = "floor"

[[shapes]]
type = "sphere"
material = "chrome"
subdivisions = 1
transform = [{{ scale = 0.3 }}, {{ translate = [0.5, 0, 0.5] }}]

[[shapes]]
type = "cube"
material = "glass"
transform = [{{ scale = 0.2 }}, {{ translate = [-0.5, 0, 0.5] }}]

[[shapes]]
type = "cube"
material = "brushed"
transform = [{{ scale = 0.2 }}, {{ translate = [0, 0.5, 0.5] }}]

[[shapes]]
type = "rectangle"
material = "floor"
emitter = "lamp"
transform = [{{ scale = 0.2 }}, {{ rotate = {{ axis = [1, 0, 0], angle = 180 }} }}, {{ translate = [0, 0, 2] }}]
"""


def write(tmp_path, floor='reflectance = [0.5, 0.4, 0.3]', camera=""):
    path = tmp_path / "scene.toml"
    path.write_text(SCENE.format(floor=floor, camera=camera))
    return path


def test_material_types_load_with_their_parameters_and_constants(tmp_path):
    scene = ir.load_scene(write(tmp_path, camera="aperture_radius = 0.05\nfocus_distance = 2.5"), resolution=(16, 16))
    types = {m: scene.material_spec(i).type for i, m in enumerate(scene.materials)}
    assert types == {"floor": "diffuse", "chrome": "mirror", "glass": "dielectric", "brushed": "glossy"}
    assert scene.material_spec(2).constants == {"ior": 1.33}
    assert scene.material_spec(3).constants == {"eta": (0.0, 0.0, 0.0), "k": (1.0, 1.0, 1.0), "alpha_v": 0.0}  # material none, isotropic
    assert set(scene.params) == {"floor.reflectance", "chrome.specular_reflectance", "brushed.specular_reflectance", "brushed.roughness", "lamp.emission", "chrome.normals"}  # the sphere's vertex normals
    torch.testing.assert_close(scene.params["brushed.roughness"], torch.full((3,), 0.3))  # a parameter now (differentiable)
    torch.testing.assert_close(scene.params["brushed.specular_reflectance"], torch.full((3,), 0.5))
    assert scene.camera.aperture_radius == 0.05 and scene.camera.focus_distance == 2.5
    assert bool(scene.triangles.smooth[scene.triangles.material == 1].all())  # the sphere shades smoothly
    assert not bool(scene.triangles.smooth[scene.triangles.material != 1].any())
    img = ir.render(scene, spp=4, max_depth=4, progress=False)
    assert torch.isfinite(img).all() and float(img.mean()) > 0


def test_type_defaults_to_diffuse_and_defaults_follow_mitsuba(tmp_path):
    scene = ir.load_scene(write(tmp_path, floor=""), resolution=(8, 8))
    torch.testing.assert_close(scene.params["floor.reflectance"], torch.full((3,), 0.5))
    m = Material.of("glossy")
    assert m.constants == {"eta": (0.0, 0.0, 0.0), "k": (1.0, 1.0, 1.0), "alpha_v": 0.0} and m.values == {"specular_reflectance": 1.0, "roughness": 0.1}
    assert Material.of("dielectric").constants == {"ior": 1.5}


def test_every_kind_and_type_is_registered_once():
    principled = {"base_color", "metallic", "spec_tint", "anisotropic", "sheen", "sheen_tint", "clearcoat", "clearcoat_gloss", "spec_trans", "flatness"}
    assert set(KINDS) == {"reflectance", "specular_reflectance", "emission", "roughness", *principled, "weight", "opacity", "normals", "normalmap"}
    assert kind_of("white.reflectance").reparam == "sigmoid" and kind_of("light.emission").reparam == "exp"
    assert kind_of("a.b.specular_reflectance").upper == 1.0
    with pytest.raises(ParameterError, match="not a parameter name"):
        kind_of("red.albedo")
    for spec in MATERIAL_TYPES.values():
        for kind, _ in spec.params.values():
            assert kind.key in KINDS


@pytest.mark.parametrize(
    "floor, camera, message",
    [
        ('type = "hair"', "", r"\[materials.floor\]: unknown material type 'hair' \(known: diffuse, mirror, dielectric, glossy, glossy_beckmann, plastic, roughplastic, roughplastic_ggx, roughdielectric, roughdielectric_ggx, thindielectric, principled, principledthin, pplastic, pplastic_ggx, blendbsdf, mask\)"),
        ('type = "diffuse"\nroughness = 0.2', "", r"\[materials.floor\]: unknown key 'roughness'"),
        ('type = "glossy"\nroughness = 0', "", r"floor.roughness: roughness alpha must lie in \(0, 1\], got values in \[0, 0\]"),
        ('type = "glossy"\nroughness = 1.5', "", r"floor.roughness: roughness alpha must lie in \(0, 1\], got values in \[1.5, 1.5\]"),
        ('type = "dielectric"\nior = 0', "", r"'ior' must lie in \[0.01, 100\], got 0"),
        ('type = "dielectric"\nior = -1.5', "", r"'ior' must lie in \[0.01, 100\], got -1.5"),
        ('type = "dielectric"\nior = 1e6', "", r"'ior' must lie in \[0.01, 100\], got 1e\+06"),
        ('type = "dielectric"\nior = "glass"', "", r"'ior' must be a finite number, got 'glass'"),
        ('type = "mirror"\nspecular_reflectance = [1.2, 0.5, 0.5]', "", r"floor.specular_reflectance: specular_reflectance k_s must lie in \[0, 1\], got values in \[0.5, 1.2\]"),
        ('type = "mirror"\nspecular_reflectance_texture = "x.png"', "", r"unknown key 'specular_reflectance_texture'"),
        ("", "aperture_radius = -0.1", r"\[camera\]: camera aperture_radius must be >= 0 \(0 = pinhole\), got -0.1"),
        ("", "focus_distance = 0", r"\[camera\]: camera focus_distance must be positive, got 0"),
        ("", "target = [0, nan, 0]", r"\[camera\]: 'target' must be 3 finite numbers, got \[0, nan, 0\]"),
        ("", "up = [0, 1e39, 0]", r"\[camera\]: camera up must be 3 finite numbers \(\|x\| <= 3.403e\+38\), got \[0.0, 1e\+39, 0.0\]"),
    ],
)
def test_bad_materials_and_lenses_give_one_line_errors(tmp_path, floor, camera, message):
    path = write(tmp_path, floor=floor, camera=camera)
    with pytest.raises(InvRenderError, match=message) as info:
        ir.load_scene(path)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, (SceneError, ParameterError))
    # the CLI: one line, status 2, nothing written
    out = tmp_path / "out.exr"
    assert main(["render", str(path), "--out", str(out), "--spp", "1", "--quiet"]) == 2
    assert not out.exists()


def test_render_rejects_settings_the_integrator_does_not_have():
    scene = ir.load_scene("cornell_box", resolution=(4, 4))
    with pytest.raises(ParameterError, match="integrator 'whitted' has no setting 'rr_depth'"):
        ir.render(scene, "whitted", rr_depth=3, spp=1)
    with pytest.raises(ParameterError, match="whitted needs a finite max_depth >= 1, got -1"):
        ir.render(scene, "whitted", max_depth=-1, spp=1)
    with pytest.raises(ParameterError, match="unknown integrator 'kajiya'"):
        ir.render(scene, "kajiya", spp=1)


def test_pyrender_baseline_refuses_non_diffuse_materials_before_any_gl():
    from invrender.baseline.pyrender_baseline import pyrender_render
    from invrender.errors import BaselineError

    with pytest.raises(BaselineError, match="diffuse materials only .* material 'mirror' is mirror"):
        pyrender_render(ir.load_scene("cornell_specular", resolution=(8, 8), subdivisions=0))
