"""The Mitsuba sensor, its film, reconstruction filter and sampler onto invrender's camera.

Sensor (at most one ``<sensor>``)
    ``perspective`` and ``thinlens``: ``fov`` (degrees) with ``fov_axis`` (x, y, smaller,
    larger; default x; ``diagonal`` is an error), or ``focal_length`` (a ``<string>`` ``"<x>mm"``,
    x > 0; Mitsuba's default ``50mm`` when neither is given): as Mitsuba, the
    lens of a 36 x 24 mm film, whose diagonal field of view ``2 atan(sqrt(36^2 + 24^2) / 2f)``
    spans the film's diagonal (so its horizontal field of view depends on the film's aspect:
    that of the ``resolution`` argument when one is given); ``fov`` and ``focal_length`` together
    are an error, as in Mitsuba; ``orthographic``: parallel rays along the view direction from a
    window of camera-space ``[-1, 1] x [-1 / aspect, 1 / aspect]`` (aspect = width / height) mapped
    by ``to_world``, whose x and y scales size it (:class:`~invrender.scene.camera.OrthographicCamera`;
    ``near_clip``/``far_clip`` accepted, checked, ignored; a sheared or mirrored to_world is an error);
    ``to_world`` (lookat or any rotation and translation, optionally a uniform scale; the camera
    looks along local +z with local +y up and the image's x axis along local -x, as in Mitsuba; a
    mirrored (det < 0), non-uniformly scaled or sheared to_world is an error),
    ``principal_point_offset_x`` / ``_y`` (perspective; default 0; the image window's shift in
    fractions of the film's width and height, x right and y down, as Mitsuba: the camera's
    ``principal_point_offset``), ``near_clip`` /
    ``far_clip`` (accepted, checked, ignored), ``focus_distance`` (thinlens; default ``far_clip``;
    > 0), ``aperture_radius`` (thinlens, required, >= 0). Inside the sensor: ``<film
    type="hdrfilm">`` with ``width``/``height`` (default 768 x 576 as Mitsuba; the ``resolution``
    argument overrides them), a crop window ``crop_offset_x``/``_y``, ``crop_width``/``_height``
    (the scene's image is the crop, its camera sees that part of the full film; inside the film or
    an error; dropped with a warning when ``resolution`` resizes the film, as Mitsuba resets it on
    a resize; perspective and thinlens only), ``sample_border`` (default false), ``file_format``,
    ``pixel_format``, ``component_format``, ``banner``, ``compensate`` accepted and ignored (the
    image is RGB), and an optional ``<rfilter>``: ``box``, ``tent`` (``radius``), ``gaussian``
    (``stddev``), ``mitchell`` (``B``, ``C``), ``catmullrom``, ``lanczos`` (``lobes``), Mitsuba's
    gaussian of stddev 0.5 when there is none (the scene's ``film``,
    :mod:`invrender.plugins.filters`); ``<sampler>`` of
    any Mitsuba type with ``sample_count`` (the default spp; ``seed`` and ``jitter`` are ignored;
    invrender draws its own samples). A scene without a sensor is an error (Mitsuba 3 cannot
    render one either).

Deviations from Mitsuba
    - Sampling patterns are invrender's own; the Gaussian is evaluated with ``exp`` where
      Mitsuba's CPU variants use a polynomial fit (they agree to about 1e-7).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from invrender import registry
from invrender.errors import ParameterError, SceneError
from invrender.scene.film import FilmOptions
from invrender.scene.camera import Camera, OrthographicCamera
from invrender.scene.formats.mitsuba.context import Context
from invrender.scene.formats.mitsuba.parser import Obj

#: Mitsuba's default film size
DEFAULT_FILM = (768, 576)

SENSOR_TYPES = ("perspective", "thinlens", "orthographic")
FOV_AXES = ("x", "y", "smaller", "larger")
RFILTER_TYPES = ("box", "tent", "gaussian", "mitchell", "catmullrom", "lanczos")
FILM_TYPES = ("hdrfilm",)
SAMPLER_TYPES = ("independent", "stratified", "multijitter", "orthogonal", "ldsampler")


def sensor(ctx: Context, obj: Obj, resolution: tuple[int, int] | None = None) -> tuple[Camera, tuple[int, int], dict, FilmOptions]:
    """The camera of a ``<sensor>``, the (width, height) of the image it renders (its crop window's
    when it has one: the camera then sees that part of the full film), the render settings its
    sampler states and its film's options (filter, ``sample_border``); ``resolution`` (width,
    height), the size the scene is loaded at when it is not the film's (a ``focal_length``'s field
    of view depends on the aspect; a crop window is then dropped with a warning, as Mitsuba drops
    it when a film is resized)."""
    if obj.type not in SENSOR_TYPES:
        raise ctx.error(obj.node, f"unsupported sensor type {obj.type!r} (supported: {', '.join(SENSOR_TYPES)})", obj)
    film_obj = ctx.one_nested(obj, "film")
    spec = FilmSpec(DEFAULT_FILM, None, FilmOptions(registry.make_filter("gaussian"))) if film_obj is None else film_size(ctx, film_obj)
    film, crop = spec.size, spec.crop
    if crop is not None and resolution is not None and tuple(resolution) != film:
        warnings.warn(f"{ctx.where}:{film_obj.node.line}: the crop window of the {film[0]}x{film[1]} film is dropped at the resolution {resolution[0]}x{resolution[1]} asked for (the full film is rendered)", stacklevel=4)
        crop = None
    fov, axis = field_of_view(ctx, obj, resolution or film) if obj.type != "orthographic" else (None, None)
    near = ctx.get(obj, "near_clip", "float", 1e-2)
    far = ctx.get(obj, "far_clip", "float", 1e4)
    if not 0 < near < far:
        raise ctx.error(obj.node, f"need 0 < near_clip < far_clip, got near_clip {near:g}, far_clip {far:g}", obj)
    to_world = ctx.take(obj, "to_world", ("transform",), "a <transform>")
    matrix = np.eye(4) if to_world is None else to_world.value
    supported = ["near_clip", "far_clip", "to_world"]
    if obj.type != "orthographic":
        supported += ["fov", "fov_axis", "focal_length", "focus_distance"]
    aperture, focus = 0.0, ctx.get(obj, "focus_distance", "float", far) if obj.type != "orthographic" else 1.0
    offset = (0.0, 0.0)
    if obj.type == "perspective":
        supported += ["principal_point_offset_x", "principal_point_offset_y"]
        offset = tuple(ctx.get(obj, f"principal_point_offset_{c}", "float", 0.0) for c in "xy")
    if obj.type == "thinlens":
        supported.append("aperture_radius")
        aperture = ctx.get(obj, "aperture_radius", "float")
        if aperture is None:
            raise ctx.error(obj.node, "missing <float name=\"aperture_radius\">", obj)
        if aperture < 0:
            raise ctx.error(obj.props["aperture_radius"].node, f"'aperture_radius' must be >= 0, got {aperture:g}", obj)
        if focus <= 0:
            raise ctx.error(obj.props["focus_distance"].node, f"'focus_distance' must be positive, got {focus:g}", obj)
    ctx.finish(obj, tuple(supported), ("film", "sampler"))

    node = obj.node if to_world is None else to_world.node
    if obj.type == "orthographic":
        camera = orthographic(ctx, obj, matrix, node)
    else:
        camera = perspective(ctx, obj, matrix, node, fov, axis, aperture, focus, offset)
    if crop is None:
        return camera, film, sampler_defaults(ctx, obj), spec.options
    try:
        camera = camera.cropped(film[0], film[1], *crop)
    except SceneError as e:
        raise ctx.error(film_obj.node, str(e), film_obj) from None
    return camera, crop[1], sampler_defaults(ctx, obj), spec.options


def perspective(ctx: Context, obj: Obj, matrix: np.ndarray, node, fov: float, axis: str, aperture: float, focus: float, offset) -> Camera:
    """The camera of a ``perspective`` or ``thinlens`` sensor from its to_world (a rotation and
    translation, a uniform scale at most) and its lens settings."""
    linear = matrix[:3, :3]
    det = np.linalg.det(linear)
    if det <= 0:
        raise ctx.error(node, f"the sensor's to_world is mirrored or singular (determinant {det:.4g}); it must be a rotation (lookat) and translation", obj)
    s = det ** (1.0 / 3.0)
    if not np.allclose(linear.T @ linear, s * s * np.eye(3), rtol=0, atol=1e-5 * s * s):
        raise ctx.error(node, "the sensor's to_world must be a rotation and translation (a uniform scale at most): it scales non-uniformly or shears", obj)
    origin = matrix[:3, 3]
    forward, up = linear[:, 2] / s, linear[:, 1] / s
    try:
        if obj.type == "thinlens":
            camera = Camera(tuple(origin), tuple(origin + forward), tuple(up), fov, axis, aperture * s, focus * s)
        else:
            camera = Camera(tuple(origin), tuple(origin + forward), tuple(up), fov, axis, principal_point_offset=offset)
    except SceneError as e:
        raise ctx.error(obj.node, str(e), obj) from None
    return camera


def orthographic(ctx: Context, obj: Obj, matrix: np.ndarray, node) -> OrthographicCamera:
    """The camera of an ``orthographic`` sensor: its to_world's columns give the view frame and
    the window's extent (x and y scales); they must be orthogonal (no shear), not mirrored."""
    linear = matrix[:3, :3]
    det = np.linalg.det(linear)
    if det <= 0:
        raise ctx.error(node, f"the sensor's to_world is mirrored or singular (determinant {det:.4g}); it must be a rotation (lookat), a scale and a translation", obj)
    gram = linear.T @ linear
    if not np.allclose(gram, np.diag(np.diag(gram)), rtol=0, atol=1e-5 * float(np.max(np.diag(gram)))):
        raise ctx.error(node, "an orthographic sensor's to_world must be a scale, a rotation and a translation: it shears", obj)
    lengths = np.sqrt(np.diag(gram))
    origin = matrix[:3, 3]
    forward, up = linear[:, 2] / lengths[2], linear[:, 1] / lengths[1]
    try:
        return OrthographicCamera(tuple(origin), tuple(origin + forward), tuple(up), extent=(float(lengths[0]), float(lengths[1])))
    except SceneError as e:
        raise ctx.error(obj.node, str(e), obj) from None


