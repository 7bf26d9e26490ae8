"""The Mitsuba integrator onto the render settings a scene suggests, through the integrator registry.

Integrator (at most one ``<integrator>``)
    Each registered integrator (:data:`invrender.registry.INTEGRATORS`) names the Mitsuba plugins
    it stands for in ``mitsuba_plugins`` (``path``: Mitsuba's ``path``), and those it stands for
    with some settings fixed in ``mitsuba_aliases`` (Mitsuba's ``direct``: ``path`` at max_depth 2,
    whose sample counts are read, checked and ignored). The element's properties
    are the integrator's settings by name (``max_depth``, ``rr_depth``, ...), each read as its
    settings field's type says (``<integer>``, ``<float>``, ``<boolean>``, ``<string>``) and
    checked by the settings themselves (``hide_emitters`` is one of every integrator's). The
    message for an unsupported type lists the registry's aliases. Mitsuba's ``moment`` integrator
    (which also writes the second moment of each pixel's samples) is read as the one integrator
    it holds, with a warning that the moment images are not produced.
"""

from __future__ import annotations

import dataclasses
import warnings

from invrender import registry
from invrender.errors import ParameterError
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj
from invrender.validate import type_names

#: Mitsuba's moment integrator: its nested integrator is what is rendered
MOMENT = "moment"

#: a settings field's type -> the property element read for it
_TAGS = {"int": "integer", "float": "float", "bool": "boolean", "str": "string"}


def plugins() -> dict:
    """Mitsuba integrator plugin name -> the registered integrator class that stands for it (its
    ``mitsuba_plugins``, then its ``mitsuba_aliases``)."""
    out = {name: cls for cls in registry.INTEGRATORS.values() for name in vars(cls).get("mitsuba_plugins", ())}
    out.update({name: cls for cls in registry.INTEGRATORS.values() for name in vars(cls).get("mitsuba_aliases", {})})
    return out


def integrator(ctx: Context, obj: Obj) -> dict:
    """The render settings an ``<integrator>`` states (for ``scene.defaults``): ``{"integrator":
    name, setting: value, ...}`` with the settings the element gives (and, for an alias such as
    Mitsuba's ``direct``, the settings it fixes; its sample counts checked and ignored)."""
    if obj.type == MOMENT:
        inner = ctx.nested(obj, "integrator")
        if len(inner) != 1:
            raise ctx.error(obj.node, f"a moment integrator must hold one <integrator> (got {len(inner)})", obj)
        ctx.finish(obj, (), ("integrator",))
        warnings.warn(f"{obj.node.where or ctx.where}:{obj.node.line}: {obj.describe()}: rendered as its nested <integrator type=\"{inner[0].type}\">; "
                      "the moment images (the second moment of each pixel's samples) are not produced", stacklevel=2)
        return integrator(ctx, inner[0])
    known = plugins()
    if obj.type not in known:
        raise ctx.error(obj.node, f"unsupported integrator type {obj.type!r} (supported: {', '.join(known)})", obj)
    cls = known[obj.type]
    alias = vars(cls).get("mitsuba_aliases", {}).get(obj.type)
    fields = {f.name: f for f in dataclasses.fields(cls.Settings) if f.init}
    if alias is not None:
        fields = {k: f for k, f in fields.items() if k in alias.passed}
    settings = {}
    for name in list(obj.props):
        if name in fields:
            kind = type_names(fields[name].type)[0]
            value = ctx.get(obj, name, _TAGS.get(kind, "string"))
            settings[name] = int(value) if kind == "int" else value
    counts = alias.counts if alias is not None else {}
    for name, (low, high, why) in counts.items():
        prop = ctx.take(obj, name, ("integer",), "an <integer>")
        if prop is not None and not (int(prop.value) >= low and (high is None or int(prop.value) <= high)):
            raise ctx.error(prop.node, f"'{name}' {prop.value}: {why}", obj)
    ctx.finish(obj, tuple(fields) + tuple(counts))
    if alias is not None:
        settings = {**alias.settings, **settings}
    try:
        cls(**settings)  # the settings check their own values
    except ParameterError as e:
        message = str(e)
        key = next((k for k in settings if message.startswith(f"{k} ")), None)
        node = obj.props[key].node if key else obj.node
        raise ctx.error(node, f"'{key}'{message[len(key):]}" if key else message, obj) from None
    return {"integrator": cls.name, **settings}
