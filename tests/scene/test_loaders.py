"""Scene files: the TOML format, glTF/GLB and OBJ through trimesh, and their errors."""

import base64
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import invrender as ir
from invrender.errors import ParameterError, SceneError
from invrender.scene.builtin import cornell_box
from invrender.scene.camera import Camera
from invrender.scene.loaders import load_mesh_file, load_toml

FORWARD = Path(__file__).parents[2] / "forward"


def test_toml_cornell_box_equals_builtin():
    a = cornell_box(resolution=(32, 32))
    b = load_toml(FORWARD / "cornell_box.toml", resolution=(32, 32))
    for field in ("p0", "e1", "e2", "normal", "area", "uv"):
        assert torch.allclose(getattr(a.triangles, field), getattr(b.triangles, field), atol=1e-6), field
    assert torch.equal(a.triangles.material, b.triangles.material) and torch.equal(a.triangles.emitter, b.triangles.emitter)
    assert a.camera == b.camera and a.materials == b.materials and a.emitters == b.emitters and a.name == b.name
    assert a.params.keys() == b.params.keys() and all(torch.equal(a.params[k], b.params[k]) for k in a.params)
    assert torch.equal(ir.render(a, spp=2, progress=False), ir.render(b, spp=2, progress=False))
    assert load_toml(FORWARD / "cornell_box.toml").resolution == (256, 256)


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


def test_minimal_file_defaults(tmp_path):
    scene = load_toml(write(tmp_path, BASE))
    assert scene.resolution == (256, 256) and scene.camera == Camera() and scene.name == "s"
    assert torch.equal(scene.params["m.reflectance"], torch.full((3,), 0.5))
    assert load_toml(write(tmp_path, 'resolution = [40, 30]\n' + BASE)).resolution == (40, 30)
    assert load_toml(write(tmp_path, 'resolution = [40, 30]\n' + BASE), resolution=(8, 6)).resolution == (8, 6)


def test_transform_steps_apply_in_listed_order(tmp_path):
    path = write(tmp_path, BASE + 'transform = [{ scale = 2 }, { rotate = { axis = [0, 0, 1], angle = 90 } }, { translate = [10, 0, 0] }]\n')
    corners = load_toml(path).triangles.corners()  # rectangle triangles (0, 1, 2), (0, 2, 3) of (-1,-1), (1,-1), (1,1), (-1,1)
    expected = torch.tensor([[[12.0, -2, 0], [12, 2, 0], [8, 2, 0]], [[12, -2, 0], [8, 2, 0], [8, -2, 0]]])  # x2, 90 deg about z, +10 x
    assert torch.allclose(corners, expected, atol=1e-5)
    reordered = write(tmp_path, BASE + 'transform = [{ translate = [10, 0, 0] }, { rotate = { axis = [0, 0, 1], angle = 90 } }, { scale = 2 }]\n')
    corners = load_toml(reordered).triangles.corners()[0]  # moved first: (-1,-1) -> (9,-1) -> (1, 9) -> (2, 18)
    assert torch.allclose(corners[0], torch.tensor([2.0, 18, 0]), atol=1e-5)


def test_flip_normals_and_sphere(tmp_path):
    front = load_toml(write(tmp_path, BASE)).triangles.normal[0]
    back = load_toml(write(tmp_path, BASE + "flip_normals = true\n")).triangles.normal[0]
    assert torch.allclose(front, torch.tensor([0.0, 0, 1])) and torch.allclose(back, torch.tensor([0.0, 0, -1]))
    sphere = load_toml(write(tmp_path, BASE.replace('"rectangle"', '"sphere"') + "subdivisions = 1\n"))
    assert sphere.triangles.count == 80


