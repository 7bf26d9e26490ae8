"""Scene files: the TOML scene format, and glTF/GLB/OBJ files through trimesh.

TOML scene format (every key optional unless marked; unknown keys are errors)::

    name = "my scene"
    resolution = [64, 64]              # width, height (default 256 x 256)

    [camera]                           # defaults: Camera()'s (the Cornell box view)
    origin = [0, 0, 3.9]
    target = [0, 0, 0]
    up = [0, 1, 0]
    fov = 39.3077                      # degrees, along fov_axis
    fov_axis = "smaller"               # x | y | smaller | larger

    [materials.white]                  # one table per material: diffuse reflectance rho
    reflectance = [0.8, 0.8, 0.8]      # RGB in [0, 1] (or one number), or instead:
    # reflectance_texture = "albedo.png"   (relative to this file; PNG/JPEG sRGB-decoded, EXR linear)

    [emitters.light]                   # one table per emitter: emitted radiance eps (front side)
    emission = [17, 12, 4]             # RGB >= 0 (or one number), or emission_texture = "glow.exr"

    [[shapes]]                         # one table per shape
    type = "rectangle"                 # required: rectangle | cube | sphere | mesh
    material = "white"                 # required
    emitter = "light"
    file = "bunny.obj"                 # mesh only, required there: relative to this file (OBJ, glTF, GLB, PLY, STL)
    subdivisions = 3                   # sphere only: 20 * 4^n triangles
    flip_normals = false               # turn the shape inside out (front side = emitting side)
    transform = [{ scale = [0.23, 0.19, 0.19] }, { rotate = { axis = [1, 0, 0], angle = 90 } }, { translate = [0, 0.99, 0.01] }]
                                       # applied in the order listed (here: scale, then rotate, then translate)

Whole-scene mesh files (.gltf, .glb, .obj) load through trimesh with their scene-graph transforms:
each material becomes a material of the same name with rho = glTF ``baseColorFactor`` (RGB, linear)
x ``baseColorTexture`` (sRGB-decoded), or OBJ ``Kd``; a material with a non-zero glTF
``emissiveFactor`` x ``KHR_materials_emissive_strength`` (x ``emissiveTexture``) also becomes the
emitter ``<material>_emission``. A perspective glTF camera is used when the file has one (``yfov``,
looking down the camera node's -z); otherwise a camera looks at the bounding box from +z.
"""

from __future__ import annotations

import json
import math
import struct
import tomllib
from pathlib import Path

import numpy as np

from invrender.errors import InvRenderError, SceneError
from invrender.scene.camera import Camera
from invrender.scene.scene import Scene, build_scene
from invrender.scene.shapes import PRIMITIVES, Mesh, rotate, scale, translate

TOP_KEYS = {"name", "resolution", "camera", "materials", "emitters", "shapes"}
CAMERA_KEYS = {"origin", "target", "up", "fov", "fov_axis"}
MATERIAL_KEYS = {"reflectance", "reflectance_texture"}
EMITTER_KEYS = {"emission", "emission_texture"}
SHAPE_KEYS = {"type", "material", "emitter", "file", "subdivisions", "flip_normals", "transform"}
SHAPE_TYPES = (*PRIMITIVES, "mesh")
DEFAULT_RESOLUTION = (256, 256)


# ---------------------------------------------------------------- TOML


