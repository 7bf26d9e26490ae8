"""Colours and textures (bitmap, checkerboard) of Mitsuba properties, checked against the parameter kinds.

Colours
    ``<rgb>``, ``<float>`` (grey) or a constant ``<spectrum>`` (grey), or a ``<texture
    type="bitmap">`` or ``<texture type="checkerboard">`` (inline or a ``<ref>``) where the
    parameter may be a texture; each value is
    checked against its kind's range (:mod:`invrender.scene.kinds`). Colours are linear RGB (RGB
    variants of Mitsuba); spectra are turned into RGB when read (:mod:`.spectra`).

Bitmap textures (``<texture type="bitmap">``)
    ``filename`` (relative to the XML file; EXR linear, PNG/JPEG sRGB-decoded, like Mitsuba's
    ``raw=false``; with ``raw=true`` PNG/JPEG values as stored: normal and height maps), ``format``
    (Mitsuba's storage: read, invrender keeps float32 texels), ``filter_type`` ``bilinear`` (the default) or
    ``nearest``, ``wrap_mode`` ``repeat`` (the default), ``clamp`` or ``mirror``, and ``to_uv`` (a
    ``<transform>``; its 2D part, as Mitsuba reads it), with Mitsuba 3's semantics
    (:mod:`invrender.core.textures` gives the arithmetic). Options other than the defaults are
    kept per parameter (``Scene.texture_sampling``) and supported on material parameters; an
    emitter's texture must use the defaults. Texture coordinates
    follow Mitsuba's parametrizations (rectangle ``uv = ((x + 1) / 2, (y + 1) / 2)``, the sphere's
    ``(phi / 2 pi, theta / pi)`` about local z, the cube's per-face layout, OBJ/PLY as Mitsuba
    reads them) and Mitsuba's image convention (``v = 0`` is the image's top row), so an image
    lands where Mitsuba puts it; they are stored in invrender's convention (``v`` flipped, and
    ``to_uv`` converted to match).

Mesh attributes (``<texture type="mesh_attribute">``)
    ``name`` (``vertex_color`` or ``vertex_<x>``: a PLY file's colours or extra vertex properties,
    or a serialized mesh's colours; ``face_color`` or ``face_<x>``: a PLY file's face properties)
    and ``scale`` (default 1), on material parameters: the attribute of each shape using the
    material, interpolated barycentrically at the hit (:class:`~invrender.scene.textures.VertexAttribute`);
    a face attribute is constant over each face, as Mitsuba reads it (a mesh with face attributes
    is read with three vertices of its own per face, which carry its face's value).

Checkerboard textures (``<texture type="checkerboard">``)
    ``color0`` (default 0.4), ``color1`` (default 0.2), each an ``<rgb>``, ``<float>`` or constant
    ``<spectrum>`` (not a nested texture), and ``to_uv`` (a ``<transform>``; its 2D part, as
    Mitsuba reads it). Mitsuba's rule: with ``(s, t) = to_uv (u, v)``, ``color0`` where
    ``frac(s) > 0.5`` and ``frac(t) > 0.5`` agree, else ``color1`` (so the cell at the origin,
    ``[0, 0.5)^2``, is ``color0``). Baked into a 512 x 512 texture over ``[0, 1]^2``
    (:func:`invrender.scene.formats.values.checkerboard`): exact away from half a texel of the
    cell edges when those fall on texel edges (``to_uv`` an integer scale dividing 256), filtered
    bilinearly like every texture; beyond ``[0, 1]^2`` it repeats (Mitsuba's board when ``to_uv``
    makes it periodic with period 1).
"""

from __future__ import annotations

import math

import numpy as np

from invrender.errors import InvRenderError
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj, Ref
from invrender.scene.formats.values import CHECKERBOARD_RESOLUTION, checkerboard, one_line
from invrender.scene.kinds import ParamKind
from invrender.scene.textures import DEFAULT, FILTERS, WRAPS, SampledTexture, TextureSampling, VertexAttribute, mitsuba_to_uv

#: the texture plugins read
TEXTURE_TYPES = ("bitmap", "checkerboard", "mesh_attribute")
#: a bitmap's ``format`` values (its storage in Mitsuba; invrender keeps float32 texels for each)
BITMAP_FORMATS = ("auto", "variant", "float16", "fp16", "uint8")


def colour(ctx: Context, obj: Obj, name: str, kind: ParamKind, default: float, texture: bool = True):
    """An RGB triple (3,), a linear texture (h, w, 3) (a :class:`SampledTexture` where it has
    options other than the defaults) or a :class:`VertexAttribute` from a property of ``obj``,
    checked against ``kind``'s range (a vertex attribute's when the scene is built)."""
    prop = obj.props.get(name)
    if prop is None:
        return np.full(3, default)
    obj.used.add(name)
    value = ctx.resolve(prop.value) if isinstance(prop.value, (Ref, Obj)) else prop.value
    if isinstance(value, Obj):
        if value.tag != "texture":
            raise ctx.error(prop.node, f"'{name}' must be a colour or a texture, got {value.describe()}", obj)
        if not texture or not kind.texture:
            raise ctx.error(prop.node, f"'{name}' must be a constant (<rgb>, <float> or <spectrum>): textures are not supported here", obj)
        if value.type == "mesh_attribute":
            return mesh_attribute(ctx, value)
        rgb = bitmap(ctx, value)
        sampling = ctx.texture_sampling.get(id(value), DEFAULT)
    elif prop.tag in ("rgb", "spectrum", "float"):
        rgb = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
    else:
        raise ctx.error(prop.node, f"'{name}' must be <rgb>, <float>, <spectrum> or a texture, got <{prop.tag}>", obj)
    lo, hi = float(np.min(rgb)), float(np.max(rgb))
    if lo < 0 or hi > kind.upper:
        expected = f"lie in [0, {kind.upper:g}]" if math.isfinite(kind.upper) else "be >= 0"
        shown = ", ".join(f"{v:g}" for v in rgb) if rgb.ndim == 1 else f"values in [{lo:.4g}, {hi:.4g}]"
        raise ctx.error(prop.node, f"'{name}' ({kind.doc.split(',')[0]}) must {expected}, got {shown}", obj)
    return SampledTexture(rgb, sampling) if isinstance(value, Obj) and sampling != DEFAULT else rgb


