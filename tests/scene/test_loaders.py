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
from invrender.scene.formats.toml import load_toml
from invrender.scene.formats.trimesh import load_mesh_file

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
    scene = ir.load_scene(FORWARD / "meshes" / "torus.obj", resolution=(16, 16), studio=False)  # the file as it is: no studio
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
    materials = [  # metallicFactor 0: glTF's default is 1, a metal
        gltf_material("paint", baseColorFactor=[1.0, 0.5, 1.0, 1.0], baseColorTexture={"index": 0}, metallicFactor=0),
        {**gltf_material("paint", baseColorFactor=[0.2, 0.3, 0.4, 1.0], metallicFactor=0), "emissiveFactor": [1, 1, 1]},
        gltf_material("paint_emission", baseColorFactor=[0.1, 0.1, 0.1, 1.0], metallicFactor=0.0),
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


# ---------------------------------------------------------------- shading normals and material types from files


def icosphere(subdivisions=1):
    """(vertices, faces) of trimesh's unit icosphere, faces outward."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def obj_text(vertices, faces, normals=None, normal_index=None):
    """An OBJ: ``v`` lines, ``vn`` lines when ``normals`` is given, faces ``v//vn`` (normal per vertex,
    or ``normal_index`` (F, 3) into ``normals``) or ``v``."""
    lines = ["v " + " ".join(repr(float(c)) for c in row) for row in vertices]
    if normals is None:
        lines += [f"f {a} {b} {c}" for a, b, c in faces + 1]
    else:
        lines += ["vn " + " ".join(repr(float(c)) for c in row) for row in normals]
        index = faces if normal_index is None else normal_index
        lines += [" ".join(["f"] + [f"{v}//{n}" for v, n in zip(f, i)]) for f, i in zip(faces + 1, index + 1)]
    return "\n".join(lines) + "\n"


def unit(x):
    return x / x.norm(dim=-1, keepdim=True)


def test_obj_vertex_normals_are_shading_normals(tmp_path):
    v, f = icosphere()
    (tmp_path / "ball.obj").write_text(obj_text(2 * v, f, normals=v))  # radius 2, unit outward normals
    tri = load_mesh_file(tmp_path / "ball.obj").triangles
    assert tri.count == 80 and bool(tri.smooth.all())
    assert torch.allclose(tri.vertex_normal, tri.corners().double().div(2).float(), atol=1e-5)  # the normals written

    (tmp_path / "flat.obj").write_text(obj_text(2 * v, f))
    flat = load_mesh_file(tmp_path / "flat.obj").triangles
    assert not bool(flat.smooth.any()) and torch.equal(flat.vertex_normal, flat.normal[:, None].expand(-1, 3, -1))
    assert torch.equal(flat.p0, tri.p0) and torch.equal(flat.e1, tri.e1) and torch.equal(flat.normal, tri.normal)  # same geometry


def test_obj_normals_keep_hard_edges_and_follow_the_winding(tmp_path):
    import trimesh

    box = trimesh.creation.box()  # 8 vertices, 12 outward triangles
    face_normals = np.asarray(box.face_normals)
    axes, index = np.unique(np.round(face_normals), axis=0, return_inverse=True)  # the 6 face directions
    index = np.repeat(index.reshape(-1, 1), 3, axis=1)
    for sign in (1, -1):  # normals written inwards (against the winding) are turned to the front side
        text = obj_text(np.asarray(box.vertices), np.asarray(box.faces), normals=sign * axes, normal_index=index)
        (tmp_path / "box.obj").write_text(text)
        tri = load_mesh_file(tmp_path / "box.obj").triangles
        assert tri.count == 12 and bool(tri.smooth.all())
        # not averaged across the cube's edges: every corner keeps its own face's normal
        assert torch.allclose(tri.vertex_normal, tri.normal[:, None].expand(-1, 3, -1), atol=1e-6), sign


def gltf_meshes(path: Path, parts: list):
    """A .gltf with one mesh + node per part (vertices, faces, normals or None, node dict)."""
    blob, views, accessors, meshes, nodes = b"", [], [], [], []

    def add(array, kind):
        nonlocal blob
        data = np.ascontiguousarray(array).tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        accessor = {"bufferView": len(views) - 1, "count": len(array), "type": kind}
        accessor["componentType"] = 5125 if array.dtype == np.uint32 else 5126
        if kind == "VEC3":
            accessor["min"], accessor["max"] = array.min(0).tolist(), array.max(0).tolist()
        accessors.append(accessor)
        blob += data + b"\0" * (-len(data) % 4)
        return len(accessors) - 1

    for i, (vertices, faces, normals, node) in enumerate(parts):
        attributes = {"POSITION": add(vertices.astype(np.float32), "VEC3")}
        if normals is not None:
            attributes["NORMAL"] = add(normals.astype(np.float32), "VEC3")
        meshes.append({"primitives": [{"attributes": attributes, "indices": add(faces.astype(np.uint32).reshape(-1), "SCALAR")}]})
        nodes.append({"mesh": i, **node})
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": meshes,
        "buffers": [{"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": views,
        "accessors": accessors,
    }
    path.write_text(json.dumps(doc))
    return path


def test_gltf_normals_move_to_world_space(tmp_path):
    v, f = icosphere()
    mirror = {"scale": [-2.0, 1.0, 0.5], "rotation": [0, 0, 0.3826834, 0.9238795], "translation": [5.0, 0, 0]}  # 45 deg about z
    path = gltf_meshes(tmp_path / "balls.gltf", [(v, f, v, {}), (v, f, v, mirror), (v, f, None, {"translation": [0, 5.0, 0]})])
    scene = load_mesh_file(path)
    tri = scene.triangles
    assert tri.count == 240 and tri.smooth.tolist() == [True] * 160 + [False] * 80
    c = tri.corners().double()
    assert torch.allclose(tri.vertex_normal[:80].double(), unit(c[:80]), atol=1e-6)
    # the mirrored, stretched ball: normals by the inverse transpose, on the front (outer) side like its faces
    h = 0.5**0.5  # cos and sin of 45 degrees
    rotation = torch.tensor([[h, -h, 0], [h, h, 0], [0, 0, 1]], dtype=torch.float64)
    linear = rotation @ torch.diag(torch.tensor([-2.0, 1.0, 0.5], dtype=torch.float64))
    local = (c[80:160] - torch.tensor([5.0, 0, 0], dtype=torch.float64)) @ torch.linalg.inv(linear).T  # back on the unit sphere
    assert torch.allclose(local.norm(dim=-1), torch.ones(80, 3, dtype=torch.float64), atol=1e-5)
    expected = unit(local @ torch.linalg.inv(linear))
    assert torch.allclose(tri.vertex_normal[80:160].double(), expected, atol=1e-5)
    assert bool(((tri.vertex_normal[80:160] * tri.normal[80:160, None]).sum(-1) > 0.5).all())  # geometric normals outward too
    assert torch.equal(tri.vertex_normal[160:], tri.normal[160:, None].expand(-1, 3, -1))  # no NORMAL: flat


def gltf_material(name, extensions=None, **pbr):
    return {"name": name, **({"pbrMetallicRoughness": pbr} if pbr else {}), **({"extensions": extensions} if extensions else {})}


def test_gltf_material_types(tmp_path):
    texture = np.zeros((2, 4, 3), dtype=np.uint8)
    texture[0] = 188  # top row linear 0.5, bottom row 0: mean 0.25
    Image.fromarray(texture).save(tmp_path / "base.png")
    glass = {"KHR_materials_transmission": {"transmissionFactor": 1.0}, "KHR_materials_ior": {"ior": 1.33}}
    materials = [
        gltf_material("gold", baseColorFactor=[1.0, 0.766, 0.336, 1.0], metallicFactor=1.0, roughnessFactor=0.5),
        gltf_material("chrome", baseColorFactor=[0.9, 0.8, 0.7, 1.0], roughnessFactor=0.0),  # metallic omitted: 1
        gltf_material("glass", glass, metallicFactor=0.0, roughnessFactor=0.0),  # clear glass: full transmission, smooth, not metallic
        gltf_material("frosted", {"KHR_materials_transmission": {"transmissionFactor": 0.5}}, metallicFactor=0.0),  # partial and rough: principled
        gltf_material("plastic", baseColorFactor=[0.2, 0.4, 0.6, 1.0], metallicFactor=0.3, roughnessFactor=0.1),
        {"name": "bare"},  # every glTF default: metallic 1, roughness 1, white
        gltf_material("polished", metallicFactor=0.5, roughnessFactor=0.03),  # alpha 9e-4: a mirror
        gltf_material("brushed", metallicFactor=0.5, roughnessFactor=0.04),  # alpha 1.6e-3: glossy
        gltf_material("patina", baseColorFactor=[1.0, 0.5, 1.0, 1.0], baseColorTexture={"index": 0}, roughnessFactor=0.2),
    ]
    scene = load_mesh_file(gltf_file(tmp_path / "m.gltf", materials, list(range(len(materials))), images=["base.png"]))
    assert scene.materials == tuple(m["name"] for m in materials)
    specs = dict(zip(scene.materials, scene.material_specs))
    types = {k: (s.type, s.constants) for k, s in specs.items()}
    alpha = {k.rpartition(".")[0]: float(v[0]) for k, v in scene.params.items() if k.endswith(".roughness")}
    assert types["gold"][0] == "glossy" and alpha["gold"] == pytest.approx(0.25)
    none = {"eta": (0.0, 0.0, 0.0), "k": (1.0, 1.0, 1.0)}  # conductor material none: Fresnel 1
    assert types["chrome"] == ("mirror", none) and types["polished"] == ("mirror", none)
    assert types["glass"] == ("dielectric", {"ior": 1.33}) and types["frosted"][0] == "principled"
    assert float(scene.params["frosted.spec_trans"][0]) == 0.5 and float(scene.params["frosted.metallic"][0]) == 0.0 and alpha["frosted"] == 1.0
    assert types["plastic"][0] == "principled" and types["bare"] == ("glossy", {**none, "alpha_v": 0.0}) and alpha["bare"] == 1.0  # a partial metal: principled; isotropic
    assert types["plastic"][1]["eta"] == pytest.approx(1.5) and types["plastic"][1]["two_sided"] == 1.0
    assert float(scene.params["plastic.metallic"][0]) == pytest.approx(0.3) and alpha["plastic"] == pytest.approx(0.1)  # its roughness: glTF's perceptual one
    assert types["brushed"][0] == "principled" and alpha["brushed"] == pytest.approx(0.04)
    p = scene.params
    assert torch.allclose(p["gold.specular_reflectance"], torch.tensor([1.0, 0.766, 0.336]))  # exact, not 8-bit
    assert torch.allclose(p["chrome.specular_reflectance"], torch.tensor([0.9, 0.8, 0.7]))
    assert torch.allclose(p["plastic.base_color"], torch.tensor([0.2, 0.4, 0.6]))
    assert torch.equal(p["bare.specular_reflectance"], torch.ones(3))
    assert torch.allclose(p["patina.specular_reflectance"], torch.tensor([0.25, 0.125, 0.25]), atol=0.003)  # texture mean x factor
    assert not any(k.startswith("glass.") for k in p)
    assert "plastic.specular_reflectance" not in p and "gold.reflectance" not in p


def test_bundled_assets_stay_diffuse_and_flat():
    for name in ("lamp.glb", "torus.obj"):
        scene = load_mesh_file(FORWARD / "meshes" / name)
        assert all(m.type == "diffuse" for m in scene.material_specs) and not bool(scene.triangles.smooth.any()), name


@pytest.mark.parametrize(
    "material, words",
    [
        (gltf_material("x", metallicFactor=1.5), "material 'x': glTF metallicFactor must lie in [0, 1], got 1.5"),
        (gltf_material("x", {"KHR_materials_transmission": {"transmissionFactor": "yes"}}), "glTF transmissionFactor must be a number"),
        (gltf_material("x", roughnessFactor=2.0), "glTF roughnessFactor must lie in [0, 1]"),
        (gltf_material("x", {"KHR_materials_transmission": {"transmissionFactor": 1}, "KHR_materials_ior": {"ior": 0}}, metallicFactor=0, roughnessFactor=0), "'ior' must lie in [0.01, 100], got 0"),
    ],
)
def test_bad_gltf_material_factors(tmp_path, material, words):
    with pytest.raises(SceneError) as e:
        load_mesh_file(gltf_file(tmp_path / "bad.gltf", [material], [0]))
    assert words in str(e.value) and "bad.gltf" in str(e.value) and "\n" not in str(e.value)


def test_obj_mtl_illum_3_is_a_mirror(tmp_path):
    (tmp_path / "m.mtl").write_text(
        "newmtl chrome\nKd 0.1 0.1 0.1\nKs 0.9 0.8 0.7\nillum 3\n"
        "newmtl shiny\nKd 0.5 0.4 0.3\nKs 1 1 1\nillum 2\n"  # highlights only: diffuse
        "newmtl dull\nKd 0.2 0.2 0.2\nillum 3\n"  # reflection on but no Ks: diffuse
    )
    faces = "usemtl chrome\nf 1 2 3\nusemtl shiny\nf 1 3 4\nv 0 0 1\nusemtl dull\nf 1 2 5\n"
    (tmp_path / "m.obj").write_text("mtllib m.mtl\n" + QUAD + faces)
    scene = load_mesh_file(tmp_path / "m.obj")
    types = {k: s.type for k, s in zip(scene.materials, scene.material_specs)}
    assert types == {"chrome": "mirror", "shiny": "diffuse", "dull": "diffuse"}
    assert torch.allclose(scene.params["chrome.specular_reflectance"], torch.tensor([0.9, 0.8, 0.7]))
    assert torch.allclose(scene.params["shiny.reflectance"], torch.tensor([0.5, 0.4, 0.3]))


MESH_SHAPE = """
[materials.m]
reflectance = 0.5
[[shapes]]
type = "mesh"
material = "m"
file = "FILE"
"""


def test_toml_mesh_shape_with_normals_is_smooth(tmp_path):
    v, f = icosphere()
    (tmp_path / "ball.obj").write_text(obj_text(v, f, normals=v))
    text = MESH_SHAPE.replace("FILE", "ball.obj") + "transform = [{ scale = [2, 1, 1] }, { translate = [0, 0, 3] }]\n"
    tri = load_toml(write(tmp_path, text)).triangles
    assert tri.count == 80 and bool(tri.smooth.all())
    local = (tri.corners().double() - torch.tensor([0.0, 0, 3], dtype=torch.float64)) / torch.tensor([2.0, 1, 1], dtype=torch.float64)
    assert torch.allclose(tri.vertex_normal.double(), unit(local / torch.tensor([2.0, 1, 1], dtype=torch.float64)), atol=1e-5)
    flipped = load_toml(write(tmp_path, text + "flip_normals = true\n")).triangles
    assert torch.allclose(flipped.vertex_normal[:, [2, 1, 0]], -tri.vertex_normal, atol=1e-6)

    (tmp_path / "flat.obj").write_text(obj_text(v, f))
    assert not bool(load_toml(write(tmp_path, MESH_SHAPE.replace("FILE", "flat.obj"))).triangles.smooth.any())
    # a file whose parts only partly have normals: the others keep their own flat normals
    gltf_meshes(tmp_path / "mixed.gltf", [(v, f, v, {}), (v, f, None, {"translation": [3.0, 0, 0]})])
    mixed = load_toml(write(tmp_path, MESH_SHAPE.replace("FILE", "mixed.gltf"))).triangles
    assert mixed.count == 160 and bool(mixed.smooth.all())
    assert torch.allclose(mixed.vertex_normal[:80].double(), unit(mixed.corners()[:80].double()), atol=1e-6)
    assert torch.allclose(mixed.vertex_normal[80:], mixed.normal[80:, None].expand(-1, 3, -1), atol=1e-6)


def test_smooth_ball_renders_without_facets(tmp_path):
    v, f = icosphere(1)  # 80 triangles: facets a few pixels wide at 32 x 32
    scene_text = """
