"""The Mitsuba integrator onto the render settings a scene suggests, through the integrator registry.

Integrator (at most one ``<integrator>``)
    Each registered integrator (:data:`invrender.registry.INTEGRATORS`) names the Mitsuba plugins
    it stands for in ``mitsuba_plugins`` (``path``: Mitsuba's ``path``). The element's properties
    are the integrator's settings by name (``max_depth``, ``rr_depth``, ...), each read as its
    settings field's type says (``<integer>``, ``<float>``, ``<boolean>``, ``<string>``) and
    checked by the settings themselves (``hide_emitters`` is one of every integrator's). The
    message for an unsupported type lists the registry's aliases.
"""

from __future__ import annotations

import dataclasses

from invrender import registry
from invrender.errors import ParameterError
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj
from invrender.validate import type_names

#: a settings field's type -> the property element read for it
_TAGS = {"int": "integer", "float": "float", "bool": "boolean", "str": "string"}


def plugins() -> dict:
    """Mitsuba integrator plugin name -> the registered integrator class that stands for it."""
    return {name: cls for cls in registry.INTEGRATORS.values() for name in vars(cls).get("mitsuba_plugins", ())}


def integrator(ctx: Context, obj: Obj) -> dict:
    """The render settings an ``<integrator>`` states (for ``scene.defaults``): ``{"integrator":
    name, setting: value, ...}`` with the settings the element gives."""
    known = plugins()
    if obj.type not in known:
        raise ctx.error(obj.node, f"unsupported integrator type {obj.type!r} (supported: {', '.join(known)})", obj)
    cls = known[obj.type]
    fields = {f.name: f for f in dataclasses.fields(cls.Settings) if f.init}
    settings = {}
    for name in list(obj.props):
        if name in fields:
            kind = type_names(fields[name].type)[0]
            value = ctx.get(obj, name, _TAGS.get(kind, "string"))
            settings[name] = int(value) if kind == "int" else value
    ctx.finish(obj, tuple(fields))
    try:
        cls(**settings)  # the settings check their own values
    except ParameterError as e:
        message = str(e)
        key = next((k for k in settings if message.startswith(f"{k} ")), None)
        node = obj.props[key].node if key else obj.node
        raise ctx.error(node, f"'{key}'{message[len(key):]}" if key else message, obj) from None
    return {"integrator": cls.name, **settings}
