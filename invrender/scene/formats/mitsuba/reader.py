"""The reader a plugin's ``from_mitsuba`` gets: one Mitsuba element (a ``<bsdf>``, an ``<emitter>``)
behind typed getters whose errors name the file, the line, the element and the property, so every
plugin's messages say the same things the same way."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from invrender.errors import SceneError
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj, Ref
from invrender.scene.formats.mitsuba.textures import colour
from invrender.scene.kinds import ParamKind
from invrender.scene.plugins import Constant
from invrender.scene.textures import SampledTexture, VertexAttribute

#: Rec. 709 luminance of linear RGB, as Mitsuba's ``luminance`` (a bitmap's ``eval_1``)
LUMINANCE = (0.212671, 0.715160, 0.072169)


#: (element, Mitsuba plugin or "*" for any) -> properties accepted at Mitsuba's default value only
AT_DEFAULT = {
    ("emitter", "*"): {"sampling_weight": 1.0},
    ("bsdf", "dielectric"): {"specular_reflectance": 1.0, "specular_transmittance": 1.0},
    ("bsdf", "thindielectric"): {"specular_reflectance": 1.0, "specular_transmittance": 1.0},
}


class PluginReader:
    """One element as a plugin class's ``from_mitsuba`` reads it: typed getters and :meth:`finish`,
    which rejects the properties nothing read. Each getter marks its property as read.

    Attributes:
        type: the plugin name (``"roughconductor"``).
    """

    def __init__(self, ctx: Context, obj: Obj):
        self._ctx, self._obj = ctx, obj
        self.type = obj.type

    def has(self, name: str) -> bool:
        """Does the element give property ``name``?"""
        return name in self._obj.props

    def tag(self, name: str) -> str:
        """The element of property ``name`` (``"float"``, ``"rgb"``, ``"texture"``, ``"ref"``, ...)."""
        return self._obj.props[name].tag

    def error(self, name: str | None, message: str) -> SceneError:
        """A one-line error at property ``name``'s line (the ``<bsdf>``'s for None), to raise."""
        node = self._obj.node if name is None else self._obj.props[name].node
        return self._ctx.error(node, message, self._obj)

    def colour(self, name: str, kind: ParamKind, default: float, texture: bool = True) -> np.ndarray:
        """An RGB triple (3,) or, where ``texture`` and ``kind`` allow, a bitmap texture
        (h, w, 3), linear, checked against ``kind``'s range (:mod:`.textures`); ``default``
        (grey) when absent."""
        return colour(self._ctx, self._obj, name, kind, default, texture)

    def grey(self, name: str, kind: ParamKind, default: float):
        """A property Mitsuba reads as one number (``Texture::eval_1``: a blend's weight, a mask's
        opacity, a roughness): a colour's channel mean, a texture's luminance per texel, as
        (3,) or (h, w, 3) equal channels (a :class:`SampledTexture`'s texels likewise). A
        checkerboard's ``eval_1`` puts ``color0`` where Mitsuba's ``eval`` puts ``color1`` and the
        reverse (checkerboard.cpp, 3.9.1), so its grey map is the complement of the baked board:
        ``g0 + g1 - g``."""
        value = self.colour(name, kind, default)
        texels = value.texels if isinstance(value, SampledTexture) else value
        if isinstance(texels, VertexAttribute):
            return value
        texels = np.asarray(texels, dtype=np.float64)
        grey = texels.mean(-1) if texels.ndim == 1 else texels @ np.asarray(LUMINANCE)
        board = self._texture(name)
        if board is not None and board.type == "checkerboard":
            g0, g1 = (float(np.dot(np.broadcast_to(np.asarray(board.props[k].value if k in board.props else d, dtype=np.float64), (3,)), LUMINANCE)) for k, d in (("color0", 0.4), ("color1", 0.2)))
            grey = g0 + g1 - grey
        out = np.broadcast_to(np.asarray(grey)[..., None], texels.shape).copy()
        return SampledTexture(out, value.sampling) if isinstance(value, SampledTexture) else out

    def _texture(self, name: str) -> Obj | None:
        """The ``<texture>`` object property ``name`` holds (a ``<ref>`` followed), or None."""
        prop = self._obj.props.get(name)
        if prop is None or not isinstance(prop.value, (Obj, Ref)):
            return None
        target = self._ctx.resolve(prop.value)
        return target if target.tag == "texture" else None

    def string(self, name: str, default: str | None = None, allowed: tuple = ()) -> str | None:
        """A ``<string>``, ``default`` when absent; with ``allowed``, one of those (compared
        case-insensitively)."""
        prop = self._ctx.take(self._obj, name, ("string",), "a <string>")
        if prop is None:
            return default
        if allowed and prop.value.lower() not in allowed:
            raise self.error(name, f"{name} {prop.value!r} is not supported (supported: {', '.join(allowed)})")
        return prop.value

    def boolean(self, name: str, default: bool | None = None) -> bool | None:
        """A ``<boolean>``, ``default`` when absent."""
        return self._ctx.get(self._obj, name, "boolean", default)

    def number(self, name: str, constant: Constant, label: str, what: str = "a <float>") -> float:
        """A ``<float>`` (or ``<integer>``) in the interval of the material's ``constant``, its
        default when absent; out of range, an error naming the property with ``label`` (what the
        number is); ``what`` says what the property must be."""
        prop = self._ctx.take(self._obj, name, ("float", "integer"), what)
        value = constant.default if prop is None else float(prop.value)
        try:
            return constant.check(self._ctx.where, name, value)
        except SceneError as e:  # the constant's range ("... 'alpha' must lie in (0, 1], got 0"), said of this property
            requirement = str(e).split(f"'{name}' ", 1)[1]
            raise self.error(name, f"'{name}' ({label}) {requirement}") from None

    def transform(self, name: str = "to_world") -> np.ndarray:
        """A ``<transform>`` as its (4, 4) matrix (float64), the identity when absent."""
        prop = self._ctx.take(self._obj, name, ("transform",), "a <transform>")
        return np.eye(4) if prop is None else np.asarray(prop.value, dtype=np.float64)

    def vector(self, name: str, default=None) -> np.ndarray | None:
        """A ``<point>`` or ``<vector>`` as (3,) float64, ``default`` when absent."""
        value = self._ctx.get(self._obj, name, "point", None)
        return default if value is None else np.asarray(value, dtype=np.float64)

    def field_of_view(self, size: tuple[int, int]) -> tuple[float, str]:
        """(fov in degrees, fov_axis) from ``fov`` and ``fov_axis`` or ``focal_length``, as a
        perspective sensor with a film of ``size`` (width, height) reads them
        (:func:`.sensor.field_of_view`)."""
        from invrender.scene.formats.mitsuba.sensor import field_of_view

        return field_of_view(self._ctx, self._obj, size)

    def filename(self, name: str = "filename") -> Path:
        """A ``<string>`` naming a file relative to the scene file's folder; an error naming the
        property when the file does not exist."""
        value = self.string(name)
        if value is None:
            raise self.error(None, f"'{name}' is required")
        path = self._ctx.find_file(self._obj.props[name].node, value)
        if path is None or not path.is_file():
            raise self.error(name, f"file not found: {self._ctx.base / value}")
        return path

    def finish(self, supported: tuple, children: tuple = ()) -> None:
        """Errors for the properties nothing read (listing ``supported``) and for nested objects
        other than ``children`` tags (a blend's ``bsdf``); the properties of :data:`AT_DEFAULT` are
        accepted at their Mitsuba default value."""
        obj = self._obj
        for key in (obj.type, "*"):
            for name, default in AT_DEFAULT.get((obj.tag, key), {}).items():
                prop = obj.props.get(name)
                if prop is None or name in obj.used:
                    continue
                obj.used.add(name)
                value = prop.value
                ok = prop.tag in ("float", "integer", "rgb", "spectrum") and np.allclose(np.asarray(value, dtype=np.float64), default, rtol=0, atol=1e-9)
                if not ok:
                    raise self.error(name, f"'{name}' other than {default:g} (Mitsuba's default) is not supported by invrender's {obj.type}")
        self._ctx.finish(obj, supported, children)
