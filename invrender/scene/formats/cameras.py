"""Camera poses and intrinsics from the files multi-view datasets ship, and writers for them.

Two formats, both read into a list of :class:`Frame` (camera, image path, resolution) and written
from a list of :class:`~invrender.scene.camera.Camera` (docs/cameras.md states every convention):

NeRF ``transforms.json`` (the Blender synthetic scenes, instant-ngp, nerfstudio)
    ``frames``: a list of ``{"file_path": ..., "transform_matrix": ...}``; ``transform_matrix`` is
    the 4 x 4 (or 3 x 4) camera-to-world matrix in the OpenGL convention: its columns are the
    camera's +x (image right), +y (image up) and +z axes and its position; the camera looks along
    -z. Columns are normalized (a uniform scale is harmless); sheared or mirrored matrices are
    errors. Intrinsics at the top level or per frame (a frame's own win): ``fl_x`` / ``fl_y``
    (pixels; ``fl_y`` defaults to ``fl_x``) or ``camera_angle_x`` / ``camera_angle_y`` (full angles
    in radians), ``cx`` / ``cy`` (pixels, default the image centre), ``w`` / ``h`` (default: the
    image's size). Pixel coordinates as COLMAP's: the top-left corner is (0, 0), pixel centres are
    at i + 0.5. ``file_path`` is relative to the JSON file and may omit the image's suffix (the
    Blender scenes' ``./train/r_0``): the first of the suffixes invrender reads that exists is
    taken. Non-zero lens distortion (``k1`` .. ``k4``, ``p1``, ``p2``), a fisheye and camera models
    other than pinholes are errors; other keys (``aabb_scale``, ``scale``, ``offset``, a frame's
    ``rotation`` ...) are ignored.

COLMAP's text export (``cameras.txt`` + ``images.txt`` in one folder)
    ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS``; the models ``SIMPLE_PINHOLE``
    (f, cx, cy) and ``PINHOLE`` (fx, fy, cx, cy), in pixels, the top-left pixel's centre at
    (0.5, 0.5); any other model is an error (undistort the images first: COLMAP's
    ``image_undistorter`` writes PINHOLE cameras). ``images.txt``: per image a line
    ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` and a line of 2D points (read past): the
    world-to-camera rotation as a Hamilton quaternion (normalized on reading) and translation,
    camera coordinates x right, y down, z forward (the camera looks along +z). ``NAME`` is relative
    to the image folder: ``images`` when given, else the first of the model folder, its
    ``images/`` and the ``images/`` folders one and two levels up (COLMAP's ``sparse/0`` layout)
    that holds the file.

Every bad input raises :class:`~invrender.errors.SceneError` with a one-line message naming the file
(and line or frame), before any work starts; writers write atomically.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np
import trimesh.transformations as tf

from invrender.errors import ImageError, SceneError
from invrender.io.atomic import atomic_file
from invrender.io.images import READ_SUFFIXES, read_image
from invrender.scene.camera import Camera

#: the COLMAP camera models read, with their parameters
COLMAP_MODELS = {"SIMPLE_PINHOLE": ("f", "cx", "cy"), "PINHOLE": ("fx", "fy", "cx", "cy")}
#: transforms.json lens distortion coefficients, which must be 0 when present
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
#: transforms.json ``camera_model`` values that are pinholes (with zero distortion)
PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV")
#: tolerance of the orthogonality check of a transform_matrix's rotation (after normalizing its columns)
ORTHO_TOL = 1e-4


class Frame(NamedTuple):
    """One view of a dataset.

    Attributes:
        camera: the pinhole :class:`~invrender.scene.camera.Camera`.
        image: the view's image file, or None (not given, or not found with ``require_images=False``).
        resolution: (width, height) in pixels.
    """

    camera: Camera
    image: Path | None
    resolution: tuple[int, int]


# ---------------------------------------------------------------- reading


def load_cameras(path, *, images=None, require_images: bool = True) -> list[Frame]:
    """The views of a dataset file: a ``transforms.json`` (any ``.json``), a COLMAP ``cameras.txt``
    or ``images.txt``, or a folder holding ``transforms.json`` or ``cameras.txt`` + ``images.txt``
    (directly or in ``sparse/0``).

    Args:
        images: COLMAP only: the folder the image names are relative to (module docstring).
        require_images: a view whose image file does not exist is an error (True) or gets
            ``image=None`` (False).
    Returns:
        one :class:`Frame` per view, in the file's order.
    """
    path = Path(path)
    if not path.exists():
        raise SceneError(f"camera file {path} not found (expected a transforms.json, a COLMAP cameras.txt / images.txt or a folder holding them)")
    if path.is_dir():
        if (path / "transforms.json").is_file():
            return load_transforms(path / "transforms.json", require_images=require_images)
        for folder in (path, path / "sparse" / "0", path / "sparse"):
            if (folder / "cameras.txt").is_file():
                return load_colmap(folder, images=images, require_images=require_images)
            if (folder / "cameras.bin").is_file():
                raise SceneError(f"{folder} holds a binary COLMAP model: export it as text (colmap model_converter --output_type TXT)")
        raise SceneError(f"{path} holds neither a transforms.json nor a COLMAP cameras.txt and images.txt")
    if path.suffix.lower() == ".json":
        return load_transforms(path, require_images=require_images)
    if path.name in ("cameras.txt", "images.txt"):
        return load_colmap(path.parent, images=images, require_images=require_images)
    raise SceneError(f"camera file {path}: expected a transforms.json (.json), a COLMAP cameras.txt or images.txt, or a folder")


def common_resolution(frames: list[Frame], where) -> tuple[int, int]:
    """The (width, height) every frame shares; a :class:`SceneError` naming ``where`` when they differ."""
    sizes = sorted({f.resolution for f in frames})
    if len(sizes) > 1:
        raise SceneError(f"{where}: the views have different sizes ({', '.join(f'{w}x{h}' for w, h in sizes)}); one fit renders one size")
    return sizes[0]


def load_transforms(path, *, require_images: bool = True) -> list[Frame]:
    """The views of a NeRF ``transforms.json`` (module docstring)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except OSError as e:
        raise SceneError(f"cannot read {path}: {e.strerror or e}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SceneError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("frames"), list):
        raise SceneError(f"{path}: no 'frames' list (a transforms.json lists its views, each with a camera-to-world 'transform_matrix', under 'frames')")
    if not doc["frames"]:
        raise SceneError(f"{path}: 'frames' is empty: no camera poses")
    return [_nerf_frame(path, doc, frame, i, require_images) for i, frame in enumerate(doc["frames"])]


def _nerf_frame(path: Path, doc: dict, frame, i: int, require_images: bool) -> Frame:
    where = f"{path}: frame {i}"
    if not isinstance(frame, dict):
        raise SceneError(f"{where}: expected an object with 'file_path' and 'transform_matrix', got {type(frame).__name__}")
    if "transform_matrix" not in frame:
        raise SceneError(f"{where}: no 'transform_matrix' (the camera-to-world pose)")
    matrix = _matrix(frame["transform_matrix"], where)

    def key(name):
        return frame[name] if name in frame else doc.get(name)

    model = key("camera_model")
    if model is not None and str(model).upper() not in PINHOLE_MODELS:
        raise SceneError(f"{where}: camera_model {model!r} is not supported (supported: pinholes, {', '.join(PINHOLE_MODELS)} without distortion)")
    if key("is_fisheye"):
        raise SceneError(f"{where}: fisheye cameras are not supported (invrender's camera is a pinhole)")
    for name in DISTORTION_KEYS:
        value = key(name)
        if value is not None and _number(value, f"{where}: '{name}'") != 0:
            raise SceneError(f"{where}: lens distortion {name} = {value:g} is not supported (undistort the images first)")

    image = None
    if key("file_path") is not None:
        image = _find_image(path.parent / str(key("file_path")))
        if image is None and require_images:
            raise SceneError(f"{where}: image {key('file_path')!r} not found (looked beside {path.name}, with and without the suffixes {', '.join(READ_SUFFIXES)})")
    elif require_images:
        raise SceneError(f"{where}: no 'file_path' (the view's image)")

    w, h = key("w"), key("h")
    if w is None or h is None:
        if image is None:
            raise SceneError(f"{where}: no image size: give 'w' and 'h' or an existing image")
        w, h = _image_size(image, where)
    w, h = _size(w, f"{where}: 'w'"), _size(h, f"{where}: 'h'")

    fx = _focal(key("fl_x"), key("camera_angle_x"), w, where, "x")
    if fx is None:
        raise SceneError(f"{where}: no focal length: give 'fl_x' (pixels) or 'camera_angle_x' (the horizontal field of view, radians)")
    fy = _focal(key("fl_y"), key("camera_angle_y"), h, where, "y") or fx
    cx = _number(key("cx"), f"{where}: 'cx'") if key("cx") is not None else w / 2.0
    cy = _number(key("cy"), f"{where}: 'cy'") if key("cy") is not None else h / 2.0
    right, up, back = (_unit(matrix[:3, c], f"{where}: 'transform_matrix'") for c in range(3))
    _check_frame(right, up, back, f"{where}: 'transform_matrix'")
    origin = matrix[:3, 3]
    pose = dict(origin=tuple(origin), target=tuple(origin - back), up=tuple(up))
    return Frame(_camera(fx, fy, cx, cy, w, h, pose, where), image, (w, h))


def load_colmap(folder, *, images=None, require_images: bool = True) -> list[Frame]:
    """The views of a COLMAP text model: ``folder/cameras.txt`` and ``folder/images.txt`` (module
    docstring)."""
    folder = Path(folder)
    cameras_txt, images_txt = folder / "cameras.txt", folder / "images.txt"
    for f in (cameras_txt, images_txt):
        if not f.is_file():
            raise SceneError(f"COLMAP model {folder}: {f.name} not found (a text model has cameras.txt and images.txt)")
    intrinsics = {}
    for n, line in _lines(cameras_txt):
        fields = line.split()
        if len(fields) < 4:
            raise SceneError(f"{cameras_txt}:{n}: malformed line (expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...'): {_short(line)}")
        cam_id, model = _int(fields[0], cameras_txt, n, "CAMERA_ID"), fields[1]
        if model not in COLMAP_MODELS:
            raise SceneError(f"{cameras_txt}:{n}: camera model {model!r} is not supported (supported: {', '.join(COLMAP_MODELS)}; undistort the images first, e.g. colmap image_undistorter)")
        names = COLMAP_MODELS[model]
        if len(fields) != 4 + len(names):
            raise SceneError(f"{cameras_txt}:{n}: a {model} camera has {len(names)} parameters ({', '.join(names)}), got {len(fields) - 4}")
        if cam_id in intrinsics:
            raise SceneError(f"{cameras_txt}:{n}: camera {cam_id} is defined twice")
        w, h = (_size(_int(v, cameras_txt, n, k), f"{cameras_txt}:{n}: {k}") for v, k in zip(fields[2:4], ("WIDTH", "HEIGHT")))
        params = [_float(v, cameras_txt, n, k) for v, k in zip(fields[4:], names)]
        fx, fy, cx, cy = (params[0], params[0], params[1], params[2]) if model == "SIMPLE_PINHOLE" else params
        intrinsics[cam_id] = (fx, fy, cx, cy, w, h, f"{cameras_txt}:{n}")
    if not intrinsics:
        raise SceneError(f"{cameras_txt}: no cameras")

    roots = [Path(images)] if images is not None else [folder, folder / "images", folder.parent / "images", folder.parent.parent / "images"]
    frames, lines = [], _lines(images_txt, keep_blank=True)
    k = 0
    while k < len(lines):
        n, line = lines[k]
        k += 1
        if not line.strip():
            continue
        fields = line.split()
        if len(fields) != 10:
            raise SceneError(f"{images_txt}:{n}: malformed line (expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME'): {_short(line)}")
        _int(fields[0], images_txt, n, "IMAGE_ID")
        q = np.array([_float(v, images_txt, n, name) for v, name in zip(fields[1:5], ("QW", "QX", "QY", "QZ"))])
        t = np.array([_float(v, images_txt, n, name) for v, name in zip(fields[5:8], ("TX", "TY", "TZ"))])
        cam_id, name = _int(fields[8], images_txt, n, "CAMERA_ID"), fields[9]
        if k < len(lines) and not _is_image_line(lines[k][1]):
            k += 1  # the image's POINTS2D line (read past)
        if cam_id not in intrinsics:
            raise SceneError(f"{images_txt}:{n}: camera {cam_id} is not in cameras.txt")
        norm = float(np.linalg.norm(q))
        if norm < 1e-12:
            raise SceneError(f"{images_txt}:{n}: the quaternion (QW QX QY QZ) is zero")
        rotation = tf.quaternion_matrix(q / norm)[:3, :3]  # world to camera; its rows are the camera's axes
        right, down, forward = rotation
        origin = -rotation.T @ t
        image = next((root / name for root in roots if (root / name).is_file()), None)
        if image is None and require_images:
            raise SceneError(f"{images_txt}:{n}: image {name!r} not found (looked in {', '.join(str(r) for r in roots)})")
        fx, fy, cx, cy, w, h, where = intrinsics[cam_id]
        pose = dict(origin=tuple(origin), target=tuple(origin + forward), up=tuple(-down))
        frames.append(Frame(_camera(fx, fy, cx, cy, w, h, pose, where), image, (w, h)))
    if not frames:
        raise SceneError(f"{images_txt}: no images (no camera poses)")
    return frames


def _lines(path: Path, keep_blank: bool = False) -> list[tuple[int, str]]:
    """(1-based line number, text) of the lines of a COLMAP text file, comments left out."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f"cannot read {path}: {getattr(e, 'strerror', None) or e}") from None
    return [(n, line) for n, line in enumerate(text.splitlines(), 1) if not line.startswith("#") and (keep_blank or line.strip())]


def _is_image_line(line: str) -> bool:
    """Whether an images.txt line is an image line (10 fields, numbers first) rather than a POINTS2D
    line (X Y POINT3D_ID triples): lets a file without POINTS2D lines through."""
    fields = line.split()
    if len(fields) != 10:
        return False
    try:
        [float(v) for v in fields[:9]]
    except ValueError:
        return False
    return True


def _camera(fx, fy, cx, cy, w, h, pose, where) -> Camera:
    try:
        return Camera.from_intrinsics(fx, fy, cx, cy, w, h, **pose)
    except SceneError as e:
        raise SceneError(f"{where}: {e}") from None


def _matrix(value, where: str) -> np.ndarray:
    try:
        m = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        m = None
    if m is None or m.shape not in ((4, 4), (3, 4)) or not np.isfinite(m).all():
        raise SceneError(f"{where}: 'transform_matrix' must be a 4x4 (or 3x4) matrix of finite numbers")
    return m


def _unit(v: np.ndarray, where: str) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        raise SceneError(f"{where}: its rotation has a zero column (singular)")
    return v / n


def _check_frame(right, up, back, where: str) -> None:
    if max(abs(right @ up), abs(up @ back), abs(right @ back)) > ORTHO_TOL:
        raise SceneError(f"{where}: its rotation columns are not orthogonal (a shear): expected a rotation and translation")
    if np.cross(right, up) @ back < 0:
        raise SceneError(f"{where}: its rotation is mirrored (determinant < 0): expected a rotation and translation")


def _focal(fl, angle, size: int, where: str, axis: str) -> float | None:
    """A focal length in pixels from ``fl_<axis>`` or ``camera_angle_<axis>``; None when neither is given."""
    if fl is not None:
        return _number(fl, f"{where}: 'fl_{axis}'")
    if angle is not None:
        a = _number(angle, f"{where}: 'camera_angle_{axis}'")
        if not 0 < a < math.pi:
            raise SceneError(f"{where}: 'camera_angle_{axis}' must lie in (0, pi) radians, got {a:g}")
        return size / (2.0 * math.tan(a / 2.0))
    return None


def _number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _size(value, where: str) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise SceneError(f"{where} must be a positive whole number of pixels, got {value!r}")
    return value


def _int(text: str, path: Path, n: int, name: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise SceneError(f"{path}:{n}: {name} must be an integer, got {text!r}") from None


def _float(text: str, path: Path, n: int, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise SceneError(f"{path}:{n}: {name} must be a finite number, got {text!r}")
    return value


def _short(line: str) -> str:
    line = line.strip()
    return repr(line if len(line) <= 60 else line[:57] + "...")


def _find_image(path: Path) -> Path | None:
    """``path`` if it is a file, else ``path`` with the first suffix invrender reads (lower or
    upper case) that names one; None when none does."""
    if path.is_file():
        return path
    for suffix in READ_SUFFIXES:
        for s in (suffix, suffix.upper()):
            candidate = path.with_name(path.name + s)
            if candidate.is_file():
                return candidate
    return None


def _image_size(path: Path, where: str) -> tuple[int, int]:
    """(width, height) of an image file, from its header where PIL reads it."""
    try:
        if path.suffix.lower() in (".png", ".jpg", ".jpeg"):
            from PIL import Image

            with Image.open(path) as im:
                return im.size
        h, w = read_image(path).shape[:2]
        return w, h
    except ImageError as e:
        raise SceneError(f"{where}: {e}") from None
    except Exception as e:  # PIL's OSError / UnidentifiedImageError
        raise SceneError(f"{where}: cannot read the size of image {path} ({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None


# ---------------------------------------------------------------- writing


def write_transforms(path, cameras: list[Camera], resolution: tuple[int, int], images=None) -> None:
    """Write ``cameras`` (pinholes) on a ``resolution`` = (width, height) film as a NeRF
    ``transforms.json`` at ``path``, atomically: shared intrinsics at the top level (``fl_x``,
    ``fl_y``, ``cx``, ``cy``, ``w``, ``h`` and ``camera_angle_x`` / ``_y``), per frame when the
    cameras differ; ``file_path`` of ``images[i]`` relative to the file (omitted without ``images``)."""
    path = Path(path)
    w, h = resolution
    _check_writable(cameras, images, path)
    keys = [_nerf_intrinsics(c, w, h) for c in cameras]
    shared = all(k == keys[0] for k in keys)
    frames = []
    for i, cam in enumerate(cameras):
        right, up, forward = (v.numpy() for v in cam.frame())
        matrix = np.eye(4)
        matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = right, up, -forward, cam.origin
        frame = {} if images is None else {"file_path": _relative(images[i], path.parent)}
        frame["transform_matrix"] = matrix.tolist()
        frames.append(frame if shared else {**frame, **keys[i]})
    doc = {**(keys[0] if shared else {}), "frames": frames}
    text = re.sub(r"\[\s+([^\[\]{}\"]*?)\s+\]", lambda m: "[" + " ".join(m.group(1).split()) + "]", json.dumps(doc, indent=2))  # a matrix row on one line
    with atomic_file(path) as f:
        f.write((text + "\n").encode())


def write_colmap(folder, cameras: list[Camera], resolution: tuple[int, int], images=None) -> None:
    """Write ``cameras`` (pinholes) on a ``resolution`` = (width, height) film as a COLMAP text
    model in ``folder``: ``cameras.txt`` (one PINHOLE camera per distinct intrinsics),
    ``images.txt`` (world-to-camera poses; ``NAME`` the image's path relative to ``folder``, or
    ``view_NNN.png`` without ``images``) and an empty ``points3D.txt``; each file atomically."""
    folder = Path(folder)
    w, h = resolution
    _check_writable(cameras, images, folder)
    ids: dict[tuple, int] = {}
    image_lines = []
    for i, cam in enumerate(cameras):
        k = cam.intrinsics(w, h)
        cam_id = ids.setdefault(k, len(ids) + 1)
        right, up, forward = (v.numpy() for v in cam.frame())
        rotation = np.stack([right, -up, forward])  # world to camera: x right, y down, z forward
        t = -rotation @ np.asarray(cam.origin)
        m = np.eye(4)
        m[:3, :3] = rotation
        q = tf.quaternion_from_matrix(m, isprecise=True)
        q = -q if q[0] < 0 else q  # the same rotation; COLMAP keeps qw >= 0
        name = _relative(images[i], folder) if images is not None else f"view_{i:03d}.png"
        if any(c.isspace() for c in name):
            raise SceneError(f"COLMAP model {folder}: image name {name!r} contains whitespace, which images.txt cannot hold")
        image_lines.append(" ".join([str(i + 1), *(repr(float(x)) for x in (*q, *t)), str(cam_id), name]) + "\n\n")
    camera_lines = [" ".join([str(j), "PINHOLE", str(w), str(h), *(repr(float(x)) for x in k)]) + "\n" for k, j in ids.items()]
    texts = {
        "cameras.txt": f"# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# Number of cameras: {len(ids)}\n" + "".join(camera_lines),
        "images.txt": "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
        f"# Number of images: {len(cameras)}\n" + "".join(image_lines),
        "points3D.txt": "# 3D point list with one line of data per point:\n#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n# Number of points: 0\n",
    }
    for name, text in texts.items():
        with atomic_file(folder / name) as f:
            f.write(text.encode())


def _check_writable(cameras, images, where: Path) -> None:
    if not cameras:
        raise SceneError(f"{where}: no cameras to write")
    if images is not None and len(images) != len(cameras):
        raise SceneError(f"{where}: {len(cameras)} camera(s) but {len(images)} image(s)")
    for i, cam in enumerate(cameras):
        if not cam.is_pinhole:
            raise SceneError(f"{where}: camera {i} is a thin lens (aperture_radius {cam.aperture_radius:g}); transforms.json and COLMAP describe pinholes")


def _nerf_intrinsics(cam: Camera, w: int, h: int) -> dict:
    fx, fy, cx, cy = cam.intrinsics(w, h)
    angle_x, angle_y = 2.0 * math.atan(w / (2.0 * fx)), 2.0 * math.atan(h / (2.0 * fy))
    return {"camera_angle_x": angle_x, "camera_angle_y": angle_y, "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": w, "h": h}


def _relative(image, base: Path) -> str:
    return Path(os.path.relpath(Path(image).absolute(), base.absolute())).as_posix()


__all__ = ["Frame", "common_resolution", "load_cameras", "load_colmap", "load_transforms", "write_colmap", "write_transforms"]
