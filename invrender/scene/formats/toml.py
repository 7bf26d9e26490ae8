"""The TOML scene format (``.toml``): invrender's own scene files.

Every key is optional unless marked *required*. An unknown key anywhere, a value of the wrong type
(a string where a number is expected, a list of the wrong length, ``true`` where a number is
expected), a missing or unreadable file is a :class:`~invrender.errors.SceneError` whose one-line
message names the file, the table and the key, and what was expected (for unknown keys: the
allowed keys). Out-of-range colours (rho outside [0, 1], eps < 0) are
:class:`~invrender.errors.ParameterError` from :func:`~invrender.scene.scene.build_scene`::

    name = "cornell box"               # default: the file name without .toml
    resolution = [64, 64]              # width, height in pixels (default 256 x 256);
                                       # the ``resolution`` argument (CLI --resolution) overrides it
    ambient = [0.1, 0.1, 0.1]          # the Utah approximation's ambient radiance eps0 (RGB >= 0 or one
                                       # number), read by the utah integrator and the pyrender baseline only

    [camera]                           # every key optional; defaults are Camera()'s (the Cornell box view)
    origin = [0, 0, 3.9]               # eye position
    target = [0, 0, 0]                 # point looked at
    up = [0, 1, 0]                     # approximate up direction
    fov = 39.3077                      # full field of view in degrees, along fov_axis
    fov_axis = "smaller"               # x | y | smaller | larger
    aperture_radius = 0.0              # thin lens radius, >= 0 (0 = pinhole, the default)
    focus_distance = 3.9               # distance of the plane in focus along the view axis, > 0

    [film]                             # every key optional (docs/rendering.md#reconstruction-filters)
    filter = "box"                     # the default (unlike Mitsuba's files, whose default is gaussian): box | tent |
                                       # gaussian | mitchell | catmullrom | lanczos, or a table with settings:
                                       # filter = { type = "gaussian", stddev = 0.5 }
    sample_border = false              # also trace samples in the border the filter reaches from (Mitsuba's)
    crop_offset = [0, 0]               # a crop window (x, y, and width, height, pixels, inside the film): the image
    crop_size = [64, 64]               # is the crop; the camera keeps the full film's projection (dropped, with a
                                       # warning, when the ``resolution`` argument resizes the film)

    [materials.white]                  # one table per material; type = "diffuse" (the default when type is absent):
    reflectance = [0.8, 0.8, 0.8]      # Lambertian, two-sided; rho in linear RGB [0, 1] or one number (default 0.5); or
    # reflectance_texture = "albedo.png"   # relative to this file; PNG/JPEG are sRGB-decoded to linear, EXR read as linear

    [materials.chrome]
    type = "mirror"                    # a smooth conductor, two-sided (Mitsuba's conductor)
    specular_reflectance = [0.9, 0.9, 0.9]   # k_s, RGB in [0, 1] (default 1), differentiable
    material = "Cr"                    # a conductor's index: one of Mitsuba's named metals (Au, Cu, Al, Ag, Cr, ...)
                                       # or "none" (the default: Fresnel 1, a perfect mirror); or instead
    # eta = [3.2, 2.9, 1.7]            # the complex index eta + i k itself, 3 numbers each >= 0 (defaults 0 and 1)
    # k = [3.3, 3.1, 2.8]

    [materials.glass]
    type = "dielectric"                # smooth glass: Fresnel reflection and refraction (Mitsuba's dielectric)
    ior = 1.5                          # interior index over the exterior's (1.0), in [0.01, 100] (default 1.5); a constant

    [materials.brushed]
    type = "glossy"                    # GGX rough conductor, two-sided (Mitsuba's roughconductor, distribution ggx);
                                       # "glossy_beckmann": the same with Beckmann (Mitsuba's default distribution)
    roughness = 0.2                    # alpha in (0, 1] (default 0.1), differentiable (fit it with adam);
                                       # or roughness_texture = "alpha.exr" (grey), as specular_reflectance_texture
    specular_reflectance = [0.95, 0.8, 0.5]   # k_s in [0, 1] (default 1), differentiable
    material = "none"                  # or a named metal, or eta / k, as for a mirror (default none: Fresnel 1)

    [materials.bumpy]                  # any material's shading normal may be perturbed by one map (Mitsuba's wrappers):
    reflectance = 0.6
    normalmap = "normals.png"          # tangent-space normals n stored as (n + 1) / 2 (OpenGL's: green up), read as
                                       # stored (not sRGB-decoded); or a table with the options below
    # bumpmap = { file = "height.png", scale = 0.05 }   # a height (its luminance, read as stored) times scale
                                       # (default 1); both tables also take flip_invalid_normals and
                                       # use_shadowing_function (true / false, default true, Mitsuba's)

    [materials.tiles]                  # a colour that may be a texture may also be a procedural one (baked, bilinear):
    reflectance = { checkerboard = { color0 = [0.8, 0.8, 0.8], color1 = 0.2, scale = 4, translate = [0, 0], resolution = 512 } }
                                       # Mitsuba's checkerboard (defaults 0.4, 0.2, scale 1, no translation, 512^2 texels)

    [emitters.light]                   # one table per emitter: type (default "area": emits from the shapes naming it,
                                       # from their front side only), then the type's keys
    emission = [17, 12, 4]             # linear RGB >= 0, or one number; or instead emission_texture = "glow.exr"

    [[shapes]]                         # one table per shape, in order (triangles keep this order)
    type = "rectangle"                 # required: rectangle | cube | sphere | mesh
    material = "white"                 # required: the name of a [materials.NAME] table
    emitter = "light"                  # the name of an [emitters.NAME] table: the shape also emits
    flip_normals = false               # exchange front and back (applied before the transform)
    subdivisions = 3                   # sphere only: an icosphere of 20 * 4^n triangles (0..7, default 3)
    file = "bunny.obj"                 # mesh only, required there: relative to this file, any format trimesh
                                       # reads (OBJ, glTF, GLB, PLY, STL); all its parts merged, in world space
    transform = [{ scale = [0.23, 0.19, 0.19] }, { rotate = { axis = [1, 0, 0], angle = 90 } }, { translate = [0, 0.99, 0.01] }]

A material's ``normalmap`` or ``bumpmap`` perturbs its shading normal as Mitsuba's wrappers of the
same names do (:mod:`invrender.core.shading`: the tangent frame of the mesh's UVs, ``s`` along
dp/du, ``t = n x s``, so a normal map's green channel points towards +v, up the image); the map
perturbs the frame turned to the side the ray arrives from (TOML materials are two-sided, as a map
inside Mitsuba's ``twosided``), the front side's frame for a material that transmits.

``transform`` is a list of steps applied in the order listed (above: scale, then rotate, then
translate): ``{ translate = [x, y, z] }``, ``{ scale = s }`` or ``{ scale = [x, y, z] }`` (non-zero),
``{ rotate = { axis = [x, y, z], angle = degrees } }`` (right-handed). The primitives are Mitsuba 3's
(:mod:`invrender.scene.shapes`): ``rectangle`` is [-1, 1]^2 at z = 0 facing +z, ``cube`` [-1, 1]^3
facing outwards, ``sphere`` the unit sphere facing outwards,
shaded with its exact normals (smooth although tessellated).

Typed readers
-------------

The checked readers below (:func:`read_toml`, :func:`check_keys`, :func:`table`, :func:`number`,
:func:`string`, :func:`integer`, :func:`vector`) serve this format and the recipes'
TOML files alike. Every check raises a :class:`~invrender.errors.SceneError` whose message names
``where`` (the file and table) and the key, and says what was expected; callers that report
another error class (recipes raise ParameterError) convert it.
"""