def load_toml(path, resolution=None) -> Scene:
    """A scene from a TOML scene file (format in this module's docstring)."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as e:
        raise SceneError(f"cannot read scene file {path}: {e.strerror or e}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise SceneError(f"{path}: invalid TOML: {e}") from None
    where = str(path)
    _check_keys(doc, TOP_KEYS, where)
    name = doc.get("name", path.stem)
    if not isinstance(name, str):
        raise SceneError(f"{where}: 'name' must be a string")

    camera_doc = _table(doc, "camera", where)
    _check_keys(camera_doc, CAMERA_KEYS, f"{where} [camera]")
    cam_args = {k: _vector(camera_doc, k, f"{where} [camera]") for k in ("origin", "target", "up") if k in camera_doc}
    if "fov" in camera_doc:
        cam_args["fov"] = _number(camera_doc, "fov", f"{where} [camera]")
    if "fov_axis" in camera_doc:
        cam_args["fov_axis"] = _string(camera_doc, "fov_axis", f"{where} [camera]")
    camera = Camera(**cam_args)

    reflectance = {
        k: _colour_or_texture(v, "reflectance", f"{where} [materials.{k}]", path.parent)
        for k, v in _table(doc, "materials", where).items()
    }
    emission = {
        k: _colour_or_texture(v, "emission", f"{where} [emitters.{k}]", path.parent)
        for k, v in _table(doc, "emitters", where).items()
    }
    shapes_doc = doc.get("shapes", [])
    if not isinstance(shapes_doc, list) or not all(isinstance(s, dict) for s in shapes_doc):
        raise SceneError(f"{where}: 'shapes' must be an array of tables ([[shapes]])")
    meshes = [_shape(s, f"{where} shapes[{i}]", path.parent) for i, s in enumerate(shapes_doc)]

    if resolution is None:
        resolution = tuple(_vector(doc, "resolution", where, length=2)) if "resolution" in doc else DEFAULT_RESOLUTION
    return build_scene(meshes, reflectance, emission, camera, resolution, name=name)


def _shape(doc: dict, where: str, base: Path) -> Mesh:
    _check_keys(doc, SHAPE_KEYS, where)
    kind = _string(doc, "type", where, required=True)
    if kind not in SHAPE_TYPES:
        raise SceneError(f"{where}: unknown shape type {kind!r} (known: {', '.join(SHAPE_TYPES)})")
    material = _string(doc, "material", where, required=True)
    emitter = _string(doc, "emitter", where) if "emitter" in doc else None
    if kind != "sphere" and "subdivisions" in doc:
        raise SceneError(f"{where}: 'subdivisions' applies to spheres only")
    if kind == "mesh":
        v, f, uv = _mesh_arrays(base / _string(doc, "file", where, required=True))
    else:
        if "file" in doc:
            raise SceneError(f"{where}: 'file' applies to type = \"mesh\" only")
        v, f, uv = PRIMITIVES[kind](int(_number(doc, "subdivisions", where))) if "subdivisions" in doc else PRIMITIVES[kind]()
    mesh = Mesh(v, f, uv, material, emitter)
    flip = doc.get("flip_normals", False)
    if not isinstance(flip, bool):
        raise SceneError(f"{where}: 'flip_normals' must be true or false")
    if flip:
        mesh = mesh.flipped()
    return mesh.transformed(_transform(doc.get("transform", []), where))


def _transform(ops, where: str) -> np.ndarray:
    """4x4 matrix of a list of {translate|rotate|scale} steps applied in order."""
    if not isinstance(ops, list):
        raise SceneError(f"{where}: 'transform' must be a list of {{translate|rotate|scale = ...}} tables")
    matrix = np.eye(4)
    for i, op in enumerate(ops):
        w = f"{where} transform[{i}]"
        if not isinstance(op, dict) or len(op) != 1:
            raise SceneError(f"{w}: each step must be one of {{ translate = [x, y, z] }}, {{ rotate = {{ axis = [x, y, z], angle = deg }} }}, {{ scale = s or [x, y, z] }}")
        (kind, value), = op.items()
        if kind == "translate":
            step = translate(_vector(op, kind, w))
        elif kind == "scale":
            step = scale(value if _is_number(value) else _vector(op, kind, w))
        elif kind == "rotate":
            if not isinstance(value, dict):
                raise SceneError(f"{w}: 'rotate' must be a table {{ axis = [x, y, z], angle = degrees }}")
            _check_keys(value, {"axis", "angle"}, f"{w} rotate")
            step = rotate(_vector(value, "axis", w), _number(value, "angle", w, required=True))
        else:
            raise SceneError(f"{w}: unknown transform step {kind!r} (known: translate, rotate, scale)")
        matrix = step @ matrix
    return matrix


def _colour_or_texture(doc, kind: str, where: str, base: Path):
    if not isinstance(doc, dict):
        raise SceneError(f"{where}: must be a table")
    _check_keys(doc, {kind, f"{kind}_texture"}, where)
    if (kind in doc) == (f"{kind}_texture" in doc):
        raise SceneError(f"{where}: give exactly one of '{kind}' or '{kind}_texture'")
    if kind in doc:
        value = doc[kind]
        return [float(value)] * 3 if _is_number(value) else _vector(doc, kind, where)
    from invrender.io import read_image

    texture_path = base / _string(doc, f"{kind}_texture", where)
    try:
        return read_image(texture_path)
    except InvRenderError as e:
        raise SceneError(f"{where}: {e}") from None


def _mesh_arrays(path: Path):
    """(vertices, faces, uvs) of a mesh file, all its parts merged in world space."""
    meshes = [m for m, _ in _trimesh_parts(path)]
    v = np.concatenate([m.vertices for m in meshes])
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    f = np.concatenate([m.faces + o for m, o in zip(meshes, offsets)])
    uv = np.concatenate([_uv(m) for m in meshes])
    if len(f) == 0:
        raise SceneError(f"mesh file {path} has no faces")
    return v, f, uv


# ---------------------------------------------------------------- glTF / GLB / OBJ


def load_mesh_file(path, resolution=None) -> Scene:
    """A whole scene from a .gltf/.glb/.obj file (mapping in this module's docstring)."""
    path = Path(path)
    gltf = _gltf_json(path) if path.suffix.lower() in (".gltf", ".glb") else {}
    factors = {m.get("name"): m for m in gltf.get("materials", []) if m.get("name")}
    meshes, reflectance, emission = [], {}, {}
    for mesh, material in _trimesh_parts(path):
        name = getattr(material, "name", None) or "default"
        if name not in reflectance:
            rho, eps = _material_values(material, factors.get(name, {}))
            reflectance[name] = rho
            if eps is not None:
                emission[f"{name}_emission"] = eps
        emitter = f"{name}_emission" if f"{name}_emission" in emission else None
        meshes.append(Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), _uv(mesh), name, emitter))
    camera, aspect = _gltf_camera(gltf)
    if camera is None:
        camera = _framing_camera(np.concatenate([m.vertices for m in meshes]))
    if resolution is None:
        resolution = (round(256 * aspect), 256) if aspect else DEFAULT_RESOLUTION
    return build_scene(meshes, reflectance, emission, camera, resolution, name=path.stem)