@pytest.mark.parametrize(
    "text, words",
    [
        (BASE + "colour = 1\n", "unknown key 'colour'"),
        (BASE + "colour = 1\n", "allowed: emitter, file, flip_normals, material, subdivisions, transform, type"),
        ("nmae = 'x'\n" + BASE, "unknown key 'nmae'"),
        (BASE + "[camera]\nfocal = 3\n", "[camera]: unknown key 'focal'"),
        (BASE.replace("reflectance = 0.5", "reflectance = 0.5\nalbedo = 1"), "[materials.m]: unknown key 'albedo'"),
        (BASE + "[emitters.e]\nemission = 1\npower = 2\n", "[emitters.e]: unknown key 'power'"),
        (BASE + "transform = [{ rotate = { axis = [0, 0, 1], angle = 9, about = 1 } }]\n", "unknown key 'about'"),
        (BASE.replace("reflectance = 0.5", "reflectance = 'grey'"), "'reflectance' must be a number or a list of 3 numbers"),
        (BASE.replace("reflectance = 0.5", "reflectance = [0.5, 0.5]"), "'reflectance' must be a number or a list of 3 numbers"),
        (BASE.replace("reflectance = 0.5", "reflectance = true"), "'reflectance' must be a number or a list of 3 numbers"),
        (BASE + "[camera]\nfov = 'wide'\n", "'fov' must be a number"),
        (BASE + "[camera]\nfov = true\n", "'fov' must be a number"),
        (BASE + "[camera]\norigin = [0, 1]\n", "'origin' must be a list of 3 numbers"),
        (BASE + "[camera]\nfov_axis = 'diagonal'\n", "'fov_axis' must be one of x, y, smaller, larger"),
        ("resolution = '64x64'\n" + BASE, "'resolution' must be a list of 2 numbers"),
        (BASE + "flip_normals = 1\n", "'flip_normals' must be true or false"),
        (BASE.replace('"rectangle"', '"sphere"') + "subdivisions = 2.5\n", "'subdivisions' must be an integer"),
        (BASE + "subdivisions = 2\n", "'subdivisions' applies to type = \"sphere\" only"),
        (BASE.replace('type = "rectangle"', 'type = "cone"'), "unknown shape type 'cone'"),
        (BASE.replace('type = "rectangle"\n', ""), "missing required key 'type'"),
        (BASE.replace('material = "m"', 'material = "x"'), "unknown material 'x'"),
        (BASE.replace('type = "rectangle"', 'type = "mesh"') + 'file = "nope.obj"\n', "mesh file not found"),
        (BASE.replace('type = "rectangle"', 'type = "mesh"'), "missing required key 'file'"),
        (BASE.replace("reflectance = 0.5", 'reflectance_texture = "nope.png"'), "texture file not found"),
        ("resolution = [16, \n", "invalid TOML"),
        ("a = 1\na = 2\n", "line 2"),
        (BASE + "transform = [{ shear = 1 }]\n", "unknown transform step 'shear'"),
        (BASE + "transform = { scale = 2 }\n", "'transform' must be a list"),
        (BASE + "transform = [{ scale = [1, 2] }]\n", "'scale' must be a number or a list of 3 numbers"),
        (BASE + "transform = [{ rotate = { angle = 9 } }]\n", "missing required key 'axis'"),
        (BASE + "transform = [{ scale = 0 }]\n", "scale factor must be non-zero"),
    ],
)
def test_bad_scene_files_give_one_line_errors(tmp_path, text, words):
    with pytest.raises(SceneError) as e:
        load_toml(write(tmp_path, text))
    assert words in str(e.value) and "\n" not in str(e.value)
    assert "s.toml" in str(e.value)


def test_out_of_range_values_are_parameter_errors(tmp_path):
    with pytest.raises(ParameterError, match="m.reflectance"):
        load_toml(write(tmp_path, BASE.replace("reflectance = 0.5", "reflectance = 1.5")))
    with pytest.raises(ParameterError, match="e.emission"):
        load_toml(write(tmp_path, BASE + "emitter = 'e'\n[emitters.e]\nemission = [-1, 0, 0]\n"))


