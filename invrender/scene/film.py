"""The film's options a scene carries: its reconstruction filter and ``sample_border``.

Every render of the scene uses them (forward, both estimators, fits), so a Mitsuba file's
``<rfilter>`` is honoured wherever the scene goes; ``ir.render(..., filter=...)`` overrides the
filter for one render. The filter is an object of :mod:`invrender.plugins.filters` (this layer
holds it without importing the plugins); None is the box of radius 1/2, the default of TOML,
glTF and built-in scenes (docs/rendering.md#reconstruction-filters). Crop windows are not an
option here: a loader turns one into the scene's resolution and a camera that sees the crop's part
of the full film (:meth:`invrender.scene.camera.Camera.cropped`).
"""

from __future__ import annotations

from dataclasses import dataclass

from invrender.errors import SceneError


@dataclass(frozen=True)
class FilmOptions:
    """How samples become pixels.

    Attributes:
        filter: the reconstruction filter (a :class:`~invrender.core.rfilter.ReconstructionFilter`
            from :func:`invrender.plugins.filters.make_filter`); None = the box of radius 1/2.
        sample_border: also trace samples in a border of ``filter.border_size`` pixels around the
            image, whose filter footprints reach into it (Mitsuba's ``sample_border``; nothing
            changes with the box).
    """

    filter: object = None
    sample_border: bool = False

    def __post_init__(self):
        if not isinstance(self.sample_border, bool):
            raise SceneError(f"film sample_border must be true or false, got {self.sample_border!r}")

    @property
    def is_box(self) -> bool:
        """True when samples land in their own pixel only (the film's fast path)."""
        return self.filter is None or self.filter.is_box

    @property
    def border(self) -> int:
        """Pixels sampled beyond each edge of the image: the filter's border size with
        ``sample_border``, else 0."""
        return self.filter.border_size if self.sample_border and not self.is_box else 0
