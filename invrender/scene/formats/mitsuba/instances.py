"""Mitsuba's instancing: ``<shape type="shapegroup" id=...>`` holding shapes, and ``<shape
type="instance">`` placing a group (a ``<ref>`` to it) with its own ``to_world``.

Instances are expanded to triangles when the file is read: each instance adds a copy of its
group's meshes, transformed by the instance's ``to_world`` (after the shapes' own). invrender never
differentiates geometry, and both intersection backends (Embree, the Warp BVH) take one flat
triangle list, so a copy costs memory only, and it keeps every triangle's material, UVs and
normals exact. The expanded scene may hold at most :data:`MAX_INSTANCED_TRIANGLES` triangles from
instances (a one-line error beyond). A group's shapes may not emit (Mitsuba refuses emitters in
instances too) nor hold groups or instances themselves; a group no instance uses is read (its
problems reported) and adds nothing.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj, Ref
from invrender.scene.shapes import Mesh

#: the shape plugins this module reads
SHAPE_TYPES = ("shapegroup", "instance")
#: most triangles instances may add to a scene (each costs about 200 bytes of float32 geometry)
MAX_INSTANCED_TRIANGLES = 20_000_000


class Groups:
    """The shape groups of a file, each read once, and the triangles instances have added."""

    def __init__(self, ctx: Context, convert: Callable[[Obj], tuple[Mesh, int]]):
        self.ctx, self.convert = ctx, convert
        self.meshes: dict[int, list[tuple[Mesh, int]]] = {}  # id(group) -> [(mesh, material key)]
        self.added = 0

    def group(self, obj: Obj) -> list[tuple[Mesh, int]]:
        """The meshes (and material keys) of a ``shapegroup``, converted on first use."""
        ctx = self.ctx
        ctx.check_broken(obj)
        if id(obj) not in self.meshes:
            out = []
            for child in obj.children:
                shape = ctx.resolve(child)
                if shape.tag != "shape":
                    raise ctx.error(shape.node, f"a shapegroup holds only <shape>s, got <{shape.tag}>", obj)
                if shape.type in ("shapegroup", "instance"):
                    raise ctx.error(shape.node, f"a shapegroup cannot hold a {shape.type} (nested instancing is not supported)", obj)
                if ctx.nested_items(shape, "emitter"):
                    raise ctx.error(shape.node, "a shape in a shapegroup cannot emit (emitters are not instanced, as in Mitsuba)", shape)
                out.append(self.convert(shape))
            ctx.finish(obj, (), ("shape",))
            if not out:
                raise ctx.error(obj.node, "the shapegroup holds no shapes", obj)
            self.meshes[id(obj)] = out
        return self.meshes[id(obj)]

    def instance(self, obj: Obj) -> list[tuple[Mesh, int]]:
        """The meshes of an ``instance``: its group's, under its ``to_world``."""
        ctx = self.ctx
        refs = [c for c in obj.children if isinstance(c, (Ref, Obj))] + [p.value for p in obj.props.values() if isinstance(p.value, (Ref, Obj))]
        if len(refs) != 1:
            raise ctx.error(obj.node, f"an instance needs exactly one <ref id=...> to a shapegroup, got {len(refs)}", obj)
        for name, prop in obj.props.items():
            if prop.value is refs[0]:
                obj.used.add(name)
        group = ctx.resolve(refs[0])
        if group.tag != "shape" or group.type != "shapegroup":
            raise ctx.error(refs[0].node, f"an instance refers to a shapegroup, got {group.describe()}", obj)
        to_world = ctx.take(obj, "to_world", ("transform",), "a <transform>")
        matrix = np.eye(4) if to_world is None else np.asarray(to_world.value, dtype=np.float64)
        if np.linalg.det(matrix[:3, :3]) == 0:
            raise ctx.error(to_world.node, "to_world is singular", obj)
        ctx.finish(obj, ("to_world",), ("shape",))
        meshes = self.group(group)
        count = sum(len(m.faces) for m, _ in meshes)
        if self.added + count > MAX_INSTANCED_TRIANGLES:
            raise ctx.error(obj.node, f"instances expand to more than {MAX_INSTANCED_TRIANGLES:,} triangles ({self.added + count:,} so far): invrender expands instances to triangles; instance fewer copies or simplify the group", obj)
        self.added += count
        return [(m.transformed(matrix), key) for m, key in meshes]
