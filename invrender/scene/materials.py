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

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch

from invrender import registry
from invrender.scene.plugins import Constant, Param, PluginSpec

#: material type name -> its plugin class (the registry, read by name)
MATERIAL_TYPES = registry.MATERIALS

DEFAULT_TYPE = "diffuse"


#: the kinds of normal perturbation (Mitsuba's wrapper plugins of the same names)
PERTURBATIONS = ("normalmap", "bumpmap")


@dataclass(frozen=True)
class NormalPerturbation:
    """A material's shading normal perturbed by a texture, as Mitsuba's ``normalmap`` and
    ``bumpmap`` wrap a BSDF (the conventions: :mod:`invrender.core.shading`).

    Attributes:
        kind: ``"normalmap"`` (the texture's RGB ``c`` is the tangent-space normal ``2 c - 1``) or
            ``"bumpmap"`` (its luminance is a height, differentiated over uv).
        texture: (h, w, 3) float32 the texels (row 0 at the top, invrender's UV convention).
        sampling: how the texture is read (:class:`~invrender.scene.textures.TextureSampling`;
            None: bilinear, repeat).
        scale: the bump map's height scale (Mitsuba's ``scale``, default 1).
        on_turned: ``twosided`` wraps the map: it perturbs the frame turned to the side the ray
            arrives from (else the front side's frame, as a map wrapping ``twosided`` does).
        flip_invalid: Mitsuba's ``flip_invalid_normals`` (default true).
        shadowing: Mitsuba's ``use_shadowing_function`` (default true).
        source: where it was read (for messages).
    """

    kind: str
    texture: torch.Tensor = field(compare=False, repr=False)
    sampling: object = None
    scale: float = 1.0
    on_turned: bool = False
    flip_invalid: bool = True
    shadowing: bool = True
    source: str = ""


#: the shortest normal a normal map's texel may encode (a grey texel, 0.5 0.5 0.5 in 8 bits, is
#: 0.0068 long: no direction); shorter ones are errors, longer ones are normalized when read
#: (files do hold short normals, 0.45)
MIN_NORMAL_LENGTH = 0.01


def normal_map_problem(texels) -> str | None:
    """What is wrong with a normal map's texels (h, w, 3) (each texel ``c`` encodes the
    tangent-space normal ``2 c - 1``): the first texel whose normal is not a number or shorter than
    :data:`MIN_NORMAL_LENGTH`, in words; None when every texel has a direction."""
    length = np.linalg.norm(2.0 * np.asarray(texels, dtype=np.float64) - 1.0, axis=-1)
    bad = ~np.isfinite(length) | (length < MIN_NORMAL_LENGTH)
    if not bad.any():
        return None
    i, j = np.argwhere(bad)[0]
    what = "not a number" if not np.isfinite(length[i, j]) else f"of length {length[i, j]:.3g}"
    return f"the normal at texel (row {i}, column {j}) is {what}: a normal map's texels encode unit normals n as (n + 1) / 2"


@dataclass(frozen=True)
class Material(PluginSpec):
    """A material of a scene being built (:class:`~invrender.scene.plugins.PluginSpec`): its type
    (a registered material type, default ``diffuse``), parameter values and constants.

    Attributes:
        one_sided: True: a ray arriving at the back of a surface (behind its geometric normal)
            finds a black surface, as Mitsuba's BSDFs do unless wrapped in ``twosided`` (the XML
            reader sets it for those); False (the default): both sides reflect alike. Materials
            that transmit are always two-sided.
        perturbation: its shading normal perturbed by a normal or bump map
            (:class:`NormalPerturbation`), or None.
    """

    one_sided: bool = False
    perturbation: NormalPerturbation | None = None

    registry = registry.MATERIALS
    noun = "material"
    default_type = DEFAULT_TYPE

    def perturbed(self, perturbation: NormalPerturbation) -> Material:
        """This material with its shading normal perturbed by ``perturbation``, as a scene format
        without Mitsuba's wrappers (TOML, glTF) states it: the map perturbs the frame turned to the
        side the ray arrives from (``on_turned``: the material is two-sided), except where the
        material transmits (the front side's frame, as Mitsuba's ``normalmap`` around a dielectric)."""
        lobes = self.spec.lobes
        return dataclasses.replace(self, perturbation=dataclasses.replace(perturbation, on_turned=not bool(lobes & type(lobes).TRANSMISSION)))


def material_type(name, where: str = "material"):
    """The plugin class of material type ``name``; a one-line :class:`SceneError` naming ``where``
    and the known types otherwise."""
    return MATERIAL_TYPES.get(name, where)


__all__ = ["Constant", "DEFAULT_TYPE", "MATERIAL_TYPES", "Material", "NormalPerturbation", "PERTURBATIONS", "Param", "material_type", "normal_map_problem"]
