"""Cameras from dataset files (invrender/scene/formats/cameras.py): NeRF transforms.json and COLMAP's
text export against their conventions, round trips of the shipped scenes' cameras, the principal
point against a crop of a wider render, and one-line errors for bad files."""

import dataclasses
import json
import math

import numpy as np
import pytest
import torch
import trimesh.transformations as tf

import invrender as ir
from invrender.cli import main
from invrender.errors import SceneError
from invrender.scene.builtin import cornell_box, sky_spheres
from invrender.scene.camera import Camera
from invrender.scene.formats.cameras import load_cameras, write_colmap, write_transforms
from invrender.vec import normalize


def orbit(n: int = 3) -> list[Camera]:
    """Views around the Cornell box, one of them off-centre with non-square pixels."""
    cams = [Camera(origin=(3.9 * math.sin(a), 0.4 * math.cos(3 * a), 3.9 * math.cos(a)), target=(0.1, -0.1, 0), up=(0.1 * a, 1, 0), fov=40) for a in np.linspace(-0.6, 0.6, n)]
    return cams[:-1] + [dataclasses.replace(cams[-1], principal_point_offset=(0.125, -0.0625), pixel_aspect=1.25)]


def rays(camera: Camera, size, n: int = 256):
    xy = torch.rand(n, 2, generator=torch.Generator().manual_seed(0)) * torch.tensor(size, dtype=torch.float32)
    return xy, camera.generate_rays(xy, *size)


def write_images(folder, n, size=(12, 10)):
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"img_{i}.png" for i in range(n)]
    for p in paths:
        ir.write_image(p, torch.full((size[1], size[0], 3), 0.5))
    return paths


# ---------------------------------------------------------------- the camera itself


def test_centred_square_pixel_rays_are_the_old_formula_bit_for_bit():
    cam = cornell_box().camera
    xy, (o, d) = rays(cam, (20, 14))
    right, up, forward = (v.float() for v in cam.frame())
    tx, ty = cam.tan_half_fov(20, 14)
    t = math.tan(math.radians(cam.fov) / 2)
    assert (tx, ty) == (t * 20 / 14, t)  # fov along the smaller axis, y
    sx, sy = (2.0 * xy[:, 0] / 20 - 1.0) * tx, (1.0 - 2.0 * xy[:, 1] / 14) * ty  # before principal points existed
    assert torch.equal(d, normalize(sx[:, None] * right + sy[:, None] * up + forward))


def test_intrinsics_round_trip_and_projection():
    cam = Camera(origin=(0.2, 0.1, 3), target=(0, 0, 0), up=(0, 1, 0), fov=35, fov_axis="y", principal_point_offset=(0.1, -0.2), pixel_aspect=0.8)
    w, h = 30, 20
    fx, fy, cx, cy = cam.intrinsics(w, h)
    assert fy / fx == pytest.approx(0.8) and (cx, cy) == pytest.approx((0.4 * w, 0.7 * h))
    assert fy == pytest.approx(h / 2 / math.tan(math.radians(35) / 2))
    back = Camera.from_intrinsics(fx, fy, cx, cy, w, h, origin=cam.origin, target=cam.target, up=cam.up)
    assert back.intrinsics(w, h) == pytest.approx((fx, fy, cx, cy), rel=1e-12)
    # a world point seen at camera coordinates (right r, down d, depth z) lands at (cx + fx r / z, cy + fy d / z)
    right, up, forward = (v.numpy() for v in cam.frame())
    p = np.array([0.3, -0.2, 0.1])
    rel = p - np.array(cam.origin)
    u, v = cx + fx * (rel @ right) / (rel @ forward), cy + fy * (-(rel @ up)) / (rel @ forward)
    _, d = cam.generate_rays(torch.tensor([[u, v]], dtype=torch.float32), w, h)
    assert np.allclose(d[0].numpy(), rel / np.linalg.norm(rel), atol=1e-6)


def test_pixel_aspect_is_a_row_subsampling_of_square_pixels():
    """fy = fx / 2: row y of a W x H film sees what row 2y of a W x 2H square-pixel film sees."""
    square = Camera(origin=(0, 0, 3), target=(0, 0, 0), up=(0, 1, 0), fov=40, fov_axis="x")
    stretched = dataclasses.replace(square, pixel_aspect=0.5)
    xy, (_, d) = rays(stretched, (16, 8))
    _, d2 = square.generate_rays(xy * torch.tensor([1.0, 2.0]), 16, 16)
    assert torch.allclose(d, d2, atol=1e-6)


