"""What the plugin mappings share while one Mitsuba XML file becomes a scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from invrender.scene.formats.mitsuba.parser import Document, Obj
from invrender.scene.materials import Material


class Context(Document):
    """A parsed file (:class:`~invrender.scene.formats.mitsuba.parser.Document`: its objects and
    the readers of their properties) and what the mapping has converted of it so far.

    Attributes:
        base: the folder file names in the file are relative to.
        subdivisions: icosphere subdivisions of ``sphere`` shapes (20 * 4^n triangles).
        materials: ``id(bsdf)`` -> (the BSDF object, its :class:`Material`, the id of the first
            shape that used it or None): each BSDF converted once, references share it.
        textures: ``id(texture)`` -> its linear RGB (h, w, 3) float64, each read once.
        texture_sampling: ``id(texture)`` -> how a bitmap is read (its ``to_uv``, ``filter_type``,
            ``wrap_mode``).
        sample_counts: the sample counts an integrator alias read (Mitsuba's ``direct``:
            ``emitter_samples``, ...) -> (value, its node), for the loader's warnings.
    """

    def __init__(self, path: Path, parameters: dict | None, subdivisions: int):
        super().__init__(path, parameters)
        self.base = path.parent
        self.subdivisions = subdivisions
        self.materials: dict[int, tuple[Obj, Material, str | None]] = {}
        self.textures: dict[int, np.ndarray] = {}
        self.texture_sampling: dict = {}
        self.sample_counts: dict[str, tuple] = {}