def test_missing_and_corrupt_files(tmp_path):
    for call in (lambda: load_toml(tmp_path / "missing.toml"), lambda: ir.load_scene(tmp_path / "missing.toml")):
        with pytest.raises(SceneError, match="missing.toml.*not found|not found.*missing.toml"):
            call()
    (tmp_path / "binary.toml").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(SceneError, match="binary.toml.*invalid TOML"):
        load_toml(tmp_path / "binary.toml")
    (tmp_path / "broken.obj").write_bytes(b"\x00\x01garbage")
    with pytest.raises(SceneError, match="broken.obj") as e:
        load_mesh_file(tmp_path / "broken.obj")
    assert "\n" not in str(e.value)
    (tmp_path / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage")
    with pytest.raises(SceneError, match="broken.glb"):
        load_mesh_file(tmp_path / "broken.glb")
    with pytest.raises(SceneError, match="not found: .*nope.glb"):
        load_mesh_file(tmp_path / "nope.glb")


def test_mesh_without_faces_is_an_error(tmp_path):
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    path = write(tmp_path, BASE.replace('type = "rectangle"', 'type = "mesh"') + 'file = "points.obj"\n')
    with pytest.raises(SceneError, match="points.obj has no faces"):
        load_toml(path)


def test_reflectance_texture_from_png(tmp_path):
    pixels = np.full((4, 8, 3), 188, dtype=np.uint8)  # sRGB 188/255 = linear 0.5
    pixels[0, 0] = 255
    Image.fromarray(pixels).save(tmp_path / "albedo.png")
    path = write(tmp_path, BASE.replace("reflectance = 0.5", 'reflectance_texture = "albedo.png"'))
    rho = load_toml(path).params["m.reflectance"]
    assert rho.shape == (4, 8, 3) and torch.allclose(rho[1:], torch.full_like(rho[1:], 0.5), atol=0.005)
    assert torch.allclose(rho[0, 0], torch.ones(3))  # row 0 stays the image's top row


def test_mesh_in_box_scene():
    scene = load_toml(FORWARD / "mesh_in_box.toml")
    assert scene.triangles.count == 5 * 2 + 576 + 2
    assert "torus.reflectance" in scene.params and "panel.emission" in scene.params
    assert scene.triangles.emitter.tolist().count(0) == 2


def test_glb_materials_emission_strength_and_camera():
    scene = load_mesh_file(FORWARD / "meshes" / "lamp.glb")
    assert scene.materials == ("floor", "lamp") and scene.emitters == ("lamp_emission",)
    assert torch.allclose(scene.params["floor.reflectance"], torch.tensor([0.6, 0.5, 0.4]))  # exact, not 8-bit
    assert torch.allclose(scene.params["lamp.reflectance"], torch.tensor([0.8, 0.8, 0.8]))
    assert torch.allclose(scene.params["lamp_emission.emission"], torch.tensor([1.0, 0.8, 0.5]) * 12.0)
    assert scene.camera.origin == (0.0, 0.5, 3.0) and scene.camera.target == (0.0, 0.5, 2.0) and scene.camera.up == (0.0, 1.0, 0.0)
    assert scene.camera.fov_axis == "y" and abs(scene.camera.fov - np.degrees(0.8)) < 1e-9
    assert scene.resolution == (384, 256)  # aspectRatio 1.5
    assert load_mesh_file(FORWARD / "meshes" / "lamp.glb", resolution=(24, 16)).resolution == (24, 16)
    emitting = scene.triangles.emitter == 0
    assert int(emitting.sum()) == 2 and torch.allclose(scene.triangles.normal[emitting], torch.tensor([0.0, -1, 0]))
    img = ir.render(scene.with_resolution((24, 16)), spp=4, max_depth=2, progress=False)
    assert img.shape == (16, 24, 3) and img.max() > 0


def test_obj_loads_with_default_camera():
    scene = ir.load_scene(FORWARD / "meshes" / "torus.obj", resolution=(16, 16))
    assert scene.triangles.count == 576 and scene.emitters == () and scene.materials == ("material",)
    assert torch.allclose(scene.params["material.reflectance"], torch.full((3,), 0.8))  # no .mtl: grey
    cam = scene.camera
    assert cam.fov == 45.0 and cam.fov_axis == "smaller" and cam.origin[2] > 0.47 and cam.origin[:2] == cam.target[:2]
    assert torch.count_nonzero(ir.render(scene, spp=1, progress=False)) == 0  # nothing emits
    assert load_mesh_file(FORWARD / "meshes" / "torus.obj").resolution == (256, 256)


QUAD = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"


def test_obj_mtl_kd_ke_and_texture(tmp_path):
    texture = np.zeros((2, 3, 3), dtype=np.uint8)
    texture[0] = 255  # top row white
    Image.fromarray(texture).save(tmp_path / "tex.png")
    (tmp_path / "a.mtl").write_text(
        "newmtl paint\nKd 0.885809 0.1 0.05\n"
        "newmtl glow\nKd 0.5 0.5 0.5\nKe 2 1 0.5\n"
        "newmtl pic\nKd 0.5 1 1\nmap_Kd tex.png\n"
    )
    (tmp_path / "a.obj").write_text(
        "mtllib a.mtl\n" + QUAD + "usemtl paint\nf 1/1 2/2 3/3\nusemtl glow\nf 1/1 3/3 4/4\n"
        "v -1 -1 1\nv 1 -1 1\nv 1 1 1\nusemtl pic\nf 5/1 6/2 7/3\n"
    )
    scene = load_mesh_file(tmp_path / "a.obj")
    assert set(scene.materials) == {"paint", "glow", "pic"} and scene.emitters == ("glow_emission",)
    assert torch.allclose(scene.params["paint.reflectance"], torch.tensor([0.885809, 0.1, 0.05]))  # Kd exact, linear
    assert torch.allclose(scene.params["glow_emission.emission"], torch.tensor([2.0, 1.0, 0.5]))
    rho = scene.params["pic.reflectance"]
    assert rho.shape == (2, 3, 3)
    assert torch.allclose(rho[0], torch.tensor([0.5, 1, 1]).expand(3, 3)) and torch.equal(rho[1], torch.zeros(3, 3))  # not flipped
    uv = scene.triangles.uv[scene.triangles.material == scene.materials.index("pic")][0]
    assert torch.equal(uv, torch.tensor([[0.0, 0], [1, 0], [1, 1]]))  # OBJ UVs as written
    # also usable as a TOML mesh shape: geometry only, merged
    shape = load_toml(write(tmp_path, BASE.replace('type = "rectangle"', 'type = "mesh"') + 'file = "a.obj"\n'))
    assert shape.triangles.count == 3 and shape.materials == ("m",)


def gltf_file(path: Path, materials: list, mesh_materials: list, nodes_extra=(), images=(), cameras=()):
    """A .gltf with one quad per entry of ``mesh_materials`` (a material index or None), buffers as data URIs."""
    pos = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32)  # glTF: v down, (0, 0) at the image's top-left
    idx = np.array([0, 1, 2, 0, 2, 3], dtype=np.uint16)
    blob = pos.tobytes() + uv.tobytes() + idx.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 32},
            {"buffer": 0, "byteOffset": 80, "byteLength": 12},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [-1, -1, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
        "meshes": [
            {"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, **({} if m is None else {"material": m})}]}
            for m in mesh_materials
        ],
        "nodes": [{"mesh": i, "translation": [0, 0, -float(i)]} for i in range(len(mesh_materials))] + list(nodes_extra),
        "materials": materials,
    }
    doc["scenes"] = [{"nodes": list(range(len(doc["nodes"])))}]
    if images:
        doc["images"] = [{"uri": name} for name in images]
        doc["textures"] = [{"source": i} for i in range(len(images))]
    if cameras:
        doc["cameras"] = list(cameras)
    path.write_text(json.dumps(doc))
    return path


def test_gltf_texture_duplicate_names_and_nested_camera(tmp_path):
    texture = np.zeros((2, 4, 3), dtype=np.uint8)
    texture[0] = [188, 188, 188]  # top row: linear 0.5
    Image.fromarray(texture).save(tmp_path / "base.png")
    materials = [
        {"name": "paint", "pbrMetallicRoughness": {"baseColorFactor": [1.0, 0.5, 1.0, 1.0], "baseColorTexture": {"index": 0}}},
        {"name": "paint", "pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.3, 0.4, 1.0]}, "emissiveFactor": [1, 1, 1]},
        {"name": "paint_emission", "pbrMetallicRoughness": {"baseColorFactor": [0.1, 0.1, 0.1, 1.0]}},
    ]
    rig = [
        {"name": "rig", "translation": [0, 0, 5], "rotation": [0, 0.7071068, 0, 0.7071068], "children": [4]},  # 90 deg about +y
        {"name": "cam", "camera": 0, "translation": [0, 1, 0]},
    ]
    camera = {"type": "perspective", "perspective": {"yfov": 0.5, "znear": 0.1}}
    path = gltf_file(tmp_path / "s.gltf", materials, [0, 1, 2], nodes_extra=rig, images=["base.png"], cameras=[camera])
    scene = load_mesh_file(path)
    assert scene.materials == ("paint", "paint_2", "paint_emission") and scene.emitters == ("paint_2_emission",)
    rho = scene.params["paint.reflectance"]
    assert rho.shape == (2, 4, 3)
    assert torch.allclose(rho[0], torch.tensor([0.5, 0.25, 0.5]).expand(4, 3), atol=0.005) and torch.equal(rho[1], torch.zeros(4, 3))
    uv = scene.triangles.uv[0]  # trimesh turns glTF's v (down) into OpenGL's (up): v = 1 - v_gltf
    assert torch.allclose(uv, torch.tensor([[0.0, 0], [1, 0], [1, 1]]))
    assert torch.allclose(scene.params["paint_2.reflectance"], torch.tensor([0.2, 0.3, 0.4]))
    assert torch.allclose(scene.params["paint_2_emission.emission"], torch.ones(3))  # no strength extension: 1
    cam = scene.camera  # the child node's transform composed with its parent's
    assert np.allclose(cam.origin, [0, 1, 5]) and np.allclose(np.subtract(cam.target, cam.origin), [-1, 0, 0], atol=1e-6)
    assert cam.fov_axis == "y" and scene.resolution == (256, 256)  # no aspectRatio


def test_gltf_without_material_or_camera(tmp_path):
    scene = load_mesh_file(gltf_file(tmp_path / "plain.gltf", [], [None]))
    assert scene.materials == ("material",) and torch.allclose(scene.params["material.reflectance"], torch.full((3,), 0.8))
    assert scene.camera.fov == 45.0 and scene.camera.target == (0.0, 0.0, 0.0) and scene.camera.origin[2] > 1.4


def test_loader_errors_are_one_line(tmp_path):
    (tmp_path / "bad.toml").write_text("[materials\nx = 1\n")
    messages = []
    for call in (
        lambda: load_toml(tmp_path / "bad.toml"),
        lambda: load_mesh_file(tmp_path / "nope.obj"),
        lambda: load_toml(write(tmp_path, BASE + "transform = [{ rotate = { axis = [0, 0, 0], angle = 1 } }]\n")),
    ):
        with pytest.raises(SceneError) as e:
            call()
        messages.append(str(e.value))
    assert all(m and "\n" not in m for m in messages), messages