def mesh_attribute(ctx: Context, tex: Obj) -> VertexAttribute:
    """A ``<texture type="mesh_attribute">`` (see this module's docstring)."""
    ctx.check_broken(tex)
    name = ctx.get(tex, "name", "string")
    if name is None:
        raise ctx.error(tex.node, "missing <string name=\"name\"> (the mesh attribute: vertex_color, vertex_<x>, face_color, face_<x>)", tex)
    if not name.startswith(("vertex_", "face_")):
        raise ctx.error(tex.props["name"].node, f"mesh attribute {name!r} is not supported (supported: vertex_color, vertex_<x>, face_color, face_<x>)", tex)
    scale = float(ctx.get(tex, "scale", "float", 1.0))
    if not (math.isfinite(scale) and scale >= 0):
        raise ctx.error(tex.props["scale"].node, f"'scale' must be a finite number >= 0, got {scale:g}", tex)
    ctx.finish(tex, ("name", "scale"))
    return VertexAttribute(name, scale)


def bitmap(ctx: Context, tex: Obj) -> np.ndarray:
    """The linear RGB (h, w, 3) float64 of a ``<texture>`` (read or baked once; references share it)."""
    ctx.check_broken(tex)
    if tex.type == "mesh_attribute":  # declared at the top level: checked, read where a material refers to it
        mesh_attribute(ctx, tex)
        return None
    if id(tex) not in ctx.textures:
        ctx.textures[id(tex)] = read_checkerboard(ctx, tex) if tex.type == "checkerboard" else read_bitmap(ctx, tex)
    return ctx.textures[id(tex)]


def read_checkerboard(ctx: Context, tex: Obj) -> np.ndarray:
    """A ``<texture type="checkerboard">`` baked (see this module's docstring)."""
    colours = []
    for key, default in (("color0", 0.4), ("color1", 0.2)):
        prop = ctx.take(tex, key, ("rgb", "float", "spectrum"), "an <rgb>, a <float> or a constant <spectrum> (nested textures are not supported)")
        colours.append(default if prop is None else prop.value)
    to_uv = ctx.take(tex, "to_uv", ("transform",), "a <transform>")
    ctx.finish(tex, ("color0", "color1", "to_uv"))
    return checkerboard(*colours, None if to_uv is None else to_uv.value, CHECKERBOARD_RESOLUTION)


def read_bitmap(ctx: Context, tex: Obj) -> np.ndarray:
    """Read a ``<texture type="bitmap">``'s file (see this module's docstring)."""
    if tex.type != "bitmap":
        raise ctx.error(tex.node, f"unsupported texture type {tex.type!r} (supported: {', '.join(TEXTURE_TYPES)})", tex)
    filename = ctx.get(tex, "filename", "string")
    if filename is None:
        raise ctx.error(tex.node, "missing <string name=\"filename\">", tex)
    options = {}
    for key, allowed in (("filter_type", FILTERS), ("wrap_mode", WRAPS)):
        value = ctx.get(tex, key, "string", allowed[0])
        options[key] = value.strip().lower()
        if options[key] not in allowed:
            raise ctx.error(tex.props[key].node, f"{key} {value!r} is not supported (supported: {', '.join(allowed)})", tex)
    to_uv = ctx.take(tex, "to_uv", ("transform",), "a <transform>")
    try:
        to_uv = None if to_uv is None else mitsuba_to_uv(to_uv.value)
    except InvRenderError as e:
        raise ctx.error(tex.props["to_uv"].node, one_line(e), tex) from None
    ctx.texture_sampling[id(tex)] = TextureSampling(options["filter_type"], options["wrap_mode"], to_uv)
    path = ctx.find_file(tex.props["filename"].node, filename) or ctx.base / filename
    raw = ctx.get(tex, "raw", "boolean", False)
    storage = ctx.get(tex, "format", "string", "auto")  # how Mitsuba stores the texels: invrender holds float32 whatever it says
    if storage not in BITMAP_FORMATS:
        raise ctx.error(tex.props["format"].node, f"format {storage!r} is not one of Mitsuba's ({', '.join(BITMAP_FORMATS)})", tex)
    ctx.finish(tex, ("filename", "filter_type", "wrap_mode", "raw", "to_uv", "format"))
    from invrender.io.images import read_image  # lazily: images need kornia/OpenEXR

    try:
        return read_image(path, raw=raw).numpy().astype(np.float64)
    except InvRenderError as e:
        raise ctx.error(tex.props["filename"].node, one_line(e), tex) from None