def sampler_defaults(ctx: Context, obj: Obj) -> dict:
    """The render settings a sensor's ``<sampler>`` states (its ``sample_count``)."""
    defaults = {}
    sampler = ctx.one_nested(obj, "sampler")
    if sampler is not None:
        if sampler.type not in SAMPLER_TYPES:
            raise ctx.error(sampler.node, f"unsupported sampler type {sampler.type!r} (supported: {', '.join(SAMPLER_TYPES)})", sampler)
        spp = ctx.get(sampler, "sample_count", "integer")
        if spp is not None:
            if spp <= 0:
                raise ctx.error(sampler.props["sample_count"].node, f"'sample_count' must be positive, got {spp}", sampler)
            defaults["spp"] = spp
        ctx.get(sampler, "seed", "integer")
        ctx.get(sampler, "jitter", "boolean")
        ctx.finish(sampler, ("sample_count", "seed", "jitter"))
    return defaults


#: Mitsuba's focal length when a perspective sensor gives neither ``fov`` nor ``focal_length`` (mm)
DEFAULT_FOCAL_LENGTH = 50.0
#: the diagonal of the 36 x 24 mm film Mitsuba's ``focal_length`` refers to (mm)
FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)


def field_of_view(ctx: Context, obj: Obj, size: tuple[int, int]) -> tuple[float, str]:
    """(fov in degrees, fov_axis) of a perspective sensor: its ``fov`` and ``fov_axis``, or its
    ``focal_length`` (default 50 mm) as the horizontal field of view of a ``size`` (width, height) film."""
    if "fov" in obj.props and "focal_length" in obj.props:
        raise ctx.error(obj.props["focal_length"].node, "give either 'fov' or 'focal_length', not both (as Mitsuba)", obj)
    if "fov" in obj.props:
        fov = ctx.get(obj, "fov", "float")
        if not 0 < fov < 180:
            raise ctx.error(obj.props["fov"].node, f"'fov' must lie in (0, 180) degrees, got {fov:g}", obj)
        axis = ctx.get(obj, "fov_axis", "string", "x").lower()
        if axis not in FOV_AXES:
            raise ctx.error(obj.props["fov_axis"].node, f"fov_axis {axis!r} is not supported (supported: {', '.join(FOV_AXES)})", obj)
        return fov, axis
    if "fov_axis" in obj.props:  # Mitsuba ignores it beside a focal length: the lens fixes the diagonal
        ctx.get(obj, "fov_axis", "string")
    focal = DEFAULT_FOCAL_LENGTH
    prop = ctx.take(obj, "focal_length", ("string",), 'a <string> such as "50mm"')
    if prop is not None:
        text = str(prop.value).strip()
        try:
            focal = float(text[:-2] if text.endswith("mm") else text)
        except ValueError:
            focal = math.nan
        if not (math.isfinite(focal) and focal > 0):
            raise ctx.error(prop.node, f"'focal_length' {text!r} must be a positive length in millimetres such as \"50mm\"", obj)
    width, height = size
    aspect = width / height
    diagonal = FILM_DIAGONAL_MM / focal  # 2 tan(half the diagonal field of view)
    return math.degrees(2.0 * math.atan(0.5 * diagonal / math.sqrt(1.0 + 1.0 / (aspect * aspect)))), "x"


