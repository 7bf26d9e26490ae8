"""Mitsuba 3's XML scene format as a tree of objects and properties, knowing no particular plugin.

:class:`Document` reads a file with the standard library's expat parser into :class:`Obj` objects
(``<shape>``, ``<bsdf>``, ... of some ``type``) holding named :class:`Prop` properties (numbers,
strings, points, colours, 4x4 transforms, nested objects, references) and unnamed nested objects,
each with the line it came from. What a plugin type means is the mapping's business
(:mod:`invrender.scene.formats.mitsuba`); this module gives it the typed readers
(:meth:`Document.get`, :meth:`~Document.take`, :meth:`~Document.nested`, ...) and the check that
nothing was left unread (:meth:`~Document.finish`). Every error is a one-line
:class:`~invrender.errors.SceneError` naming the file, the line and the element
(:meth:`Document.error`); malformed XML is reported with the line expat stopped at. A problem in
one element is noted (:meth:`Document.problem`) and reading goes on; the element holding it is
marked broken and left out, and :meth:`Document.check_problems` raises them together: one as it
is, several as one error listing the first five in document order and counting the rest.

File structure
    ``<scene version="x.y.z">`` root (at most 3.x; Mitsuba 0.x files are upgraded as Mitsuba 3
    does, :func:`upgrade_tree`). ``<default name="x" value="..."/>`` declares a parameter and ``$x`` in any
    attribute value is replaced by it (as Mitsuba does: in document order, longer names first; a
    ``$`` left over is an error); values passed to :func:`~invrender.scene.formats.mitsuba.load_mitsuba_xml` as ``parameters``
    override the defaults (Mitsuba's ``-D x=...``). Objects may carry an ``id`` (unique in the
    file) and be referenced with ``<ref id="..."/>`` (before or after their definition): BSDFs,
    textures and area emitters defined at the top level and used by shapes. ``<path
    value="folder"/>`` (a child of ``<scene>``, relative to its file) adds a folder searched first
    for files (:meth:`Document.find_file`). ``<include filename="part.xml"/>`` reads another file's
    ``<scene>`` children as if they stood there (relative to the including file; its defaults join
    the others; a cycle or a missing file is an error at the include's line; errors inside it name
    that file). Comments are ignored; text content, ``<alias>`` and unknown elements or attributes
    are errors, and so is any property a plugin does not list (:meth:`Document.finish`; Mitsuba
    also rejects unused properties).

Property elements
    ``<float>``, ``<integer>``, ``<boolean>`` (true/false), ``<string>``, ``<point>``/``<vector>``
    (``value="x y z"`` or ``x``/``y``/``z`` attributes), ``<rgb value="r, g, b"/>`` (one or three
    numbers), ``<spectrum value="v"/>`` (a constant: read as grey ``v, v, v``), ``<spectrum
    value="400:0.1, 500:0.3"/>`` or ``<spectrum filename="x.spd"/>`` (a linear sRGB triple as
    Mitsuba's RGB variants compute it: :meth:`Document.parse_spectrum`, :mod:`.spectra`),
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
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

import numpy as np

from invrender.errors import SceneError
from invrender.scene.formats.mitsuba import spectra
from invrender.scene.shapes import rotate, scale, translate

OBJECT_TAGS = ("shape", "bsdf", "emitter", "sensor", "film", "rfilter", "sampler", "integrator", "texture")
PROPERTY_TAGS = ("float", "integer", "boolean", "string", "point", "vector", "rgb", "spectrum", "transform", "ref")
TRANSFORM_OPS = ("translate", "rotate", "scale", "matrix", "lookat")
#: the file-structure elements read (parameters, search paths, included files)
STRUCTURE_TAGS = ("default", "path", "include")
#: Mitsuba elements outside the subset (a clearer message than "unknown element")
UNSUPPORTED_TAGS = ("alias", "medium", "phase", "volume", "shapegroup")
#: the newest major version of the format read (Mitsuba 3's; 0.x files are upgraded)
NEWEST_MAJOR = 3
#: property names whose spectra are unbounded outside emitters (Mitsuba's is_unbounded_spectrum)
UNBOUNDED_SPECTRA = ("eta", "k", "int_ior", "ext_ior")

#: problems listed in the error of a scene that has several
SHOWN_PROBLEMS = 5

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
    #: the file the element is in (an included file's own)
    where: str = ""

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
    #: something inside it could not be read (reported in :attr:`Document.problems`): not converted
    broken: bool = False

    @property
    def tag(self) -> str:
        return self.node.tag

    @property
    def id(self) -> str | None:
        return self.node.attrs.get("id")

    def describe(self) -> str:
        return f'<{self.tag} type="{self.type}">'


class Reported(SceneError):
    """An error standing for problems already noted (:meth:`Document.problem`): it stops the
    conversion of the object it is raised for, and is not listed itself."""


class _Expat:
    """The element tree of one file, with the line of each element (expat)."""

    def __init__(self, where: str):
        self.where = where

    def parse(self, data: bytes) -> Node:
        parser = expat.ParserCreate()
        stack: list[Node] = []
        roots: list[Node] = []

        def start(tag, attrs):
            node = Node(tag, dict(attrs), parser.CurrentLineNumber, where=self.where)
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
        #: folders ``<path>`` added, newest first (searched before the scene's folder)
        self.paths: list[Path] = []
        #: the files being read, outermost first (an ``<include>`` of one of them is a cycle)
        self.reading: list[Path] = [path.resolve()]
        #: the problems found so far (:meth:`problem`), raised together by :meth:`check_problems`
        self.problems: list[SceneError] = []
        #: the ids some ``<ref>`` names
        self.referenced: set[str] = set()
        #: every file read, in the order met (the main one first)
        self.files: list[str] = [self.where]
        self.scene = self.read()

    # ---- errors

    def error(self, node: Node, message: str, obj: Obj | None = None) -> SceneError:
        """A one-line error at ``node``'s line (in the file it is in), naming ``obj`` (or the node)."""
        what = obj.describe() if obj is not None else node.describe()
        return SceneError(f"{node.where or self.where}:{node.line}: {what}: {message}")

    def problem(self, error: SceneError) -> None:
        """Note a problem and go on (the same message once; a :class:`Reported` is not one)."""
        if not isinstance(error, Reported) and all(str(e) != str(error) for e in self.problems):
            self.problems.append(error)

    def check_broken(self, obj: Obj) -> None:
        """Stop converting ``obj`` when something inside it could not be read (already noted)."""
        if obj.broken:
            raise Reported(f"{obj.describe()} at line {obj.node.line} has problems already noted")

    def check_problems(self) -> None:
        """Raise the problems noted: one as it is, several as one error listing the first
        :data:`SHOWN_PROBLEMS` in document order (each naming its file relative to the scene's
        folder, and its line; abbreviated past 240 characters) and counting the rest."""
        if len(self.problems) == 1:
            raise self.problems[0]
        if self.problems:
            problems = sorted(self.problems, key=self._place)  # in document order
            folder = str(self.path.parent) + os.sep  # each entry names its file relative to the scene's folder
            shown = "; ".join(f"({i}) {_abbreviate(str(e).removeprefix(folder))}" for i, e in enumerate(problems[:SHOWN_PROBLEMS], 1))
            more = len(self.problems) - SHOWN_PROBLEMS
            rest = f"; ... and {more} more" if more > 0 else ""
            raise SceneError(f"{self.where}: {len(self.problems)} problems stop this scene from loading: {shown}{rest}")

    def _place(self, error: SceneError) -> tuple:
        """(the file's rank, the line) a problem's message starts with (files in the order met)."""
        m = re.match(r"(.*?):(\d+): ", str(error))
        if m is None:
            return (len(self.files), 0)
        return (self.files.index(m.group(1)) if m.group(1) in self.files else len(self.files), int(m.group(2)))

    def find_file(self, node: Node, name: str) -> Path | None:
        """A file a property names, as Mitsuba's file resolver finds it: absolute, or in the
        ``<path>`` folders (newest first), then the scene file's folder, then (invrender's
        fallback) the folder of the file the element is in; None when in none of them."""
        path = Path(name)
        if path.is_absolute():
            return path if path.exists() else None
        for folder in (*self.paths, self.path.parent, Path(node.where or self.where).parent):
            if (folder / path).exists():
                return folder / path
        return None

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
        self.add_children(scene, root.children)
        return scene

    def add_children(self, parent: Obj, nodes: list) -> None:
        """Parse ``nodes`` into ``parent``, noting each child's problem (:meth:`problem`) and
        going on; a problem marks ``parent`` broken."""
        for child in nodes:
            try:
                self.add_child(parent, child)
            except SceneError as e:
                self.problem(e)
                parent.broken = True

    def check_version(self, node: Node) -> None:
        """Check a root's ``version`` (three numbers, at most :data:`NEWEST_MAJOR`.x) and upgrade a
        Mitsuba 0.x tree in place as Mitsuba 3 does (:func:`upgrade_tree`)."""
        text = node.attrs["version"]
        parts = text.split(".")
        if len(parts) != 3 or not all(p.strip().isdigit() for p in parts):
            raise self.error(node, f"version must be three numbers like 3.0.0, got {_show(text)}")
        major = int(parts[0])
        if major > NEWEST_MAJOR:
            raise self.error(node, f"version {text} is newer than the format invrender reads (Mitsuba {NEWEST_MAJOR}: versions up to {NEWEST_MAJOR}.x; 0.x files are upgraded)")
        if major < 2:
            upgrade_tree(node, self.number)

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
        if tag == "path":
            self.add_path(parent, node)
            return
        if tag == "include":
            self.include(parent, node)
            return
        if tag in OBJECT_TAGS or (tag == "spectrum" and "type" in node.attrs):
            obj = self.parse_object(node)
            parent.broken |= obj.broken
            name = node.attrs.get("name")
            if name is None or parent.tag == "scene":  # the scene's objects are its children, named or not (Mitsuba-Blender names them)
                parent.children.append(obj)
            else:
                self.set_prop(parent, node, name, obj)
            return
        if tag == "ref":
            self.check_attrs(node, {"id", "name"}, required={"id"})
            self.no_children(node)
            ref = Ref(node.attrs["id"], node)
            self.referenced.add(ref.id)
            if "name" in node.attrs:
                self.set_prop(parent, node, node.attrs["name"], ref)
            else:
                parent.children.append(ref)
            return
        if tag in PROPERTY_TAGS:
            if parent.tag == "scene":
                raise self.error(node, "properties must be inside an object (a <shape>, <bsdf>, ...), not directly in <scene>")
            self.set_prop(parent, node, node.attrs.get("name"), self.parse_property(node, parent))
            return
        if tag in TRANSFORM_OPS:
            raise self.error(node, "transform operations must be inside a <transform name=\"to_world\">")
        if tag in UNSUPPORTED_TAGS or tag == "spectrum":
            raise self.error(node, f"<{tag}> is not supported by invrender's Mitsuba subset")
        if tag == "scene":
            raise self.error(node, "<scene> must be the root element")
        raise self.error(node, f"unknown element <{tag}> (supported: {', '.join((*OBJECT_TAGS, *PROPERTY_TAGS, *STRUCTURE_TAGS))})")

    def add_path(self, parent: Obj, node: Node) -> None:
        """``<path value="folder"/>`` (a child of ``<scene>``): a folder searched for files first
        (relative to the file it is in, else to the folders already searched)."""
        self.check_attrs(node, {"value"}, required={"value"})
        self.no_children(node)
        if parent.tag != "scene":
            raise self.error(node, "<path> must be a child of <scene>")
        value = node.attrs["value"]
        folder = Path(value)
        if not folder.is_absolute():
            here = Path(node.where or self.where).parent / folder
            folder = here if here.is_dir() else next((f / folder for f in (*self.paths, self.path.parent) if (f / folder).is_dir()), here)
        if not folder.is_dir():
            raise self.error(node, f"folder not found: {_show(value)} (looked for {folder})")
        self.paths.insert(0, folder)

    def include(self, parent: Obj, node: Node) -> None:
        """``<include filename="part.xml"/>``: the children of the file's ``<scene>`` (or its root
        object) read as if they stood here; the file is found relative to the including file,
        then as any file (:meth:`find_file`); its ``<default>`` parameters join the others (the
        first definition of a name wins, as in Mitsuba)."""
        self.check_attrs(node, {"filename"}, required={"filename"})
        self.no_children(node)
        name = node.attrs["filename"]
        here = Path(node.where or self.where).parent / name
        path = here if here.is_file() else self.find_file(node, name)
        if path is None or not path.is_file():
            raise self.error(node, f"included file not found: {_show(name)} (looked for {here})")
        key = path.resolve()
        if key in self.reading:
            chain = " -> ".join(p.name for p in (*self.reading[self.reading.index(key):], key))
            raise self.error(node, f"<include> cycle: {chain}")
        try:
            data = path.read_bytes()
        except OSError as e:
            raise self.error(node, f"cannot read included file {path}: {e.strerror or e}") from None
        root = _Expat(str(path)).parse(data)
        self.substitute(root)
        if str(path) not in self.files:
            self.files.append(str(path))
        self.reading.append(key)
        try:
            if root.tag == "scene":
                self.check_attrs(root, {"version"})
                if "version" in root.attrs:
                    self.check_version(root)
                self.add_children(parent, root.children)
            else:
                self.add_children(parent, [root])
        finally:
            self.reading.pop()

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
                first = self.ids[obj.id].node
                place = f"line {first.line}" if first.where == node.where else f"{first.where}:{first.line}"
                raise self.error(node, f"duplicate id {obj.id!r} (first used at {place})", obj)
            self.ids[obj.id] = obj
        self.add_children(obj, node.children)
        return obj

    def parse_property(self, node: Node, parent: Obj | None = None):
        tag, attrs = node.tag, node.attrs
        if tag == "transform":
            self.check_attrs(node, {"name"}, required={"name"})
            return self.parse_transform(node)
        self.no_children(node)
        if tag in ("point", "vector"):
            self.check_attrs(node, {"name", "value", "x", "y", "z"}, required={"name"})
            return tuple(self.xyz(node, 0.0))
        if tag == "spectrum":
            return self.parse_spectrum(node, parent)
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
        raise self.error(node, f"unhandled property element <{tag}>")  # pragma: no cover (PROPERTY_TAGS are all handled)

    def parse_spectrum(self, node: Node, parent: Obj | None):
        """A ``<spectrum>``: one constant ``value`` (a float, read as grey), or ``wavelength:value``
        pairs or a ``filename`` (.spd) converted to a linear sRGB triple as Mitsuba's RGB variants
        do (:mod:`.spectra`): inside an ``<emitter>`` unbounded and without the D65 weighting,
        else with it, bounded to [0, 1] except for ``eta``, ``k``, ``int_ior``, ``ext_ior``."""
        self.check_attrs(node, {"name", "value", "filename"}, required={"name"})
        attrs = node.attrs
        if ("value" in attrs) == ("filename" in attrs):
            raise self.error(node, "a <spectrum> needs either 'value' or 'filename'")
        try:
            if "filename" in attrs:
                path = self.find_file(node, attrs["filename"])
                if path is None or not path.is_file():
                    raise self.error(node, f"spectrum file not found: {_show(attrs['filename'])}")
                wavelengths, values = spectra.read_spd(path)
            else:
                tokens = _tokens(attrs["value"])
                if len(tokens) == 1 and ":" not in tokens[0]:
                    return self.number(node, tokens[0])
                wavelengths, values = spectra.parse_pairs(attrs["value"])
        except spectra.SpectrumError as e:
            raise self.error(node, f"malformed spectrum: {e}") from None
        emitter = parent is not None and parent.tag == "emitter"
        bounded = not emitter and attrs["name"] not in UNBOUNDED_SPECTRA
        return tuple(float(x) for x in spectra.spectrum_to_srgb(wavelengths, values, bounded=bounded, d65=not emitter))

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
        found = []
        for name, prop in obj.props.items():
            if name not in obj.used:
                listed = ", ".join(supported) or "none"
                found.append(self.error(prop.node, f"unsupported property {name!r} (supported: {listed})", obj))
        for child in obj.children:
            target = self.resolve(child)
            if target.tag not in children:
                node = child.node
                allowed = f"it may hold {', '.join(f'<{c}>' for c in children)}" if children else "it holds no nested objects"
                found.append(self.error(node, f"unexpected {target.describe()} inside {obj.describe()} ({allowed})"))
        if len(found) == 1:
            raise found[0]
        if found:  # every one listed, the object left out
            for e in found:
                self.problem(e)
            raise Reported(f"{obj.describe()}: {len(found)} problems noted")

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


