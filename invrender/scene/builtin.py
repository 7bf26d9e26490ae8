"""Built-in scenes by name: ``cornell_box`` (the default), ``cornell_specular``,
``cornell_materials``, ``furnace``, ``sky_spheres`` and ``normal_plane``."""

from __future__ import annotations

import dataclasses
import inspect
import math
import numbers

import numpy as np
import torch

from invrender.errors import SceneError, did_you_mean
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.materials import Material, NormalPerturbation
from invrender.scene.scene import Scene, build_scene
from invrender.scene.shapes import Mesh, primitive, rotate, scale, sphere, translate

# Mitsuba 3's cornell_box() (docs/conventions.md#materials): diffuse albedos in linear RGB and the light's radiance.
CORNELL_WHITE = (0.885809, 0.698859, 0.666422)
CORNELL_GREEN = (0.105421, 0.37798, 0.076425)
CORNELL_RED = (0.570068, 0.0430135, 0.0443706)
CORNELL_LIGHT = (18.387, 13.9873, 6.75357)


CORNELL_CAMERA = Camera(origin=(0, 0, 3.9), target=(0, 0, 0), up=(0, 1, 0), fov=39.3077, fov_axis="smaller")
#: the tall box's transform (unit cube scaled, rotated about y, translated)
TALL_BOX = translate([-0.33, -0.4, -0.28]) @ rotate([0, 1, 0], 18.25) @ scale([0.3, 0.61, 0.3])


def _shape(kind: str, matrix, material, emitter=None) -> Mesh:
    return primitive(kind, material, emitter).transformed(matrix)


def _walls() -> list[Mesh]:
    """The Cornell box's five 2 x 2 walls, facing inwards: floor, ceiling, back, green right, red left."""
    return [
        _shape("rectangle", translate([0, -1, 0]) @ rotate([1, 0, 0], -90), "white"),  # floor
        _shape("rectangle", translate([0, 1, 0]) @ rotate([1, 0, 0], 90), "white"),  # ceiling
        _shape("rectangle", translate([0, 0, -1]), "white"),  # back wall
        _shape("rectangle", translate([1, 0, 0]) @ rotate([0, 1, 0], -90), "green"),  # right wall
        _shape("rectangle", translate([-1, 0, 0]) @ rotate([0, 1, 0], 90), "red"),  # left wall
    ]


def _light() -> Mesh:
    """The 0.46 x 0.38 light just below the ceiling, facing down, its surface ``white``."""
    return _shape("rectangle", translate([0, 0.99, 0.01]) @ rotate([1, 0, 0], 90) @ scale([0.23, 0.19, 0.19]), "white", "light")


def cornell_box(resolution=(256, 256)) -> Scene:
    """The classic Cornell box exactly as Mitsuba 3's ``cornell_box()`` defines it.

    Walls are 2 x 2 rectangles facing inwards (no front wall); the red wall (x = -1) appears on
    the left of the image. The light is a one-sided 0.46 x 0.38 rectangle just below the ceiling,
    facing down, whose surface reflects like ``white``. Materials: ``white``, ``red``, ``green``;
    emitter: ``light``.
    """
    shapes = [
        *_walls(),
        _shape("cube", translate([0.335, -0.7, 0.38]) @ rotate([0, 1, 0], -17) @ scale(0.3), "white"),
        _shape("cube", TALL_BOX, "white"),
        _light(),
    ]
    return build_scene(
        shapes,
        materials={"white": CORNELL_WHITE, "red": CORNELL_RED, "green": CORNELL_GREEN},
        emission={"light": CORNELL_LIGHT},
        camera=CORNELL_CAMERA,
        resolution=resolution,
        name="cornell_box",
    )


#: the specular Cornell box: a mirror sphere, a glass sphere and a glossy (GGX) block
SPECULAR_MIRROR = (0.95, 0.95, 0.95)
SPECULAR_GLOSSY = (0.95, 0.75, 0.4)
GLOSSY_ROUGHNESS = 0.25
GLASS_IOR = 1.5