resolution = [32, 32]
[camera]
origin = [0, 0, 4]
target = [0, 0, 0]
fov = 40
[materials.white]
reflectance = 0.8
[materials.black]
reflectance = 0
[emitters.light]
emission = 3000
[[shapes]]
type = "mesh"
file = "FILE"
material = "white"
[[shapes]]
type = "rectangle"
material = "black"
emitter = "light"
transform = [{ scale = 0.05 }, { rotate = { axis = [1, 0, 0], angle = 150 } }, { translate = [0, 2.5, 4.33] }]
"""
    (tmp_path / "smooth.obj").write_text(obj_text(v, f, normals=v))
    (tmp_path / "flat.obj").write_text(obj_text(v, f))
    luminance = {}
    for kind in ("smooth", "flat"):
        scene = load_toml(write(tmp_path, scene_text.replace("FILE", f"{kind}.obj"), f"{kind}.toml"))
        luminance[kind] = ir.render(scene, spp=8, max_depth=2, progress=False) @ torch.tensor([0.2126, 0.7152, 0.0722])
    lit = (luminance["smooth"] > 0) & (luminance["flat"] > 0)
    inner = lit[1:-1, 1:-1] & lit[:-2, 1:-1] & lit[2:, 1:-1] & lit[1:-1, :-2] & lit[1:-1, 2:]
    assert int(inner.sum()) > 200

    def kinks(lum):  # mean squared second difference between neighbouring pixels: facet edges are kinks and steps
        across = lum[1:-1, :-2] + lum[1:-1, 2:] - 2 * lum[1:-1, 1:-1]
        down = lum[:-2, 1:-1] + lum[2:, 1:-1] - 2 * lum[1:-1, 1:-1]
        return float(torch.cat([across[inner], down[inner]]).pow(2).mean())

    assert kinks(luminance["smooth"]) < 0.6 * kinks(luminance["flat"]), (kinks(luminance["smooth"]), kinks(luminance["flat"]))
