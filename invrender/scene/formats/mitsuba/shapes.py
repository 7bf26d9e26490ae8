"""Mitsuba shapes onto invrender meshes: the primitives, and OBJ/PLY files through trimesh.

Shapes (``<shape type=...>``)
    ``rectangle`` ([-1, 1]^2 at z = 0 facing +z), ``cube`` ([-1, 1]^3 facing outwards), ``sphere``
    (``center`` point, default 0 0 0; ``radius`` float > 0, default 1: Mitsuba's analytic sphere
    becomes an icosphere of 20 * 4^5 = 20480 triangles (``sphere_subdivisions``, default 5) shaded
    with its exact normals), ``obj`` and ``ply`` (``filename`` relative to the XML file, read with
    trimesh, every part merged; vertex normals are the file's when it has them, else computed as
    Mitsuba computes them (angle-weighted, from the world-space triangles), and
    ``face_normals=true`` drops them for flat shading;
    ``flip_tex_coords``, default true for obj and false for ply as in Mitsuba). Every shape takes
    ``to_world`` and ``flip_normals``; one BSDF (an inline ``<bsdf>`` or a ``<ref>``), else
    Mitsuba's default, diffuse with reflectance 0.5 (:mod:`.bsdfs`); and optionally an
    ``<emitter type="area">`` (:mod:`.emitters`). Texture coordinates follow Mitsuba's
    parametrizations (:mod:`.textures`).

    ``disk`` (radius 1 at z = 0 facing +z, ``uv = (r, phi / 2 pi)``) and ``cylinder`` (``p0``
    default 0 0 0, ``p1`` default 0 0 1, ``radius`` default 1: open, facing outwards, ``uv =
    (phi / 2 pi, t)`` with ``t`` from p0 to p1, ``phi`` about Mitsuba's frame of ``p1 - p0``) are
    tessellated with 256 segments around (:data:`ROUND_SEGMENTS`: a disk's area is 1.0e-4 smaller
    than the round one, the rim within 7.5e-5 of the radius; a cylinder's exact normals shade it
    smoothly). ``serialized`` (Mitsuba's mesh format, :mod:`.serialized`: ``filename``,
    ``shape_index`` default 0, ``face_normals``; the file's normals, else computed as for
    OBJ/PLY, and its texture coordinates as stored).

Deviations from Mitsuba
    - Spheres, disks and cylinders are tessellated (see above); rectangles and cubes are exact.
    - Textures on spheres show a seam where ``u`` wraps around (the tessellation interpolates
      across it).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from invrender.errors import SceneError
from invrender.scene.formats.mitsuba.bsdfs import material
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.emitters import emitter as emitter_of
from invrender.scene.formats.mitsuba.parser import Node, Obj, Reported, _coordinate_system
from invrender.scene.formats.mitsuba.serialized import SerializedError, read_serialized
from invrender.scene.formats.values import one_line
from invrender.scene.shapes import Mesh, primitive, scale, translate

#: icosphere subdivisions of a Mitsuba sphere: 20 * 4**5 = 20480 triangles
SPHERE_SUBDIVISIONS = 5

SHAPE_TYPES = ("rectangle", "cube", "sphere", "disk", "cylinder", "obj", "ply", "serialized")
#: segments around a disk and a cylinder (their tessellation; see the module docstring)
ROUND_SEGMENTS = 256

# Mitsuba's cube (src/shapes/cube.cpp): positions, face normals and texture coordinates of its 24 vertices
_MITSUBA_CUBE = (
    [(1, -1, -1), (1, -1, 1), (-1, -1, 1), (-1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, 1, 1), (1, 1, 1),
     (1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1), (-1, -1, 1),
     (-1, -1, 1), (-1, 1, 1), (-1, 1, -1), (-1, -1, -1), (1, 1, -1), (1, -1, -1), (-1, -1, -1), (-1, 1, -1)],
    [(0, -1, 0)] * 4 + [(0, 1, 0)] * 4 + [(1, 0, 0)] * 4 + [(0, 0, 1)] * 4 + [(-1, 0, 0)] * 4 + [(0, 0, -1)] * 4,
    [(0, 1), (1, 1), (1, 0), (0, 0)] * 6,
)  # fmt: skip


def shape(ctx: Context, obj: Obj, emitter_name) -> tuple[Mesh, int]:
    """The mesh of a shape (material and emitter names filled in later) and its material key."""
    t = obj.type
    if t not in SHAPE_TYPES:
        raise ctx.error(obj.node, f"unsupported shape type {t!r} (supported: {', '.join(SHAPE_TYPES)})", obj)
    to_world = ctx.take(obj, "to_world", ("transform",), "a <transform>")
    matrix = np.eye(4) if to_world is None else to_world.value
    flip = ctx.get(obj, "flip_normals", "boolean", False)
    supported = ["to_world", "flip_normals"]
    compute_normals = False
    if t in ("disk", "cylinder"):
        mesh, mitsuba_uv = _disk() if t == "disk" else _cylinder()
        if t == "cylinder":
            supported += ["p0", "p1", "radius"]
            matrix = matrix @ _cylinder_frame(ctx, obj)
    elif t == "serialized":
        supported += ["filename", "shape_index", "face_normals"]
        mesh, mitsuba_uv, compute_normals = serialized_file(ctx, obj)
    elif t in ("rectangle", "cube", "sphere"):
        mesh = primitive(t, "", None, ctx.subdivisions) if t == "sphere" else primitive(t, "", None)
        mitsuba_uv = _primitive_uv(t, mesh)
        if t == "sphere":
            supported += ["center", "radius"]
            center = ctx.get(obj, "center", "point", (0.0, 0.0, 0.0))
            radius = ctx.get(obj, "radius", "float", 1.0)
            if radius <= 0:
                raise ctx.error(obj.props["radius"].node, f"'radius' must be positive, got {radius:g}", obj)
            matrix = matrix @ translate(center) @ scale(radius)
    else:
        supported += ["filename", "face_normals", "flip_tex_coords"]
        mesh, mitsuba_uv, compute_normals = mesh_file(ctx, obj)
    mesh = Mesh(mesh.vertices, mesh.faces, np.stack([mitsuba_uv[:, 0], 1.0 - mitsuba_uv[:, 1]], axis=1), "", None, mesh.normals, mesh.sphere, mesh.attributes)
    if flip:
        mesh = mesh.flipped()
    if np.linalg.det(matrix[:3, :3]) == 0:
        raise ctx.error(to_world.node, "to_world is singular", obj)
    mesh = mesh.transformed(matrix)
    if compute_normals:  # as Mitsuba does: angle-weighted, from the world-space triangles
        mesh = Mesh(mesh.vertices, mesh.faces, mesh.uvs, "", None, _vertex_normals(mesh.vertices, mesh.faces), attributes=mesh.attributes)
    if any(k.startswith("face_") for k in mesh.attributes or {}):
        mesh = _unwelded(mesh)
    found = []  # its own problems, its BSDF's and its emitter's: each checked
    try:
        ctx.finish(obj, tuple(supported), ("bsdf", "emitter"))
    except SceneError as e:
        found.append(e)
    bsdf = ctx.one_nested(obj, "bsdf")
    if bsdf is None:  # Mitsuba's default BSDF
        bsdf = Obj(Node("bsdf", {"type": "diffuse"}, obj.node.line, where=obj.node.where), "diffuse", obj.order)
    try:
        key = material(ctx, bsdf, obj.id)
    except SceneError as e:
        found.append(e)
    emitter = ctx.one_nested(obj, "emitter")
    if emitter is not None:
        try:
            mesh = Mesh(mesh.vertices, mesh.faces, mesh.uvs, "", emitter_name(obj, emitter_of(ctx, emitter, in_shape=True)), mesh.normals, mesh.sphere, mesh.attributes)
        except SceneError as e:
            found.append(e)
    if len(found) == 1:
        raise found[0]
    if found:
        for e in found:
            ctx.problem(e)
        raise Reported(f"{obj.describe()}: {len(found)} problems noted")
    return mesh, key


def _mesh_path(ctx: Context, obj: Obj):
    """(the ``filename`` property, the file it names on the search path) of a mesh-file shape; a
    one-line error when it is missing or names no file."""
    prop = ctx.take(obj, "filename", ("string",), "a <string>")
    if prop is None:
        raise ctx.error(obj.node, "missing <string name=\"filename\">", obj)
    path = ctx.find_file(prop.node, prop.value)
    if path is None or not path.is_file():
        raise ctx.error(prop.node, f"mesh file not found: {ctx.base / prop.value}", obj)
    return prop, path


def serialized_file(ctx: Context, obj: Obj) -> tuple[Mesh, np.ndarray, bool]:
    """The mesh of a serialized shape (:mod:`.serialized`), its texture coordinates as stored
    (Mitsuba does not flip them), and whether its vertex normals are to be computed."""
    prop, path = _mesh_path(ctx, obj)
    index = ctx.take(obj, "shape_index", ("integer",), "an <integer>")
    face_normals = ctx.get(obj, "face_normals", "boolean", False)
    try:
        m = read_serialized(path, 0 if index is None else int(index.value))
    except SerializedError as e:
        raise ctx.error(prop.node if index is None or "shape_index" not in str(e) else index.node, f"corrupt serialized file {path}: {e}", obj) from None
    except OSError as e:
        raise ctx.error(prop.node, f"cannot read mesh file {path}: {e.strerror or e}", obj) from None
    if len(m.faces) == 0:
        raise ctx.error(prop.node, f"mesh file {path} has no faces", obj)
    flat = face_normals or m.face_normals
    normals = None if flat else m.normals
    uv = m.uvs if m.uvs is not None else np.zeros((len(m.vertices), 2))
    return Mesh(m.vertices, m.faces, None, "", None, normals), uv, not flat and normals is None


def mesh_file(ctx: Context, obj: Obj) -> tuple[Mesh, np.ndarray, bool]:
    """The mesh of an obj/ply shape, its texture coordinates as Mitsuba reads them, and whether
    its vertex normals are to be computed (the file has none, and face_normals is false)."""
    import trimesh

    prop, path = _mesh_path(ctx, obj)
    face_normals = ctx.get(obj, "face_normals", "boolean", False)
    flip_uv = ctx.get(obj, "flip_tex_coords", "boolean", obj.type == "obj")
    try:
        loaded = trimesh.load(str(path), file_type=obj.type, process=False)
        parts = []
        if isinstance(loaded, trimesh.Scene):
            order = {name: i for i, name in enumerate(loaded.geometry)}
            nodes = sorted(((order.get(g, len(order)), n, t, g) for n in loaded.graph.nodes_geometry for t, g in [loaded.graph[n]]), key=lambda x: (x[0], str(x[1])))
            parts = [(loaded.geometry[g], t) for _, _, t, g in nodes if isinstance(loaded.geometry.get(g), trimesh.Trimesh)]
        elif isinstance(loaded, trimesh.Trimesh):
            parts = [(loaded, np.eye(4))]
        # trimesh returns a file's vertex normals as they are (it computes its own only without)
        has_normals = not face_normals and _file_has_normals(path, obj.type)
        vs, fs, uvs, ns, offset = [], [], [], [], 0
        attributes = _ply_attributes(loaded) if obj.type == "ply" and isinstance(loaded, trimesh.Trimesh) else None
        for m, t in parts:
            if len(m.faces) == 0:
                continue
            v = np.asarray(m.vertices, dtype=np.float64)
            vs.append(v @ t[:3, :3].T + t[:3, 3])
            fs.append(np.asarray(m.faces, dtype=np.int64) + offset)
            uv = getattr(m.visual, "uv", None)
            uvs.append(np.asarray(uv, dtype=np.float64) if uv is not None and len(uv) == len(v) else np.zeros((len(v), 2)))
            if has_normals:
                ns.append(np.asarray(m.vertex_normals, dtype=np.float64) @ np.linalg.inv(t[:3, :3]))
            offset += len(v)
    except SceneError:
        raise
    except Exception as e:  # trimesh raises anything from ValueError to KeyError on bad files
        raise ctx.error(prop.node, f"cannot read mesh file {path}: {one_line(e) or type(e).__name__}", obj) from None
    if not fs:
        raise ctx.error(prop.node, f"mesh file {path} has no faces", obj)
    uv = np.concatenate(uvs)
    if flip_uv:  # Mitsuba's v = 1 - v_file
        uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)
    normals = np.concatenate(ns) if has_normals else None
    return Mesh(np.concatenate(vs), np.concatenate(fs), None, "", None, normals, attributes=attributes), uv, not face_normals and not has_normals


# ---------------------------------------------------------------- helpers


#: the suffixes by which Mitsuba groups PLY vertex properties into a ``vertex_<prefix>`` attribute, in channel order
_PLY_SUFFIXES = (("x", "y", "z", "w"), ("0", "1", "2", "3"))


def _ply_attributes(mesh) -> dict[str, np.ndarray] | None:
    """A PLY file's per-vertex and per-face attributes as Mitsuba 3.9.1 reads them (measured):
    properties ``r g b`` or ``red green blue`` of the vertices become ``vertex_color`` (values as
    stored: 8-bit colours stay 0..255, as Mitsuba warns), ``<prefix>_x, _y, _z`` or ``<prefix>_0,
    _1, _2`` (one or three of them) become ``vertex_<prefix>`` (Mitsuba's own writer stores
    ``vertex_color`` as ``color_0..2``); the faces' properties beside their vertex indices become
    ``face_color`` and ``face_<prefix>`` by the same rules, (F, C) one row per face; other
    properties are ignored, as Mitsuba ignores them. None when there are none."""
    out = {}
    for element, count in (("vertex", len(mesh.vertices)), ("face", len(mesh.faces))):
        raw = (mesh.metadata.get("_ply_raw") or {}).get(element, {}).get("data")
        if isinstance(raw, np.ndarray) and raw.dtype.names:  # a binary file's structured array
            raw = {name: raw[name] for name in raw.dtype.names}
        if not isinstance(raw, dict):
            continue
        columns = {}
        for k, v in raw.items():
            if k in ("vertex_indices", "vertex_index"):
                continue
            try:
                a = np.asarray(v, dtype=np.float64)
            except (TypeError, ValueError):  # a list property: not an attribute
                continue
            if a.size == count:
                columns[k] = a.reshape(count)
        out.update(_grouped(columns, element))
    return out or None


def _grouped(columns: dict[str, np.ndarray], element: str) -> dict[str, np.ndarray]:
    """The attributes ``<element>_color`` and ``<element>_<prefix>`` of one PLY element's scalar
    properties ``columns`` (name -> (n,)), by :func:`_ply_attributes`'s rules."""
    out = {}
    for names in (("r", "g", "b"), ("red", "green", "blue")):
        if all(n in columns for n in names):
            out[f"{element}_color"] = np.stack([columns[n] for n in names], axis=1)
    for prefix in dict.fromkeys(k.rpartition("_")[0] for k in columns if k.rpartition("_")[0]):
        for suffixes in _PLY_SUFFIXES:
            channels = []
            for suffix in suffixes:
                if f"{prefix}_{suffix}" not in columns:
                    break
                channels.append(columns[f"{prefix}_{suffix}"])
            if len(channels) in (1, 3):
                out[f"{element}_{prefix}"] = np.stack(channels, axis=1)
    return out


