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

    Mitsuba's defaults: an ``<integrator>`` whose integrator has a ``max_depth`` setting but which
    states none gets Mitsuba's default, ``max_depth`` -1 (unbounded: paths end by Russian
    roulette, from ``rr_depth``, 5 by default in both), not invrender's 8: the file is rendered as
    Mitsuba renders it (``scene.defaults`` then holds ``"max_depth": -1``). A file without an
    ``<integrator>`` states nothing and gets invrender's defaults.

    Mitsuba's ``direct`` with other sample counts (``emitter_samples``, ``bsdf_samples``, both
    set by ``shading_samples``; each >= 0) estimates the same image with another variance, and is
    read as the same ``path`` at max_depth 2, except where Mitsuba's own weighting differs, which
    invrender does not copy and says in a warning (:func:`direct_deviations`): Mitsuba adds each
    point, spot or directional light once per emitter sample, so ``emitter_samples`` N counts it
    N times (none with 0), and with ``bsdf_samples`` 0 it misses the emitters seen through
    mirrors and glass; invrender counts each light once and sees those emitters.

    Volumetric path tracers: Mitsuba's ``volpath`` and ``volpathmis`` in a scene without media
    (invrender reads no ``<medium>``: one is an error of its own) compute what ``path`` computes,
    and are read as ``path`` (``max_depth``, ``rr_depth``, ``hide_emitters``), with a warning
    saying so (invrender's ``path`` combines emitter and BSDF samples by MIS as ``volpathmis`` does;
    ``volpath``'s own weighting differs in the noise only).
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

#: Mitsuba's volumetric path tracers, read as ``path`` in a scene without media
VOLUMETRIC = ("volpath", "volpathmis")

#: Mitsuba's max_depth when an integrator states none (unbounded, Russian roulette ends paths)
MITSUBA_MAX_DEPTH = -1

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
    if obj.type in VOLUMETRIC and "path" in known:
        warnings.warn(f"{obj.node.where or ctx.where}:{obj.node.line}: {obj.describe()}: read as <integrator type=\"path\"> (the scene has no media, "
                      "where the two compute the same image)", stacklevel=2)
        return _settings(ctx, obj, known["path"])
    if obj.type not in known:
        raise ctx.error(obj.node, f"unsupported integrator type {obj.type!r} (supported: {', '.join(known)})", obj)
    return _settings(ctx, obj, known[obj.type])


def _settings(ctx: Context, obj: Obj, cls) -> dict:
    """The settings an ``<integrator>`` read as registered integrator ``cls`` states (see :func:`integrator`)."""
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
        if prop is not None:
            ctx.sample_counts[name] = (int(prop.value), prop.node)
    ctx.finish(obj, tuple(fields) + tuple(counts))
    if alias is not None:
        settings = {**alias.settings, **settings}
    elif "max_depth" in fields and "max_depth" not in settings:
        settings["max_depth"] = MITSUBA_MAX_DEPTH
    try:
        cls(**settings)  # the settings check their own values
    except ParameterError as e:
        message = str(e)
        key = next((k for k in settings if message.startswith(f"{k} ")), None)
        node = obj.props[key].node if key in obj.props else obj.node
        raise ctx.error(node, f"'{key}'{message[len(key):]}" if key else message, obj) from None
    return {"integrator": cls.name, **settings}


def direct_deviations(ctx: Context, delta_lights: bool, delta_lobes: bool) -> list[str]:
    """Where Mitsuba's ``direct`` with the sample counts the file gave renders another image than
    invrender's reading of it, in a scene with point/spot/directional lights (``delta_lights``)
    and mirrors or glass (``delta_lobes``): one line each, for a warning."""
    counts = {k: v for k, (v, _) in ctx.sample_counts.items()}
    shading = counts.get("shading_samples", 1)
    emitter, bsdf = counts.get("emitter_samples", shading), counts.get("bsdf_samples", shading)
    out = []
    if delta_lights and emitter != 1:
        out.append(f"Mitsuba's direct with emitter_samples {emitter} counts each point, spot or directional light {emitter} times (mitsuba3 issue #1861); invrender counts it once")
    if delta_lobes and bsdf == 0:
        out.append("Mitsuba's direct with bsdf_samples 0 misses the emitters seen through mirrors and glass; invrender counts them")
    return out
