"""Mitsuba 3 XML scene files: a documented subset of Mitsuba's scene format, read into invrender's
own scene objects (``load_scene("scene.xml")``, ``invrender render scene.xml``).

Anything outside the subset below is a :class:`~invrender.errors.SceneError` whose one-line message
names the file, the line, the element (tag and type) and what is supported, e.g.
``scene.xml:12: <emitter type="point">: unsupported emitter type 'point' (supported: area)``.
Out-of-range values (a reflectance of 1.5, a roughness of 0, a negative index of refraction) are
SceneErrors naming the line and the value too. The file is parsed with the standard library's
expat parser; malformed XML is reported with the line expat stopped at.

The subset
----------

File structure
    ``<scene version="x.y.z">`` root (version 2.0.0 or later; Mitsuba 0.x files with camelCase names
    are not upgraded). ``<default name="x" value="..."/>`` declares a parameter and ``$x`` in any
    attribute value is replaced by it (as Mitsuba does: in document order, longer names first; a
    ``$`` left over is an error); values passed to :func:`load_mitsuba_xml` as ``parameters``
    override the defaults (Mitsuba's ``-D x=...``). Objects may carry an ``id`` (unique in the
    file) and be referenced with ``<ref id="..."/>`` (before or after their definition): BSDFs
    defined at the top level and used by shapes, and bitmap textures. Comments are ignored; text
    content, ``<include>``, ``<alias>``, ``<path>`` and unknown elements or attributes are errors,
    and so is any property a plugin below does not list (Mitsuba also rejects unused properties).

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

Shapes (``<shape type=...>``)
    ``rectangle`` ([-1, 1]^2 at z = 0 facing +z), ``cube`` ([-1, 1]^3 facing outwards), ``sphere``
    (``center`` point, default 0 0 0; ``radius`` float > 0, default 1: Mitsuba's analytic sphere
    becomes an icosphere of 20 * 4^5 = 20480 triangles (``sphere_subdivisions``, default 5) shaded
    with its exact normals), ``obj`` and ``ply`` (``filename`` relative to the XML file, read with
    trimesh, every part merged; vertex normals are the file's when it has them, else computed as
    Mitsuba computes them (angle-weighted, from the world-space triangles), and
    ``face_normals=true`` drops them for flat shading;
    ``flip_tex_coords``, default true for obj and false for ply as in Mitsuba). Every shape takes
    ``to_world`` and ``flip_normals``; one BSDF (an inline ``<bsdf>`` or a ``<ref>``), else
    Mitsuba's default, diffuse with reflectance 0.5; and optionally ``<emitter type="area">`` with
    ``radiance`` (rgb, spectrum, float or a bitmap texture; default 1), emitted from the front side.

BSDFs (``<bsdf type=...>``), mapped to invrender's materials (:mod:`invrender.scene.materials`)
    - ``diffuse`` -> ``diffuse``: ``reflectance`` (rgb, float, constant spectrum, or
      ``<texture type="bitmap">``; default 0.5).
    - ``conductor`` -> ``mirror`` and ``roughconductor`` -> ``glossy`` (GGX): only Fresnel 1,
      i.e. ``<string name="material" value="none"/>``, which is Mitsuba 3's default when
      ``material`` is absent; any other material and ``eta``/``k`` are errors.
      ``specular_reflectance`` (rgb, float or constant spectrum; default 1). roughconductor:
      ``distribution`` must be given as ``ggx`` (Mitsuba's default is ``beckmann``, which invrender
      does not have), ``alpha`` a float in (0, 1] (default 0.1) is invrender's ``roughness``;
      ``alpha_u``/``alpha_v`` (anisotropy) are errors; ``sample_visible`` is accepted and ignored.
    - ``dielectric`` -> ``dielectric``: ``int_ior`` and ``ext_ior`` as positive numbers or
      Mitsuba's named media (:data:`NAMED_IOR`; defaults ``bk7`` and ``air``). invrender's
      dielectric has one relative index ``ior = int_ior / ext_ior`` (its exterior is 1.0), which
      is exactly what a smooth dielectric interface depends on.
    - ``twosided`` wrapping one BSDF (or two references to the same one): accepted, the material
      is the nested one (a dielectric cannot be nested).

Bitmap textures (``<texture type="bitmap">``)
    ``filename`` (relative to the XML file; EXR linear, PNG/JPEG sRGB-decoded, like Mitsuba's
    ``raw=false``; ``raw=true`` only for EXR), ``filter_type`` bilinear, ``wrap_mode`` repeat (the
    only ones invrender has, and Mitsuba's defaults). ``to_uv`` is an error. Texture coordinates
    follow Mitsuba's parametrizations (rectangle ``uv = ((x + 1) / 2, (y + 1) / 2)``, the sphere's
    ``(phi / 2 pi, theta / pi)`` about local z, the cube's per-face layout, OBJ/PLY as Mitsuba
    reads them) and Mitsuba's image convention (``v = 0`` is the image's top row), so an image
    lands where Mitsuba puts it; they are stored in invrender's convention (``v`` flipped).

Sensor (at most one ``<sensor>``)
    ``perspective`` and ``thinlens``: ``fov`` (degrees; required, ``focal_length`` is not
    supported), ``fov_axis`` (x, y, smaller, larger; default x; ``diagonal`` is an error),
    ``to_world`` (lookat or any rotation and translation, optionally a uniform scale; the camera
    looks along local +z with local +y up and the image's x axis along local -x, as in Mitsuba; a
    mirrored (det < 0), non-uniformly scaled or sheared to_world is an error), ``near_clip`` /
    ``far_clip`` (accepted, checked, ignored), ``focus_distance`` (thinlens; default ``far_clip``;
    > 0), ``aperture_radius`` (thinlens, required, >= 0). Inside the sensor: ``<film
    type="hdrfilm">`` with ``width``/``height`` (default 768 x 576 as Mitsuba; the ``resolution``
    argument overrides them; ``file_format``, ``pixel_format``, ``component_format``, ``banner``,
    ``compensate`` accepted and ignored) and an optional ``<rfilter>`` (invrender always uses a box
    filter: ``box`` is accepted silently, Mitsuba's other filters with a warning); ``<sampler>`` of
    any Mitsuba type with ``sample_count`` (the default spp; ``seed`` and ``jitter`` are ignored;
    invrender draws its own samples). A scene without a sensor is an error (Mitsuba 3 cannot
    render one either).

Integrator (at most one ``<integrator>``)
    ``path`` with ``max_depth`` (-1 or >= 1) and ``rr_depth`` (>= 1); ``hide_emitters`` only false.
    Other integrators are errors.

Render settings the file suggests go to ``scene.defaults`` (only those the file states):
``{"spp": sample_count, "integrator": "path", "max_depth": ..., "rr_depth": ...}``; ``invrender
render`` uses them when ``--spp`` / ``--max-depth`` / ``--rr-depth`` are not given (max_depth and
rr_depth only for ``--integrator path``). Mitsuba's own defaults when the file is silent (4 spp,
max_depth -1) are not assumed: invrender's (64 spp, max_depth 8) apply.

Names
    A material is named by its BSDF's ``id`` (for ``twosided``, the outer one's), else by its
    shape's id + ``_bsdf``, else ``material_N``; an emitter by its shape's ``id``, else
    ``emitter``, ``emitter_2``, ... Names are made unique (``_2``, ``_3``, ... suffixes) and never
    ``ambient``. Materials are ordered by where their BSDF appears in the file; BSDFs no shape uses
    are checked but left out of the scene.

Deviations from Mitsuba
    - invrender's diffuse, mirror and glossy materials are two-sided: one-sided Mitsuba materials
      (diffuse, conductor, roughconductor without ``twosided``) are rendered two-sided (Mitsuba
      renders their back side black).
    - Spheres are tessellated (see above); rectangles and cubes are exact.
    - Textures on spheres show a seam where ``u`` wraps around (the tessellation interpolates
      across it).
    - The film's reconstruction filter is always a box; sampling patterns are invrender's own.
    - Colours are linear RGB (RGB variants of Mitsuba); spectra other than constants are errors.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

import numpy as np

from invrender.errors import InvRenderError, SceneError
from invrender.scene.camera import Camera
from invrender.scene.kinds import EMISSION, REFLECTANCE, SPECULAR_REFLECTANCE, ParamKind
from invrender.scene.materials import Material
from invrender.scene.scene import Scene, build_scene
from invrender.scene.shapes import Mesh, primitive, rotate, scale, translate

#: icosphere subdivisions of a Mitsuba sphere: 20 * 4**5 = 20480 triangles
SPHERE_SUBDIVISIONS = 5

#: Mitsuba's default film size
DEFAULT_FILM = (768, 576)

#: Mitsuba 3's named indices of refraction (include/mitsuba/render/ior.h; Hecht, Optics, ~589 nm)
NAMED_IOR = {
    "vacuum": 1.0,
    "helium": 1.000036,
    "hydrogen": 1.000132,
    "air": 1.000277,
    "carbon dioxide": 1.00045,
    "water": 1.3330,
    "acetone": 1.36,
    "ethanol": 1.361,
    "carbon tetrachloride": 1.461,
    "glycerol": 1.4729,
    "benzene": 1.501,
    "silicone oil": 1.52045,
    "bromine": 1.661,
    "water ice": 1.31,
    "fused quartz": 1.458,
    "pyrex": 1.470,
    "acrylic glass": 1.49,
    "polypropylene": 1.49,
    "bk7": 1.5046,
    "sodium chloride": 1.544,
    "amber": 1.55,
    "pet": 1.5750,
    "diamond": 2.419,
}

SHAPE_TYPES = ("rectangle", "cube", "sphere", "obj", "ply")
BSDF_TYPES = ("diffuse", "conductor", "roughconductor", "dielectric", "twosided")
SENSOR_TYPES = ("perspective", "thinlens")
FOV_AXES = ("x", "y", "smaller", "larger")
RFILTER_TYPES = ("box", "tent", "gaussian", "mitchell", "catmullrom", "lanczos")
SAMPLER_TYPES = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")
OBJECT_TAGS = ("shape", "bsdf", "emitter", "sensor", "film", "rfilter", "sampler", "integrator", "texture")
PROPERTY_TAGS = ("float", "integer", "boolean", "string", "point", "vector", "rgb", "spectrum", "transform", "ref")
TRANSFORM_OPS = ("translate", "rotate", "scale", "matrix", "lookat")
#: Mitsuba elements outside the subset (a clearer message than "unknown element")
UNSUPPORTED_TAGS = ("include", "alias", "path", "medium", "phase", "volume", "shapegroup")

_PARAMETER = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)?")
_SPLIT = re.compile(r"[,\s]+")

# Mitsuba's cube (src/shapes/cube.cpp): positions, face normals and texture coordinates of its 24 vertices
_MITSUBA_CUBE = (
    [(1, -1, -1), (1, -1, 1), (-1, -1, 1), (-1, -1, -1), (1, 1, -1), (-1, 1, -1), (-1, 1, 1), (1, 1, 1),
     (1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1), (-1, -1, 1),
     (-1, -1, 1), (-1, 1, 1), (-1, 1, -1), (-1, -1, -1), (1, 1, -1), (1, -1, -1), (-1, -1, -1), (-1, 1, -1)],
    [(0, -1, 0)] * 4 + [(0, 1, 0)] * 4 + [(1, 0, 0)] * 4 + [(0, 0, 1)] * 4 + [(-1, 0, 0)] * 4 + [(0, 0, -1)] * 4,
    [(0, 1), (1, 1), (1, 0), (0, 0)] * 6,
)  # fmt: skip


# ---------------------------------------------------------------- the element tree


@dataclass
class _Node:
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
class _Ref:
    id: str
    node: _Node


@dataclass
class _Prop:
    """A named property of an object: its element, and its value (a number, string, tuple, 4x4
    matrix, nested :class:`_Obj` or :class:`_Ref`)."""

    node: _Node
    value: object

    @property
    def tag(self) -> str:
        return self.node.tag


@dataclass
class _Obj:
    """A plugin element (shape, bsdf, ...): its type, id, named properties and unnamed children."""

    node: _Node
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


class _Parser:
    """The element tree of one file, with the line of each element (expat)."""

    def __init__(self, where: str):
        self.where = where

    def parse(self, data: bytes) -> _Node:
        parser = expat.ParserCreate()
        stack: list[_Node] = []
        roots: list[_Node] = []

        def start(tag, attrs):
            node = _Node(tag, dict(attrs), parser.CurrentLineNumber)
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


# ---------------------------------------------------------------- loading


def load_mitsuba_xml(path, resolution=None, parameters: dict | None = None, sphere_subdivisions: int = SPHERE_SUBDIVISIONS) -> Scene:
    """A scene from a Mitsuba 3 XML file (the subset in this module's docstring).

    Args:
        path: the .xml file; file names inside it are relative to its folder.
        resolution: (width, height), overriding the film's; None = the film's (768 x 576 without one).
        parameters: values of ``$name`` parameters, overriding the file's ``<default>`` ones.
        sphere_subdivisions: icosphere subdivisions of ``sphere`` shapes (20 * 4^n triangles).
    Raises:
        SceneError: a missing, unreadable or malformed file, anything outside the subset, a value
            out of range; the message names the file and line.
    """
    return _Loader(Path(path), parameters, sphere_subdivisions).load(resolution)


class _Loader:
    def __init__(self, path: Path, parameters, sphere_subdivisions: int):
        self.path = path
        self.where = str(path)
        self.base = path.parent
        self.params = {str(k): str(v) for k, v in (parameters or {}).items()}
        self.subdivisions = sphere_subdivisions
        self.ids: dict[str, _Obj] = {}
        self.count = 0
        self.materials: dict[int, tuple[_Obj, Material, str | None]] = {}  # id(bsdf) -> (bsdf, material, owner shape id)
        self.textures: dict[int, np.ndarray] = {}  # id(texture) -> its linear RGB

    # ---- errors

    def error(self, node: _Node, message: str, obj: _Obj | None = None) -> SceneError:
        """A one-line error at ``node``'s line, naming ``obj`` (or the node itself)."""
        what = obj.describe() if obj is not None else node.describe()
        return SceneError(f"{self.where}:{node.line}: {what}: {message}")

    # ---- parsing

    def load(self, resolution) -> Scene:
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            raise SceneError(f"scene file not found: {self.path}") from None
        except OSError as e:
            raise SceneError(f"cannot read scene file {self.path}: {e.strerror or e}") from None
        root = _Parser(self.where).parse(data)
        self.substitute(root)
        if root.tag != "scene":
            raise self.error(root, "the root element must be <scene version=...>")
        self.check_attrs(root, {"version"}, required={"version"})
        self.check_version(root)
        scene = _Obj(root, "scene", 0)
        for child in root.children:
            self.add_child(scene, child)
        return self.build(scene, resolution)

    def check_version(self, node: _Node) -> None:
        text = node.attrs["version"]
        parts = text.split(".")
        if len(parts) != 3 or not all(p.strip().isdigit() for p in parts):
            raise self.error(node, f"version must be three numbers like 3.0.0, got {text!r}")
        if int(parts[0]) < 2:
            raise self.error(node, f"version {text} files (Mitsuba 0.x, camelCase names) are not supported (supported: 2.0.0 or later)")

    def substitute(self, node: _Node) -> None:
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

    def check_attrs(self, node: _Node, allowed: set, required: set = frozenset()) -> None:
        for key in node.attrs:
            if key not in allowed:
                raise self.error(node, f"unexpected attribute {key!r} (allowed: {', '.join(sorted(allowed))})")
        for key in sorted(required):
            if key not in node.attrs:
                raise self.error(node, f"missing attribute {key!r}")

    def add_child(self, parent: _Obj, node: _Node) -> None:
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
            ref = _Ref(node.attrs["id"], node)
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

    def set_prop(self, parent: _Obj, node: _Node, name, value) -> None:
        if name is None:
            raise self.error(node, "missing attribute 'name'")
        if name in parent.props:
            raise self.error(node, f"property {name!r} given twice (first at line {parent.props[name].node.line})", parent if parent.tag != "scene" else None)
        parent.props[name] = _Prop(node, value)

    def no_children(self, node: _Node) -> None:
        if node.children:
            raise self.error(node.children[0], f"unexpected element inside {node.describe()}")

    def parse_object(self, node: _Node) -> _Obj:
        self.check_attrs(node, {"type", "id", "name"}, required={"type"})
        self.count += 1
        obj = _Obj(node, node.attrs["type"], self.count)
        if obj.id is not None:
            if obj.id in self.ids:
                raise self.error(node, f"duplicate id {obj.id!r} (first used at line {self.ids[obj.id].node.line})", obj)
            self.ids[obj.id] = obj
        for child in node.children:
            self.add_child(obj, child)
        return obj

    def parse_property(self, node: _Node):
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

    def number(self, node: _Node, text: str) -> float:
        try:
            v = float(text.strip())
        except ValueError:
            raise self.error(node, f"could not parse a number from {text!r}") from None
        if not math.isfinite(v):
            raise self.error(node, f"values must be finite, got {text!r}")
        return v

    def numbers(self, node: _Node, text: str) -> list[float]:
        return [self.number(node, t) for t in _tokens(text)]

    def xyz(self, node: _Node, default: float) -> list[float]:
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

    def vector3(self, node: _Node, key: str) -> np.ndarray:
        values = self.numbers(node, node.attrs[key])
        if len(values) != 3:
            raise self.error(node, f"{key!r} must have three numbers, got {node.attrs[key]!r}")
        return np.asarray(values, dtype=np.float64)

    def parse_transform(self, node: _Node) -> np.ndarray:
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

    def transform_op(self, op: _Node) -> np.ndarray:
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
        if isinstance(item, _Ref):
            if item.id not in self.ids:
                known = ", ".join(sorted(self.ids)) or "none"
                raise self.error(item.node, f"reference to unknown id {item.id!r} (ids in this file: {known})")
            return self.ids[item.id]
        return item

    def take(self, obj: _Obj, name: str, tags: tuple, what: str):
        """The property ``name`` of ``obj`` (its :class:`_Prop`), None when absent; an error when its
        element is not one of ``tags``."""
        prop = obj.props.get(name)
        if prop is None:
            return None
        obj.used.add(name)
        if prop.tag not in tags:
            raise self.error(prop.node, f"'{name}' must be {what}, got <{prop.tag}>", obj)
        return prop

    def get(self, obj: _Obj, name: str, tag: str, default=None):
        what = {"float": "a <float>", "integer": "an <integer>", "boolean": "a <boolean>", "string": "a <string>", "point": "a <point>"}[tag]
        tags = ("point", "vector") if tag == "point" else ("float", "integer") if tag == "float" else (tag,)
        prop = self.take(obj, name, tags, what)
        return default if prop is None else (float(prop.value) if tag == "float" else prop.value)

    def finish(self, obj: _Obj, supported: tuple, children: tuple = ()) -> None:
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

    def nested_items(self, obj: _Obj, tag: str) -> list:
        """The nested objects (or references) of ``obj`` that are ``<tag>`` objects, in document
        order: unnamed ones, and named ones (Mitsuba ignores their names, e.g. ``<ref name="bsdf"
        id=.../>``), which count as read."""
        items = [c for c in obj.children if self.resolve(c).tag == tag]
        for name, prop in obj.props.items():
            if isinstance(prop.value, (_Obj, _Ref)) and self.resolve(prop.value).tag == tag:
                obj.used.add(name)
                items.append(prop.value)
        return sorted(items, key=lambda c: c.node.line)

    def nested(self, obj: _Obj, tag: str) -> list[_Obj]:
        return [self.resolve(c) for c in self.nested_items(obj, tag)]

    def one_nested(self, obj: _Obj, tag: str) -> _Obj | None:
        items = self.nested_items(obj, tag)
        if len(items) > 1:
            raise self.error(items[1].node, f"only one <{tag}> per {obj.describe()} is supported", obj)
        return self.resolve(items[0]) if items else None

    def colour(self, obj: _Obj, name: str, kind: ParamKind, default: float, texture: bool = True):
        """An RGB triple (3,) or a linear texture (h, w, 3) from a property of ``obj``, checked
        against ``kind``'s range."""
        prop = obj.props.get(name)
        if prop is None:
            return np.full(3, default)
        obj.used.add(name)
        value = self.resolve(prop.value) if isinstance(prop.value, (_Ref, _Obj)) else prop.value
        if isinstance(value, _Obj):
            if value.tag != "texture":
                raise self.error(prop.node, f"'{name}' must be a colour or a texture, got {value.describe()}", obj)
            if not texture or not kind.texture:
                raise self.error(prop.node, f"'{name}' must be a constant (<rgb>, <float> or <spectrum>): textures are not supported here", obj)
            rgb = self.bitmap(value)
        elif prop.tag in ("rgb", "spectrum", "float"):
            rgb = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()
        else:
            raise self.error(prop.node, f"'{name}' must be <rgb>, <float>, <spectrum> or a texture, got <{prop.tag}>", obj)
        lo, hi = float(np.min(rgb)), float(np.max(rgb))
        if lo < 0 or hi > kind.upper:
            expected = f"lie in [0, {kind.upper:g}]" if math.isfinite(kind.upper) else "be >= 0"
            shown = ", ".join(f"{v:g}" for v in rgb) if rgb.ndim == 1 else f"values in [{lo:.4g}, {hi:.4g}]"
            raise self.error(prop.node, f"'{name}' ({kind.doc.split(',')[0]}) must {expected}, got {shown}", obj)
        return rgb

    def bitmap(self, tex: _Obj) -> np.ndarray:
        if id(tex) not in self.textures:
            self.textures[id(tex)] = self.read_bitmap(tex)
        return self.textures[id(tex)]

    def read_bitmap(self, tex: _Obj) -> np.ndarray:
        if tex.type != "bitmap":
            raise self.error(tex.node, f"unsupported texture type {tex.type!r} (supported: bitmap)", tex)
        filename = self.get(tex, "filename", "string")
        if filename is None:
            raise self.error(tex.node, "missing <string name=\"filename\">", tex)
        for key, allowed in (("filter_type", "bilinear"), ("wrap_mode", "repeat")):
            value = self.get(tex, key, "string", allowed)
            if value != allowed:
                raise self.error(tex.props[key].node, f"{key} {value!r} is not supported (supported: {allowed})", tex)
        path = self.base / filename
        raw = self.get(tex, "raw", "boolean", False)
        if raw and path.suffix.lower() != ".exr":
            raise self.error(tex.props["raw"].node, "raw=true is supported for EXR files only (PNG/JPEG are always sRGB-decoded)", tex)
        self.finish(tex, ("filename", "filter_type", "wrap_mode", "raw"))
        from invrender.io.images import read_image  # lazily: images need kornia/OpenEXR

        try:
            return read_image(path).numpy().astype(np.float64)
        except InvRenderError as e:
            raise self.error(tex.props["filename"].node, _one_line(e), tex) from None

    # ---- BSDFs

    def material(self, bsdf: _Obj, owner: str | None) -> int:
        """The key of ``bsdf``'s material (converting it once; references share it)."""
        key = id(bsdf)
        if key not in self.materials:
            self.materials[key] = (bsdf, self.convert_bsdf(bsdf), owner)
        return key

    def convert_bsdf(self, bsdf: _Obj) -> Material:
        where = f"{self.where}:{bsdf.node.line}: {bsdf.describe()}"
        t = bsdf.type
        if t == "twosided":
            inner = self.nested(bsdf, "bsdf")
            if not inner or len(inner) > 2 or (len(inner) == 2 and inner[0] is not inner[1]):
                raise self.error(bsdf.node, "twosided must wrap one BSDF (two different sides are not supported: invrender's materials are two-sided)", bsdf)
            if inner[0].type in ("dielectric", "twosided"):
                raise self.error(inner[0].node, f"twosided cannot wrap a {inner[0].type} BSDF", bsdf)
            self.finish(bsdf, (), ("bsdf",))
            return self.convert_bsdf(inner[0])
        if t == "diffuse":
            rho = self.colour(bsdf, "reflectance", REFLECTANCE, 0.5)
            self.finish(bsdf, ("reflectance",))
            return Material.of("diffuse", where, reflectance=rho)
        if t in ("conductor", "roughconductor"):
            material = self.take(bsdf, "material", ("string",), "a <string>")
            if material is not None and material.value != "none":
                raise self.error(material.node, f"conductor material {material.value!r} is not supported: only 'none' (Fresnel 1, a perfect reflector) is", bsdf)
            for key in ("eta", "k"):
                if key in bsdf.props:
                    raise self.error(bsdf.props[key].node, f"'{key}' is not supported: only material 'none' (Fresnel 1) is", bsdf)
            ks = self.colour(bsdf, "specular_reflectance", SPECULAR_REFLECTANCE, 1.0, texture=False)
            if t == "conductor":
                self.finish(bsdf, ("material", "specular_reflectance"))
                return Material.of("mirror", where, specular_reflectance=ks)
            distribution = self.take(bsdf, "distribution", ("string",), "a <string>")
            if distribution is None:
                raise self.error(bsdf.node, "give <string name=\"distribution\" value=\"ggx\"/>: Mitsuba's default distribution is beckmann, and invrender has GGX only", bsdf)
            if distribution.value.lower() != "ggx":
                raise self.error(distribution.node, f"distribution {distribution.value!r} is not supported (supported: ggx)", bsdf)
            for key in ("alpha_u", "alpha_v"):
                if key in bsdf.props:
                    raise self.error(bsdf.props[key].node, f"'{key}' (anisotropic roughness) is not supported: give one 'alpha'", bsdf)
            alpha = self.take(bsdf, "alpha", ("float", "integer"), "a <float> (textured roughness is not supported)")
            value = 0.1 if alpha is None else float(alpha.value)
            if not 0.0 < value <= 1.0:
                raise self.error(alpha.node, f"'alpha' (GGX roughness) must lie in (0, 1], got {value:g}", bsdf)
            self.get(bsdf, "sample_visible", "boolean")
            self.finish(bsdf, ("material", "specular_reflectance", "distribution", "alpha", "sample_visible"))
            return Material.of("glossy", where, specular_reflectance=ks, roughness=value)
        if t == "dielectric":
            int_ior = self.ior(bsdf, "int_ior", "bk7")
            ext_ior = self.ior(bsdf, "ext_ior", "air")
            self.finish(bsdf, ("int_ior", "ext_ior"))
            return Material.of("dielectric", where, ior=int_ior / ext_ior)
        raise self.error(bsdf.node, f"unsupported bsdf type {t!r} (supported: {', '.join(BSDF_TYPES)})", bsdf)

    def ior(self, bsdf: _Obj, name: str, default: str) -> float:
        prop = self.take(bsdf, name, ("float", "integer", "string"), "a <float> or a <string> naming a medium")
        if prop is None:
            return NAMED_IOR[default]
        if prop.tag == "string":
            key = prop.value.strip().lower()
            if key not in NAMED_IOR:
                raise self.error(prop.node, f"unknown {name} {prop.value!r} (known: {', '.join(NAMED_IOR)})", bsdf)
            return NAMED_IOR[key]
        value = float(prop.value)
        if value <= 0:
            raise self.error(prop.node, f"'{name}' must be positive, got {value:g}", bsdf)
        return value

    # ---- shapes

    def shape(self, obj: _Obj, emitter_name) -> tuple[Mesh, int]:
        """The mesh of a shape (material and emitter names filled in later) and its material key."""
        t = obj.type
        if t not in SHAPE_TYPES:
            raise self.error(obj.node, f"unsupported shape type {t!r} (supported: {', '.join(SHAPE_TYPES)})", obj)
        to_world = self.take(obj, "to_world", ("transform",), "a <transform>")
        matrix = np.eye(4) if to_world is None else to_world.value
        flip = self.get(obj, "flip_normals", "boolean", False)
        supported = ["to_world", "flip_normals"]
        compute_normals = False
        if t in ("rectangle", "cube", "sphere"):
            mesh = primitive(t, "", None, self.subdivisions) if t == "sphere" else primitive(t, "", None)
            mitsuba_uv = _primitive_uv(t, mesh)
            if t == "sphere":
                supported += ["center", "radius"]
                center = self.get(obj, "center", "point", (0.0, 0.0, 0.0))
                radius = self.get(obj, "radius", "float", 1.0)
                if radius <= 0:
                    raise self.error(obj.props["radius"].node, f"'radius' must be positive, got {radius:g}", obj)
                matrix = matrix @ translate(center) @ scale(radius)
        else:
            supported += ["filename", "face_normals", "flip_tex_coords"]
            mesh, mitsuba_uv, compute_normals = self.mesh_file(obj)
        mesh = Mesh(mesh.vertices, mesh.faces, np.stack([mitsuba_uv[:, 0], 1.0 - mitsuba_uv[:, 1]], axis=1), "", None, mesh.normals)
        if flip:
            mesh = mesh.flipped()
        if np.linalg.det(matrix[:3, :3]) == 0:
            raise self.error(to_world.node, "to_world is singular", obj)
        mesh = mesh.transformed(matrix)
        if compute_normals:  # as Mitsuba does: angle-weighted, from the world-space triangles
            mesh = Mesh(mesh.vertices, mesh.faces, mesh.uvs, "", None, _vertex_normals(mesh.vertices, mesh.faces))
        self.finish(obj, tuple(supported), ("bsdf", "emitter"))

        bsdf = self.one_nested(obj, "bsdf")
        if bsdf is None:  # Mitsuba's default BSDF
            bsdf = _Obj(_Node("bsdf", {"type": "diffuse"}, obj.node.line), "diffuse", obj.order)
        key = self.material(bsdf, obj.id)
        emitter = self.one_nested(obj, "emitter")
        if emitter is not None:
            emission = self.area_emitter(emitter)
            mesh = Mesh(mesh.vertices, mesh.faces, mesh.uvs, "", emitter_name(obj, emission), mesh.normals)
        return mesh, key

    def area_emitter(self, emitter: _Obj):
        if emitter.type != "area":
            raise self.error(emitter.node, f"unsupported emitter type {emitter.type!r} (supported: area)", emitter)
        eps = self.colour(emitter, "radiance", EMISSION, 1.0)
        self.finish(emitter, ("radiance",))
        return eps

    def mesh_file(self, obj: _Obj) -> tuple[Mesh, np.ndarray, bool]:
        """The mesh of an obj/ply shape, its texture coordinates as Mitsuba reads them, and whether
        its vertex normals are to be computed (the file has none, and face_normals is false)."""
        import trimesh

        prop = self.take(obj, "filename", ("string",), "a <string>")
        if prop is None:
            raise self.error(obj.node, "missing <string name=\"filename\">", obj)
        path = self.base / prop.value
        if not path.is_file():
            raise self.error(prop.node, f"mesh file not found: {path}", obj)
        face_normals = self.get(obj, "face_normals", "boolean", False)
        flip_uv = self.get(obj, "flip_tex_coords", "boolean", obj.type == "obj")
        try:
            loaded = trimesh.load(str(path), file_type=obj.type, process=False)
            parts = []
            if isinstance(loaded, trimesh.Scene):
                order = {name: i for i, name in enumerate(loaded.geometry)}
                nodes = sorted(((order.get(g, len(order)), n, t, g) for n in loaded.graph.nodes_geometry for t, g in [loaded.graph[n]]), key=lambda x: (x[0], str(x[1])))
                parts = [(loaded.geometry[g], t) for _, _, t, g in nodes if isinstance(loaded.geometry.get(g), trimesh.Trimesh)]
            elif isinstance(loaded, trimesh.Trimesh):
                parts = [(loaded, np.eye(4))]
            # trimesh returns a file's vertex normals as they are (it computes its own only without)
            has_normals = not face_normals and _file_has_normals(path, obj.type)
            vs, fs, uvs, ns, offset = [], [], [], [], 0
            for m, t in parts:
                if len(m.faces) == 0:
                    continue
                v = np.asarray(m.vertices, dtype=np.float64)
                vs.append(v @ t[:3, :3].T + t[:3, 3])
                fs.append(np.asarray(m.faces, dtype=np.int64) + offset)
                uv = getattr(m.visual, "uv", None)
                uvs.append(np.asarray(uv, dtype=np.float64) if uv is not None and len(uv) == len(v) else np.zeros((len(v), 2)))
                if has_normals:
                    ns.append(np.asarray(m.vertex_normals, dtype=np.float64) @ np.linalg.inv(t[:3, :3]))
                offset += len(v)
        except SceneError:
            raise
        except Exception as e:  # trimesh raises anything from ValueError to KeyError on bad files
            raise self.error(prop.node, f"cannot read mesh file {path}: {_one_line(e) or type(e).__name__}", obj) from None
        if not fs:
            raise self.error(prop.node, f"mesh file {path} has no faces", obj)
        uv = np.concatenate(uvs)
        if flip_uv:  # Mitsuba's v = 1 - v_file
            uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)
        normals = np.concatenate(ns) if has_normals else None
        return Mesh(np.concatenate(vs), np.concatenate(fs), None, "", None, normals), uv, not face_normals and not has_normals

    # ---- sensor, integrator

    def sensor(self, obj: _Obj) -> tuple[Camera, tuple[int, int], dict]:
        if obj.type not in SENSOR_TYPES:
            raise self.error(obj.node, f"unsupported sensor type {obj.type!r} (supported: {', '.join(SENSOR_TYPES)})", obj)
        if "focal_length" in obj.props:
            raise self.error(obj.props["focal_length"].node, "'focal_length' is not supported: give 'fov'", obj)
        fov = self.get(obj, "fov", "float")
        if fov is None:
            raise self.error(obj.node, "missing <float name=\"fov\"> (the field of view in degrees)", obj)
        if not 0 < fov < 180:
            raise self.error(obj.props["fov"].node, f"'fov' must lie in (0, 180) degrees, got {fov:g}", obj)
        axis = self.get(obj, "fov_axis", "string", "x").lower()
        if axis not in FOV_AXES:
            raise self.error(obj.props["fov_axis"].node, f"fov_axis {axis!r} is not supported (supported: {', '.join(FOV_AXES)})", obj)
        near = self.get(obj, "near_clip", "float", 1e-2)
        far = self.get(obj, "far_clip", "float", 1e4)
        if not 0 < near < far:
            raise self.error(obj.node, f"need 0 < near_clip < far_clip, got near_clip {near:g}, far_clip {far:g}", obj)
        to_world = self.take(obj, "to_world", ("transform",), "a <transform>")
        matrix = np.eye(4) if to_world is None else to_world.value
        supported = ["fov", "fov_axis", "near_clip", "far_clip", "to_world", "focus_distance"]
        aperture, focus = 0.0, self.get(obj, "focus_distance", "float", far)
        if obj.type == "thinlens":
            supported.append("aperture_radius")
            aperture = self.get(obj, "aperture_radius", "float")
            if aperture is None:
                raise self.error(obj.node, "missing <float name=\"aperture_radius\">", obj)
            if aperture < 0:
                raise self.error(obj.props["aperture_radius"].node, f"'aperture_radius' must be >= 0, got {aperture:g}", obj)
            if focus <= 0:
                raise self.error(obj.props["focus_distance"].node, f"'focus_distance' must be positive, got {focus:g}", obj)
        self.finish(obj, tuple(supported), ("film", "sampler"))

        node = obj.node if to_world is None else to_world.node
        linear = matrix[:3, :3]
        det = np.linalg.det(linear)
        if det <= 0:
            raise self.error(node, f"the sensor's to_world is mirrored or singular (determinant {det:.4g}); it must be a rotation (lookat) and translation", obj)
        s = det ** (1.0 / 3.0)
        if not np.allclose(linear.T @ linear, s * s * np.eye(3), rtol=0, atol=1e-5 * s * s):
            raise self.error(node, "the sensor's to_world must be a rotation and translation (a uniform scale at most): it scales non-uniformly or shears", obj)
        origin = matrix[:3, 3]
        forward, up = linear[:, 2] / s, linear[:, 1] / s
        try:
            if obj.type == "thinlens":
                camera = Camera(tuple(origin), tuple(origin + forward), tuple(up), fov, axis, aperture * s, focus * s)
            else:
                camera = Camera(tuple(origin), tuple(origin + forward), tuple(up), fov, axis)
        except SceneError as e:
            raise self.error(obj.node, str(e), obj) from None

        resolution = DEFAULT_FILM
        film = self.one_nested(obj, "film")
        if film is not None:
            resolution = self.film(film)
        defaults = {}
        sampler = self.one_nested(obj, "sampler")
        if sampler is not None:
            if sampler.type not in SAMPLER_TYPES:
                raise self.error(sampler.node, f"unsupported sampler type {sampler.type!r} (supported: {', '.join(SAMPLER_TYPES)})", sampler)
            spp = self.get(sampler, "sample_count", "integer")
            if spp is not None:
                if spp <= 0:
                    raise self.error(sampler.props["sample_count"].node, f"'sample_count' must be positive, got {spp}", sampler)
                defaults["spp"] = spp
            self.get(sampler, "seed", "integer")
            self.get(sampler, "jitter", "boolean")
            self.finish(sampler, ("sample_count", "seed", "jitter"))
        return camera, resolution, defaults

    def film(self, film: _Obj) -> tuple[int, int]:
        if film.type != "hdrfilm":
            raise self.error(film.node, f"unsupported film type {film.type!r} (supported: hdrfilm)", film)
        size = []
        for key, default in zip(("width", "height"), DEFAULT_FILM):
            value = self.get(film, key, "integer", default)
            if value <= 0:
                raise self.error(film.props[key].node, f"'{key}' must be positive, got {value}", film)
            size.append(value)
        for key in ("file_format", "pixel_format", "component_format"):
            self.get(film, key, "string")
        for key in ("banner", "compensate"):
            self.get(film, key, "boolean")
        self.finish(film, ("width", "height", "file_format", "pixel_format", "component_format", "banner", "compensate"), ("rfilter",))
        rfilter = self.one_nested(film, "rfilter")
        if rfilter is not None:
            if rfilter.type not in RFILTER_TYPES:
                raise self.error(rfilter.node, f"unsupported rfilter type {rfilter.type!r} (Mitsuba's are {', '.join(RFILTER_TYPES)})", rfilter)
            rfilter.used.update(rfilter.props)  # its radius, stddev, B, C, lobes are irrelevant to a box
            self.finish(rfilter, ())
            if rfilter.type != "box":
                warnings.warn(f"{self.where}:{rfilter.node.line}: {rfilter.describe()}: invrender always uses a box filter; the {rfilter.type} filter is ignored", stacklevel=4)
        return tuple(size)

    def integrator(self, obj: _Obj) -> dict:
        if obj.type != "path":
            raise self.error(obj.node, f"unsupported integrator type {obj.type!r} (supported: path)", obj)
        defaults = {"integrator": "path"}
        max_depth = self.get(obj, "max_depth", "integer")
        if max_depth is not None:
            if max_depth == 0 or max_depth < -1:
                raise self.error(obj.props["max_depth"].node, f"'max_depth' must be >= 1, or -1 for unbounded, got {max_depth}", obj)
            defaults["max_depth"] = max_depth
        rr_depth = self.get(obj, "rr_depth", "integer")
        if rr_depth is not None:
            if rr_depth < 1:
                raise self.error(obj.props["rr_depth"].node, f"'rr_depth' must be >= 1, got {rr_depth}", obj)
            defaults["rr_depth"] = rr_depth
        if self.get(obj, "hide_emitters", "boolean", False):
            raise self.error(obj.props["hide_emitters"].node, "hide_emitters=true is not supported", obj)
        self.finish(obj, ("max_depth", "rr_depth", "hide_emitters"))
        return defaults

    # ---- the scene

    def build(self, scene: _Obj, resolution) -> Scene:
        used_names = {"ambient"}
        emission: dict[str, object] = {}
        meshes: list[tuple[Mesh, int]] = []

        def emitter_name(shape: _Obj, eps) -> str:
            # a shape's id is its own; the fallback avoids every id (BSDF ids become material names)
            name = shape.id if shape.id and shape.id not in used_names else _unique(shape.id or "emitter", used_names | set(self.ids))
            used_names.add(name)
            emission[name] = eps
            return name

        camera, film, defaults, seen = None, DEFAULT_FILM, {}, {}
        for item in scene.children:
            obj = self.resolve(item)
            if obj.tag in seen and obj.tag in ("sensor", "integrator"):
                raise self.error(obj.node, f"only one <{obj.tag}> is supported (the first is at line {seen[obj.tag]})", obj)
            seen.setdefault(obj.tag, obj.node.line)
            if obj.tag == "shape":
                meshes.append(self.shape(obj, emitter_name))
            elif obj.tag == "bsdf":
                self.material(obj, None)  # checked even when no shape uses it
            elif obj.tag == "texture":
                self.bitmap(obj)
            elif obj.tag == "sensor":
                camera, film, sensor_defaults = self.sensor(obj)
                defaults.update(sensor_defaults)
            elif obj.tag == "integrator":
                defaults.update(self.integrator(obj))
            elif obj.tag == "emitter":
                if obj.type == "area":
                    raise self.error(obj.node, "an area emitter must be nested in the <shape> that emits", obj)
                raise self.error(obj.node, f"unsupported emitter type {obj.type!r} (supported: area, nested in a shape)", obj)
            else:
                home = {"film": " (it belongs inside a <sensor>)", "sampler": " (it belongs inside a <sensor>)", "rfilter": " (it belongs inside a <film>)"}
                raise self.error(obj.node, f"<{obj.tag}> cannot be a child of <scene>{home.get(obj.tag, '')}", obj)
        if scene.props:
            prop = next(iter(scene.props.values()))
            raise self.error(prop.node, "unexpected property of <scene>")
        if not meshes:
            raise SceneError(f"{self.where}: the scene has no shapes")

        # materials, in the order their BSDFs appear: named by the BSDF's id (ids are unique and no
        # emitter took one), then the others by shape id + _bsdf or material_N, avoiding every id
        used_keys = {k for _, k in meshes}
        ordered = sorted((bsdf.order, key) for key, (bsdf, _, _) in self.materials.items() if key in used_keys)
        names: dict[int, str] = {}
        for _, key in ordered:
            bsdf = self.materials[key][0]
            if bsdf.id:
                names[key] = _unique(bsdf.id, used_names)
                used_names.add(names[key])
        anonymous = 0
        for _, key in ordered:
            bsdf, _, owner = self.materials[key]
            if key not in names:
                if owner:
                    base = f"{owner}_bsdf"
                else:
                    anonymous += 1
                    base = f"material_{anonymous}"
                names[key] = _unique(base, used_names | set(self.ids))
                used_names.add(names[key])
        materials = {names[key]: self.materials[key][1] for _, key in ordered}
        shapes = [Mesh(m.vertices, m.faces, m.uvs, names[k], m.emitter, m.normals) for m, k in meshes]

        if camera is None:  # Mitsuba 3 cannot render such a scene either ("No sensor specified")
            raise SceneError(f"{self.where}:{scene.node.line}: <scene>: no <sensor>: add a <sensor type=\"perspective\"> with a fov and a to_world")
        try:
            built = build_scene(shapes, materials, emission, camera, film if resolution is None else resolution, name=self.path.stem)
        except InvRenderError as e:
            raise SceneError(f"{self.where}: {_one_line(e)}") from None
        built.defaults = defaults
        return built