def _unwelded(mesh: Mesh) -> Mesh:
    """``mesh`` with three vertices of its own per face (positions, normals, UVs and vertex
    attributes copied to them), so that a face attribute ((F, C), ``face_*``) becomes a per-vertex
    one equal at the face's three corners: interpolated barycentrically at a hit it is the face's
    value, as Mitsuba's ``mesh_attribute`` reads a face attribute (constant over the face)."""
    f = np.asarray(mesh.faces, dtype=np.int64)
    corners = f.reshape(-1)
    n = len(f)
    attributes = {k: np.repeat(np.asarray(a), 3, axis=0) if k.startswith("face_") else np.asarray(a)[corners] for k, a in mesh.attributes.items()}
    return Mesh(
        np.asarray(mesh.vertices)[corners], np.arange(3 * n, dtype=np.int64).reshape(n, 3), None if mesh.uvs is None else np.asarray(mesh.uvs)[corners],
        mesh.material, mesh.emitter, None if mesh.normals is None else np.asarray(mesh.normals)[corners], mesh.sphere, attributes,
    )  # fmt: skip


def _file_has_normals(path: Path, kind: str) -> bool:
    """Does an OBJ file have ``vn`` lines, a PLY file's vertices an ``nx`` property?"""
    with open(path, "rb") as f:
        if kind == "obj":
            return any(line.lstrip().startswith(b"vn ") for line in f)
        header = f.read(1 << 16).split(b"end_header")[0]
    return re.search(rb"property\s+\w+\s+nx\b", header) is not None


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Mitsuba's computed vertex normals: each face's unit normal weighted by its angle at the
    vertex (Thuermer and Wuethrich 1998), summed and normalized; (1, 0, 0) where that sum is zero."""
    p = v[f]  # (F, 3, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    ok = length[:, 0] > 0
    n = np.where(ok[:, None], n / np.where(length > 0, length, 1.0), 0.0)
    out = np.zeros_like(v)
    for j in range(3):
        a = p[:, (j + 1) % 3] - p[:, j]
        b = p[:, (j + 2) % 3] - p[:, j]
        cos = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        np.add.at(out, f[:, j], n * np.arccos(np.clip(cos, -1.0, 1.0))[:, None])
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(length > 0, out / np.where(length > 0, length, 1.0), np.array([1.0, 0.0, 0.0]))


def _disk(n: int = ROUND_SEGMENTS) -> tuple[Mesh, np.ndarray]:
    """Mitsuba's disk (radius 1 at z = 0 facing +z) as a fan of ``n`` triangles, a centre vertex
    per triangle and the rim's seam vertex twice, and its ``uv = (r, phi / 2 pi)``."""
    phi = 2 * math.pi * np.arange(n + 1) / n
    rim = np.stack([np.cos(phi), np.sin(phi), np.zeros(n + 1)], axis=1)
    centre = np.zeros((n, 3))
    v = np.concatenate([rim, centre])
    f = np.stack([n + 1 + np.arange(n), np.arange(n), np.arange(n) + 1], axis=1)
    uv = np.concatenate([np.stack([np.ones(n + 1), phi / (2 * math.pi)], axis=1), np.stack([np.zeros(n), (np.arange(n) + 0.5) / n], axis=1)])
    return Mesh(v, f.astype(np.int64), None, "", None, np.tile([0.0, 0.0, 1.0], (len(v), 1))), uv