def _abbreviate(message: str, limit: int = 240) -> str:
    return message if len(message) <= limit else message[: limit - 3] + "..."


def snake_case(name: str) -> str:
    """Mitsuba 3's upgrade of a 0.x property name: ``camelCase`` -> ``camel_case`` (a run of
    capitals after a lower-case letter becomes one lower-case word: ``intIOR`` -> ``int_ior``)."""
    i = 0
    while i < len(name) - 1:
        if name[i].islower() and name[i + 1].isupper():
            name = name[: i + 1] + "_" + name[i + 1 :]
            i += 2
            while i < len(name) and name[i].isupper():
                name = name[:i] + name[i].lower() + name[i + 1 :]
                i += 1
        else:
            i += 1
    return name


def upgrade_tree(root: Node, number) -> None:
    """Upgrade a Mitsuba 0.x element tree in place, as Mitsuba 3's ``upgrade_tree`` does: every
    ``name`` (except a ``<default>``'s) to snake_case, ``<lookAt>`` to ``<lookat>``, ids starting
    with ``_`` to ``ID_...__UPGR``, a diffuse BSDF's ``diffuse_reflectance`` to ``reflectance``,
    and ``uoffset``/``voffset``/``uscale``/``vscale`` floats to a ``to_uv`` transform, their values
    read by ``number(node, text)`` (the parser's: a one-line error for what is not a finite number)."""
    nodes, stack = [], [root]
    while stack:
        node = stack.pop()
        nodes.append(node)
        stack.extend(reversed(node.children))
    for node in nodes:
        if "name" in node.attrs and node.tag != "default":
            node.attrs["name"] = snake_case(node.attrs["name"])
        if node.tag == "lookAt":
            node.tag = "lookat"
        if node.attrs.get("id", "").startswith("_"):
            node.attrs["id"] = "ID" + node.attrs["id"] + "__UPGR"
    for node in nodes:
        if node.tag == "bsdf" and node.attrs.get("type") == "diffuse":
            for child in node.children:
                if child.attrs.get("name") == "diffuse_reflectance":
                    child.attrs["name"] = "reflectance"
        keys = ("uoffset", "voffset", "uscale", "vscale")
        found = {c.attrs["name"]: c for c in node.children if c.tag == "float" and c.attrs.get("name") in keys}
        if found:
            node.children = [c for c in node.children if not any(c is f for f in found.values())]
            get = {k: number(found[k], found[k].attrs.get("value", "0")) for k in found}  # a one-line error for text
            ops = []
            if get.get("uoffset", 0.0) or get.get("voffset", 0.0):
                ops.append(Node("translate", {"x": repr(get.get("uoffset", 0.0)), "y": repr(get.get("voffset", 0.0))}, node.line, where=node.where))
            if get.get("uscale", 1.0) != 1.0 or get.get("vscale", 1.0) != 1.0:
                ops.append(Node("scale", {"x": repr(get.get("uscale", 1.0)), "y": repr(get.get("vscale", 1.0))}, node.line, where=node.where))
            node.children.append(Node("transform", {"name": "to_uv"}, node.line, ops, where=node.where))


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