from __future__ import annotations

import math
import tomllib
import warnings
from pathlib import Path

import numpy as np

from invrender import registry
from invrender.errors import InvRenderError, SceneError, did_you_mean
from invrender.scene.camera import FOV_AXES, Camera
from invrender.scene.formats.trimesh import mesh_arrays
from invrender.scene.formats.values import CHECKERBOARD_RESOLUTION, checkerboard, is_number, one_line, show
from invrender.scene.emitters import Emitter
from invrender.scene.film import FilmOptions
from invrender.scene.materials import PERTURBATIONS, Material, NormalPerturbation, normal_map_problem
from invrender.scene.plugins import PluginSpec
from invrender.scene.scene import Scene, build_scene
from invrender.scene.shapes import PRIMITIVES, Mesh, primitive, rotate, scale, translate

TOP_KEYS = {"name", "resolution", "ambient", "camera", "film", "materials", "emitters", "shapes"}
FILM_KEYS = {"filter", "sample_border", "crop_offset", "crop_size"}
CAMERA_KEYS = {"origin", "target", "up", "fov", "fov_axis", "aperture_radius", "focus_distance", "principal_point_offset", "pixel_aspect"}
SHAPE_KEYS = {"type", "material", "emitter", "file", "subdivisions", "flip_normals", "transform"}
SHAPE_TYPES = (*PRIMITIVES, "mesh")
TRANSFORM_STEPS = ("translate", "rotate", "scale")
DEFAULT_RESOLUTION = (256, 256)