def _cylinder(n: int = ROUND_SEGMENTS) -> tuple[Mesh, np.ndarray]:
    """Mitsuba's cylinder (radius 1 about z from z = 0 to 1, open, facing outwards) as ``n``
    quads, its exact normals, and its ``uv = (phi / 2 pi, z)``."""
    phi = 2 * math.pi * np.arange(n + 1) / n
    ring = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    v = np.concatenate([np.c_[ring, np.zeros(n + 1)], np.c_[ring, np.ones(n + 1)]])
    i = np.arange(n)
    f = np.concatenate([np.stack([i, i + 1, n + 2 + i], axis=1), np.stack([i, n + 2 + i, n + 1 + i], axis=1)])
    uv = np.concatenate([np.stack([phi / (2 * math.pi), np.zeros(n + 1)], axis=1), np.stack([phi / (2 * math.pi), np.ones(n + 1)], axis=1)])
    normals = np.c_[np.concatenate([ring, ring]), np.zeros(2 * n + 2)]
    return Mesh(v, f.astype(np.int64), None, "", None, normals), uv


def _cylinder_frame(ctx: Context, obj: Obj) -> np.ndarray:
    """Mitsuba's cylinder placement: translate(p0) * to_frame(Frame(p1 - p0)) * scale(radius,
    radius, |p1 - p0|) (``p0`` default 0 0 0, ``p1`` 0 0 1, ``radius`` 1)."""
    p0 = np.asarray(ctx.get(obj, "p0", "point", (0.0, 0.0, 0.0)), dtype=np.float64)
    p1 = np.asarray(ctx.get(obj, "p1", "point", (0.0, 0.0, 1.0)), dtype=np.float64)
    radius = ctx.get(obj, "radius", "float", 1.0)
    if radius <= 0:
        raise ctx.error(obj.props["radius"].node, f"'radius' must be positive, got {radius:g}", obj)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length == 0:
        raise ctx.error(obj.props.get("p1", obj.props.get("p0")).node, "p0 and p1 coincide", obj)
    n = d / length
    s = _coordinate_system(n)
    frame = np.eye(4)
    frame[:3, 0], frame[:3, 1], frame[:3, 2] = s, np.cross(n, s), n
    return translate(p0) @ frame @ scale((radius, radius, length))


