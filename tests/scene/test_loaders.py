"""Scene files: the TOML format, glTF/GLB and OBJ through trimesh, and their errors."""

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import invrender as ir
from invrender.errors import ParameterError, SceneError

FORWARD = Path(__file__).parents[2] / "forward"


def test_toml_cornell_box_equals_builtin():
    a = ir.load_scene("cornell_box", resolution=(32, 32))
    b = ir.load_scene(FORWARD / "cornell_box.toml", resolution=(32, 32))
    assert torch.allclose(a.triangles.corners(), b.triangles.corners(), atol=1e-6)
    assert torch.equal(a.triangles.material, b.triangles.material) and torch.equal(a.triangles.emitter, b.triangles.emitter)
    assert a.camera == b.camera and a.materials == b.materials and a.emitters == b.emitters
    assert all(torch.equal(a.params[k], b.params[k]) for k in a.params)
    assert torch.equal(ir.render(a, spp=2, progress=False), ir.render(b, spp=2, progress=False))
    assert ir.load_scene(FORWARD / "cornell_box.toml").resolution == (256, 256)


def write(tmp_path, text, name="s.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


BASE = """
[materials.m]
reflectance = 0.5
[[shapes]]
type = "rectangle"
material = "m"
"""


def test_transform_steps_apply_in_listed_order(tmp_path):
    path = write(tmp_path, BASE + 'transform = [{ scale = 2 }, { rotate = { axis = [0, 0, 1], angle = 90 } }, { translate = [10, 0, 0] }]\n')
    corners = ir.load_scene(path).triangles.corners()[0]  # rectangle vertices 0, 1, 2 = (-1,-1), (1,-1), (1,1)
    expected = torch.tensor([[12.0, -2, 0], [12, 2, 0], [8, 2, 0]])  # scaled by 2, turned 90 degrees about z, then moved
    assert torch.allclose(corners, expected, atol=1e-5)


@pytest.mark.parametrize(
    "text, words",
    [
        (BASE + "colour = 1\n", "unknown key 'colour'"),
        (BASE.replace("reflectance = 0.5", "reflectance = 'grey'"), "must be a list of 3 numbers"),
        (BASE.replace("reflectance = 0.5", "reflectance = [0.5, 0.5]"), "must be a list of 3 numbers"),
        (BASE + "[camera]\nfov = 'wide'\n", "'fov' must be a number"),
        (BASE.replace('type = "rectangle"', 'type = "cone"'), "unknown shape type 'cone'"),
        (BASE.replace('material = "m"', 'material = "x"'), "unknown material 'x'"),
        (BASE + 'type2 = 1\n', "unknown key 'type2'"),
        (BASE.replace('type = "rectangle"', 'type = "mesh"') + 'file = "nope.obj"\n', "mesh file not found"),
        ("resolution = [16, \n", "invalid TOML"),
        (BASE + "transform = [{ shear = 1 }]\n", "unknown transform step 'shear'"),
    ],
)
def test_bad_scene_files_give_one_line_errors(tmp_path, text, words):
    with pytest.raises(SceneError) as e:
        ir.load_scene(write(tmp_path, text))
    assert words in str(e.value) and "\n" not in str(e.value)


def test_out_of_range_values_and_missing_files(tmp_path):
    with pytest.raises(ParameterError, match="m.reflectance"):
        ir.load_scene(write(tmp_path, BASE.replace("reflectance = 0.5", "reflectance = 1.5")))
    with pytest.raises(SceneError, match="not found"):
        ir.load_scene(tmp_path / "missing.toml")
    (tmp_path / "broken.obj").write_bytes(b"\x00\x01garbage")
    with pytest.raises(SceneError, match="broken.obj"):
        ir.load_scene(tmp_path / "broken.obj")


def test_reflectance_texture_from_png(tmp_path):
    Image.fromarray(np.full((4, 8, 3), 188, dtype=np.uint8)).save(tmp_path / "albedo.png")
    path = write(tmp_path, BASE.replace("reflectance = 0.5", 'reflectance_texture = "albedo.png"'))
    rho = ir.load_scene(path).params["m.reflectance"]
    assert rho.shape == (4, 8, 3) and torch.allclose(rho, torch.full_like(rho, 0.5), atol=0.005)


def test_mesh_in_box_scene():
    scene = ir.load_scene(FORWARD / "mesh_in_box.toml")
    assert scene.triangles.count == 5 * 2 + 576 + 2
    assert "torus.reflectance" in scene.params and "panel.emission" in scene.params


def test_glb_materials_emission_strength_and_camera():
    scene = ir.load_scene(FORWARD / "meshes" / "lamp.glb")
    assert torch.allclose(scene.params["floor.reflectance"], torch.tensor([0.6, 0.5, 0.4]))
    assert torch.allclose(scene.params["lamp_emission.emission"], torch.tensor([1.0, 0.8, 0.5]) * 12.0)
    assert scene.camera.origin == (0.0, 0.5, 3.0) and scene.camera.fov_axis == "y"
    assert abs(scene.camera.fov - np.degrees(0.8)) < 1e-9
    assert scene.resolution == (384, 256)  # aspectRatio 1.5
    img = ir.render(scene.with_resolution((24, 16)), spp=4, max_depth=2, progress=False)
    assert img.shape == (16, 24, 3) and img.max() > 0


def test_obj_loads_with_default_camera():
    scene = ir.load_scene(FORWARD / "meshes" / "torus.obj", resolution=(16, 16))
    assert scene.triangles.count == 576 and scene.emitters == ()
    assert torch.count_nonzero(ir.render(scene, spp=1, progress=False)) == 0  # nothing emits