# ---------------------------------------------------------------- the scene format


def load_toml(path, resolution=None) -> Scene:
    """A scene from a TOML scene file (format in this module's docstring).

    Args:
        path: the .toml file; relative paths inside it are relative to its folder.
        resolution: (width, height), overriding the file's ``resolution``; None = the file's.
    Raises:
        SceneError: missing/unreadable/invalid file, unknown keys, wrong types, missing mesh or
            texture files, meshes without faces.
        ParameterError: colours out of range.
    """
    path = Path(path)
    where = str(path)
    doc = read_toml(path, "scene file")
    check_keys(doc, TOP_KEYS, where)
    name = string(doc, "name", where) if "name" in doc else path.stem
    file_resolution = tuple(vector(doc, "resolution", where, length=2)) if "resolution" in doc else DEFAULT_RESOLUTION
    camera = camera_from_table(table(doc, "camera", where), f"{where} [camera]")
    materials = {k: _plugin(v, Material, f"{where} [materials.{k}]", path.parent) for k, v in table(doc, "materials", where).items()}
    emission = {k: _plugin(v, Emitter, f"{where} [emitters.{k}]", path.parent) for k, v in table(doc, "emitters", where).items()}
    shapes_doc = doc.get("shapes", [])
    if not isinstance(shapes_doc, list) or not all(isinstance(s, dict) for s in shapes_doc):
        raise SceneError(f"{where}: 'shapes' must be an array of tables ([[shapes]]), got {show(shapes_doc)}")
    meshes = [_shape(s, f"{where} shapes[{i}]", path.parent) for i, s in enumerate(shapes_doc)]

    film, crop = film_from_table(table(doc, "film", where), f"{where} [film]", file_resolution)
    size = file_resolution if resolution is None else resolution
    if crop is not None:
        if resolution is None or tuple(resolution) == tuple(file_resolution):
            camera, size = camera.cropped(*file_resolution, *crop), crop[1]
        else:
            warnings.warn(f"{where} [film]: the crop window is dropped at the resolution {resolution[0]}x{resolution[1]} asked for (the full film is rendered)", stacklevel=3)
    try:
        scene = build_scene(meshes, materials, emission, camera, size, name=name)
    except SceneError as e:
        raise SceneError(f"{where}: {e}") from None
    scene.film = film
    if "ambient" in doc:
        scene = scene.with_ambient(vector(doc, "ambient", where, scalar_ok=True))
    return scene