#: each Mitsuba filter's settings and their XML tags
RFILTER_SETTINGS = {"box": {}, "tent": {"radius": "float"}, "gaussian": {"stddev": "float"}, "mitchell": {"B": "float", "C": "float"}, "catmullrom": {}, "lanczos": {"lobes": "integer"}}


@dataclass(frozen=True)
class FilmSpec:
    """What a ``<film>`` states.

    Attributes:
        size: (width, height) of the full film, pixels.
        crop: ((x, y) offset, (width, height) size) of the crop window, None for the full film.
        options: its filter and ``sample_border`` (:class:`~invrender.scene.film.FilmOptions`).
    """

    size: tuple[int, int]
    crop: tuple[tuple[int, int], tuple[int, int]] | None = None
    options: FilmOptions = FilmOptions(filter=None)


def film_size(ctx: Context, film: Obj) -> FilmSpec:
    """The :class:`FilmSpec` of a ``<film>``: its size, crop window, ``sample_border`` and
    ``<rfilter>`` (Mitsuba's default: a gaussian of stddev 0.5)."""
    if film.type not in FILM_TYPES:
        raise ctx.error(film.node, f"unsupported film type {film.type!r} (supported: {', '.join(FILM_TYPES)})", film)
    size = []
    for key, default in zip(("width", "height"), DEFAULT_FILM):
        value = ctx.get(film, key, "integer", default)
        if value <= 0:
            raise ctx.error(film.props[key].node, f"'{key}' must be positive, got {value}", film)
        size.append(value)
    for key in ("file_format", "pixel_format", "component_format"):
        ctx.get(film, key, "string")
    for key in ("banner", "compensate"):
        ctx.get(film, key, "boolean")
    crop = crop_window(ctx, film, tuple(size))
    border = ctx.get(film, "sample_border", "boolean", False)
    ctx.finish(film, ("width", "height", "crop_offset_x", "crop_offset_y", "crop_width", "crop_height", "sample_border", "file_format", "pixel_format", "component_format", "banner", "compensate"), ("rfilter",))
    rfilter = ctx.one_nested(film, "rfilter")
    return FilmSpec(tuple(size), crop, FilmOptions(reconstruction_filter(ctx, rfilter), sample_border=border))


