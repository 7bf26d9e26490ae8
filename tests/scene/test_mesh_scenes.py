"""Any mesh file is a scene: PLY, STL, OBJ and glTF files without an emitter load in the default
studio (a camera framing the bounding box, a floor and an area light) and render at once."""

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

import invrender as ir
from invrender.cli import main
from invrender.errors import SceneError
from invrender.scene.formats import studio
from invrender.scene.scene import build_scene

FORWARD = Path(__file__).parents[2] / "forward"
SIZE = (24, 18)


def mesh_file(tmp_path, suffix, offset=(0.3, -0.2, 0.1), extents=(1.0, 0.6, 0.8)):
    """A small box, off the origin and not a cube, written by trimesh."""
    box = trimesh.creation.box(extents=extents)
    box.apply_translation(offset)
    path = tmp_path / f"box{suffix}"
    box.export(path)
    return path, box


def projected(camera, points, width, height):
    """Film positions (N, 2) and depths (N,) of world ``points`` (N, 3) (camera.py's convention)."""
    fx, fy, cx, cy = camera.intrinsics(width, height)
    right, up, forward = (t.numpy() for t in camera.frame())
    rel = np.asarray(points) - np.asarray(camera.origin)
    z = rel @ forward
    return np.stack([cx + fx * (rel @ right) / z, cy - fy * (rel @ up) / z], axis=1), z


@pytest.mark.parametrize("suffix", [".ply", ".stl"])
def test_mesh_file_renders_in_the_studio(tmp_path, suffix):
    path, box = mesh_file(tmp_path, suffix)
    scene = ir.load_scene(path, resolution=SIZE)
    assert scene.name == "box" and scene.emitters == ("studio_light",)
    assert set(scene.materials) == {"material", "studio_floor", "studio_lamp"}
    assert torch.allclose(scene.params["material.reflectance"], torch.full((3,), 0.8))  # grey diffuse
    assert scene.triangles.count == 12 + 2 + 2
    # the camera frames the bounding box: every corner in front of it and inside the image
    xy, z = projected(scene.camera, trimesh.bounds.corners(box.bounds), *SIZE)
    assert (z > 0).all() and (xy > 0).all() and (xy[:, 0] < SIZE[0]).all() and (xy[:, 1] < SIZE[1]).all()
    assert scene.camera.fov == studio.FOV and scene.camera.target == pytest.approx(tuple(box.bounds.mean(0)))
    # the floor lies just under the mesh
    floor = scene.triangles.corners()[scene.triangles.material == scene.materials.index("studio_floor")]
    assert float(floor[..., 1].max()) < box.bounds[0, 1] and float(floor[..., 1].min()) > box.bounds[0, 1] - 0.01
    # the mesh is visible: the image differs from the empty studio's, most where the box projects
    image = ir.render(scene, spp=4, progress=False)
    empty = build_scene(*studio.studio_parts(box.vertices, set()), scene.camera, SIZE)
    diff = (image - ir.render(empty, spp=4, progress=False)).abs().mean(-1)
    (x0, y0), (x1, y1) = xy.min(0).astype(int), xy.max(0).astype(int) + 1
    inside = torch.zeros(SIZE[1], SIZE[0], dtype=torch.bool)
    inside[y0:y1, x0:x1] = True
    assert float((diff[inside] > 0.05).float().mean()) > 0.5  # most of the box's pixels change
    assert float(image.mean(-1)[inside].mean()) > 0.1  # and they are lit, not black


def test_obj_and_gltf_get_the_studio_when_nothing_emits(tmp_path):
    torus = ir.load_scene(FORWARD / "meshes" / "torus.obj", resolution=SIZE)
    assert torus.emitters == ("studio_light",) and torus.camera.fov == studio.FOV
    assert float(ir.render(torus, spp=2, progress=False).max()) > 0
    # a file that lights itself is a scene as it is: its camera and its emitters
    lamp = ir.load_scene(FORWARD / "meshes" / "lamp.glb")
    assert lamp.emitters == ("lamp_emission",) and lamp.materials == ("floor", "lamp") and lamp.camera.fov_axis == "y"
    # asked for, the studio comes anyway, named apart from the file's names
    lit = ir.load_scene(FORWARD / "meshes" / "lamp.glb", studio=True)
    assert lit.emitters == ("lamp_emission", "studio_light") and lit.camera == lamp.camera
    bare = ir.load_scene(FORWARD / "meshes" / "torus.obj", studio=False)
    assert bare.emitters == () and bare.materials == ("material",)
    with pytest.raises(SceneError, match="studio applies to mesh files"):
        ir.load_scene("cornell_box", studio=True)


def test_studio_names_avoid_the_files(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl studio_floor\nKd 0.2 0.3 0.4\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl studio_floor\nf 1 2 3\n")
    scene = ir.load_scene(tmp_path / "m.obj", resolution=(4, 4))
    assert scene.materials == ("studio_floor", "studio_floor_2", "studio_lamp")
    assert torch.allclose(scene.params["studio_floor.reflectance"], torch.tensor([0.2, 0.3, 0.4]))  # the file's own material


def test_studio_framing_is_scale_invariant():
    v = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 2]])
    a, b = studio.studio_camera(v), studio.studio_camera(1000 * v + 5)
    assert np.allclose(np.subtract(b.origin, 5) / 1000, a.origin) and b.fov == a.fov
    _, _, radius = studio.bounds(v)
    assert np.linalg.norm(np.subtract(a.origin, a.target)) == pytest.approx(studio.MARGIN * radius / np.sin(np.radians(studio.FOV / 2)))


def test_cli_renders_a_mesh_file(tmp_path, capsys):
    path, _ = mesh_file(tmp_path, ".ply")
    out = tmp_path / "box.exr"
    assert main(["render", str(path), "--resolution", "16x12", "--spp", "2", "--out", str(out), "--quiet"]) == 0
    image = ir.read_image(out)
    assert image.shape == (12, 16, 3) and float(image.mean()) > 0.01
    assert torch.allclose(image, ir.render(ir.load_scene(path, resolution=(16, 12)), spp=2, progress=False))


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("empty.ply", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n", "has no faces"),
        ("points.stl", "solid x\nendsolid x\n", "points.stl"),
        ("corrupt.ply", "ply\nformat binary_little_endian 1.0\nelement vertex 9\nproperty float x\nend_header\n\x01\x02", "corrupt.ply"),
        ("garbage.stl", "\x00\x01garbage", "garbage.stl"),
        ("bunny.off3", "whatever", "unknown scene"),
        ("far.obj", "v 0 0 0\nv 1 0 1e39\nv 0 1 0\nf 1 2 3\n", "vertex positions must be finite numbers within float32's range (|x| <= 3.403e+38), got up to 1e+39"),
    ],
)
def test_bad_mesh_files_fail_in_one_line(tmp_path, capsys, name, content, words):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(SceneError) as e:
        ir.load_scene(path)
    message = str(e.value)
    assert words in message and name in message and "\n" not in message
    assert main(["render", str(path), "--out", str(tmp_path / "o.exr")]) == 2
    err = capsys.readouterr().err
    assert name in err and len(err.strip().splitlines()) == 1