def _trimesh_parts(path: Path):
    """[(trimesh.Trimesh in world space, its material or None)] of a mesh file."""
    import trimesh

    if not path.is_file():
        raise SceneError(f"mesh file not found: {path}")
    try:
        scene = trimesh.load(str(path), force="scene")
    except Exception as e:
        raise SceneError(f"cannot read mesh file {path}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
    parts = []
    for node in scene.graph.nodes_geometry:
        transform, geometry = scene.graph[node]
        mesh = scene.geometry[geometry]
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            continue
        mesh = mesh.copy()
        mesh.apply_transform(transform)
        parts.append((mesh, getattr(mesh.visual, "material", None)))
    if not parts:
        raise SceneError(f"mesh file {path} has no triangle meshes")
    return parts


def _uv(mesh) -> np.ndarray:
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        return np.zeros((len(mesh.vertices), 2))
    return np.asarray(uv, dtype=np.float64)


def _material_values(material, gltf_material: dict):
    """(rho, eps or None) of a trimesh material, exact factors taken from the glTF JSON when known."""
    pbr = gltf_material.get("pbrMetallicRoughness", {})
    if "baseColorFactor" in pbr:
        base = np.asarray(pbr["baseColorFactor"][:3], dtype=np.float64)
    elif material is not None and getattr(material, "baseColorFactor", None) is not None:
        base = np.asarray(material.baseColorFactor[:3], dtype=np.float64) / 255.0
    elif material is not None and getattr(material, "diffuse", None) is not None:  # OBJ Kd (0-255)
        base = np.asarray(material.diffuse[:3], dtype=np.float64) / 255.0
    else:
        base = np.full(3, 0.8)
    texture = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
    rho = _texture(texture) * base if texture is not None else np.clip(base, 0.0, 1.0)

    strength = gltf_material.get("extensions", {}).get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0)
    factor = gltf_material.get("emissiveFactor")
    if factor is None and getattr(material, "emissiveFactor", None) is not None:
        factor = material.emissiveFactor
    eps = None
    if factor is not None and np.any(np.asarray(factor, dtype=np.float64) > 0):
        eps = np.asarray(factor, dtype=np.float64)[:3] * float(strength)
        emissive_texture = getattr(material, "emissiveTexture", None)
        if emissive_texture is not None:
            eps = _texture(emissive_texture) * eps
    return rho, eps


