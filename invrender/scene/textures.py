"""How a scene's textures are read: Mitsuba's bitmap options (:class:`TextureSampling`), and
per-vertex attributes (:class:`VertexAttribute`) as parameter values.

This module describes; :mod:`invrender.core.textures` evaluates (its docstring gives the lookup's
arithmetic). A texture value with options (:class:`SampledTexture`) becomes its texels in
``Scene.params`` and its options in ``Scene.texture_sampling``. A scene keeps one :class:`TextureSampling` per textured parameter that does not use
the defaults (``Scene.texture_sampling``, keyed by parameter name).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.errors import SceneError

#: texture filters, as Mitsuba's bitmap ``filter_type`` names them
FILTERS = ("bilinear", "nearest")
#: wrap modes of texel indices outside the image, as Mitsuba's bitmap ``wrap_mode`` names them
WRAPS = ("repeat", "clamp", "mirror")


@dataclass(frozen=True)
class TextureSampling:
    """How a texture is read at a UV.

    Attributes:
        filter: one of :data:`FILTERS`.
        wrap: one of :data:`WRAPS`.
        to_uv: None (identity) or the affine map ``(a, b, c, d, e, f)`` taking a hit's UV to the
            lookup's, ``u' = a u + b v + c``, ``v' = d u + e v + f``, in invrender's UV convention
            (the Mitsuba reader converts Mitsuba's ``to_uv``, whose ``v`` points down).
    """

    filter: str = "bilinear"
    wrap: str = "repeat"
    to_uv: tuple[float, float, float, float, float, float] | None = None

    def __post_init__(self):
        if self.filter not in FILTERS:
            raise SceneError(f"unknown texture filter {self.filter!r} (expected one of {', '.join(FILTERS)})")
        if self.wrap not in WRAPS:
            raise SceneError(f"unknown texture wrap mode {self.wrap!r} (expected one of {', '.join(WRAPS)})")
        if self.to_uv is not None:
            if len(self.to_uv) != 6 or not all(isinstance(c, (int, float)) and abs(c) < float("inf") for c in self.to_uv):
                raise SceneError(f"a texture's to_uv must be 6 finite numbers (a, b, c, d, e, f), got {self.to_uv!r}")
            object.__setattr__(self, "to_uv", tuple(float(c) for c in self.to_uv))

    def transform(self, uv: torch.Tensor) -> torch.Tensor:
        """``to_uv`` applied to ``uv`` (N, 2)."""
        if self.to_uv is None:
            return uv
        a, b, c, d, e, f = self.to_uv
        u, v = uv[:, 0], uv[:, 1]
        return torch.stack([a * u + b * v + c, d * u + e * v + f], dim=1)


#: what a texture without options uses (Mitsuba's defaults)
DEFAULT = TextureSampling()


@dataclass(frozen=True)
class VertexAttribute:
    """A parameter value read from a per-vertex attribute of the meshes that use it (Mitsuba's
    ``mesh_attribute`` texture): ``name`` is the attribute (``"vertex_color"``, ``"vertex_<x>"``),
    looked up in each mesh's :attr:`Mesh.attributes <invrender.scene.shapes.Mesh.attributes>`;
    a one-channel attribute stands for grey. :func:`~invrender.scene.scene.build_scene` turns it
    into a (V, 3) parameter (one row per scene vertex)."""

    name: str
    #: a factor on the attribute (Mitsuba's ``scale``)
    scale: float = 1.0


@dataclass(frozen=True)
class SampledTexture:
    """A texture value read with options other than the defaults: ``texels`` (h, w, 3) (an array or
    tensor, as any texture value) and its :class:`TextureSampling`. :func:`~invrender.scene.scene.build_scene`
    keeps the texels as the parameter and the options in ``Scene.texture_sampling``."""

    texels: object
    sampling: TextureSampling


def mitsuba_to_uv(matrix) -> tuple[float, ...] | None:
    """Mitsuba's ``to_uv`` (a (3, 3) or (4, 4) matrix on ``(u, v, 1)``; of a 4 x 4, rows and columns 0,
    1 and 3, as Mitsuba reads a 4 x 4 as a 2D transform) in invrender's UV convention (``v`` up,
    Mitsuba's down): ``(a, b, c, d, e, f)`` of :attr:`TextureSampling.to_uv`, None for the identity.
    Raises :class:`SceneError` for a projective matrix (its last row not ``(0, 0, 1)``)."""
    m = torch.as_tensor(matrix, dtype=torch.float64)
    if m.shape == (4, 4):
        m = m[[0, 1, 3]][:, [0, 1, 3]]
    if m.shape != (3, 3) or not torch.allclose(m[2], torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)):
        raise SceneError(f"to_uv must be an affine 2D transform (last row 0, 0, 1), got {m.tolist()}")
    (m00, m01, m02), (m10, m11, m12) = m[0].tolist(), m[1].tolist()
    # with Mitsuba's (u, 1 - v): u' = m00 u + m01 (1 - v) + m02, 1 - v' = m10 u + m11 (1 - v) + m12
    out = (m00, -m01, m01 + m02, -m10, m11, 1.0 - m11 - m12)
    return None if out == (1.0, 0.0, 0.0, 0.0, 1.0, 0.0) else out
