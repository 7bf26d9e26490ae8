"""The default studio: a mesh file (PLY, STL, OBJ, glTF/GLB) placed so that it can be seen at once.

A mesh file without an emitter has nothing to light it and (PLY, STL, OBJ) no camera; loaded as a
scene (``invrender render bunny.ply``, ``ir.load_scene("bunny.ply")``) it is placed in this
studio, sized from the bounding box of its triangles (lower corner ``lo``, upper ``hi``, centre
``c = (lo + hi) / 2``, bounding-sphere radius ``r = |hi - lo| / 2``), with +y up (the glTF and OBJ
convention; a z-up file lies on its side):

- **camera** (unless the glTF file has its own): a pinhole at ``c + d (0, sin 20°, cos 20°)``
  looking at ``c`` (from +z and 20 degrees above), up +y, a 40-degree field of view on the image's
  smaller axis, at the distance ``d = 1.1 r / sin 20°`` where the bounding sphere fills 1/1.1 of
  that field of view: the whole mesh is in the image, whatever its orientation;
- **floor** ``studio_floor``: a square of side ``20 r`` centred under ``c``, facing +y, at the
  height ``lo_y - 0.001 r`` (just under the mesh, not coplanar with a flat bottom), a grey
  diffuse of reflectance :data:`FLOOR_RHO`;
- **light** ``studio_light``: a square area light of side ``2 r`` at ``c + 4 r (1, 2, 1) / √6``
  (above, to the front right), facing ``c``, of radiance ``4π`` (:data:`LIGHT_RADIANCE`): the
  irradiance it gives a surface at ``c`` facing it is about π, so a white diffuse surface facing it
  has a radiance of about 1 (the shape shows by its shading and its shadow on the floor; the
  black material ``studio_lamp`` is the light's own surface).

The mesh keeps its materials (glTF, OBJ with MTL: :mod:`.trimesh`); PLY and STL files (and faces
without a material) are a grey diffuse of reflectance 0.8. The names ``studio_floor``,
``studio_lamp`` and ``studio_light`` are made unique against the file's (``_2``, ...).
"""

from __future__ import annotations

import math

import numpy as np

from invrender.scene.camera import Camera
from invrender.scene.shapes import Mesh, rectangle, rotate, scale, translate

#: the camera's field of view (degrees, on the image's smaller axis) and its elevation (degrees)
FOV = 40.0
ELEVATION = 20.0
#: the bounding sphere fills 1 / MARGIN of the field of view
MARGIN = 1.1
#: the floor's reflectance and half its side (in bounding-sphere radii)
FLOOR_RHO = 0.5
FLOOR_HALF_SIDE = 10.0
#: the light's half side and distance from the centre (radii), its direction and radiance
LIGHT_HALF_SIDE = 1.0
LIGHT_DISTANCE = 4.0
LIGHT_DIRECTION = (1.0, 2.0, 1.0)
LIGHT_RADIANCE = 4.0 * math.pi


def bounds(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(lower corner, centre, bounding-sphere radius) of (V, 3) vertices; the radius at least 1e-6."""
    lo, hi = vertices.min(0), vertices.max(0)
    return lo, (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)


def studio_camera(vertices: np.ndarray) -> Camera:
    """The studio's camera framing (V, 3) ``vertices`` (module docstring)."""
    _, centre, radius = bounds(vertices)
    distance = MARGIN * radius / math.sin(math.radians(FOV / 2))
    e = math.radians(ELEVATION)
    origin = centre + distance * np.array([0.0, math.sin(e), math.cos(e)])
    return Camera(origin=tuple(origin.tolist()), target=tuple(centre.tolist()), up=(0, 1, 0), fov=FOV, fov_axis="smaller")


def studio_parts(vertices: np.ndarray, used: set) -> tuple[list[Mesh], dict, dict]:
    """(meshes, materials, emission) of the studio's floor and light around (V, 3) ``vertices``,
    named apart from the names in ``used``."""
    lo, centre, radius = bounds(vertices)
    floor_name, lamp_name, light_name = (_unique(n, used) for n in ("studio_floor", "studio_lamp", "studio_light"))
    v, f, uv = rectangle()
    floor = Mesh(v, f, uv, floor_name).transformed(
        translate([centre[0], lo[1] - 1e-3 * radius, centre[2]]) @ rotate([1, 0, 0], -90) @ scale(FLOOR_HALF_SIDE * radius)
    )
    direction = np.asarray(LIGHT_DIRECTION) / np.linalg.norm(LIGHT_DIRECTION)
    normal = -direction  # the light faces the centre
    t1 = np.cross([0.0, 1.0, 0.0], normal)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    frame = np.eye(4)
    frame[:3, :3] = np.stack([t1, t2, normal], axis=1)  # rectangle's x, y, +z (its front) -> t1, t2, normal
    light = Mesh(v, f, uv, lamp_name, light_name).transformed(translate(centre + LIGHT_DISTANCE * radius * direction) @ frame @ scale(LIGHT_HALF_SIDE * radius))
    return [floor, light], {floor_name: [FLOOR_RHO] * 3, lamp_name: [0.0] * 3}, {light_name: [LIGHT_RADIANCE] * 3}


def _unique(base: str, used: set) -> str:
    name, i = base, 1
    while name in used or f"{name}_emission" in used:
        i += 1
        name = f"{base}_{i}"
    used.add(name)
    return name
