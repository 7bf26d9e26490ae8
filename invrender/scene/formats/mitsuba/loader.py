"""A Mitsuba XML file into a :class:`~invrender.scene.scene.Scene`: the ``<scene>``'s children
mapped by the plugin modules, named, and assembled.

Render settings the file suggests go to ``scene.defaults`` (only those the file states):
``{"spp": sample_count, "integrator": "path", "max_depth": ..., "rr_depth": ...}``; ``ir.render``,
``fit``, studies and the CLI take them as their defaults where nothing is given
(:mod:`invrender.estimators.defaults`; the file's settings only with the file's integrator). An
``<integrator>`` that states no ``max_depth`` gets Mitsuba's default, -1 (unbounded, Russian
roulette from ``rr_depth``; :mod:`.integrator`), so the file renders as in Mitsuba. A file that
states nothing (no ``<integrator>``, no ``sample_count``) gets invrender's defaults (path, 64 spp,
max_depth 8), not Mitsuba's (4 spp, max_depth -1).

Names
    A material is named by its BSDF's ``id`` (for ``twosided``, the outer one's), else by its
    shape's id + ``_bsdf``, else ``material_N``; an emitter by its shape's ``id``, else
    ``emitter``, ``emitter_2``, ... Names are made unique (``_2``, ``_3``, ... suffixes) and never
    ``ambient``. Materials are ordered by where their BSDF appears in the file; BSDFs no shape uses
    are checked but left out of the scene.

"""

from __future__ import annotations

import warnings
from pathlib import Path

from invrender import registry

from invrender.errors import InvRenderError, SceneError
from invrender.scene.formats.mitsuba.bsdfs import material
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.emitters import emitter
from invrender.scene.formats.mitsuba.emitters import plugins as emitter_plugins
from invrender.scene.formats.mitsuba.integrator import direct_deviations, integrator
from invrender.scene.formats.mitsuba.parser import Obj
from invrender.scene.formats.mitsuba.sensor import DEFAULT_FILM, sensor
from invrender.scene.formats.mitsuba.shapes import SPHERE_SUBDIVISIONS, shape
from invrender.scene.formats.mitsuba.textures import bitmap
from invrender.scene.formats.values import one_line
from invrender.scene.formats.mitsuba.instances import Groups
from invrender.scene.scene import Scene, build_scene
from invrender.scene.shapes import Mesh


def load_mitsuba_xml(path, resolution=None, parameters: dict | None = None, sphere_subdivisions: int = SPHERE_SUBDIVISIONS) -> Scene:
    """A scene from a Mitsuba 3 XML file (the subset in :mod:`invrender.scene.formats.mitsuba`'s modules).

    Args:
        path: the .xml file; file names inside it are relative to its folder.
        resolution: (width, height), overriding the film's; None = the film's (768 x 576 without one).
        parameters: values of ``$name`` parameters, overriding the file's ``<default>`` ones.
        sphere_subdivisions: icosphere subdivisions of ``sphere`` shapes (20 * 4^n triangles).
    Raises:
        SceneError: a missing, unreadable or malformed file, anything outside the subset, a value
            out of range; the message names the file and line.
    """
    return build(Context(Path(path), parameters, sphere_subdivisions), resolution)


