"""Emitters as a scene declares them: a type name, parameter values and constants.

An emitter is one of the registered emitter types (:data:`invrender.registry.EMITTERS`; the
built-in ones are in :mod:`invrender.plugins.emitters`, one module each). ``area`` (the default) emits from
the front side of the shapes that name it; other types emit from outside the scene (rays that leave
it). Its differentiable values (``emission``) become entries of ``scene.params``
(``"<emitter>.emission"``).
"""

from __future__ import annotations

from dataclasses import dataclass

from invrender import registry
from invrender.scene.plugins import PluginSpec

DEFAULT_TYPE = "area"


@dataclass(frozen=True)
class Emitter(PluginSpec):
    """An emitter of a scene being built (:class:`~invrender.scene.plugins.PluginSpec`): its type
    (a registered emitter type, default ``area``), parameter values and constants."""

    registry = registry.EMITTERS
    noun = "emitter"
    default_type = DEFAULT_TYPE