def film_from_table(doc: dict, where: str, size) -> tuple[FilmOptions, tuple | None]:
    """(film options, crop window ((x, y), (w, h)) or None) of a ``[film]`` table; a
    :class:`SceneError` naming ``where`` and the key when one is invalid."""
    check_keys(doc, FILM_KEYS, where)
    spec = doc.get("filter")
    if spec is not None and not isinstance(spec, (str, dict)):
        raise SceneError(f"{where}: 'filter' must be a filter name or a table {{ type = ..., ... }}, got {show(spec)}")
    try:
        rfilter = registry.make_filter(spec, f"{where} filter")
    except InvRenderError as e:
        raise SceneError(one_line(e)) from None
    border = doc.get("sample_border", False)
    if not isinstance(border, bool):
        raise SceneError(f"{where}: 'sample_border' must be true or false, got {show(border)}")
    crop = None
    if "crop_offset" in doc or "crop_size" in doc:
        offset = [int(x) for x in vector(doc, "crop_offset", where, length=2)] if "crop_offset" in doc else [0, 0]
        extent = [int(x) for x in vector(doc, "crop_size", where, length=2)] if "crop_size" in doc else [size[0] - offset[0], size[1] - offset[1]]
        raw = [*(doc.get("crop_offset") or []), *(doc.get("crop_size") or [])]
        if any(isinstance(x, float) and not x.is_integer() for x in raw) or min(offset) < 0 or min(extent) <= 0 or offset[0] + extent[0] > size[0] or offset[1] + extent[1] > size[1]:
            raise SceneError(f"{where}: the crop window (offset {offset}, size {extent}) must be whole pixels inside the {int(size[0])}x{int(size[1])} film (offsets >= 0, sizes > 0)")
        crop = (tuple(offset), tuple(extent))
    return FilmOptions(None if rfilter.is_box else rfilter, sample_border=border), crop


def camera_from_table(doc, where: str) -> Camera:
    """A :class:`Camera` from a table of the scene format's ``[camera]`` keys (each optional,
    defaults Camera()'s); a :class:`SceneError` naming ``where`` and the key when it is invalid."""
    if not isinstance(doc, dict):
        raise SceneError(f"{where}: must be a table of camera keys, got {show(doc)}")
    check_keys(doc, CAMERA_KEYS, where)
    args = {k: vector(doc, k, where) for k in ("origin", "target", "up") if k in doc}
    for key in ("fov", "aperture_radius", "focus_distance", "pixel_aspect"):
        if key in doc:
            args[key] = number(doc, key, where)
    if "principal_point_offset" in doc:
        offset = doc["principal_point_offset"]
        if not (isinstance(offset, list) and len(offset) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in offset)):
            raise SceneError(f"{where}: 'principal_point_offset' must be [ox, oy] (fractions of the image width and height), got {show(offset)}")
        args["principal_point_offset"] = tuple(float(x) for x in offset)
    if "fov_axis" in doc:
        args["fov_axis"] = string(doc, "fov_axis", where)
        if args["fov_axis"] not in FOV_AXES:
            raise SceneError(f"{where}: 'fov_axis' must be one of {', '.join(FOV_AXES)}, got {args['fov_axis']!r}")
    try:
        return Camera(**args)
    except SceneError as e:  # the camera's own checks (fov range, degenerate view)
        raise SceneError(f"{where}: {e}") from None


def _shape(doc: dict, where: str, base: Path) -> Mesh:
    check_keys(doc, SHAPE_KEYS, where)
    kind = string(doc, "type", where, required=True)
    if kind not in SHAPE_TYPES:
        raise SceneError(f"{where}: unknown shape type {kind!r}{did_you_mean(kind, SHAPE_TYPES)} (known: {', '.join(SHAPE_TYPES)})")
    material = string(doc, "material", where, required=True)
    emitter = string(doc, "emitter", where) if "emitter" in doc else None
    if kind != "sphere" and "subdivisions" in doc:
        raise SceneError(f"{where}: 'subdivisions' applies to type = \"sphere\" only")
    if kind != "mesh" and "file" in doc:
        raise SceneError(f"{where}: 'file' applies to type = \"mesh\" only")
    try:
        if kind == "mesh":
            v, f, uv, vn = mesh_arrays(base / string(doc, "file", where, required=True))
            mesh = Mesh(v, f, uv, material, emitter, vn)
        else:
            mesh = primitive(kind, material, emitter, *((integer(doc, "subdivisions", where),) if "subdivisions" in doc else ()))
    except SceneError as e:  # a bad mesh file, subdivisions out of range
        raise SceneError(f"{where}: {e}") from None
    flip = doc.get("flip_normals", False)
    if not isinstance(flip, bool):
        raise SceneError(f"{where}: 'flip_normals' must be true or false, got {show(flip)}")
    if flip:
        mesh = mesh.flipped()
    return mesh.transformed(_transform(doc.get("transform", []), where))