def build(ctx: Context, resolution) -> Scene:
    """The scene of a parsed file: every child of its ``<scene>`` mapped, materials and emitters named."""
    scene = ctx.scene
    used_names = {"ambient"}
    emission: dict[str, object] = {}
    meshes: list[tuple[Mesh, int]] = []

    def emitter_name(owner: Obj, spec) -> str:
        # named by its owner's id (the shape that emits, or the emitter itself outside shapes);
        # the fallback avoids every id (BSDF ids become material names)
        name = owner.id if owner.id and owner.id not in used_names else _unique(owner.id or "emitter", used_names | set(ctx.ids))
        used_names.add(name)
        emission[name] = spec
        return name

    camera, film, defaults, seen, film_options = None, DEFAULT_FILM, {}, {}, None
    surface_emitters = []  # declared at the top level, for shapes to reference
    groups, group_objs = Groups(ctx, lambda obj: shape(ctx, obj, emitter_name)), []
    for item in scene.children:
        try:
            obj = ctx.resolve(item)
            if obj.broken:  # its problems are noted
                continue
            if obj.tag in seen and obj.tag in ("sensor", "integrator"):
                raise ctx.error(obj.node, f"only one <{obj.tag}> is supported (the first is at line {seen[obj.tag]})", obj)
            seen.setdefault(obj.tag, obj.node.line)
            if obj.tag == "shape" and obj.type == "shapegroup":
                group_objs.append(obj)  # converted where an instance uses it (else checked below)
            elif obj.tag == "shape" and obj.type == "instance":
                meshes.extend(groups.instance(obj))
            elif obj.tag == "shape":
                meshes.append(shape(ctx, obj, emitter_name))
            elif obj.tag == "bsdf":
                material(ctx, obj, None)  # checked even when no shape uses it
            elif obj.tag == "texture":
                bitmap(ctx, obj)
            elif obj.tag == "sensor":
                camera, film, sensor_defaults, film_options = sensor(ctx, obj, resolution)
                defaults.update(sensor_defaults)
            elif obj.tag == "integrator":
                defaults.update(integrator(ctx, obj))
            elif obj.tag == "emitter" and obj.id is not None and getattr(emitter_plugins().get(obj.type), "surface", False):
                surface_emitters.append(obj)
            elif obj.tag == "emitter":
                emitter_name(obj, emitter(ctx, obj, in_shape=False))
            elif obj.tag in ("film", "sampler", "rfilter") and obj.id in ctx.referenced:
                continue  # declared at the top level for a <ref> where it belongs (a <sensor>, a <film>)
            else:
                home = {"film": " (it belongs inside a <sensor>)", "sampler": " (it belongs inside a <sensor>)", "rfilter": " (it belongs inside a <film>)"}
                raise ctx.error(obj.node, f"<{obj.tag}> cannot be a child of <scene>{home.get(obj.tag, '')}", obj)
        except SceneError as e:
            ctx.problem(e)
    for obj in group_objs:  # groups no instance used: read for their problems, adding nothing
        try:
            groups.group(obj)
        except SceneError as e:
            ctx.problem(e)
    for obj in surface_emitters:
        if obj.id not in ctx.referenced:
            ctx.problem(ctx.error(obj.node, f"an emitter of type {obj.type!r} declared outside a shape must be attached to one (<ref id=\"{obj.id}\"/> inside the <shape>)", obj))
    for prop in scene.props.values():
        ctx.problem(ctx.error(prop.node, "unexpected property of <scene>"))
    if not meshes and not ctx.problems:
        raise SceneError(f"{ctx.where}: the scene has no shapes")
    ctx.check_problems()

    # materials, in the order their BSDFs appear: named by the BSDF's id (ids are unique and no
    # emitter took one), then the others by shape id + _bsdf or material_N, avoiding every id
    used_keys = {k for _, k in meshes}
    ordered = sorted((bsdf.order, key) for key, (bsdf, _, _) in ctx.materials.items() if key in used_keys)
    names: dict[int, str] = {}
    for _, key in ordered:
        bsdf = ctx.materials[key][0]
        if bsdf.id:
            names[key] = _unique(bsdf.id, used_names)
            used_names.add(names[key])
    anonymous = 0
    for _, key in ordered:
        bsdf, _, owner = ctx.materials[key]
        if key not in names:
            if owner:
                base = f"{owner}_bsdf"
            else:
                anonymous += 1
                base = f"material_{anonymous}"
            names[key] = _unique(base, used_names | set(ctx.ids))
            used_names.add(names[key])
    materials = {names[key]: ctx.materials[key][1] for _, key in ordered}
    shapes = [Mesh(m.vertices, m.faces, m.uvs, names[k], m.emitter, m.normals, m.sphere, m.attributes) for m, k in meshes]

    if camera is None:  # Mitsuba 3 cannot render such a scene either ("No sensor specified")
        raise SceneError(f"{ctx.where}:{scene.node.line}: <scene>: no <sensor>: add a <sensor type=\"perspective\"> with a fov and a to_world")
    try:
        built = build_scene(shapes, materials, emission, camera, film if resolution is None else resolution, name=ctx.path.stem)
    except InvRenderError as e:
        raise SceneError(f"{ctx.where}: {one_line(e)}") from None
    built.defaults = defaults
    if film_options is not None:
        built.film = film_options
    if ctx.sample_counts:
        delta_lights = any(not (c.surface or c.infinite) for c in (registry.EMITTERS[e.type] for e in emission.values()))
        delta_lobes = any(_has_delta_lobe(registry.MATERIALS[m.type].lobes) for m in materials.values())
        for line in direct_deviations(ctx, delta_lights, delta_lobes):
            warnings.warn(f"{ctx.where}: {line}", stacklevel=3)
    return built


def _has_delta_lobe(lobes) -> bool:
    """Do a material's lobe flags (read from the flags themselves: the scene layer imports no BSDF) include a delta lobe?"""
    flags = type(lobes)
    return bool(lobes & (flags.DELTA_REFLECTION | flags.DELTA_TRANSMISSION))


def _unique(base: str, used: set) -> str:
    name, i = base, 1
    while name in used:
        i += 1
        name = f"{base}_{i}"
    return name