def cornell_specular(resolution=(256, 256), subdivisions: int = 4) -> Scene:
    """The Cornell box with the materials beyond Lambertian: Mitsuba's box, walls and light, with
    the tall box turned into a glossy GGX conductor (``glossy``, roughness 0.25, a gold-like
    specular reflectance), the short box replaced by a mirror sphere (``mirror``) and a glass
    sphere (``glass``, ior 1.5) in front. Spheres are icospheres of ``subdivisions`` (20 * 4^n
    triangles) shaded with their exact normals.
    """
    shapes = [
        *_walls(),
        _shape("cube", TALL_BOX, "glossy"),
        primitive("sphere", "mirror", None, subdivisions).transformed(translate([0.45, -0.7, -0.3]) @ scale(0.3)),
        primitive("sphere", "glass", None, subdivisions).transformed(translate([0.1, -0.72, 0.45]) @ scale(0.28)),
        _light(),
    ]
    materials = {
        "white": CORNELL_WHITE,
        "red": CORNELL_RED,
        "green": CORNELL_GREEN,
        "mirror": Material.of("mirror", specular_reflectance=SPECULAR_MIRROR),
        "glass": Material.of("dielectric", ior=GLASS_IOR),
        "glossy": Material.of("glossy", specular_reflectance=SPECULAR_GLOSSY, roughness=GLOSSY_ROUGHNESS),
    }
    return build_scene(shapes, materials, {"light": CORNELL_LIGHT}, CORNELL_CAMERA, resolution, name="cornell_specular")


#: the materials Cornell box: a rough gold-tinted metal block and a blue plastic sphere
MATERIALS_METAL = (0.9, 0.7, 0.45)
MATERIALS_METAL_ROUGHNESS = 0.3
MATERIALS_PLASTIC = (0.15, 0.3, 0.65)


def cornell_materials(resolution=(48, 48), subdivisions: int = 3) -> Scene:
    """The Cornell box with the materials people fit: Mitsuba's box, walls and light, the tall box
    a rough GGX conductor (``metal``: Mitsuba's ``roughconductor``, ``distribution = "ggx"``,
    alpha 0.3, a gold-like specular reflectance with Fresnel 1) and, in place of the short box, a
    smooth plastic sphere (``plastic``: a blue diffuse base under a polypropylene coating, Mitsuba's
    ``plastic``) of radius 0.3, an icosphere of ``subdivisions`` (20 * 4^n triangles) shaded with
    its exact normals. Its parameters: ``metal.roughness``, ``metal.specular_reflectance``,
    ``plastic.reflectance``, ``plastic.specular_reflectance`` besides the box's; small by default
    (48 x 48), the size of a fit (docs/fitting.md#roughness).
    """
    shapes = [
        *_walls(),
        _shape("cube", TALL_BOX, "metal"),
        primitive("sphere", "plastic", None, subdivisions).transformed(translate([0.335, -0.7, 0.38]) @ scale(0.3)),
        _light(),
    ]
    materials = {
        "white": CORNELL_WHITE,
        "red": CORNELL_RED,
        "green": CORNELL_GREEN,
        "metal": Material.of("glossy", specular_reflectance=MATERIALS_METAL, roughness=MATERIALS_METAL_ROUGHNESS),
        "plastic": Material.of("plastic", reflectance=MATERIALS_PLASTIC),
    }
    return build_scene(shapes, materials, {"light": CORNELL_LIGHT}, CORNELL_CAMERA, resolution, name="cornell_materials")


def furnace(resolution=(32, 32), rho=0.5, eps=1.0, subdivisions: int = 3) -> Scene:
    """The inside of a closed unit sphere with uniform reflectance ``rho`` and emission ``eps``.

    Every surface point both reflects and emits, so the radiance everywhere is ``eps / (1 - rho)``
    (``eps (1 - rho^D) / (1 - rho)`` with D Neumann terms). The camera sits at the centre.
    Material ``wall``, emitter ``glow``.
    """
    shell = Mesh(*sphere(subdivisions), material="wall", emitter="glow").flipped()  # faces point inwards
    camera = Camera(origin=(0, 0, 0), target=(0, 0, -1), up=(0, 1, 0), fov=60.0)
    return build_scene(
        [shell], materials={"wall": _rgb(rho)}, emission={"glow": _rgb(eps)}, camera=camera, resolution=resolution, name="furnace"
    )


def _rgb(x):
    """One number as an RGB triple; a triple or a texture as it is."""
    return [float(x)] * 3 if isinstance(x, numbers.Real) else x


