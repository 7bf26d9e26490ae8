"""Materials as a scene declares them: a type name, parameter values and constants.

A material is one of the registered material types (:data:`invrender.registry.MATERIALS`; the
built-in ones are in :mod:`invrender.plugins.bsdfs`, one module each), named in scene files by
``type =`` (TOML) or by the Mitsuba plugin it stands for (XML). Its differentiable values
(reflectance-like factors) become entries of ``scene.params`` (``"<material>.<kind>"``, kinds in
:mod:`invrender.scene.kinds`); its constants (index of refraction, roughness) are fixed properties
of the scene. Each type declares both in its own module (:class:`~invrender.scene.plugins.Param`,
:class:`~invrender.scene.plugins.Constant`); this module reads them from the registry and never
lists the types itself.
"""

from __future__ import annotations

from dataclasses import dataclass

from invrender import registry
from invrender.scene.plugins import Constant, Param, PluginSpec

#: material type name -> its plugin class (the registry, read by name)
MATERIAL_TYPES = registry.MATERIALS

DEFAULT_TYPE = "diffuse"


@dataclass(frozen=True)
class Material(PluginSpec):
    """A material of a scene being built (:class:`~invrender.scene.plugins.PluginSpec`): its type
    (a registered material type, default ``diffuse``), parameter values and constants.

    Attributes:
        one_sided: True: a ray arriving at the back of a surface (behind its geometric normal)
            finds a black surface, as Mitsuba's BSDFs do unless wrapped in ``twosided`` (the XML
            reader sets it for those); False (the default): both sides reflect alike. Materials
            that transmit are always two-sided.
    """

    one_sided: bool = False

    registry = registry.MATERIALS
    noun = "material"
    default_type = DEFAULT_TYPE


def material_type(name, where: str = "material"):
    """The plugin class of material type ``name``; a one-line :class:`SceneError` naming ``where``
    and the known types otherwise."""
    return MATERIAL_TYPES.get(name, where)


__all__ = ["Constant", "DEFAULT_TYPE", "MATERIAL_TYPES", "Material", "Param", "material_type"]