def crop_window(ctx: Context, film: Obj, size: tuple[int, int]):
    """((x, y), (w, h)) of a film's crop window (Mitsuba's ``crop_offset_x/_y``, ``crop_width/_height``;
    defaults: the whole film), None when it is the whole film; an error when it leaves the film."""
    keys = ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height")
    if not any(k in film.props for k in keys):
        return None
    x, y = (ctx.get(film, k, "integer", 0) for k in keys[:2])
    w, h = ctx.get(film, "crop_width", "integer", size[0]), ctx.get(film, "crop_height", "integer", size[1])
    if x < 0 or y < 0 or w <= 0 or h <= 0 or x + w > size[0] or y + h > size[1]:
        key = next(k for k in keys if k in film.props)
        raise ctx.error(film.props[key].node, f"crop window offset ({x}, {y}) size {w}x{h} must lie inside the {size[0]}x{size[1]} film (offsets >= 0, sizes > 0)", film)
    return None if (x, y, w, h) == (0, 0, *size) else ((x, y), (w, h))


def reconstruction_filter(ctx: Context, rfilter: Obj | None):
    """The filter object of an ``<rfilter>`` (its settings checked); Mitsuba's default, the
    gaussian of stddev 0.5, when there is none."""
    if rfilter is None:
        return registry.make_filter("gaussian")
    if rfilter.type not in RFILTER_TYPES:
        raise ctx.error(rfilter.node, f"unsupported rfilter type {rfilter.type!r} (Mitsuba's are {', '.join(RFILTER_TYPES)})", rfilter)
    settings = RFILTER_SETTINGS[rfilter.type]
    values = {k: ctx.get(rfilter, k, tag) for k, tag in settings.items() if k in rfilter.props}
    ctx.finish(rfilter, tuple(settings))
    try:
        return registry.make_filter({"type": rfilter.type, **values})
    except ParameterError as e:
        raise ctx.error(rfilter.node, str(e), rfilter) from None