#: sky_spheres: the sky's colours (linear RGB) at the zenith, at the horizon and below it, and the sun
SKY_ZENITH = (0.25, 0.45, 0.95)
SKY_HORIZON = (0.9, 0.9, 0.85)
SKY_GROUND = (0.25, 0.2, 0.15)
SUN_RGB = (1.0, 0.9, 0.75)
#: the sun: its peak radiance over the sky's, its elevation and azimuth (u in the map), its width
SUN_PEAK, SUN_ELEVATION, SUN_U, SUN_WIDTH = 20.0, 35.0, 0.3, 10.0
SKY_CAMERA = Camera(origin=(0, 0.35, 4.2), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")


def map_directions(h: int, w: int) -> torch.Tensor:
    """(h, w, 3) unit directions of an envmap's texel centres in its own frame (docs/environment.md:
    row i at theta = pi i / (h - 1), column j at u = (j + 0.5) / w, +Y up, u = 0 towards -Z)."""
    theta = (torch.arange(h, dtype=torch.float64) * math.pi / max(h - 1, 1))[:, None].expand(h, w)
    phi = ((torch.arange(w, dtype=torch.float64) + 0.5) * 2 * math.pi / w)[None, :].expand(h, w)
    return torch.stack([torch.sin(phi) * torch.sin(theta), torch.cos(theta), -torch.cos(phi) * torch.sin(theta)], dim=-1)


def sun_direction() -> torch.Tensor:
    """The sky_spheres sun's direction (the map's frame, which is the world's: no rotation)."""
    st, sp = math.radians(90.0 - SUN_ELEVATION), SUN_U * 2 * math.pi
    return torch.tensor([math.sin(sp) * math.sin(st), math.cos(st), -math.cos(sp) * math.sin(st)], dtype=torch.float64)


def sky_map(h: int = 16, w: int = 32) -> torch.Tensor:
    """The sky_spheres map: (h, w, 3) linear HDR RGB, procedural and deterministic. Above the
    horizon a gradient from ``SKY_HORIZON`` to ``SKY_ZENITH`` (in sqrt of the height), below it a
    uniform ``SKY_GROUND``, plus a sun: a Gaussian blob of ``SUN_WIDTH`` degrees peaking at
    ``SUN_PEAK`` x ``SUN_RGB``, ``SUN_ELEVATION`` degrees above the horizon at ``u = SUN_U``."""
    _map_size("sky_spheres", "map_size", (h, w))
    d = map_directions(h, w)
    up = d[..., 1:2]
    zenith, horizon, ground = (torch.tensor(c, dtype=torch.float64) for c in (SKY_ZENITH, SKY_HORIZON, SKY_GROUND))
    sky = torch.where(up >= 0, horizon + (zenith - horizon) * up.clamp_min(0).sqrt(), ground)
    angle = torch.acos((d @ sun_direction()).clamp(-1, 1))
    blob = SUN_PEAK * torch.exp(-0.5 * (angle / math.radians(SUN_WIDTH)) ** 2)
    return (sky + blob[..., None] * torch.tensor(SUN_RGB, dtype=torch.float64)).float()


def sky_spheres(resolution=(64, 64), map_size=(16, 32), subdivisions: int = 4, sky=None) -> Scene:
    """A diffuse sphere (``diffuse``, left) and a glossy GGX sphere (``glossy``, roughness 0.2,
    right), radius 0.5, on a 6 x 6 diffuse floor (``floor``, y = -1) under an ``envmap`` emitter
    ``sky`` whose map (``sky.emission``, (h, w, 3)) is :func:`sky_map` of ``map_size`` (or the
    given ``sky`` texture), seen in the background above the floor. The scene of
    ``bench/envmap_compare.py`` without its map's rotation and scale: the example of inverse
    lighting (docs/environment.md#inverse-lighting).
    """
    h, w = _map_size("sky_spheres", "map_size", map_size)
    texture = sky_map(h, w) if sky is None else _texture("sky_spheres", "sky", sky)
    ball = lambda x, material: primitive("sphere", material, None, subdivisions).transformed(translate([x, -0.5, 0]) @ scale(0.5))  # noqa: E731
    shapes = [_shape("rectangle", translate([0, -1, 0]) @ rotate([1, 0, 0], -90) @ scale(3.0), "floor"), ball(-0.65, "diffuse"), ball(0.65, "glossy")]
    materials = {
        "floor": (0.5, 0.5, 0.5),
        "diffuse": (0.7, 0.45, 0.3),
        "glossy": Material.of("glossy", specular_reflectance=(0.9, 0.9, 0.85), roughness=0.2),
    }
    return build_scene(shapes, materials, {"sky": Emitter.of("envmap", emission=texture)}, SKY_CAMERA, resolution, name="sky_spheres")


#: normal_plane: the bumps' tilts from the plane's normal, in degrees (least, most)
BUMP_TILTS = (10.0, 25.0)
#: normal_plane: its cameras' elevation above the plane and distance from its centre
PLANE_VIEW_ELEVATION, PLANE_VIEW_DISTANCE = 50.0, 2.7


def bumpy_normals(h: int = 16, w: int = 16) -> torch.Tensor:
    """normal_plane's normal map: (h, w, 3) texels ``c = (n + 1) / 2`` of tangent-space unit normals
    ``n`` tilted from +z by between ``BUMP_TILTS`` degrees, tilt and azimuth varying from texel to
    texel in a fixed pattern (deterministic)."""
    i = torch.arange(h, dtype=torch.float64)[:, None].expand(h, w)
    j = torch.arange(w, dtype=torch.float64)[None, :].expand(h, w)
    lo, hi = BUMP_TILTS
    tilt = torch.deg2rad(lo + (hi - lo) * torch.remainder(7 * i + 3 * j, 5) / 4)
    azimuth = 2 * math.pi * torch.remainder(0.37 * i + 0.61 * j + 0.13 * i * j, 1.0)
    n = torch.stack([torch.sin(tilt) * torch.cos(azimuth), torch.sin(tilt) * torch.sin(azimuth), torch.cos(tilt)], dim=-1)
    return ((n + 1) / 2).float()


def plane_views(count: int = 4) -> list[Camera]:
    """normal_plane's cameras: ``count`` views evenly spaced in azimuth around the plane, each
    ``PLANE_VIEW_ELEVATION`` degrees above it, looking at its centre (the first is the scene's)."""
    e = math.radians(PLANE_VIEW_ELEVATION)
    views = []
    for k in range(count):
        a = 2 * math.pi * (k + 0.125) / count
        origin = PLANE_VIEW_DISTANCE * torch.tensor([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
        views.append(Camera(origin=tuple(origin.tolist()), target=(0, 0, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller"))
    return views


def tinted_sky(h: int = 16, w: int = 32) -> torch.Tensor:
    """normal_plane's environment: (h, w, 3) radiance whose red, green and blue grow linearly with
    the direction's x, y (up) and z, ``0.5 + 0.4 d`` (deterministic). Light that varies along
    every axis makes a surface's shading depend on its normal's every component (a sky symmetric
    about the zenith leaves a normal's turn about it unseen)."""
    return (0.5 + 0.4 * map_directions(h, w)).float()


def normal_plane(resolution=(48, 48), normalmap_size=(16, 16), normalmap=None, map_size=(16, 32)) -> Scene:
    """A 2 x 2 plane (``plane``, y = 0, facing +y, its vertex normals +y) of GGX rough plastic (a
    grey base under a coating of roughness 0.25) wrapped in a normal map (``plane.normalmap``:
    :func:`bumpy_normals` of ``normalmap_size``, or the given ``normalmap`` texels) under an
    ``envmap`` ``sky`` (:func:`tinted_sky` of ``map_size``), seen from above by the first of
    :func:`plane_views`. The scene of normal-map fitting (docs/fitting.md#normals): four views of
    it determine the map's normals.
    """
    h, w = _map_size("normal_plane", "normalmap_size", normalmap_size)
    texels = bumpy_normals(h, w) if normalmap is None else _texture("normal_plane", "normalmap", normalmap)
    mh, mw = _map_size("normal_plane", "map_size", map_size)
    plane = _shape("rectangle", rotate([1, 0, 0], -90), "plane")
    plane = dataclasses.replace(plane, normals=np.tile([0.0, 1.0, 0.0], (len(plane.vertices), 1)))  # Mitsuba's rectangle carries its normals
    coating = Material.of("roughplastic_ggx", reflectance=(0.45, 0.45, 0.45), roughness=0.25)
    material = dataclasses.replace(coating, perturbation=NormalPerturbation("normalmap", texels, source="normal_plane"))
    return build_scene([plane], {"plane": material}, {"sky": Emitter.of("envmap", emission=tinted_sky(mh, mw))}, plane_views()[0], resolution, name="normal_plane")


BUILTIN_SCENES = {
    "cornell_box": cornell_box, "cornell_specular": cornell_specular, "cornell_materials": cornell_materials, "furnace": furnace, "sky_spheres": sky_spheres,
    "normal_plane": normal_plane,
}  # fmt: skip


#: sky_spheres: the most texels its map may have (h * w; 2^24 texels are 192 MiB of float32 RGB)
MAX_MAP_TEXELS = 2**24


def _map_size(scene: str, key: str, value) -> tuple[int, int]:
    """``(h, w)``: two integers, at least 3 rows and 4 columns, at most :data:`MAX_MAP_TEXELS`."""
    ok = isinstance(value, (tuple, list)) and len(value) == 2 and all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in value)
    if not ok:
        raise SceneError(f"{scene}: {key!r} must be two integers (rows, columns), got {value!r}")
    h, w = (int(v) for v in value)
    if h < 3 or w < 4:
        raise SceneError(f"{scene}: {key!r} must be at least (3, 4), got ({h}, {w})")
    if h * w > MAX_MAP_TEXELS:
        raise SceneError(f"{scene}: {key!r} ({h}, {w}) is {h * w} texels, more than {MAX_MAP_TEXELS}")
    return h, w


def _subdivisions(scene: str, key: str, value) -> int:
    """An icosphere's subdivisions: an integer in [0, 7] (20 * 4^n triangles)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 0 <= value <= 7:
        raise SceneError(f"{scene}: {key!r} must be an integer in [0, 7] (an icosphere of 20 * 4^n triangles), got {value!r}")
    return int(value)


def _rgb_option(scene: str, key: str, value):
    """A number, an RGB triple or an (h, w, 3) texture (its range is the parameter's, checked when
    the scene is built)."""
    try:
        t = None if isinstance(value, (bool, str)) else torch.as_tensor(value, dtype=torch.float32)
    except (TypeError, ValueError, RuntimeError):
        t = None
    if t is None or not (t.ndim == 0 or tuple(t.shape) == (3,) or (t.ndim == 3 and t.shape[2] == 3)):
        raise SceneError(f"{scene}: {key!r} must be a number, an RGB triple or an (h, w, 3) texture, got {value!r:.60}")
    return value


def _texture(scene: str, key: str, value) -> torch.Tensor:
    """An (h, w, 3) texture as float32 (its values are the parameter's, checked when the scene is built)."""
    try:
        t = torch.as_tensor(value, dtype=torch.float32)
    except (TypeError, ValueError, RuntimeError):
        t = None
    if t is None or t.ndim != 3 or t.shape[2] != 3 or t.shape[0] < 1 or t.shape[1] < 1:
        raise SceneError(f"{scene}: {key!r} must be an (h, w, 3) texture, got {value!r:.60}")
    return t


#: how each keyword option of the built-in scenes is checked before the scene is made (resolution:
#: by build_scene)
OPTION_CHECKS = {"subdivisions": _subdivisions, "map_size": _map_size, "normalmap_size": _map_size, "rho": _rgb_option, "eps": _rgb_option, "sky": _texture, "normalmap": _texture}


def builtin_scene(name: str, **kwargs) -> Scene:
    """A built-in scene by name; ``kwargs`` go to its constructor (e.g. ``resolution``, ``rho``),
    each checked first (:data:`OPTION_CHECKS`): an unknown name or a bad value is a one-line
    :class:`SceneError` naming the scene, the option and the value."""
    try:
        make = BUILTIN_SCENES[name]
    except KeyError:
        raise SceneError(f"unknown built-in scene {name!r}{did_you_mean(name, BUILTIN_SCENES)} (built-in: {', '.join(BUILTIN_SCENES)})") from None
    options = list(inspect.signature(make).parameters)
    for key, value in kwargs.items():
        if key not in options:
            raise SceneError(f"built-in scene {name!r} has no option {key!r}{did_you_mean(key, options)} (options: {', '.join(options)})")
        if key in OPTION_CHECKS:
            kwargs[key] = OPTION_CHECKS[key](name, key, value)
    return make(**kwargs)