def _primitive_uv(kind: str, mesh: Mesh) -> np.ndarray:
    """Mitsuba's texture coordinates of a primitive's vertices (``v = 0`` at the image's top)."""
    v = mesh.vertices
    if kind == "rectangle":
        return (v[:, :2] + 1.0) / 2.0
    if kind == "sphere":  # (phi / 2 pi, theta / pi) about local z
        phi = np.mod(np.arctan2(v[:, 1], v[:, 0]), 2 * math.pi)
        theta = np.arccos(np.clip(v[:, 2] / np.linalg.norm(v, axis=1), -1.0, 1.0))
        return np.stack([phi / (2 * math.pi), theta / math.pi], axis=1)
    # cube: look each vertex up by position and face normal in Mitsuba's table
    positions, normals, uvs = (np.asarray(a, dtype=np.float64) for a in _MITSUBA_CUBE)
    tri = v[mesh.faces]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vertex_n = np.zeros_like(v)
    vertex_n[mesh.faces.reshape(-1)] = np.repeat(np.round(face_n / np.linalg.norm(face_n, axis=1, keepdims=True)), 3, axis=0)
    out = np.zeros((len(v), 2))
    for i in range(len(v)):
        match = np.all(np.isclose(positions, v[i], atol=1e-6), axis=1) & np.all(np.isclose(normals, vertex_n[i], atol=1e-6), axis=1)
        out[i] = uvs[np.argmax(match)]
    return out