def _transform(ops, where: str, key: str = "transform") -> np.ndarray:
    """4x4 matrix of a list of {translate|rotate|scale} steps applied in the order listed (the
    value of ``key``, named so in messages)."""
    usage = "{ translate = [x, y, z] }, { rotate = { axis = [x, y, z], angle = degrees } } or { scale = s or [x, y, z] }"
    if not isinstance(ops, list):
        raise SceneError(f"{where}: '{key}' must be a list of steps {usage}, got {show(ops)}")
    matrix = np.eye(4)
    for i, op in enumerate(ops):
        w = f"{where} {key}[{i}]"
        if not isinstance(op, dict) or len(op) != 1:
            raise SceneError(f"{w}: each step must be a table with one key, one of {usage}; got {show(op)}")
        ((kind, value),) = op.items()
        if kind == "translate":
            make, args = translate, (vector(op, kind, w),)
        elif kind == "scale":
            make, args = scale, (vector(op, kind, w, scalar_ok=True),)
        elif kind == "rotate":
            if not isinstance(value, dict):
                raise SceneError(f"{w}: 'rotate' must be a table {{ axis = [x, y, z], angle = degrees }}, got {show(value)}")
            check_keys(value, {"axis", "angle"}, f"{w} rotate")
            make, args = rotate, (vector(value, "axis", f"{w} rotate", required=True), number(value, "angle", f"{w} rotate", required=True))
        else:
            raise SceneError(f"{w}: unknown transform step {kind!r} (allowed: {', '.join(TRANSFORM_STEPS)})")
        try:
            matrix = make(*args) @ matrix
        except SceneError as e:  # e.g. a zero scale factor
            raise SceneError(f"{w}: {e}") from None
    return matrix


def _plugin(doc, cls: type[PluginSpec], where: str, base: Path) -> PluginSpec:
    """A :class:`Material` or :class:`Emitter` (``cls``) from a ``[materials.NAME]`` or
    ``[emitters.NAME]`` table: ``type`` (default diffuse / area), the type's parameters (RGB, one
    number, or ``KEY_texture`` where the kind allows) and constants, as the type declares them."""
    if not isinstance(doc, dict):
        raise SceneError(f"{where}: must be a table of {cls.noun} keys, got {show(doc)}")
    kind = string(doc, "type", where) if "type" in doc else cls.default_type
    spec = cls.registry.get(kind, where)
    transform_key = getattr(spec, "toml_transform", None)  # a type reading a rotation (envmap's to_world)
    named_key = getattr(spec, "toml_named", None)  # a type reading a named preset of constants (a conductor's material = "Au")
    perturbation_keys = set(PERTURBATIONS) if cls is Material else set()
    check_keys(doc, spec.keys | {"type"} | {k for k in (transform_key, named_key) if k} | perturbation_keys, where)
    entries = {}
    if transform_key and transform_key in doc:
        entries.update(spec.from_transform(_transform(doc[transform_key], where, transform_key), where))
    if named_key and named_key in doc:
        entries.update(spec.from_name(doc[named_key], where, set(doc)))
    for key, (param_kind, _) in spec.params.items():
        if key in doc or f"{key}_texture" in doc:
            entries[key] = _colour_or_texture(doc, key, where, base, texture=param_kind.texture)
    for key in spec.constants:
        if key in doc:
            entries[key] = doc[key]
    made = cls.of(kind, where, **entries)
    perturbation = _perturbation(doc, where, base) if perturbation_keys else None
    return made if perturbation is None else made.perturbed(perturbation)


#: the keys of a ``normalmap = { ... }`` or ``bumpmap = { ... }`` table (``scale``: bump maps only)
PERTURBATION_KEYS = {"file", "scale", "flip_invalid_normals", "use_shadowing_function"}


