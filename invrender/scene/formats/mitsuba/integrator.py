"""The Mitsuba integrator onto the render settings a scene suggests.

Integrator (at most one ``<integrator>``)
    ``path`` with ``max_depth`` (-1 or >= 1) and ``rr_depth`` (>= 1); ``hide_emitters`` only false.
    Other integrators are errors.
"""

from __future__ import annotations

from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj


def integrator(ctx: Context, obj: Obj) -> dict:
    """The render settings an ``<integrator>`` states (for ``scene.defaults``)."""
    if obj.type != "path":
        raise ctx.error(obj.node, f"unsupported integrator type {obj.type!r} (supported: path)", obj)
    defaults = {"integrator": "path"}
    max_depth = ctx.get(obj, "max_depth", "integer")
    if max_depth is not None:
        if max_depth == 0 or max_depth < -1:
            raise ctx.error(obj.props["max_depth"].node, f"'max_depth' must be >= 1, or -1 for unbounded, got {max_depth}", obj)
        defaults["max_depth"] = max_depth
    rr_depth = ctx.get(obj, "rr_depth", "integer")
    if rr_depth is not None:
        if rr_depth < 1:
            raise ctx.error(obj.props["rr_depth"].node, f"'rr_depth' must be >= 1, got {rr_depth}", obj)
        defaults["rr_depth"] = rr_depth
    if ctx.get(obj, "hide_emitters", "boolean", False):
        raise ctx.error(obj.props["hide_emitters"].node, "hide_emitters=true is not supported", obj)
    ctx.finish(obj, ("max_depth", "rr_depth", "hide_emitters"))
    return defaults