@pytest.mark.parametrize("kw, words", [
    (dict(pixel_aspect=0), "pixel_aspect (fy / fx) must be positive"),
    (dict(pixel_aspect=float("nan")), "pixel_aspect must be a finite number"),
    (dict(principal_point_offset=(0.1,)), "principal_point_offset must be 2 finite numbers"),
    (dict(principal_point_offset=(0.1, float("inf"))), "principal_point_offset must be 2 finite numbers"),
])  # fmt: skip
def test_bad_camera_fields(kw, words):
    with pytest.raises(SceneError, match=words.replace("(", r"\(").replace(")", r"\)")):
        Camera(**kw)


# ---------------------------------------------------------------- principal point against a crop


def test_principal_point_offset_equals_a_shifted_crop_of_a_wider_render():
    """A 16 x 12 camera with the wide camera's focal length and its principal point moved by the
    crop's offset renders the crop (5, 9) .. (21, 21) of a 32 x 24 render: its rays are the wide
    camera's rays shifted by the offset, and its image differs from the crop by no more than two
    renders of the same camera with other seeds do, while a principal point one pixel off does not."""
    W, H, w, h, ox, oy = 32, 24, 16, 12, 5, 9
    wide = cornell_box(resolution=(W, H))
    c = wide.camera
    fx, fy, cx, cy = c.intrinsics(W, H)

    def crop_scene(dx=0, dy=0):
        cam = Camera.from_intrinsics(fx, fy, cx - ox - dx, cy - oy - dy, w, h, origin=c.origin, target=c.target, up=c.up)
        return dataclasses.replace(wide, camera=cam, resolution=(w, h))

    cam = crop_scene().camera
    assert cam.principal_point_offset == pytest.approx(((ox - (W - w) / 2) / w, (oy - (H - h) / 2) / h))
    xy, (_, d) = rays(cam, (w, h))
    _, d_wide = c.generate_rays(xy + torch.tensor([ox, oy], dtype=torch.float32), W, H)
    assert torch.allclose(d, d_wide, atol=3e-7)

    def render(scene, seed):
        return ir.render(scene, spp=256, max_depth=3, seed=seed, progress=False)

    def rms(x):
        return float(x.pow(2).mean().sqrt())

    ref = render(wide, 0)[oy : oy + h, ox : ox + w]
    noise = rms(render(wide, 1)[oy : oy + h, ox : ox + w] - ref)
    assert rms(render(crop_scene(), 2) - ref) < 1.3 * noise
    assert rms(render(crop_scene(dx=1), 2) - ref) > 3 * noise
    assert rms(render(crop_scene(dy=-1), 2) - ref) > 3 * noise


def test_mitsuba_principal_point_offset_loads(tmp_path):
    xml = """<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="40"/>
        <float name="principal_point_offset_x" value="-0.1875"/><float name="principal_point_offset_y" value="0.25"/>
        <transform name="to_world"><lookat origin="0.3, 0.2, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/></film></sensor>
    <shape type="sphere"/></scene>"""
    (tmp_path / "s.xml").write_text(xml)
    cam = ir.load_scene(tmp_path / "s.xml").camera
    assert cam.principal_point_offset == (-0.1875, 0.25)
    thin = xml.replace('type="perspective"', 'type="thinlens"').replace('<float name="fov"', '<float name="aperture_radius" value="0.1"/><float name="fov"')
    (tmp_path / "t.xml").write_text(thin)
    with pytest.raises(SceneError, match="principal_point_offset_x"):
        ir.load_scene(tmp_path / "t.xml")


