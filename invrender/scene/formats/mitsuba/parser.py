"""Mitsuba 3's XML scene format as a tree of objects and properties, knowing no particular plugin.

:class:`Document` reads a file with the standard library's expat parser into :class:`Obj` objects
(``<shape>``, ``<bsdf>``, ... of some ``type``) holding named :class:`Prop` properties (numbers,
strings, points, colours, 4x4 transforms, nested objects, references) and unnamed nested objects,
each with the line it came from. What a plugin type means is the mapping's business
(:mod:`invrender.scene.formats.mitsuba`); this module gives it the typed readers
(:meth:`Document.get`, :meth:`~Document.take`, :meth:`~Document.nested`, ...) and the check that
nothing was left unread (:meth:`~Document.finish`). Every error is a one-line
:class:`~invrender.errors.SceneError` naming the file, the line and the element
(:meth:`Document.error`); malformed XML is reported with the line expat stopped at.

File structure
    ``<scene version="x.y.z">`` root (version 2.0.0 or later; Mitsuba 0.x files with camelCase names
    are not upgraded). ``<default name="x" value="..."/>`` declares a parameter and ``$x`` in any
    attribute value is replaced by it (as Mitsuba does: in document order, longer names first; a
    ``$`` left over is an error); values passed to :func:`~invrender.scene.formats.mitsuba.load_mitsuba_xml` as ``parameters``
    override the defaults (Mitsuba's ``-D x=...``). Objects may carry an ``id`` (unique in the
    file) and be referenced with ``<ref id="..."/>`` (before or after their definition): BSDFs
    defined at the top level and used by shapes, and bitmap textures. Comments are ignored; text
    content, ``<include>``, ``<alias>``, ``<path>`` and unknown elements or attributes are errors,
    and so is any property a plugin does not list (:meth:`Document.finish`; Mitsuba also rejects
    unused properties).

Property elements
    ``<float>``, ``<integer>``, ``<boolean>`` (true/false), ``<string>``, ``<point>``/``<vector>``
    (``value="x y z"`` or ``x``/``y``/``z`` attributes), ``<rgb value="r, g, b"/>`` (one or three
    numbers), ``<spectrum value="v"/>`` (one constant value only: read as grey ``v, v, v``),
    ``<transform name="to_world">``.

Transforms (inside ``<transform name="to_world">``)
    ``<translate>`` (``x``/``y``/``z`` or ``value``), ``<rotate>`` (axis ``x``/``y``/``z`` or
    ``value``, ``angle`` in degrees, right-handed; like Mitsuba 3, a non-unit axis is not
    normalized, so the matrix also scales and shears: a warning says so), ``<scale>`` (``value``
    one or three numbers, or
    ``x``/``y``/``z``, missing ones 1), ``<matrix value="16 numbers, row-major"/>`` (or 9: a 3x3
    linear part), ``<lookat origin="x y z" target="x y z" up="x y z"/>`` (up optional, as in
    Mitsuba). They apply in document order, each one left-multiplied onto the previous ones, as
    Mitsuba does (``<scale/><rotate/><translate/>`` scales first).

"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

import numpy as np

from invrender.errors import SceneError
from invrender.scene.shapes import rotate, scale, translate

OBJECT_TAGS = ("shape", "bsdf", "emitter", "sensor", "film", "rfilter", "sampler", "integrator", "texture")
PROPERTY_TAGS = ("float", "integer", "boolean", "string", "point", "vector", "rgb", "spectrum", "transform", "ref")
TRANSFORM_OPS = ("translate", "rotate", "scale", "matrix", "lookat")
#: Mitsuba elements outside the subset (a clearer message than "unknown element")
UNSUPPORTED_TAGS = ("include", "alias", "path", "medium", "phase", "volume", "shapegroup")

_PARAMETER = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)?")
_SPLIT = re.compile(r"[,\s]+")


# ---------------------------------------------------------------- the element tree


@dataclass
class Node:
    """One XML element: tag, attributes (``$`` substituted when visited), children, line."""

    tag: str
    attrs: dict
    line: int
    children: list = field(default_factory=list)

    def describe(self) -> str:
        for key in ("type", "name", "id"):
            if key in self.attrs:
                return f'<{self.tag} {key}="{self.attrs[key]}">'
        return f"<{self.tag}>"


@dataclass
class Ref:
    """A ``<ref id=...>``: the id it names, resolved when read (:meth:`Document.resolve`)."""

    id: str
    node: Node


@dataclass
class Prop:
    """A named property of an object: its element, and its value (a number, string, tuple, 4x4
    matrix, nested :class:`Obj` or :class:`Ref`)."""

    node: Node
    value: object

    @property
    def tag(self) -> str:
        return self.node.tag


@dataclass
class Obj:
    """A plugin element (shape, bsdf, ...): its type, id, named properties and unnamed children."""

    node: Node
    type: str
    order: int
    props: dict = field(default_factory=dict)
    children: list = field(default_factory=list)
    used: set = field(default_factory=set)

    @property
    def tag(self) -> str:
        return self.node.tag

    @property
    def id(self) -> str | None:
        return self.node.attrs.get("id")

    def describe(self) -> str:
        return f'<{self.tag} type="{self.type}">'


class _Expat:
    """The element tree of one file, with the line of each element (expat)."""

    def __init__(self, where: str):
        self.where = where

    def parse(self, data: bytes) -> Node:
        parser = expat.ParserCreate()
        stack: list[Node] = []
        roots: list[Node] = []

        def start(tag, attrs):
            node = Node(tag, dict(attrs), parser.CurrentLineNumber)
            (stack[-1].children if stack else roots).append(node)
            stack.append(node)

        def end(tag):
            stack.pop()

        def text(data):
            if data.strip():
                parent = f" in {stack[-1].describe()}" if stack else ""
                raise SceneError(f"{self.where}:{parser.CurrentLineNumber}: unexpected text {_show(data.strip())}{parent} (values go in attributes)")

        def entity(*args):
            raise SceneError(f"{self.where}:{parser.CurrentLineNumber}: entity declarations are not supported")

        parser.StartElementHandler = start
        parser.EndElementHandler = end
        parser.CharacterDataHandler = text
        parser.EntityDeclHandler = entity
        try:
            parser.Parse(data, True)
        except expat.ExpatError as e:
            raise SceneError(f"{self.where}:{e.lineno}: malformed XML: {expat.ErrorString(e.code)} (column {e.offset + 1})") from None
        return roots[0]


# ---------------------------------------------------------------- the document


class Document:
    """A parsed Mitsuba XML file: its ``<scene>`` (:attr:`scene`), its objects by ``id``
    (:attr:`ids`), and the readers of object properties.

    Args:
        path: the .xml file.
        parameters: values of ``$name`` parameters, overriding the file's ``<default>`` ones.
    Raises:
        SceneError: a missing, unreadable or malformed file, an element or attribute outside the
            format, an undefined ``$name``; the message names the file and line.
    """

    def __init__(self, path: Path, parameters: dict | None = None):
        self.path = path
        self.where = str(path)
        self.params = {str(k): str(v) for k, v in (parameters or {}).items()}
        self.ids: dict[str, Obj] = {}
        self.count = 0
        self.scene = self.read()

    # ---- errors

    def error(self, node: Node, message: str, obj: Obj | None = None) -> SceneError:
        """A one-line error at ``node``'s line, naming ``obj`` (or the node itself)."""
        what = obj.describe() if obj is not None else node.describe()
        return SceneError(f"{self.where}:{node.line}: {what}: {message}")

    # ---- parsing

    def read(self) -> Obj:
        """The ``<scene>`` root as an object, its children parsed."""
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            raise SceneError(f"scene file not found: {self.path}") from None
        except OSError as e:
            raise SceneError(f"cannot read scene file {self.path}: {e.strerror or e}") from None
        root = _Expat(self.where).parse(data)
        self.substitute(root)
        if root.tag != "scene":
            raise self.error(root, "the root element must be <scene version=...>")
        self.check_attrs(root, {"version"}, required={"version"})
        self.check_version(root)
        scene = Obj(root, "scene", 0)
        for child in root.children:
            self.add_child(scene, child)
        return scene

    def check_version(self, node: Node) -> None:
        text = node.attrs["version"]
        parts = text.split(".")
        if len(parts) != 3 or not all(p.strip().isdigit() for p in parts):
            raise self.error(node, f"version must be three numbers like 3.0.0, got {text!r}")
        if int(parts[0]) < 2:
            raise self.error(node, f"version {text} files (Mitsuba 0.x, camelCase names) are not supported (supported: 2.0.0 or later)")

    def substitute(self, node: Node) -> None:
        """Replace ``$name`` in ``node``'s attributes by the parameters known so far (Mitsuba's order:
        longest names first); a ``$`` left over is an error."""
        names = sorted(self.params, key=len, reverse=True)
        for key, value in node.attrs.items():
            if "$" not in value:
                continue
            for name in names:
                value = value.replace("$" + name, self.params[name])
            if "$" in value:
                m = _PARAMETER.search(value)
                unknown = f"${m.group(1)}" if m and m.group(1) else "'$'"
                known = ", ".join(sorted(self.params)) or "none"
                raise self.error(node, f"undefined parameter {unknown} in {key}={node.attrs[key]!r} (defined: {known}; declare it with <default name=... value=.../>)")
            node.attrs[key] = value

    def check_attrs(self, node: Node, allowed: set, required: set = frozenset()) -> None:
        for key in node.attrs:
            if key not in allowed:
                raise self.error(node, f"unexpected attribute {key!r} (allowed: {', '.join(sorted(allowed))})")
        for key in sorted(required):
            if key not in node.attrs:
                raise self.error(node, f"missing attribute {key!r}")

    def add_child(self, parent: Obj, node: Node) -> None:
        """Parse ``node`` (a child of ``parent``) into a property or nested object of ``parent``."""
        self.substitute(node)
        tag = node.tag
        if tag == "default":
            self.check_attrs(node, {"name", "value"}, required={"name", "value"})
            if not node.attrs["name"]:
                raise self.error(node, "the parameter name must not be empty")
            self.no_children(node)
            self.params.setdefault(node.attrs["name"], node.attrs["value"])
            return
        if tag in OBJECT_TAGS or (tag == "spectrum" and "type" in node.attrs):
            obj = self.parse_object(node)
            name = node.attrs.get("name")
            if name is None:
                parent.children.append(obj)
            else:
                self.set_prop(parent, node, name, obj)
            return
        if tag == "ref":
            self.check_attrs(node, {"id", "name"}, required={"id"})
            self.no_children(node)
            ref = Ref(node.attrs["id"], node)
            if "name" in node.attrs:
                self.set_prop(parent, node, node.attrs["name"], ref)
            else:
                parent.children.append(ref)
            return
        if tag in PROPERTY_TAGS:
            if parent.tag == "scene":
                raise self.error(node, "properties must be inside an object (a <shape>, <bsdf>, ...), not directly in <scene>")
            self.set_prop(parent, node, node.attrs.get("name"), self.parse_property(node))
            return
        if tag in TRANSFORM_OPS:
            raise self.error(node, "transform operations must be inside a <transform name=\"to_world\">")
        if tag in UNSUPPORTED_TAGS or tag == "spectrum":
            raise self.error(node, f"<{tag}> is not supported by invrender's Mitsuba subset")
        if tag == "scene":
            raise self.error(node, "<scene> must be the root element")
        raise self.error(node, f"unknown element <{tag}> (supported: {', '.join((*OBJECT_TAGS, *PROPERTY_TAGS, 'default'))})")

    def set_prop(self, parent: Obj, node: Node, name, value) -> None:
        if name is None:
            raise self.error(node, "missing attribute 'name'")
        if name in parent.props:
            raise self.error(node, f"property {name!r} given twice (first at line {parent.props[name].node.line})", parent if parent.tag != "scene" else None)
        parent.props[name] = Prop(node, value)

    def no_children(self, node: Node) -> None:
        if node.children:
            raise self.error(node.children[0], f"unexpected element inside {node.describe()}")

    def parse_object(self, node: Node) -> Obj:
        self.check_attrs(node, {"type", "id", "name"}, required={"type"})
        self.count += 1
        obj = Obj(node, node.attrs["type"], self.count)
        if obj.id is not None:
            if obj.id in self.ids:
                raise self.error(node, f"duplicate id {obj.id!r} (first used at line {self.ids[obj.id].node.line})", obj)
            self.ids[obj.id] = obj
        for child in node.children:
            self.add_child(obj, child)
        return obj

    def parse_property(self, node: Node):
        tag, attrs = node.tag, node.attrs
        if tag == "transform":
            self.check_attrs(node, {"name"}, required={"name"})
            return self.parse_transform(node)
        self.no_children(node)
        if tag in ("point", "vector"):
            self.check_attrs(node, {"name", "value", "x", "y", "z"}, required={"name"})
            return tuple(self.xyz(node, 0.0))
        if tag == "spectrum" and "filename" in attrs:
            raise self.error(node, "spectra from files are not supported (give one constant value, or use <rgb>)")
        self.check_attrs(node, {"name", "value"}, required={"name", "value"})
        value = attrs["value"]
        if tag == "float":
            return self.number(node, value)
        if tag == "integer":
            try:
                return int(value.strip())
            except ValueError:
                raise self.error(node, f"could not parse integer value {value!r}") from None
        if tag == "boolean":
            if value.strip().lower() not in ("true", "false"):
                raise self.error(node, f"could not parse boolean value {value!r} (must be true or false)")
            return value.strip().lower() == "true"
        if tag == "string":
            return value
        if tag == "rgb":
            rgb = self.numbers(node, value)
            if len(rgb) not in (1, 3):
                raise self.error(node, f"<rgb> needs one or three values, got {value!r}")
            return tuple(rgb * 3 if len(rgb) == 1 else rgb)
        # <spectrum value=...>
        tokens = _tokens(value)
        if len(tokens) != 1 or ":" in value:
            raise self.error(node, f"only a constant spectrum (one value) is supported, got {value!r} (use <rgb> for colours)")
        return self.number(node, tokens[0])

    def number(self, node: Node, text: str) -> float:
        try:
            v = float(text.strip())
        except ValueError:
            raise self.error(node, f"could not parse a number from {text!r}") from None
        if not math.isfinite(v):
            raise self.error(node, f"values must be finite, got {text!r}")
        return v

    def numbers(self, node: Node, text: str) -> list[float]:
        return [self.number(node, t) for t in _tokens(text)]

    def xyz(self, node: Node, default: float) -> list[float]:
        """Mitsuba's ``value="x y z"`` (or one value for all three) or ``x``/``y``/``z`` attributes."""
        attrs = node.attrs
        if "value" in attrs:
            if any(k in attrs for k in "xyz"):
                raise self.error(node, "give either 'value' or 'x'/'y'/'z', not both")
            values = self.numbers(node, attrs["value"])
            if len(values) not in (1, 3):
                raise self.error(node, f"'value' must have one or three numbers, got {attrs['value']!r}")
            return values * 3 if len(values) == 1 else values
        return [self.number(node, attrs[k]) if k in attrs else default for k in "xyz"]

    def vector3(self, node: Node, key: str) -> np.ndarray:
        values = self.numbers(node, node.attrs[key])
        if len(values) != 3:
            raise self.error(node, f"{key!r} must have three numbers, got {node.attrs[key]!r}")
        return np.asarray(values, dtype=np.float64)

    def parse_transform(self, node: Node) -> np.ndarray:
        matrix = np.eye(4)
        for op in node.children:
            self.substitute(op)
            if op.tag not in TRANSFORM_OPS:
                raise self.error(op, f"a <transform> holds only {', '.join(TRANSFORM_OPS)}")
            self.no_children(op)
            try:
                matrix = self.transform_op(op) @ matrix
            except SceneError as e:
                if str(e).startswith(self.where + ":"):
                    raise
                raise self.error(op, str(e)) from None
        return matrix

    def transform_op(self, op: Node) -> np.ndarray:
        tag = op.tag
        if tag == "translate":
            self.check_attrs(op, {"value", "x", "y", "z"})
            return translate(self.xyz(op, 0.0))
        if tag == "scale":
            self.check_attrs(op, {"value", "x", "y", "z"})
            return scale(self.xyz(op, 1.0))
        if tag == "rotate":
            self.check_attrs(op, {"value", "x", "y", "z", "angle"}, required={"angle"})
            axis = np.asarray(self.xyz(op, 0.0))
            if not np.any(axis):
                raise self.error(op, "the rotation axis is zero (give x, y, z or value)")
            angle = self.number(op, op.attrs["angle"])
            if abs(np.linalg.norm(axis) - 1.0) < 1e-6:
                return rotate(axis, angle)
            # Mitsuba 3 does not normalize the axis: its matrix then also scales and shears
            warnings.warn(f"{self.where}:{op.line}: {op.describe()}: the rotation axis {axis.tolist()} is not a unit vector; "
                          "like Mitsuba 3, invrender does not normalize it, so this rotation also scales and shears", stacklevel=2)
            return _mitsuba_rotate(axis, angle)
        if tag == "matrix":
            self.check_attrs(op, {"value"}, required={"value"})
            values = self.numbers(op, op.attrs["value"])
            m = np.eye(4)
            if len(values) == 16:
                m = np.asarray(values, dtype=np.float64).reshape(4, 4)
            elif len(values) == 9:
                m[:3, :3] = np.asarray(values, dtype=np.float64).reshape(3, 3)
            else:
                raise self.error(op, f"a matrix needs 16 numbers (row-major) or 9, got {len(values)}")
            if not np.allclose(m[3], [0, 0, 0, 1]):
                raise self.error(op, f"the matrix's last row must be 0 0 0 1 (projective transforms are not supported), got {m[3].tolist()}")
            if abs(np.linalg.det(m[:3, :3])) < 1e-12:
                raise self.error(op, "the matrix is singular")
            return m
        # lookat (Mitsuba's Transform4f::look_at)
        self.check_attrs(op, {"origin", "target", "up"}, required={"origin", "target"})
        origin, target = self.vector3(op, "origin"), self.vector3(op, "target")
        up = self.vector3(op, "up") if "up" in op.attrs else np.zeros(3)
        d = target - origin
        if np.linalg.norm(d) == 0:
            raise self.error(op, "origin and target coincide")
        d = d / np.linalg.norm(d)
        if not np.any(up):
            up = _coordinate_system(d)
        left = np.cross(up, d)
        if np.linalg.norm(left) < 1e-9 * np.linalg.norm(up):
            raise self.error(op, "up is parallel to the view direction")
        left = left / np.linalg.norm(left)
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, np.cross(d, left), d, origin
        return m

    # ---- reading properties of an object

    def resolve(self, item):
        """The object an item stands for (following a ``<ref>``)."""
        if isinstance(item, Ref):
            if item.id not in self.ids:
                known = ", ".join(sorted(self.ids)) or "none"
                raise self.error(item.node, f"reference to unknown id {item.id!r} (ids in this file: {known})")
            return self.ids[item.id]
        return item

    def take(self, obj: Obj, name: str, tags: tuple, what: str):
        """The property ``name`` of ``obj`` (its :class:`Prop`), None when absent; an error when its
        element is not one of ``tags``."""
        prop = obj.props.get(name)
        if prop is None:
            return None
        obj.used.add(name)
        if prop.tag not in tags:
            raise self.error(prop.node, f"'{name}' must be {what}, got <{prop.tag}>", obj)
        return prop

    def get(self, obj: Obj, name: str, tag: str, default=None):
        what = {"float": "a <float>", "integer": "an <integer>", "boolean": "a <boolean>", "string": "a <string>", "point": "a <point>"}[tag]
        tags = ("point", "vector") if tag == "point" else ("float", "integer") if tag == "float" else (tag,)
        prop = self.take(obj, name, tags, what)
        return default if prop is None else (float(prop.value) if tag == "float" else prop.value)

    def finish(self, obj: Obj, supported: tuple, children: tuple = ()) -> None:
        """Errors for properties of ``obj`` nothing read, and for nested objects it cannot hold."""
        for tag in children:
            self.nested(obj, tag)  # marks named ones (<ref name="bsdf" id=.../>) as read
        for name, prop in obj.props.items():
            if name not in obj.used:
                listed = ", ".join(supported) or "none"
                raise self.error(prop.node, f"unsupported property {name!r} (supported: {listed})", obj)
        for child in obj.children:
            target = self.resolve(child)
            if target.tag not in children:
                node = child.node
                allowed = f"it may hold {', '.join(f'<{c}>' for c in children)}" if children else "it holds no nested objects"
                raise self.error(node, f"unexpected {target.describe()} inside {obj.describe()} ({allowed})")

    def nested_items(self, obj: Obj, tag: str) -> list:
        """The nested objects (or references) of ``obj`` that are ``<tag>`` objects, in document
        order: unnamed ones, and named ones (Mitsuba ignores their names, e.g. ``<ref name="bsdf"
        id=.../>``), which count as read."""
        items = [c for c in obj.children if self.resolve(c).tag == tag]
        for name, prop in obj.props.items():
            if isinstance(prop.value, (Obj, Ref)) and self.resolve(prop.value).tag == tag:
                obj.used.add(name)
                items.append(prop.value)
        return sorted(items, key=lambda c: c.node.line)

    def nested(self, obj: Obj, tag: str) -> list[Obj]:
        return [self.resolve(c) for c in self.nested_items(obj, tag)]

    def one_nested(self, obj: Obj, tag: str) -> Obj | None:
        items = self.nested_items(obj, tag)
        if len(items) > 1:
            raise self.error(items[1].node, f"only one <{tag}> per {obj.describe()} is supported", obj)
        return self.resolve(items[0]) if items else None


# ---------------------------------------------------------------- helpers


def _tokens(text: str) -> list[str]:
    return [t for t in _SPLIT.split(text.strip()) if t]


def _show(text: str) -> str:
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _mitsuba_rotate(axis: np.ndarray, degrees: float) -> np.ndarray:
    """Mitsuba 3's ``Transform4f::rotate(axis, angle)``, which does not normalize ``axis``:
    ``cos I + (1 - cos) a a^T + sin [a]x`` (a rotation only for a unit axis)."""
    x, y, z = axis
    t = math.radians(degrees)
    c, s = math.cos(t), math.sin(t)
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]]) + (1 - c) * np.outer(axis, axis)
    return m


def _coordinate_system(n: np.ndarray) -> np.ndarray:
    """The first tangent of Mitsuba's ``coordinate_system(n)`` (Duff et al. 2017), its lookat's
    default up."""
    sign = 1.0 if n[2] >= 0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])