def _texture(image) -> np.ndarray:
    """A PIL image (sRGB-encoded) -> linear (h, w, 3), row 0 at the top."""
    from invrender.io.images import srgb_decode

    rgb = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
    return srgb_decode(rgb)


def _gltf_json(path: Path) -> dict:
    """The JSON document of a .gltf, or of a .glb's first chunk."""
    try:
        data = path.read_bytes()
        if path.suffix.lower() == ".glb":
            magic, _, _ = struct.unpack_from("<4sII", data, 0)
            length, kind = struct.unpack_from("<I4s", data, 12)
            if magic != b"glTF" or kind != b"JSON":
                raise ValueError("not a binary glTF file")
            data = data[20 : 20 + length]
        return json.loads(data)
    except FileNotFoundError:
        raise SceneError(f"mesh file not found: {path}") from None
    except (OSError, ValueError, struct.error, UnicodeDecodeError) as e:
        raise SceneError(f"cannot read mesh file {path}: {e}") from None


def _gltf_camera(gltf: dict) -> tuple[Camera | None, float | None]:
    """The first perspective camera of a glTF document and its aspect ratio, if any."""
    cameras = gltf.get("cameras", [])
    nodes = gltf.get("nodes", [])
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}
    for i, node in enumerate(nodes):
        cam = cameras[node["camera"]] if "camera" in node and node["camera"] < len(cameras) else None
        if cam is None or cam.get("type") != "perspective":
            continue
        world, j = np.eye(4), i
        while j is not None:
            world = _node_matrix(nodes[j]) @ world
            j = parent.get(j)
        persp = cam["perspective"]
        origin = world[:3, 3]
        forward = -world[:3, 2]
        camera = Camera(origin=tuple(origin), target=tuple(origin + forward), up=tuple(world[:3, 1]), fov=math.degrees(persp["yfov"]), fov_axis="y")
        return camera, persp.get("aspectRatio")
    return None, None


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    m = np.eye(4)
    m[:3, :3] = r * np.asarray(node.get("scale", [1, 1, 1]))
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def _framing_camera(vertices: np.ndarray) -> Camera:
    """A camera on +z looking at the bounding box centre, far enough to see all of it (fov 45)."""
    lo, hi = vertices.min(0), vertices.max(0)
    centre, radius = (lo + hi) / 2, max(np.linalg.norm(hi - lo) / 2, 1e-6)
    distance = radius / math.sin(math.radians(45 / 2)) * 1.05
    return Camera(origin=tuple(centre + [0, 0, distance]), target=tuple(centre), up=(0, 1, 0), fov=45.0)


# ---------------------------------------------------------------- value checks


def _check_keys(doc: dict, allowed: set, where: str) -> None:
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise SceneError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(sorted(allowed))})")


def _table(doc: dict, key: str, where: str) -> dict:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise SceneError(f"{where}: '{key}' must be a table")
    return value


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _number(doc: dict, key: str, where: str, required: bool = False) -> float:
    if key not in doc and required:
        raise SceneError(f"{where}: missing required key '{key}'")
    value = doc.get(key)
    if not _is_number(value):
        raise SceneError(f"{where}: '{key}' must be a number, got {value!r}")
    return float(value)


def _string(doc: dict, key: str, where: str, required: bool = False) -> str:
    if key not in doc and required:
        raise SceneError(f"{where}: missing required key '{key}'")
    value = doc.get(key)
    if not isinstance(value, str):
        raise SceneError(f"{where}: '{key}' must be a string, got {value!r}")
    return value


def _vector(doc: dict, key: str, where: str, length: int = 3) -> list[float]:
    value = doc.get(key)
    if not isinstance(value, list) or len(value) != length or not all(_is_number(x) for x in value):
        raise SceneError(f"{where}: '{key}' must be a list of {length} numbers, got {value!r}")
    return [float(x) for x in value]
