"""The subset as tables: which Mitsuba elements and plugins invrender's reader takes, gathered from
the plugin modules' own tables and the registries (for listings such as ``bench/census.py``; each
module stays the place its part is read and documented)."""

from __future__ import annotations

from invrender.scene.formats.mitsuba import bsdfs, emitters, instances, integrator, parser, sensor, shapes, textures


def plugin_types() -> dict[str, tuple[str, ...]]:
    """Object element (``"bsdf"``, ``"shape"``, ...) -> the plugin types (``type="..."``) read."""
    return {
        "shape": (*shapes.SHAPE_TYPES, *instances.SHAPE_TYPES),
        "bsdf": (*bsdfs.plugins(), bsdfs.TWOSIDED, *bsdfs.PERTURBING),
        "emitter": tuple(emitters.plugins()),
        "integrator": (*integrator.plugins(), integrator.MOMENT, *integrator.VOLUMETRIC),
        "texture": tuple(textures.TEXTURE_TYPES),
        "sensor": tuple(sensor.SENSOR_TYPES),
        "film": tuple(sensor.FILM_TYPES),
        "rfilter": tuple(sensor.RFILTER_TYPES),
        "sampler": tuple(sensor.SAMPLER_TYPES),
    }


def element_supported(tag: str) -> bool:
    """Is element ``<tag>`` part of the file structure read (objects, properties, transforms, ``<default>``, ``<path>``, ``<include>``)?"""
    known = (*parser.OBJECT_TAGS, *parser.PROPERTY_TAGS, *parser.TRANSFORM_OPS, *parser.STRUCTURE_TAGS, "scene", "transform")
    return tag in known and tag not in parser.UNSUPPORTED_TAGS


def plugin_supported(tag: str, type_name: str) -> bool:
    """Is ``<tag type="type_name">`` read?"""
    return type_name in plugin_types().get(tag, ())


#: the newest major version of the format read (older ones are upgraded)
NEWEST_MAJOR = parser.NEWEST_MAJOR
