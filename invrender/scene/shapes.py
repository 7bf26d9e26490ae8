"""Triangle meshes, the built-in primitives and their affine transforms.

The primitives follow Mitsuba 3's definitions so that scenes carry over unchanged:
``rectangle`` is the square [-1, 1]^2 in the z = 0 plane facing +z, ``cube`` is [-1, 1]^3 with
outward faces, ``sphere`` is the unit sphere with outward faces (``flip_normals`` turns any of them
inside out). The winding order of a triangle defines its front side (counter-clockwise seen from
the front); emitters emit from their front side only.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from invrender.errors import SceneError


@dataclass(frozen=True)
class Mesh:
    """One shape: triangles with UVs, a material and optionally an emitter.

    Attributes:
        vertices: (V, 3) float64 positions, world units.
        faces: (F, 3) int64 vertex indices, counter-clockwise seen from the front side.
        uvs: (V, 2) float64 texture coordinates, or None (all zero).
        material: name of its material.
        emitter: name of the emitter giving its emitted radiance eps, or None.
        normals: (V, 3) float64 unit vertex normals on the front side, interpolated over each
            triangle into its shading normal; None = flat (the geometric normal).
        sphere: for a tessellated sphere facing outwards, the analytic sphere its vertices lie on,
            ``((cx, cy, cz), radius)`` in world units (emitters sample it by solid angle:
            :mod:`invrender.plugins.emitters.area`); None for any other shape, an ellipsoid (a sphere under
            a transform that is not a similarity) and a sphere turned inside out.
        attributes: per-vertex attributes by name (``"vertex_color"``, ...), each (V, C) float64
            with C = 1 or 3 (a PLY file's colours and extra vertex properties), read by
            :class:`~invrender.scene.textures.VertexAttribute` values; None = none.
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    material: str
    emitter: str | None = None
    normals: np.ndarray | None = None
    sphere: tuple[tuple[float, float, float], float] | None = None
    attributes: dict[str, np.ndarray] | None = None

    def transformed(self, matrix: np.ndarray) -> "Mesh":
        """This mesh with a 4x4 affine ``matrix`` applied to its vertices (winding kept front-facing;
        normals by the inverse transpose, which keeps them on the front side)."""
        linear = matrix[:3, :3]
        v = self.vertices @ linear.T + matrix[:3, 3]
        faces = self.faces if np.linalg.det(linear) > 0 else self.faces[:, ::-1].copy()
        normals = None
        if self.normals is not None:
            n = self.normals @ np.linalg.inv(linear)
            normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        return Mesh(v, faces, self.uvs, self.material, self.emitter, normals, _similar_sphere(self.sphere, matrix), self.attributes)

    def flipped(self) -> "Mesh":
        """The same mesh with every triangle's front and back exchanged."""
        normals = None if self.normals is None else -self.normals
        return dataclasses.replace(self, faces=self.faces[:, ::-1].copy(), normals=normals, sphere=None)  # emits inwards: no cone


def _similar_sphere(sphere, matrix: np.ndarray):
    """``sphere`` ((center, radius) or None) under the 4x4 affine ``matrix``: a sphere again when
    the linear part is a similarity (a rotation, reflection and uniform scale), else None."""
    if sphere is None:
        return None
    linear = matrix[:3, :3]
    gram = linear.T @ linear
    s2 = float(np.trace(gram)) / 3.0
    if s2 <= 0 or np.abs(gram - s2 * np.eye(3)).max() > 1e-9 * s2:
        return None  # an ellipsoid: sampled by area
    center = np.asarray(sphere[0], dtype=np.float64) @ linear.T + matrix[:3, 3]
    return tuple(float(c) for c in center), float(sphere[1]) * math.sqrt(s2)


def rectangle() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The square [-1, 1]^2 at z = 0 facing +z: vertices (4, 3), faces (2, 3), uvs (4, 2)."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    return v, f, uv


def cube() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cube [-1, 1]^3 with outward faces, 4 vertices per face: (24, 3), (12, 3), (24, 2)."""
    rv, rf, ruv = rectangle()
    rv = rv.copy()
    rv[:, 2] = 1.0  # the +z face
    rotations = [_rotation([1, 0, 0], a) for a in (0, 90, 180, 270)] + [_rotation([0, 1, 0], a) for a in (90, -90)]
    vs, fs, uvs = [], [], []
    for i, r in enumerate(rotations):
        vs.append(rv @ r[:3, :3].T)
        fs.append(rf + 4 * i)
        uvs.append(ruv)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(uvs)


def sphere(subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The unit sphere as an icosphere with outward faces: 20 * 4**subdivisions triangles.

    UVs are the equirectangular (longitude, latitude) of each vertex.
    """
    import trimesh

    if not 0 <= subdivisions <= 7:
        raise SceneError(f"sphere subdivisions must be in [0, 7], got {subdivisions}")
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = np.asarray(m.vertices, dtype=np.float64)
    u = 0.5 + np.arctan2(v[:, 0], v[:, 2]) / (2 * math.pi)
    w = 0.5 + np.arcsin(np.clip(v[:, 1], -1, 1)) / math.pi
    return v, np.asarray(m.faces, dtype=np.int64), np.stack([u, w], axis=1)


PRIMITIVES = {"rectangle": rectangle, "cube": cube, "sphere": sphere}


def primitive(kind: str, material: str, emitter: str | None = None, *args) -> Mesh:
    """A primitive by name as a :class:`Mesh`; ``args`` go to its constructor (``subdivisions``).

    The sphere carries its exact normals (the unit vertex positions), so it shades smoothly
    although it is tessellated, as Mitsuba's analytic sphere does, and the analytic sphere its
    vertices lie on (:attr:`Mesh.sphere`); rectangle and cube are flat.
    """
    v, f, uv = PRIMITIVES[kind](*args)
    if kind == "sphere":
        return Mesh(v, f, uv, material, emitter, v.copy(), ((0.0, 0.0, 0.0), 1.0))
    return Mesh(v, f, uv, material, emitter)


def _rotation(axis, degrees: float) -> np.ndarray:
    """4x4 right-handed rotation by ``degrees`` about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if n == 0:
        raise SceneError("rotation axis is zero")
    x, y, z = a / n
    t = math.radians(degrees)
    c, s = math.cos(t), math.sin(t)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * k + (1 - c) * np.outer([x, y, z], [x, y, z])
    return m


def translate(offset) -> np.ndarray:
    """4x4 translation by ``offset`` (3,)."""
    m = np.eye(4)
    m[:3, 3] = np.asarray(offset, dtype=np.float64)
    return m


def scale(factor) -> np.ndarray:
    """4x4 scale by a scalar or a (3,) ``factor``."""
    f = np.broadcast_to(np.asarray(factor, dtype=np.float64), (3,))
    if np.any(f == 0):
        raise SceneError(f"scale factor must be non-zero, got {list(f)}")
    m = np.eye(4)
    m[:3, :3] = np.diag(f)
    return m


def rotate(axis, degrees: float) -> np.ndarray:
    """4x4 rotation by ``degrees`` (right-handed) about ``axis`` (3,)."""
    return _rotation(axis, degrees)
