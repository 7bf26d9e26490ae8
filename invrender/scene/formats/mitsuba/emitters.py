"""Mitsuba emitters onto invrender's emitters.

Emitters (``<emitter type=...>``, nested in the ``<shape>`` that emits)
    ``area`` with ``radiance`` (rgb, spectrum, float or a bitmap texture; default 1), emitted from
    the front side. Other emitter types (and area emitters outside a shape) are errors.
"""

from __future__ import annotations

from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj
from invrender.scene.formats.mitsuba.textures import colour
from invrender.scene.kinds import EMISSION


def area_emitter(ctx: Context, emitter: Obj):
    """The radiance eps, (3,) or a texture (h, w, 3), linear, of an ``<emitter>`` nested in a shape."""
    if emitter.type != "area":
        raise ctx.error(emitter.node, f"unsupported emitter type {emitter.type!r} (supported: area)", emitter)
    eps = colour(ctx, emitter, "radiance", EMISSION, 1.0)
    ctx.finish(emitter, ("radiance",))
    return eps


def top_level_emitter(ctx: Context, emitter: Obj) -> None:
    """An ``<emitter>`` directly in ``<scene>``: an error (invrender's emitters are area lights on shapes)."""
    if emitter.type == "area":
        raise ctx.error(emitter.node, "an area emitter must be nested in the <shape> that emits", emitter)
    raise ctx.error(emitter.node, f"unsupported emitter type {emitter.type!r} (supported: area, nested in a shape)", emitter)
