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
    if emitter.type != "area":
        raise ctx.error(emitter.node, f"unsupported emitter type {emitter.type!r} (supported: area)", emitter)
    eps = colour(ctx, emitter, "radiance", EMISSION, 1.0)
    ctx.finish(emitter, ("radiance",))
    return eps