def _perturbation(doc: dict, where: str, base: Path) -> NormalPerturbation | None:
    """A material table's ``normalmap`` or ``bumpmap`` (one of them): a file name, or a table
    ``{ file = ..., scale = ... (bump maps), flip_invalid_normals = ..., use_shadowing_function =
    ... }``; the image read as stored (raw: not sRGB-decoded), a normal map's texels each encoding
    a direction. None when the table has neither."""
    given = [k for k in PERTURBATIONS if k in doc]
    if not given:
        return None
    if len(given) > 1:
        raise SceneError(f"{where}: give either 'normalmap' or 'bumpmap', not both (one normal perturbation per material)")
    kind = given[0]
    w = f"{where} {kind}"
    value = doc[kind]
    if isinstance(value, str):
        value = {"file": value}
    if not isinstance(value, dict):
        raise SceneError(f"{where}: '{kind}' must be an image file name or a table {{ file = ..., ... }}, got {show(value)}")
    check_keys(value, PERTURBATION_KEYS - ({"scale"} if kind == "normalmap" else set()), w)
    from invrender.io import read_image  # lazily: images need kornia/OpenEXR

    path = base / string(value, "file", w, required=True)
    if not path.is_file():
        raise SceneError(f"{w}: image file not found: {path}")
    try:
        texels = read_image(path, raw=True)
    except InvRenderError as e:
        raise SceneError(f"{w}: {one_line(e)}") from None
    if kind == "normalmap" and (problem := normal_map_problem(texels.numpy())) is not None:
        raise SceneError(f"{w}: {path.name}: {problem}")
    flags = {}
    for key in ("flip_invalid_normals", "use_shadowing_function"):
        flags[key] = value.get(key, True)
        if not isinstance(flags[key], bool):
            raise SceneError(f"{w}: '{key}' must be true or false, got {show(flags[key])}")
    scale = number(value, "scale", w) if "scale" in value else 1.0
    return NormalPerturbation(kind, texels, None, scale, False, flags["flip_invalid_normals"], flags["use_shadowing_function"], w)


def _colour_or_texture(doc, kind: str, where: str, base: Path, others: set | None = None, texture: bool = True):
    """An RGB list or a linear (h, w, 3) texture tensor from a material/emitter table: ``kind`` an
    RGB list, one number or (where ``texture``) a procedural texture table
    (``{ checkerboard = {...} }``, :func:`_procedural`), or ``kind_texture`` an image file.

    ``others``: further keys the table may hold (None: the table is checked by its caller)."""
    key_tex = f"{kind}_texture"
    if not isinstance(doc, dict):
        raise SceneError(f"{where}: must be a table with '{kind}' or '{key_tex}', got {show(doc)}")
    if others is not None:
        check_keys(doc, {kind, key_tex} | others, where)
    if (kind in doc) == (key_tex in doc):
        raise SceneError(f"{where}: give exactly one of '{kind}' or '{key_tex}'")
    if kind in doc and isinstance(doc[kind], dict):
        if not texture:
            raise SceneError(f"{where}: '{kind}' must be an RGB list or one number: it cannot be a texture")
        return _procedural(doc[kind], f"{where} {kind}")
    if kind in doc:
        return vector(doc, kind, where, scalar_ok=True)  # one number: grey
    from invrender.io import read_image  # lazily: images need kornia/OpenEXR

    texture_path = base / string(doc, key_tex, where)
    if not texture_path.is_file():
        raise SceneError(f"{where}: texture file not found: {texture_path}")
    try:
        return read_image(texture_path)
    except InvRenderError as e:
        raise SceneError(f"{where}: {one_line(e)}") from None


PROCEDURAL = ("checkerboard",)
CHECKERBOARD_KEYS = {"color0", "color1", "scale", "translate", "resolution"}


def _procedural(doc: dict, where: str):
    """A procedural texture table, baked: ``{ checkerboard = { color0 = [r, g, b] or v (default
    0.4), color1 = ... (default 0.2), scale = s or [su, sv] (default 1), translate = [du, dv]
    (default 0), resolution = texels per side (default 512) } }``: Mitsuba's checkerboard with
    ``to_uv`` = the scale, then the translation (:func:`~.values.checkerboard`)."""
    import torch  # lazily, as the images are

    if len(doc) != 1 or next(iter(doc)) not in PROCEDURAL:
        raise SceneError(f"{where}: a texture table holds one key naming its type ({', '.join(PROCEDURAL)}), got {show(doc)}")
    board = table(doc, "checkerboard", where)
    w = f"{where} checkerboard"
    check_keys(board, CHECKERBOARD_KEYS, w)
    colours = [vector(board, key, w, scalar_ok=True) if key in board else default for key, default in (("color0", 0.4), ("color1", 0.2))]
    to_uv = np.eye(3)
    if "scale" in board:
        s = board["scale"]
        su, sv = (float(s), float(s)) if is_number(s) else tuple(vector(board, "scale", w, length=2))
        if su == 0 or sv == 0:
            raise SceneError(f"{w}: 'scale' must be non-zero, got {show(s)}")
        to_uv = np.diag([su, sv, 1.0])
    if "translate" in board:
        to_uv[:2, 2] = vector(board, "translate", w, length=2)
    resolution = integer(board, "resolution", w) if "resolution" in board else CHECKERBOARD_RESOLUTION
    if not 2 <= resolution <= 8192:
        raise SceneError(f"{w}: 'resolution' must lie in [2, 8192], got {resolution}")
    return torch.from_numpy(checkerboard(*colours, to_uv, resolution)).float()