def test_principal_point_offset_matches_mitsuba(tmp_path):
    """Mitsuba 3's own perspective sensor (scalar variant) traces the same rays."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    test_mitsuba_principal_point_offset_loads(tmp_path)
    sensor = mi.load_file(str(tmp_path / "s.xml")).sensors()[0]
    cam = ir.load_scene(tmp_path / "s.xml").camera
    for u in [(0.25, 0.6), (0.9, 0.1), (0.05, 0.95)]:
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(*u), mi.Point2f(0.5, 0.5))
        _, d = cam.generate_rays(torch.tensor([[u[0] * 16, u[1] * 12]]), 16, 12)
        assert np.allclose([float(x) for x in ray.d], d[0].numpy(), atol=1e-6)


# ---------------------------------------------------------------- conventions of the files


def test_transforms_json_reads_the_opengl_convention(tmp_path):
    """A hand-made instant-ngp style file: a world point projects, by the format's own formula,
    to the pixel whose ray passes through it."""
    rng = np.random.default_rng(3)
    c2w = tf.random_rotation_matrix(rng.random(3))
    c2w[:3, 3] = [0.5, -1.0, 2.0]
    w, h, fx, fy, cx, cy = 40, 30, 35.0, 38.0, 21.5, 14.0
    (tmp_path / "a.png").write_bytes(b"")
    doc = {"fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": w, "h": h, "aabb_scale": 4, "k1": 0.0, "frames": [{"file_path": "a.png", "transform_matrix": c2w.tolist()}]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    (frame,) = load_cameras(tmp_path)
    assert frame.image == tmp_path / "a.png" and frame.resolution == (w, h)
    local = np.array([0.3, -0.2, -2.0])  # in front: the camera looks along -z
    p = c2w[:3, :3] @ local + c2w[:3, 3]
    u, v = cx + fx * local[0] / -local[2], cy - fy * local[1] / -local[2]  # +y up in the camera, down in the image
    o, d = frame.camera.generate_rays(torch.tensor([[u, v]], dtype=torch.float32), w, h)
    assert np.allclose(o[0].numpy(), c2w[:3, 3], atol=1e-6)
    assert np.allclose(d[0].numpy(), (p - c2w[:3, 3]) / np.linalg.norm(p - c2w[:3, 3]), atol=1e-6)


def test_blender_nerf_file_camera_angle_and_paths_without_suffix(tmp_path):
    (tmp_path / "train").mkdir()
    ir.write_image(tmp_path / "train" / "r_0.png", torch.zeros(10, 16, 3))
    c2w = np.eye(4)
    c2w[:3, 3] = [0, 0, 4]
    doc = {"camera_angle_x": 0.6911112070083618, "frames": [{"file_path": "./train/r_0", "rotation": 0.012, "transform_matrix": c2w.tolist()}]}
    (tmp_path / "transforms_train.json").write_text(json.dumps(doc))
    (frame,) = ir.load_cameras(tmp_path / "transforms_train.json")
    assert frame.image == tmp_path / "train" / "r_0.png" and frame.resolution == (16, 10)  # the size from the image
    fx, fy, cx, cy = frame.camera.intrinsics(16, 10)
    assert fx == pytest.approx(8 / math.tan(0.6911112070083618 / 2)) and fy == pytest.approx(fx) and (cx, cy) == (8.0, 5.0)
    right, up, forward = (v.numpy() for v in frame.camera.frame())
    assert np.allclose(forward, [0, 0, -1]) and np.allclose(up, [0, 1, 0]) and np.allclose(right, [1, 0, 0])


def test_colmap_reads_world_to_camera_poses(tmp_path):
    """COLMAP's projection x = K (R X + t), pixel centres at i + 0.5, against the loaded camera's
    rays; SIMPLE_PINHOLE and PINHOLE, a quaternion that is not normalized, images two levels up
    (COLMAP's sparse/0 layout), an image without its POINTS2D line."""
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    write_images(tmp_path / "images", 2)
    q = tf.quaternion_from_euler(0.3, -0.5, 0.2)  # (w, x, y, z)
    R, t = tf.quaternion_matrix(q)[:3, :3], np.array([0.2, -0.1, 3.0])
    (model / "cameras.txt").write_text("# comment\n1 SIMPLE_PINHOLE 12 10 11.0 6.5 4.5\n2 PINHOLE 12 10 10.0 13.0 6.0 5.0\n")
    (model / "images.txt").write_text(
        "# Image list\n"
        f"1 {' '.join(str(2 * x) for x in q)} {' '.join(map(str, t))} 1 img_0.png\n1.0 2.0 -1 3.0 4.0 7\n"
        f"2 1 0 0 0 0 0 0 2 img_1.png\n"
    )  # fmt: skip
    a, b = ir.load_cameras(model / "images.txt")
    assert a.image == tmp_path / "images" / "img_0.png" and a.resolution == (12, 10)
    X = np.array([0.1, 0.3, 0.2])
    Xc = R @ X + t
    u, v = 11.0 * Xc[0] / Xc[2] + 6.5, 11.0 * Xc[1] / Xc[2] + 4.5
    o, d = a.camera.generate_rays(torch.tensor([[u, v]], dtype=torch.float32), 12, 10)
    centre = -R.T @ t
    assert np.allclose(o[0].numpy(), centre, atol=1e-6) and np.allclose(d[0].numpy(), (X - centre) / np.linalg.norm(X - centre), atol=1e-6)
    # identity pose: at the origin looking along +z, image y down = world -y up
    right, up, forward = (v.numpy() for v in b.camera.frame())
    assert np.allclose(forward, [0, 0, 1]) and np.allclose(up, [0, -1, 0]) and np.allclose(right, [1, 0, 0])
    assert b.camera.intrinsics(12, 10) == pytest.approx((10.0, 13.0, 6.0, 5.0))


# ---------------------------------------------------------------- round trips


@pytest.mark.parametrize("make", [lambda: cornell_box(resolution=(20, 16)), lambda: sky_spheres(resolution=(16, 12), subdivisions=2)], ids=["cornell_box", "sky_spheres"])
@pytest.mark.parametrize("fmt", ["transforms", "colmap"])
def test_shipped_scene_cameras_round_trip_render_the_same(make, fmt, tmp_path):
    scene = make()
    cams = [scene.camera] + orbit(2)
    images = write_images(tmp_path / "images", len(cams))
    if fmt == "transforms":
        write_transforms(tmp_path / "transforms.json", cams, scene.resolution, images)
        frames = load_cameras(tmp_path / "transforms.json")
    else:
        write_colmap(tmp_path / "model", cams, scene.resolution, images)
        frames = load_cameras(tmp_path / "model")
    assert [f.image.resolve() for f in frames] == [p.resolve() for p in images] and {f.resolution for f in frames} == {scene.resolution}
    for cam, frame in zip(cams, frames):
        assert np.allclose(frame.camera.intrinsics(*scene.resolution), cam.intrinsics(*scene.resolution), rtol=1e-12)
        for v, v2 in zip(cam.frame(), frame.camera.frame()):
            assert torch.allclose(v, v2, atol=1e-12)
        assert np.allclose(frame.camera.origin, cam.origin, atol=1e-12)
    for cam, frame in list(zip(cams, frames))[:2]:
        ref = ir.render(scene.with_camera(cam), spp=4, max_depth=3, seed=1, progress=False)
        img = ir.render(scene.with_camera(frame.camera), spp=4, max_depth=3, seed=1, progress=False)
        assert torch.allclose(img, ref, rtol=1e-5, atol=1e-6), float((img - ref).abs().max())


def test_writers_share_intrinsics_and_refuse_thin_lenses(tmp_path):
    cams = orbit(3)
    write_colmap(tmp_path, cams, (12, 10))
    lines = [x for x in (tmp_path / "cameras.txt").read_text().splitlines() if not x.startswith("#")]
    assert len(lines) == 2 and (tmp_path / "points3D.txt").exists()  # two distinct intrinsics
    write_transforms(tmp_path / "t.json", cams[:2], (12, 10))
    doc = json.loads((tmp_path / "t.json").read_text())
    assert doc["w"] == 12 and "fl_x" not in doc["frames"][0] and "file_path" not in doc["frames"][0]
    assert len(load_cameras(tmp_path / "t.json", require_images=False)) == 2
    thin = dataclasses.replace(cams[0], aperture_radius=0.1)
    for write, where in ((write_transforms, tmp_path / "u.json"), (write_colmap, tmp_path / "m")):
        with pytest.raises(SceneError, match="camera 1 is a thin lens"):
            write(where, [cams[0], thin], (12, 10))
        assert not where.exists()


# ---------------------------------------------------------------- bad input


C2W = np.eye(4).tolist()
GOOD_FRAME = {"file_path": "a.png", "transform_matrix": C2W}
MIRROR = np.diag([1.0, 1.0, -1.0, 1.0]).tolist()


@pytest.mark.parametrize("doc, words", [
    ("{", "not valid JSON"),
    ({"camera_angle_x": 0.7}, "no 'frames' list"),
    ({"camera_angle_x": 0.7, "frames": []}, "'frames' is empty: no camera poses"),
    ({"camera_angle_x": 0.7, "frames": [{"file_path": "a.png"}]}, "frame 0: no 'transform_matrix'"),
    ({"camera_angle_x": 0.7, "frames": [{"file_path": "a.png", "transform_matrix": [[1, 0], [0, 1]]}]}, "must be a 4x4"),
    ({"camera_angle_x": 0.7, "frames": [{"file_path": "a.png", "transform_matrix": MIRROR}]}, "mirrored"),
    ({"camera_angle_x": 0.7, "frames": [GOOD_FRAME, {"file_path": "b", "transform_matrix": C2W}]}, "frame 1: image 'b' not found"),
    ({"camera_angle_x": 0.7, "frames": [{"transform_matrix": C2W}]}, "no 'file_path'"),
    ({"frames": [GOOD_FRAME]}, "no focal length"),
    ({"camera_angle_x": 4.0, "frames": [GOOD_FRAME]}, "'camera_angle_x' must lie in (0, pi)"),
    ({"fl_x": 10, "k1": 0.1, "frames": [GOOD_FRAME]}, "lens distortion k1 = 0.1 is not supported"),
    ({"fl_x": 10, "camera_model": "OPENCV_FISHEYE", "frames": [GOOD_FRAME]}, "camera_model 'OPENCV_FISHEYE' is not supported"),
    ({"fl_x": 10, "w": 0, "h": 4, "frames": [GOOD_FRAME]}, "'w' must be a positive whole number"),
])  # fmt: skip
def test_bad_transforms_json_one_line_naming_the_file(doc, words, tmp_path):
    ir.write_image(tmp_path / "a.png", torch.zeros(4, 6, 3))
    path = tmp_path / "transforms.json"
    path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    with pytest.raises(SceneError) as e:
        load_cameras(path)
    msg = str(e.value)
    assert str(path) in msg and words in msg and "\n" not in msg, msg


GOOD_CAMERAS = "1 PINHOLE 6 4 5 5 3 2\n"
GOOD_IMAGES = "1 1 0 0 0 0 0 3 1 a.png\n\n"


@pytest.mark.parametrize("cameras, images, file, words", [
    ("1 OPENCV 6 4 5 5 3 2 0.1 0 0 0\n", GOOD_IMAGES, "cameras.txt:1", "camera model 'OPENCV' is not supported (supported: SIMPLE_PINHOLE, PINHOLE"),
    ("1 SIMPLE_RADIAL 6 4 5 3 2 0\n", GOOD_IMAGES, "cameras.txt:1", "camera model 'SIMPLE_RADIAL' is not supported"),
    ("# c\n1 PINHOLE 6\n", GOOD_IMAGES, "cameras.txt:2", "malformed line"),
    ("1 PINHOLE 6 4 5 5 3\n", GOOD_IMAGES, "cameras.txt:1", "a PINHOLE camera has 4 parameters"),
    ("1 PINHOLE 6 x 5 5 3 2\n", GOOD_IMAGES, "cameras.txt:1", "HEIGHT must be an integer, got 'x'"),
    ("1 PINHOLE 6 4 5 nan 3 2\n", GOOD_IMAGES, "cameras.txt:1", "fy must be a finite number"),
    (GOOD_CAMERAS + GOOD_CAMERAS, GOOD_IMAGES, "cameras.txt:2", "camera 1 is defined twice"),
    ("# none\n", GOOD_IMAGES, "cameras.txt", "no cameras"),
    (GOOD_CAMERAS, "1 1 0 0 0 0 0 3 1\n", "images.txt:1", "malformed line"),
    (GOOD_CAMERAS, "1 1 0 0 q 0 0 3 1 a.png\n", "images.txt:1", "QZ must be a finite number, got 'q'"),
    (GOOD_CAMERAS, "1 1 0 0 0 0 0 3 7 a.png\n", "images.txt:1", "camera 7 is not in cameras.txt"),
    (GOOD_CAMERAS, "1 0 0 0 0 0 0 3 1 a.png\n", "images.txt:1", "the quaternion (QW QX QY QZ) is zero"),
    (GOOD_CAMERAS, GOOD_IMAGES + "2 1 0 0 0 0 0 3 1 b.png\n\n", "images.txt:3", "image 'b.png' not found"),
    (GOOD_CAMERAS, "# nothing\n", "images.txt", "no images (no camera poses)"),
    (GOOD_CAMERAS, None, "images.txt", "images.txt not found"),
])  # fmt: skip
def test_bad_colmap_model_one_line_naming_the_file(cameras, images, file, words, tmp_path):
    ir.write_image(tmp_path / "a.png", torch.zeros(4, 6, 3))
    (tmp_path / "cameras.txt").write_text(cameras)
    if images is not None:
        (tmp_path / "images.txt").write_text(images)
    with pytest.raises(SceneError) as e:
        load_cameras(tmp_path / "cameras.txt")
    msg = str(e.value)
    assert file in msg and words in msg and "\n" not in msg, msg


def test_bad_camera_paths(tmp_path):
    for path, words in ((tmp_path / "nope.json", "not found"), (tmp_path, "holds neither a transforms.json nor a COLMAP"), (tmp_path / "x.yaml", "expected a transforms.json")):
        if path.suffix == ".yaml":
            path.write_text("")
        with pytest.raises(SceneError, match=words):
            load_cameras(path)
    (tmp_path / "sparse" / "0").mkdir(parents=True)
    (tmp_path / "sparse" / "0" / "cameras.bin").write_bytes(b"\0")
    with pytest.raises(SceneError, match="binary COLMAP model: export it as text"):
        load_cameras(tmp_path)


# ---------------------------------------------------------------- invrender fit --cameras


def test_fit_cli_with_cameras_fits_every_view(tmp_path, capsys):
    """Two views written as transforms.json with their renders as the images: the fit renders each
    view against its own image (a loss at the noise level, far below that of the same file with
    the images swapped) and writes one final render per view."""
    scene = cornell_box(resolution=(10, 10))
    cams = [scene.camera, orbit(3)[0]]
    images = [tmp_path / f"view_{i}.exr" for i in range(2)]
    for cam, path in zip(cams, images):
        ir.write_image(path, ir.render(scene.with_camera(cam), spp=256, max_depth=2, seed=7, progress=False))
    args = ["fit", "--scene", "cornell_box", "--params", "light.emission", "--steps", "1", "--spp", "64", "--spp-final", "64", "--max-depth", "2", "--quiet"]
    loss = {}
    for order in ("same", "swapped"):
        write_transforms(tmp_path / f"{order}.json", cams, scene.resolution, images if order == "same" else images[::-1])
        out = tmp_path / order
        assert main(args + ["--cameras", str(tmp_path / f"{order}.json"), "--out", str(out)]) == 0
        report = json.loads((out / "report.json").read_text())
        loss[order] = report["final_loss"]
    assert report["targets"] == [str(p) for p in images[::-1]] and report["cameras"] == str(tmp_path / "swapped.json")
    assert (out / "final_00.exr").exists() and (out / "final_01.exr").exists()
    assert loss["same"] < 0.1 * loss["swapped"], loss
    # bad input: one line, exit 2, nothing written
    (tmp_path / "bad.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": [{"file_path": "gone", "transform_matrix": C2W}]}))
    capsys.readouterr()
    assert main(args + ["--cameras", str(tmp_path / "bad.json"), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.json: frame 0: image 'gone' not found" in err[0] and not (tmp_path / "o2" / "report.json").exists()


def test_the_scene_formats_camera_table_takes_the_intrinsics(tmp_path):
    """TOML ``[camera]`` keys ``principal_point_offset`` and ``pixel_aspect`` reach the Camera;
    a malformed offset is a one-line error naming the key."""
    from invrender.errors import SceneError
    from invrender.scene.formats.toml import camera_from_table

    cam = camera_from_table({"principal_point_offset": [0.1, -0.25], "pixel_aspect": 1.5}, "scene.toml [camera]")
    assert cam.principal_point_offset == (0.1, -0.25) and cam.pixel_aspect == 1.5
    with pytest.raises(SceneError, match=r"scene.toml \[camera\]: 'principal_point_offset' must be \[ox, oy\]"):
        camera_from_table({"principal_point_offset": [0.1]}, "scene.toml [camera]")
