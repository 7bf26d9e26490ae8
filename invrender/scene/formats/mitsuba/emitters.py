"""Mitsuba emitters onto invrender's emitters, through the emitter registry.

Emitters (``<emitter type=...>``)
    Each registered emitter type (:data:`invrender.registry.EMITTERS`) names the Mitsuba plugins
    it stands for in ``mitsuba_plugins`` and reads them in its ``from_mitsuba`` (whose docstring,
    in the emitter's module of :mod:`invrender.plugins.emitters`, says which properties it takes), through
    a :class:`~.reader.PluginReader`. Types that emit from surfaces (``area``: radiance from the
    front side) are nested in the ``<shape>`` that emits, or declared at the top level with an
    ``id`` and attached by a ``<ref id=.../>`` in the shape (one declared so that no shape
    references is an error); types that emit from outside the scene
    and delta lights (``point``, ``spot``, ``projector``, ``directional``) are children of ``<scene>``. The message for an unsupported type lists the registry's. Every type accepts
    Mitsuba's ``sampling_weight`` at its default 1 only (:data:`.reader.AT_DEFAULT`).
"""

from __future__ import annotations

from invrender import registry
from invrender.scene.emitters import Emitter
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj
from invrender.scene.formats.mitsuba.reader import PluginReader


def plugins() -> dict:
    """Mitsuba emitter plugin name -> the registered emitter class that reads it (the names in its
    own ``mitsuba_plugins``; a class registered later takes a name over)."""
    return {name: cls for cls in registry.EMITTERS.values() for name in vars(cls).get("mitsuba_plugins", ())}


def emitter(ctx: Context, obj: Obj, in_shape: bool) -> Emitter:
    """The :class:`Emitter` of an ``<emitter>`` nested in a shape (``in_shape``) or in the scene."""
    ctx.check_broken(obj)
    known = plugins()
    if obj.type not in known:
        listed = [name for name, cls in known.items() if cls.surface or not in_shape]  # in a shape: the ones a shape can hold
        raise ctx.error(obj.node, f"unsupported emitter type {obj.type!r} (supported: {', '.join(listed)})", obj)
    cls = known[obj.type]
    if cls.surface and not in_shape:
        raise ctx.error(obj.node, f"an emitter of type {obj.type!r} must be nested in the <shape> that emits", obj)
    if not cls.surface and in_shape:
        what = "emits from outside the scene" if cls.infinite else "is a point or a direction (a delta light), not emitted by a shape"
        raise ctx.error(obj.node, f"an emitter of type {obj.type!r} {what}: it is a child of <scene>, not of a <shape>", obj)
    entries = cls.from_mitsuba(PluginReader(ctx, obj))
    return Emitter.of(cls.type_name, f"{ctx.where}:{obj.node.line}: {obj.describe()}", **entries)