# ---------------------------------------------------------------- typed readers


def read_toml(path: Path, what: str) -> dict:
    """The document of the TOML file ``path``; a one-line :class:`SceneError` naming it as ``what``
    (e.g. ``"scene file"``) when it is missing, unreadable, not UTF-8 or not valid TOML."""
    try:
        return tomllib.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise SceneError(f"{what} not found: {path}") from None
    except OSError as e:
        raise SceneError(f"cannot read {what} {path}: {one_line(e.strerror or e)}") from None
    except UnicodeDecodeError as e:
        raise SceneError(f"{path}: invalid TOML: not UTF-8 text ({one_line(e)})") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: invalid TOML: {one_line(e)}") from None


def check_keys(doc: dict, allowed: set, where: str) -> None:
    unknown = sorted(str(k) for k in set(doc) - allowed)
    if unknown:
        raise SceneError(f"{where}: unknown key {unknown[0]!r}{did_you_mean(unknown[0], allowed)} (allowed: {', '.join(sorted(allowed))})")


def table(doc: dict, key: str, where: str) -> dict:
    value = doc.get(key, {})
    if not isinstance(value, dict):
        raise SceneError(f"{where}: '{key}' must be a table, got {show(value)}")
    return value


def number(doc: dict, key: str, where: str, required: bool = False) -> float:
    if key not in doc and required:
        raise SceneError(f"{where}: missing required key '{key}' (a number)")
    value = doc.get(key)
    if not is_number(value):
        raise SceneError(f"{where}: '{key}' must be a number, got {show(value)}")
    if not math.isfinite(value):
        raise SceneError(f"{where}: '{key}' must be a finite number, got {show(value)}")
    return float(value)


def string(doc: dict, key: str, where: str, required: bool = False) -> str:
    if key not in doc and required:
        raise SceneError(f"{where}: missing required key '{key}' (a string)")
    value = doc.get(key)
    if not isinstance(value, str):
        raise SceneError(f"{where}: '{key}' must be a string, got {show(value)}")
    return value


def integer(doc: dict, key: str, where: str) -> int:
    value = doc.get(key)
    if not isinstance(value, int) or isinstance(value, bool):
        raise SceneError(f"{where}: '{key}' must be an integer, got {show(value)}")
    return value


def vector(doc: dict, key: str, where: str, length: int = 3, required: bool = False, scalar_ok: bool = False) -> list[float] | float:
    """``doc[key]`` as ``length`` floats; with ``scalar_ok`` one number is also accepted (returned as a float)."""
    expected = f"a number or a list of {length} numbers" if scalar_ok else f"a list of {length} numbers"
    if key not in doc and required:
        raise SceneError(f"{where}: missing required key '{key}' ({expected})")
    value = doc.get(key)
    if scalar_ok and is_number(value):
        if not math.isfinite(value):
            raise SceneError(f"{where}: '{key}' must be finite, got {show(value)}")
        return float(value)
    if not isinstance(value, list) or len(value) != length or not all(is_number(x) for x in value):
        raise SceneError(f"{where}: '{key}' must be {expected}, got {show(value)}")
    if not all(math.isfinite(x) for x in value):
        raise SceneError(f"{where}: '{key}' must be {length} finite numbers, got {show(value)}")
    return [float(x) for x in value]
