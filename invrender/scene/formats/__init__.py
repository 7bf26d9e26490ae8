"""Scene file formats, each read into the same :class:`~invrender.scene.scene.Scene`.

- ``.toml``: invrender's own TOML scene format (:mod:`.toml`);
- ``.xml``: a documented subset of Mitsuba 3's XML scene format (:mod:`.mitsuba`);
- ``.gltf``, ``.glb``, ``.obj``, ``.ply``, ``.stl``: whole scenes through trimesh (:mod:`.trimesh`),
  placed in a default studio when they have no emitter (:mod:`.studio`).

:func:`load_file` picks the format by the file's suffix (:data:`SUFFIXES`). Mesh files named by
the TOML format's ``mesh`` shapes are read by :mod:`.trimesh` too; Mitsuba's ``obj``/``ply`` shapes
by :mod:`.mitsuba.shapes`, as Mitsuba reads them.

Texture coordinates
-------------------

UVs follow OpenGL's, OBJ's and trimesh's convention, which is also the renderer's
(:mod:`invrender.core.textures`): u grows left to right along the image's columns, v grows
from the image's *bottom* row to its top row, so uv (0, 0) is the bottom-left corner of the image.
Texture tensors are stored as images are, row 0 at the top, and no image is ever flipped: OBJ UVs
are used as written, and trimesh already turns glTF UVs (origin top-left) into this convention
(v -> 1 - v) when it reads them. The rectangle's uv (0, 0) is its (-1, -1) corner, so an image shows
upright on a rectangle seen from its front.

"""

from __future__ import annotations

from pathlib import Path

from invrender.scene.formats.mitsuba import load_mitsuba_xml
from invrender.scene.formats.toml import load_toml
from invrender.scene.formats.trimesh import MESH_SUFFIXES, load_mesh_file
from invrender.scene.scene import Scene

#: file suffix (lower case) -> the loader of that format: ``loader(path, resolution) -> Scene``
SUFFIXES = {".toml": load_toml, ".xml": load_mitsuba_xml, **{suffix: load_mesh_file for suffix in MESH_SUFFIXES}}


def load_file(path, resolution=None) -> Scene:
    """A scene from a file of one of the formats, chosen by its suffix (the caller checks that
    the suffix is one of :data:`SUFFIXES` and that the file exists).

    Args:
        path: the file.
        resolution: (width, height), overriding the file's own; None = the file's.
    """
    path = Path(path)
    return SUFFIXES[path.suffix.lower()](path, resolution)


__all__ = ["MESH_SUFFIXES", "SUFFIXES", "load_file", "load_mesh_file", "load_mitsuba_xml", "load_toml"]