# ---------------------------------------------------------------- helpers


def _tokens(text: str) -> list[str]:
    return [t for t in _SPLIT.split(text.strip()) if t]


def _one_line(x) -> str:
    return " ".join(str(x).split())


def _show(text: str) -> str:
    return repr(text if len(text) <= 40 else text[:37] + "...")


def _unique(base: str, used: set) -> str:
    name, i = base, 1
    while name in used:
        i += 1
        name = f"{base}_{i}"
    return name


def _mitsuba_rotate(axis: np.ndarray, degrees: float) -> np.ndarray:
    """Mitsuba 3's ``Transform4f::rotate(axis, angle)``, which does not normalize ``axis``:
    ``cos I + (1 - cos) a a^T + sin [a]x`` (a rotation only for a unit axis)."""
    x, y, z = axis
    t = math.radians(degrees)
    c, s = math.cos(t), math.sin(t)
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]]) + (1 - c) * np.outer(axis, axis)
    return m


def _file_has_normals(path: Path, kind: str) -> bool:
    """Does an OBJ file have ``vn`` lines, a PLY file's vertices an ``nx`` property?"""
    with open(path, "rb") as f:
        if kind == "obj":
            return any(line.lstrip().startswith(b"vn ") for line in f)
        header = f.read(1 << 16).split(b"end_header")[0]
    return re.search(rb"property\s+\w+\s+nx\b", header) is not None


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Mitsuba's computed vertex normals: each face's unit normal weighted by its angle at the
    vertex (Thuermer and Wuethrich 1998), summed and normalized; (1, 0, 0) where that sum is zero."""
    p = v[f]  # (F, 3, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    ok = length[:, 0] > 0
    n = np.where(ok[:, None], n / np.where(length > 0, length, 1.0), 0.0)
    out = np.zeros_like(v)
    for j in range(3):
        a = p[:, (j + 1) % 3] - p[:, j]
        b = p[:, (j + 2) % 3] - p[:, j]
        cos = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        np.add.at(out, f[:, j], n * np.arccos(np.clip(cos, -1.0, 1.0))[:, None])
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(length > 0, out / np.where(length > 0, length, 1.0), np.array([1.0, 0.0, 0.0]))


def _coordinate_system(n: np.ndarray) -> np.ndarray:
    """The first tangent of Mitsuba's ``coordinate_system(n)`` (Duff et al. 2017), its lookat's
    default up."""
    sign = 1.0 if n[2] >= 0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])


def _primitive_uv(kind: str, mesh: Mesh) -> np.ndarray:
    """Mitsuba's texture coordinates of a primitive's vertices (``v = 0`` at the image's top)."""
    v = mesh.vertices
    if kind == "rectangle":
        return (v[:, :2] + 1.0) / 2.0
    if kind == "sphere":  # (phi / 2 pi, theta / pi) about local z
        phi = np.mod(np.arctan2(v[:, 1], v[:, 0]), 2 * math.pi)
        theta = np.arccos(np.clip(v[:, 2] / np.linalg.norm(v, axis=1), -1.0, 1.0))
        return np.stack([phi / (2 * math.pi), theta / math.pi], axis=1)
    # cube: look each vertex up by position and face normal in Mitsuba's table
    positions, normals, uvs = (np.asarray(a, dtype=np.float64) for a in _MITSUBA_CUBE)
    tri = v[mesh.faces]
    face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vertex_n = np.zeros_like(v)
    vertex_n[mesh.faces.reshape(-1)] = np.repeat(np.round(face_n / np.linalg.norm(face_n, axis=1, keepdims=True)), 3, axis=0)
    out = np.zeros((len(v), 2))
    for i in range(len(v)):
        match = np.all(np.isclose(positions, v[i], atol=1e-6), axis=1) & np.all(np.isclose(normals, vertex_n[i], atol=1e-6), axis=1)
        out[i] = uvs[np.argmax(match)]
    return out
