"""Mitsuba's ``.serialized`` mesh files (the ``serialized`` shape), read with numpy and zlib.

Layout (little endian; Mitsuba's src/shapes/serialized.cpp documents it): each mesh is a
``uint16`` format identifier ``0x041C`` and a ``uint16`` version (3 or 4), then a zlib stream of:
``uint32`` flags (``0x0001`` vertex normals, ``0x0002`` texture coordinates, ``0x0008`` vertex
colours, ``0x0010`` face normals, ``0x1000`` single / ``0x2000`` double precision), in version 4
the mesh's name (a null-terminated UTF-8 string), ``uint64`` vertex and triangle counts, the
positions (3 per vertex), the normals, texture coordinates and colours when flagged, and the
triangles (3 ``uint32`` indices each). Several meshes are concatenated; the file ends with the
byte offset of each (``uint64`` in version 4, ``uint32`` in version 3) and their ``uint32`` count,
which ``shape_index`` looks up as Mitsuba does. Vertex colours are skipped (invrender does not
use them, nor does Mitsuba's loader).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

MAGIC = 0x041C
VERSIONS = (3, 4)
HAS_NORMALS, HAS_UVS, HAS_COLOURS, FACE_NORMALS, SINGLE, DOUBLE = 0x0001, 0x0002, 0x0008, 0x0010, 0x1000, 0x2000


class SerializedError(ValueError):
    """A file that is not a (valid) serialized mesh file; the message says what."""


@dataclass(frozen=True)
class SerializedMesh:
    """One mesh of a serialized file: vertices (V, 3) and faces (F, 3) int64; normals (V, 3)
    and uvs (V, 2) float64 or None; ``face_normals``: the file asks for flat shading."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    uvs: np.ndarray | None
    face_normals: bool


def read_serialized(path: Path, shape_index: int = 0) -> SerializedMesh:
    """Mesh ``shape_index`` of a serialized file; SerializedError for anything malformed."""
    data = Path(path).read_bytes()
    if len(data) < 4:
        raise SerializedError("too short for a serialized mesh file")
    magic, version = struct.unpack_from("<HH", data, 0)
    if magic != MAGIC:
        raise SerializedError(f"not a serialized mesh file (format identifier 0x{magic:04X}, expected 0x{MAGIC:04X})")
    if version not in VERSIONS:
        raise SerializedError(f"unsupported serialized file version {version} (supported: 3, 4)")
    start = 0
    if shape_index < 0:
        raise SerializedError(f"shape_index must be >= 0, got {shape_index}")
    if shape_index > 0:
        (count,) = struct.unpack_from("<I", data, len(data) - 4)
        if shape_index >= count:
            raise SerializedError(f"shape_index {shape_index} is out of range: the file has {count} mesh{'es' if count != 1 else ''}")
        size, fmt = (8, "<Q") if version == 4 else (4, "<I")
        table = len(data) - 4 - size * count
        if table < 0:
            raise SerializedError("the end-of-file table of mesh offsets is truncated")
        (start,) = struct.unpack_from(fmt, data, table + size * shape_index)
        if start + 4 > len(data) or struct.unpack_from("<HH", data, start) != (MAGIC, version):
            raise SerializedError(f"mesh {shape_index}'s offset {start} does not point at a mesh header")
    try:
        body = zlib.decompressobj().decompress(data[start + 4 :])
    except zlib.error as e:
        raise SerializedError(f"corrupt compressed data ({e})") from None
    return _parse(body, version)


def _parse(body: bytes, version: int) -> SerializedMesh:
    at = 0

    def take(n: int) -> bytes:
        nonlocal at
        if at + n > len(body):
            raise SerializedError("truncated mesh data")
        chunk = body[at : at + n]
        at += n
        return chunk

    (flags,) = struct.unpack("<I", take(4))
    name = ""
    if version == 4:
        end = body.find(b"\0", at)
        if end < 0:
            raise SerializedError("truncated mesh data (no end to the mesh's name)")
        name = body[at:end].decode("utf-8", errors="replace")
        at = end + 1
    n_vertices, n_faces = struct.unpack("<QQ", take(16))
    if n_vertices > 1 << 32 or n_faces > 1 << 34:
        raise SerializedError(f"implausible counts ({n_vertices} vertices, {n_faces} triangles)")
    dtype = np.dtype("<f8") if flags & DOUBLE else np.dtype("<f4")

    def array(dim: int, kind=dtype) -> np.ndarray:
        n = n_vertices * dim if kind is dtype else n_faces * dim
        return np.frombuffer(take(n * kind.itemsize), dtype=kind).astype(np.float64 if kind is dtype else np.int64).reshape(-1, dim)

    vertices = array(3)
    normals = array(3) if flags & HAS_NORMALS else None
    uvs = array(2) if flags & HAS_UVS else None
    if flags & HAS_COLOURS:
        array(3)
    faces = array(3, np.dtype("<u4"))
    if n_faces and (faces.max() >= n_vertices):
        raise SerializedError(f"a triangle refers to vertex {int(faces.max())} of {n_vertices}")
    if not (np.all(np.isfinite(vertices)) and (normals is None or np.all(np.isfinite(normals)))):
        raise SerializedError("non-finite vertex data")
    return SerializedMesh(name, vertices, faces, normals, uvs, bool(flags & FACE_NORMALS))


def write_serialized(meshes: list[dict], version: int = 4) -> bytes:
    """A serialized file of ``meshes`` (dicts of vertices, faces and optionally normals, uvs,
    name), single precision: what Mitsuba's writer produces (used by the tests)."""
    out, offsets = bytearray(), []
    for m in meshes:
        offsets.append(len(out))
        flags = SINGLE | (HAS_NORMALS if m.get("normals") is not None else 0) | (HAS_UVS if m.get("uvs") is not None else 0)
        body = struct.pack("<I", flags)
        if version == 4:
            body += m.get("name", "").encode() + b"\0"
        v, f = np.asarray(m["vertices"]), np.asarray(m["faces"])
        body += struct.pack("<QQ", len(v), len(f)) + v.astype("<f4").tobytes()
        for key in ("normals", "uvs"):
            if m.get(key) is not None:
                body += np.asarray(m[key]).astype("<f4").tobytes()
        body += f.astype("<u4").tobytes()
        out += struct.pack("<HH", MAGIC, version) + zlib.compress(body)
    for o in offsets:
        out += struct.pack("<Q" if version == 4 else "<I", o)
    return bytes(out + struct.pack("<I", len(meshes)))
