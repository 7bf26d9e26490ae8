"""Whole scenes from glTF, GLB, OBJ, PLY and STL files, and the mesh files of other formats' shapes, through trimesh.

:func:`load_mesh_file` reads a whole scene with ``trimesh.load(path, force="scene")``; every
geometry is moved to world space by its scene-graph transform, and triangles are ordered by
geometry in file order (trimesh's node order is not). Each distinct material becomes a material
named as in the file (unnamed: ``material``), made unique with ``_2``, ``_3``, ... suffixes when
two different materials share a name. A material's type is that of the first registered
material type (:data:`invrender.registry.MATERIALS`, in order of their ``gltf_priority``) whose
``from_gltf`` takes it; each says in its module (:mod:`invrender.plugins.bsdfs`) which materials it
takes and what it reads of them. They read a :class:`GltfMaterial`, which puts glTF's and MTL's
values in glTF's metallic-roughness terms (transmission, ior, metal, GGX alpha, base colour, metal
colour), read as follows.

- glTF factors follow the spec's defaults: ``metallicFactor`` and ``roughnessFactor`` are 1 when
  ``pbrMetallicRoughness`` omits them, so a material that does not say ``metallicFactor`` is a
  metal (a rough white conductor when it says nothing at all). They are read from the file's JSON
  (trimesh's values where the JSON has none, e.g. converted from
  ``KHR_materials_pbrSpecularGlossiness``); each must be a number in [0, 1] (``ior`` > 0).
  ``roughnessFactor`` is perceptual roughness r and GGX alpha = r^2, the glTF spec's convention.
  A primitive without any material is the exception to the spec (whose default material is
  metallic): it gets the grey diffuse of an OBJ face without a material.
- ``metallicRoughnessTexture`` (linear, as the spec says: not sRGB-decoded) multiplies the
  factors, its B channel the metallic value and its G channel the perceptual roughness; a channel
  that is uniform over the texture gives a number, one that varies a grey map (a texture value of
  the parameter). A metallic value strictly between 0 and 1, or varying (an opaque material, not a
  mirror), is a ``principled`` material: glTF's metallic-roughness model is the Disney model's core
  (base colour, metallic, perceptual roughness r with alpha = r^2, a dielectric F0 of 0.04 =
  ``eta`` 1.5, or ``ior``), metallic and roughness maps included. A uniform metal's roughness map
  is the conductor's alpha map (r^2, at least 1e-4, Mitsuba's smallest alpha); a mirror takes a
  metal only where alpha is below 1e-3 everywhere. A uniformly non-metallic material's roughness
  is not read (a diffuse surface).
- ``KHR_materials_transmission``: ``transmissionFactor`` 1 on a smooth (alpha below 1e-3),
  non-metallic material is clear glass of the material's ``ior`` (``dielectric``: its base colour
  ignored); any other transmission of a material that is not a metal is ``principled``'s
  ``spec_trans`` (a rough refracting interface tinted by the base colour). ``transmissionTexture``
  and ``KHR_materials_volume`` are not read (every transmitting material is a solid interface,
  thin-walled or not).
- ``normalTexture`` (linear; its ``scale`` s) wraps the material in a ``normalmap`` perturbation
  (:class:`~invrender.scene.materials.NormalPerturbation`, as Mitsuba's wrapper: the texels
  re-encoded so that they hold the spec's ``(2 c - 1) (s, s, 1)``, normalized after filtering).
  Tangent space: Mitsuba's and the spec's for a file without ``TANGENT`` (``s`` along dp/du, ``t =
  n x s``: the green channel points up the image, the spec's "+Y up", OpenGL's); trimesh turns
  glTF's downward v up (``v -> 1 - v``) and the images stay as stored, as for ``baseColorTexture``.
  The map perturbs the frame turned to the side the ray arrives from (the materials are two-sided),
  the front's frame for glass (:meth:`~invrender.scene.materials.Material.perturbed`). A texel of
  no direction (grey) is an error. ``TANGENT`` attributes are not read (MikkTSpace's smoothed,
  per-vertex tangents differ from dp/du, and on mirrored UV islands glTF's bitangent flips with the
  tangent's ``w`` where ``t = n x s`` does not).
- ``KHR_texture_transform`` on a material texture (base colour, metallic-roughness, normal) is its
  ``to_uv`` (:func:`_texture_sampling`); on ``emissiveTexture`` it is not applied (a warning).
  ``texCoord`` other than 0 and the samplers' wrap and filter modes are not read (TEXCOORD_0,
  repeat, bilinear).
- What invrender's types cannot hold is dropped: a conductor's texture (its
  ``specular_reflectance`` is RGB only: the linear mean of ``baseColorTexture`` x
  ``baseColorFactor``), occlusion (baked ambient occlusion: a path tracer computes it) and alpha
  (``alphaMode``). Material extensions other than ``KHR_materials_emissive_strength``,
  ``KHR_materials_ior`` and ``KHR_materials_transmission`` are named in a warning and not read:
  ``KHR_materials_specular`` (a dielectric F0 scale and colour; principled's F0 follows ``eta``),
  ``KHR_materials_clearcoat`` (a GGX coat of any roughness over an attenuated base; principled's
  clearcoat is an additive GTR1 lobe of alpha 0.001 to 0.1 scaled by 1/4), ``KHR_materials_sheen``
  (the Charlie distribution with a colour; principled's sheen is a Schlick-weighted lobe), and the
  rest (volume, iridescence, anisotropy, dispersion, diffuse transmission, ...).
- glTF base colour = ``baseColorFactor`` RGB (linear, read exactly from the file's JSON; trimesh
  rounds it to 8 bits) x ``baseColorTexture`` RGB (8-bit sRGB-encoded per the glTF spec, decoded
  to linear). eps = ``emissiveFactor`` x ``KHR_materials_emissive_strength.emissiveStrength`` (read
  from the JSON, trimesh ignores this extension) x ``emissiveTexture`` (sRGB-decoded); when eps is
  non-zero the material also becomes the emitter ``<material>_emission``, whatever its type.
- OBJ/MTL: base colour = ``Kd`` (read as *linear* RGB, exactly as written in the .mtl) x
  ``map_Kd`` (sRGB-decoded; the texture alone when ``Kd`` is absent), not a metal and opaque;
  except ``illum 3`` (reflection on) with a non-zero ``Ks``: a metal with GGX alpha 0 (a mirror)
  and metal colour ``Ks``. ``Ns``, ``Ni``, ``d`` and the other illumination models are ignored. eps = ``Ke`` (linear;
  ``map_Ke`` is ignored). Faces without a material (or an OBJ without .mtl) get rho = 0.8 grey
  (trimesh's placeholder material, with its grey 2 x 2 image, is ignored).
- Shading normals: a part whose file gives vertex normals (OBJ ``vn``, glTF ``NORMAL``, PLY
  ``nx ny nz``) shades with them, interpolated over each triangle; parts without (and STL files)
  are flat (trimesh would compute normals for them: it is not asked to). They are taken to world
  space by the inverse transpose of the node's transform (mirroring transforms reverse the
  winding, and the normals stay on the front side), normalized (zero ones replaced by the mean of
  the adjacent faces' normals), and negated when, over the whole part, they point to the back
  side of its winding: the winding decides the front side. trimesh keeps vertices with different normals
  apart when it merges vertices, so hard edges (an OBJ cube with one ``vn`` per side) stay hard.
  A TOML ``type = "mesh"`` shape keeps its file's normals the same way (parts without normals in
  a file that has some get their faces' geometric normals: still flat).
- Camera: the first perspective camera met walking the default glTF scene's node tree (depth
  first, in file order) is used, with its ``yfov`` along the image's y axis and its node's world
  transform (glTF cameras look down their local -z with +y up); its ``aspectRatio`` sets the
  default resolution (height 256, width 256 x aspectRatio rounded). Without one (OBJ files,
  orthographic cameras), a camera with a 45-degree field of view on the image's smaller axis looks
  down -z at the bounding-box centre from far enough on +z to see the whole bounding sphere, and
  the default resolution is 256 x 256.
- PLY and STL files are geometry only (a grey diffuse, reflectance 0.8). With ``studio`` (what
  :func:`invrender.load_scene` does for a file without an emitter) the mesh is placed in the
  default studio of :mod:`.studio`: its camera (unless the glTF file has one), a floor and a light.
"""

from __future__ import annotations

import hashlib
import json
import math
import struct
import warnings
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from invrender import registry
from invrender.errors import SceneError
from invrender.scene.camera import Camera
from invrender.scene.formats.studio import studio_camera, studio_parts
from invrender.scene.formats.values import is_number, one_line, show
from invrender.validate import FLOAT32_MAX
from invrender.scene.materials import Material, NormalPerturbation, normal_map_problem
from invrender.scene.textures import SampledTexture, TextureSampling, mitsuba_to_uv
from invrender.scene.scene import Scene, build_scene
from invrender.scene.shapes import Mesh

#: the suffixes (lower case) of the mesh files read as whole scenes
MESH_SUFFIXES = (".gltf", ".glb", ".obj", ".ply", ".stl")
DEFAULT_RESOLUTION = (256, 256)
DEFAULT_RHO = 0.8  # reflectance of glTF primitives / OBJ faces without a material
FRAMING_FOV = 45.0


def load_mesh_file(path, resolution=None, studio: bool | None = False) -> Scene:
    """A whole scene from a .gltf/.glb/.obj/.ply/.stl file (mapping in this module's docstring).

    Args:
        path: the file.
        resolution: (width, height); None = from the glTF camera's aspect ratio (height 256), else
            256 x 256.
        studio: place the mesh in the default studio (:mod:`.studio`: a framing camera unless the
            glTF file has one, a floor and an area light); None = when the file has no emitter;
            False (default) = the file as it is (a framing camera where it has none, no floor or light).
    Raises:
        SceneError: missing or unreadable file, no triangles, an invalid camera.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"mesh file not found: {path}")
    is_gltf = path.suffix.lower() in (".gltf", ".glb")
    gltf = _gltf_json(path) if is_gltf else {}
    json_materials = gltf.get("materials", []) if isinstance(gltf.get("materials"), list) else []

    meshes, materials, emission = [], {}, {}
    names_by_key: dict[tuple, str] = {}
    for mesh, material, normals in _trimesh_parts(path):
        base_name, spec, eps = _material_values(material, json_materials, is_gltf, path)
        key = (base_name, _material_key(spec), _fingerprint(eps))
        if key not in names_by_key:
            name = _unique_name(base_name, eps is not None, set(materials) | set(emission))
            names_by_key[key] = name
            materials[name] = spec
            if eps is not None:
                emission[f"{name}_emission"] = eps
        name = names_by_key[key]
        emitter = f"{name}_emission" if f"{name}_emission" in emission else None
        v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
        meshes.append(Mesh(v, f, _uv(mesh), name, emitter, normals))

    vertices = np.concatenate([m.vertices for m in meshes])
    if not (np.isfinite(vertices).all() and np.abs(vertices).max() <= FLOAT32_MAX):  # before a camera is framed on them
        raise SceneError(f"{path}: vertex positions must be finite numbers within float32's range (|x| <= {FLOAT32_MAX:.4g}), got up to {np.abs(vertices).max():g}")
    if studio is None:
        studio = not emission
    camera, aspect = _gltf_camera(gltf, path) if is_gltf else (None, None)
    if camera is None:
        camera = studio_camera(vertices) if studio else _framing_camera(vertices)
    if studio:
        extra, extra_materials, extra_emission = studio_parts(vertices, set(materials) | set(emission))
        meshes, materials, emission = meshes + extra, {**materials, **extra_materials}, {**emission, **extra_emission}
    if resolution is None:
        resolution = (max(1, round(256 * aspect)), 256) if aspect else DEFAULT_RESOLUTION
    try:
        return build_scene(meshes, materials, emission, camera, resolution, name=path.stem)
    except SceneError as e:
        raise SceneError(f"{path}: {e}") from None


def _trimesh_parts(path: Path) -> list:
    """[(trimesh.Trimesh in world space, its material or None, its vertex normals or None)] of a
    mesh file, in scene-graph order; normals (V, 3) as :func:`_world_normals` makes them."""
    import trimesh

    if not path.is_file():
        raise SceneError(f"mesh file not found: {path}")
    try:
        scene = trimesh.load(str(path), force="scene")
    except Exception as e:  # trimesh raises anything from ValueError to KeyError on bad files
        raise SceneError(f"cannot read mesh file {path}: {one_line(e) or type(e).__name__}") from None
    parts = []
    order = {name: i for i, name in enumerate(scene.geometry)}  # file order; nodes_geometry's order is not
    nodes = [(node, *scene.graph[node]) for node in scene.graph.nodes_geometry]
    for node, transform, geometry in sorted(nodes, key=lambda n: (order.get(n[2], len(order)), str(n[0]))):
        mesh = scene.geometry.get(geometry)
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            continue
        material = getattr(mesh.visual, "material", None)  # before copy(): shared objects stay shared
        normals = _file_normals(mesh)  # before copy() too: copies drop trimesh's cache, which holds them
        mesh = mesh.copy()
        mesh.apply_transform(transform)
        parts.append((mesh, material, None if normals is None else _world_normals(normals, transform, mesh)))
    if not parts:
        raise SceneError(f"mesh file {path} has no faces (no triangle meshes)")
    return parts


def _file_normals(mesh) -> np.ndarray | None:
    """The vertex normals a trimesh mesh was loaded with (OBJ ``vn``, glTF ``NORMAL``, PLY
    ``nx ny nz``), or None when the file had none.

    trimesh keeps loaded normals in its cache only, and puts computed ones there only when
    ``vertex_normals`` is first read (nothing on the loading path reads it), so an entry in the
    cache right after loading is one the file gave. Its vertex merging (``process=True``) keys
    vertices on their normals too, so vertices on either side of a hard edge stay apart."""
    normals = mesh._cache["vertex_normals"]
    if normals is None or np.shape(normals) != np.shape(mesh.vertices):
        return None
    return np.array(normals, dtype=np.float64)


def _world_normals(normals: np.ndarray, transform: np.ndarray, mesh) -> np.ndarray | None:
    """Local vertex normals of ``mesh`` (already moved to world space by ``transform``) in world
    space: by the inverse transpose of the linear part (trimesh reverses the faces of mirroring
    transforms, and the inverse transpose keeps the normals on the new front side), unit length;
    zero or non-finite normals replaced by the area-weighted mean of the adjacent faces' normals;
    all negated when, over the whole mesh, they point to the back side of its winding (the winding
    decides the front side, as everywhere in invrender). None for a singular transform."""
    linear = np.asarray(transform, dtype=np.float64)[:3, :3]
    if not abs(np.linalg.det(linear)) > 0:
        return None
    n = normals @ np.linalg.inv(linear)  # rows: (L^-T n)^T
    length = np.linalg.norm(n, axis=1, keepdims=True)
    bad = ~np.isfinite(length[:, 0]) | (length[:, 0] < 1e-12)
    n = np.where(bad[:, None], 0.0, n / np.where(bad[:, None], 1.0, length))
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # front-side normal x 2 area
    if bad.any():
        mean = np.zeros_like(n)
        for k in range(3):
            np.add.at(mean, f[:, k], cross)
        length = np.linalg.norm(mean, axis=1, keepdims=True)
        mean = np.where(length > 0, mean / np.where(length > 0, length, 1.0), 0.0)
        n[bad] = mean[bad]
    if sum(np.einsum("ij,ij->", n[f[:, k]], cross) for k in range(3)) < 0:
        n = -n
    return n


def _uv(mesh) -> np.ndarray:
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        return np.zeros((len(mesh.vertices), 2))
    return np.asarray(uv, dtype=np.float64)


def _material_values(material, json_materials: list, is_gltf: bool, path: Path):
    """(name, :class:`Material`, eps or None) of a trimesh material, mapped as this module's
    docstring says; eps (3,) or (h, w, 3) linear."""
    from trimesh.visual.material import PBRMaterial, SimpleMaterial

    name = getattr(material, "name", None) or "material"
    where = f"{path}: material {name!r}"
    if isinstance(material, PBRMaterial):
        view = _PbrMaterial(material, _json_material(material, json_materials) if is_gltf else {}, where, path)
    elif isinstance(material, SimpleMaterial):
        if getattr(material, "_name", None) is None and "kd" not in (material.kwargs or {}):  # its .name is then "material_0"
            # trimesh's placeholder for faces without a material
            name, view = "material", GltfMaterial(where)
        else:
            view = _MtlMaterial(material, name, where, path)
    else:
        view = GltfMaterial(where)  # no material (e.g. vertex colours only)
    spec = _registered_material(view)
    return name, spec, view.emission


def _registered_material(view: GltfMaterial) -> Material:
    """The :class:`Material` of the first registered type (by ``gltf_priority``, then in order of
    registration) whose ``from_gltf`` takes ``view``: types that declare ``from_gltf`` in their
    own class body (a subclass does not inherit its parent's aliases)."""
    readers = sorted((c for c in registry.MATERIALS.values() if "from_gltf" in vars(c)), key=lambda c: c.gltf_priority)
    for cls in readers:
        entries = cls.from_gltf(view)
        if entries is not None:
            spec = Material.of(cls.type_name, view.where, **entries)
            return spec if view.normal_map is None else spec.perturbed(view.normal_map)
    raise SceneError(f"{view.where}: no registered material type reads it (known: {', '.join(registry.MATERIALS)})")


class GltfMaterial:
    """A file's material as the material types' ``from_gltf`` read it, in glTF's
    metallic-roughness terms (this module's docstring says how each file format's values are read).

    This base class is a material a file does not give (a primitive or face without one): grey
    diffuse (rho 0.8), no emission. Every value is read when first asked for, so a value no
    material type asks for is never checked.

    A value that may vary over the surface (a *map*) is a float where it does not, else a texture
    value: (h, w, 3) texels (grey for one number per texel), or a
    :class:`~invrender.scene.textures.SampledTexture` where the texture has a
    ``KHR_texture_transform``.

    Attributes:
        where: the file and the material's name, for messages.
        transmission: ``transmissionFactor`` in [0, 1] (0: opaque).
        ior: the index of refraction ``ior`` > 0 (1.5 by default).
        metallic: glTF ``metallicFactor`` (x ``metallicRoughnessTexture``'s B) in [0, 1], a map
            (MTL: 1 for a metal, else 0).
        metal: a conductor (a uniform metallic >= 0.5; MTL ``illum 3`` with a non-zero ``Ks``).
        partial_metal: the metallic value lies strictly between 0 and 1, or varies (a principled
            material's).
        alpha: GGX alpha in [0, 1] (glTF perceptual roughness squared; 0 for an MTL mirror), a map
            (its texels at least 1e-4, Mitsuba's smallest alpha).
        roughness: perceptual roughness (sqrt alpha), at least 1e-4, a map.
        smooth: alpha below 1e-3 everywhere (a mirror where it is a metal).
        base_colour: linear RGB (3,) or a texture value: what a diffuse surface reflects.
        metal_colour: linear RGB (3,): what a metal reflects (a texture by its linear mean).
        emission: eps (3,) or (h, w, 3) linear, or None when it does not emit.
        normal_map: the ``normalmap`` perturbation of its shading normal
            (:class:`~invrender.scene.materials.NormalPerturbation`), or None.
    """

    transmission = 0.0
    ior = 1.5
    metallic = 0.0
    metal = False
    alpha = 1.0
    emission = None
    normal_map = None

    def __init__(self, where: str):
        self.where = where

    @property
    def partial_metal(self) -> bool:
        return not np.isscalar(self.metallic) or 0.0 < self.metallic < 1.0

    @property
    def roughness(self):
        return max(math.sqrt(self.alpha), 1e-4)

    @property
    def smooth(self) -> bool:
        return self.alpha < 1e-3

    @property
    def base_colour(self) -> np.ndarray:
        return np.full(3, DEFAULT_RHO)

    @property
    def metal_colour(self) -> np.ndarray:
        return self.base_colour


class _PbrMaterial(GltfMaterial):
    """A glTF material (trimesh's PBRMaterial and the file's JSON entry for it)."""

    def __init__(self, material, entry: dict, where: str, path: Path):
        super().__init__(where)
        self._material, self._entry, self._path = material, entry, path
        self._pbr = entry.get("pbrMetallicRoughness", {}) if isinstance(entry.get("pbrMetallicRoughness"), dict) else {}
        self._extensions = entry.get("extensions", {}) if isinstance(entry.get("extensions"), dict) else {}
        if "baseColorFactor" in self._pbr:  # checked whatever the type
            self._base = _factor(self._pbr["baseColorFactor"], "baseColorFactor", path)
        elif material.baseColorFactor is not None:
            self._base = np.asarray(material.baseColorFactor, dtype=np.float64)[:3] / 255.0
        else:
            self._base = np.ones(3)
        unread = sorted(k for k in self._extensions if k.startswith("KHR_materials_") and k not in READ_EXTENSIONS)
        if unread:
            warnings.warn(f"{where}: {', '.join(unread)} not read (no counterpart in invrender's materials: the module docstring of {__name__} says what maps)", stacklevel=4)

    def _extension(self, name: str) -> dict:
        value = self._extensions.get(name, {})
        return value if isinstance(value, dict) else {}

    def _sampled(self, texels: np.ndarray, info):
        """``texels`` as a texture value: with the ``KHR_texture_transform`` of the textureInfo
        ``info`` (a :class:`SampledTexture`), else as they are."""
        sampling = _texture_sampling(info, self.where)
        return texels if sampling is None else SampledTexture(texels, sampling)

    @cached_property
    def transmission(self) -> float:
        return _gltf_number(self._extension("KHR_materials_transmission"), "transmissionFactor", None, 0.0, self.where, high=1.0)

    @cached_property
    def ior(self) -> float:
        return _gltf_number(self._extension("KHR_materials_ior"), "ior", None, 1.5, self.where, high=math.inf)

    @cached_property
    def _metal_rough(self) -> tuple:
        """(metallic, perceptual roughness): the factors times ``metallicRoughnessTexture``'s B and
        G channels (linear, as the spec says), each a float where the texture's channel is uniform,
        else (h, w, 3) grey texels."""
        m = _gltf_number(self._pbr, "metallicFactor", self._material.metallicFactor, 1.0, self.where)
        r = _gltf_number(self._pbr, "roughnessFactor", self._material.roughnessFactor, 1.0, self.where)
        image = getattr(self._material, "metallicRoughnessTexture", None)
        if image is None:
            return m, r
        codes = _image_codes(image)

        def channel(c: int, factor: float):
            values = factor * codes[..., c]
            return float(values.flat[0]) if values.min() == values.max() else np.repeat(values[..., None], 3, axis=-1)

        return channel(2, m), channel(1, r)

    @cached_property
    def metallic(self):
        m = self._metal_rough[0]
        return m if np.isscalar(m) else self._sampled(m, self._pbr.get("metallicRoughnessTexture"))

    @cached_property
    def metal(self) -> bool:
        m = self._metal_rough[0]
        return np.isscalar(m) and m >= 0.5

    @property
    def partial_metal(self) -> bool:
        m = self._metal_rough[0]
        return not np.isscalar(m) or 0.0 < m < 1.0

    def _rough_map(self, fn):
        """``fn`` of the perceptual roughness: a float, or a map with the texture's transform."""
        r = self._metal_rough[1]
        return fn(r) if np.isscalar(r) else self._sampled(fn(r), self._pbr.get("metallicRoughnessTexture"))

    @cached_property
    def alpha(self):
        return self._rough_map(lambda r: r * r if np.isscalar(r) else np.maximum(r * r, 1e-4))  # perceptual roughness squared

    @cached_property
    def roughness(self):
        return self._rough_map(lambda r: max(r, 1e-4) if np.isscalar(r) else np.maximum(r, 1e-4))

    @property
    def smooth(self) -> bool:
        r = self._metal_rough[1]
        return float(np.max(r)) ** 2 < 1e-3

    @cached_property
    def base_colour(self):
        texels = _times_texture(self._base, self._material.baseColorTexture)
        return texels if texels.ndim == 1 else self._sampled(texels, self._pbr.get("baseColorTexture"))

    @cached_property
    def metal_colour(self) -> np.ndarray:
        if self._material.baseColorTexture is None:
            return self._base
        return self._base * _times_texture(np.ones(3), self._material.baseColorTexture).reshape(-1, 3).mean(0)

    @cached_property
    def normal_map(self) -> NormalPerturbation | None:
        """``normalTexture`` (linear, tangent-space ``2 c - 1`` as Mitsuba's ``normalmap``) with its
        ``scale`` s: the texels re-encoded so that they hold ``(2 c - 1) (s, s, 1)`` (normalized
        after filtering, as the spec's shader does), and its ``KHR_texture_transform``."""
        image = getattr(self._material, "normalTexture", None)
        if image is None:
            return None
        info = self._entry.get("normalTexture") if isinstance(self._entry.get("normalTexture"), dict) else {}
        scale = info.get("scale", 1.0)
        if not is_number(scale) or not math.isfinite(scale):
            raise SceneError(f"{self.where}: glTF normalTexture scale must be a finite number, got {show(scale)}")
        n = (2.0 * _image_codes(image) - 1.0) * np.array([scale, scale, 1.0])
        texels = (n + 1.0) / 2.0
        if (problem := normal_map_problem(texels)) is not None:
            raise SceneError(f"{self.where}: normalTexture: {problem}")
        sampling = _texture_sampling(info, self.where)
        return NormalPerturbation("normalmap", torch.as_tensor(texels, dtype=torch.float32), sampling, source=f"{self.where}: normalTexture")

    @cached_property
    def emission(self) -> np.ndarray | None:
        material, entry = self._material, self._entry
        extension = self._extensions.get("KHR_materials_emissive_strength", {})
        strength = extension.get("emissiveStrength", 1.0) if isinstance(extension, dict) else 1.0
        if not is_number(strength):
            raise SceneError(f"{self.where}: emissiveStrength must be a number, got {show(strength)}")
        if "emissiveFactor" in entry:
            factor = _factor(entry["emissiveFactor"], "emissiveFactor", self._path)
        elif material.emissiveFactor is not None:
            factor = np.asarray(material.emissiveFactor, dtype=np.float64).reshape(-1)[:3]
        else:
            factor = np.zeros(3)
        eps = factor * float(strength)
        if not np.any(eps != 0):
            return None
        if material.emissiveTexture is not None and _texture_sampling(entry.get("emissiveTexture"), self.where) is not None:
            warnings.warn(f"{self.where}: the emissiveTexture's KHR_texture_transform is not applied (emitters read their textures with the defaults)", stacklevel=4)
        return _times_texture(eps, material.emissiveTexture)


class _MtlMaterial(GltfMaterial):
    """An OBJ's MTL material (trimesh's SimpleMaterial): a mirror with illum 3 and a non-zero Ks,
    else diffuse; Ke is read first, as the file states it."""

    alpha = 0.0

    def __init__(self, material, name: str, where: str, path: Path):
        super().__init__(where)
        self._material, self._name, self._path = material, name, path
        self._kwargs = material.kwargs or {}
        ke = _mtl_colour(self._kwargs.get("ke"), "Ke", name, path)
        self.emission = ke if ke is not None and np.any(ke != 0) else None

    @cached_property
    def _ks(self) -> np.ndarray | None:
        """Ks when illum is 3 (reflection on), else None."""
        if _mtl_illum(self._kwargs.get("illum"), self._name, self._path) != 3:
            return None
        return _mtl_colour(self._kwargs.get("ks"), "Ks", self._name, self._path)

    @property
    def metal(self) -> bool:
        return self._ks is not None and bool(np.any(self._ks != 0))

    @property
    def metallic(self) -> float:
        return 1.0 if self.metal else 0.0

    @property
    def metal_colour(self) -> np.ndarray:
        return self._ks if self.metal else super().metal_colour

    @cached_property
    def base_colour(self) -> np.ndarray:
        kd = _mtl_colour(self._kwargs.get("kd"), "Kd", self._name, self._path)
        if kd is None:
            kd = np.ones(3) if self._material.image is not None else np.full(3, DEFAULT_RHO)
        return _times_texture(kd, self._material.image)


#: the glTF material extensions read (``KHR_materials_*``; the others are named in a warning)
READ_EXTENSIONS = ("KHR_materials_emissive_strength", "KHR_materials_ior", "KHR_materials_transmission")


def _texture_sampling(info, where: str) -> TextureSampling | None:
    """The :class:`TextureSampling` of a glTF textureInfo's ``KHR_texture_transform`` (``offset``
    o, ``rotation`` r, ``scale`` s: ``uv' = o + R S uv`` with ``R = [[cos r, sin r], [-sin r, cos
    r]]``, the matrix the extension's own example implies: offset (0, 1), rotation pi/2 and scale
    0.5 read the image's lower-left quadrant); None without one. glTF's texture coordinates point
    down as Mitsuba's do, so the matrix converts as a Mitsuba ``to_uv``. Its ``texCoord`` is not
    read (trimesh reads TEXCOORD_0 only)."""
    extensions = info.get("extensions") if isinstance(info, dict) else None
    ext = extensions.get("KHR_texture_transform") if isinstance(extensions, dict) else None
    if not isinstance(ext, dict):
        return None
    offset, rotation, scale = ext.get("offset", [0.0, 0.0]), ext.get("rotation", 0.0), ext.get("scale", [1.0, 1.0])
    pair = lambda v: isinstance(v, list) and len(v) == 2 and all(is_number(x) and math.isfinite(x) for x in v)  # noqa: E731
    if not (pair(offset) and pair(scale) and is_number(rotation) and math.isfinite(rotation)):
        raise SceneError(f"{where}: KHR_texture_transform needs offset and scale as 2 finite numbers and rotation as one, got {show(ext)}")
    c, s = math.cos(rotation), math.sin(rotation)
    matrix = [[c * scale[0], s * scale[1], offset[0]], [-s * scale[0], c * scale[1], offset[1]], [0.0, 0.0, 1.0]]
    to_uv = mitsuba_to_uv(matrix)
    return None if to_uv is None else TextureSampling(to_uv=to_uv)


def _image_codes(image) -> np.ndarray:
    """A PIL image's values as stored (a data texture: linear, not sRGB-decoded), (h, w, 3) float64."""
    from invrender.io.images import image_codes  # lazily: images need kornia/OpenEXR

    return image_codes(image).numpy().astype(np.float64)


def _gltf_number(table: dict, key: str, fallback, default: float, where: str, high: float = 1.0) -> float:
    """A glTF material number in [0, ``high``]: the JSON's, else trimesh's ``fallback`` (what it
    parsed, e.g. from KHR_materials_pbrSpecularGlossiness), else the spec's ``default``."""
    value = table[key] if key in table else (default if fallback is None else fallback)
    if isinstance(value, np.generic):
        value = value.item()
    if not is_number(value) or not math.isfinite(value):
        raise SceneError(f"{where}: glTF {key} must be a number, got {show(value)}")
    if not 0 <= value <= high:
        raise SceneError(f"{where}: glTF {key} must lie in [0, {high:g}], got {value:g}")
    return float(value)


def _mtl_illum(value, material: str, path: Path) -> int | None:
    """An MTL ``illum`` model as trimesh keeps it (a list of strings) -> int or None."""
    if value is None:
        return None
    try:
        return int(float(np.atleast_1d(value)[0]))
    except (TypeError, ValueError, IndexError):
        raise SceneError(f"{path}: material {material!r}: illum must be an integer, got {show(value)}") from None


def _material_key(spec: Material) -> tuple:
    """What tells two materials apart: type, values (fingerprinted), constants and normal map."""
    p = spec.perturbation
    perturbation = None if p is None else (p, _fingerprint(p.texture.numpy()))
    return (spec.type, tuple((k, _fingerprint(v)) for k, v in sorted(spec.values.items())), tuple(sorted(spec.constants.items())), perturbation)


def _json_material(material, json_materials: list) -> dict:
    """The glTF JSON material a trimesh PBRMaterial came from: by name, ties broken by its factors
    (base colour and emission compared at trimesh's 8 bits; metallic and roughness)."""
    candidates = [m for m in json_materials if isinstance(m, dict) and m.get("name") == material.name]
    if len(candidates) <= 1:
        return candidates[0] if candidates else {}

    def rounded(x):
        return None if x is None else np.round(np.asarray(x, dtype=np.float64).reshape(-1)[:3] * 255).astype(int).tolist()

    for m in candidates:
        pbr = m.get("pbrMetallicRoughness") if isinstance(m.get("pbrMetallicRoughness"), dict) else {}
        ok_base = rounded(pbr.get("baseColorFactor")) == (None if material.baseColorFactor is None else np.asarray(material.baseColorFactor)[:3].astype(int).tolist())
        ok_emit = rounded(m.get("emissiveFactor")) == rounded(material.emissiveFactor)
        ok_pbr = all(k not in pbr or pbr[k] == getattr(material, k, None) for k in ("metallicFactor", "roughnessFactor"))
        if ok_base and ok_emit and ok_pbr:
            return m
    return {}


def _factor(value, key: str, path: Path) -> np.ndarray:
    if not isinstance(value, list) or len(value) < 3 or not all(is_number(x) for x in value):
        raise SceneError(f"{path}: glTF {key} must be a list of 3 or 4 numbers, got {show(value)}")
    return np.asarray(value[:3], dtype=np.float64)


def _mtl_colour(value, key: str, material: str, path: Path) -> np.ndarray | None:
    """An MTL colour as trimesh keeps it (floats, or a list of strings) -> (3,) float64 or None."""
    if value is None:
        return None
    try:
        rgb = np.asarray([float(x) for x in np.atleast_1d(value)], dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"{path}: material {material!r}: {key} must be numbers, got {show(value)}") from None
    if rgb.size == 1:
        rgb = np.repeat(rgb, 3)
    if rgb.size < 3:
        raise SceneError(f"{path}: material {material!r}: {key} must have 3 components, got {rgb.size}")
    return rgb[:3]


def _times_texture(factor: np.ndarray, image) -> np.ndarray:
    """``factor`` (3,) float64, times an sRGB-encoded PIL image decoded to linear (h, w, 3), row 0
    at the top (not flipped), when there is one."""
    if image is None:
        return factor
    from invrender.io.images import decode_srgb  # lazily: images need kornia/OpenEXR

    return decode_srgb(image).numpy().astype(np.float64) * factor


def _fingerprint(value) -> str | None:
    if value is None:
        return None
    if isinstance(value, SampledTexture):
        return f"{value.sampling}:{_fingerprint(value.texels)}"
    a = np.ascontiguousarray(value, dtype=np.float64)
    return f"{a.shape}:{hashlib.sha1(a.tobytes()).hexdigest()}"


def _unique_name(base: str, emits: bool, used: set) -> str:
    """``base``, or ``base_2``, ``base_3``, ...: unused, and so is its ``_emission`` emitter if it emits."""
    candidate, i = base, 1
    while candidate in used or (emits and f"{candidate}_emission" in used):
        i += 1
        candidate = f"{base}_{i}"
    return candidate


def _gltf_json(path: Path) -> dict:
    """The JSON document of a .gltf, or of a .glb's first (JSON) chunk."""
    try:
        data = path.read_bytes()
        if path.suffix.lower() == ".glb":
            magic, _, _ = struct.unpack_from("<4sII", data, 0)
            length, kind = struct.unpack_from("<I4s", data, 12)
            if magic != b"glTF" or kind != b"JSON":
                raise ValueError("not a binary glTF file (bad header)")
            data = data[20 : 20 + length]
        doc = json.loads(data)
    except FileNotFoundError:
        raise SceneError(f"mesh file not found: {path}") from None
    except (OSError, ValueError, struct.error) as e:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise SceneError(f"cannot read mesh file {path}: {one_line(e)}") from None
    if not isinstance(doc, dict):
        raise SceneError(f"cannot read mesh file {path}: the glTF JSON is not an object")
    return doc


def _gltf_camera(gltf: dict, path: Path) -> tuple[Camera | None, float | None]:
    """The first perspective camera of the default glTF scene (depth first) and its aspect ratio."""
    cameras = gltf.get("cameras", [])
    nodes = gltf.get("nodes", [])
    if not cameras or not isinstance(cameras, list) or not isinstance(nodes, list):
        return None, None
    scenes = gltf.get("scenes") if isinstance(gltf.get("scenes"), list) else []
    index = gltf.get("scene", 0)
    if scenes and isinstance(index, int) and 0 <= index < len(scenes) and isinstance(scenes[index], dict):
        roots = list(scenes[index].get("nodes", []))
    else:
        children = {c for n in nodes if isinstance(n, dict) for c in n.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]

    try:
        stack = [(i, np.eye(4)) for i in reversed(roots)]
        seen = set()
        while stack:
            i, parent = stack.pop()
            if i in seen:
                continue
            seen.add(i)
            node = nodes[i]
            world = parent @ _node_matrix(node)
            if "camera" in node:
                cam = cameras[node["camera"]]
                if cam.get("type") == "perspective":
                    persp = cam["perspective"]
                    yfov = float(persp["yfov"])
                    aspect = persp.get("aspectRatio")
                    origin = world[:3, 3]
                    camera = Camera(
                        origin=tuple(origin), target=tuple(origin - world[:3, 2]), up=tuple(world[:3, 1]), fov=math.degrees(yfov), fov_axis="y"
                    )
                    if aspect is not None and not (is_number(aspect) and aspect > 0):
                        raise ValueError(f"aspectRatio must be a positive number, got {aspect!r}")
                    return camera, (float(aspect) if aspect is not None else None)
            stack.extend((c, world) for c in reversed(node.get("children", [])))
    except SceneError as e:
        raise SceneError(f"{path}: glTF camera: {e}") from None
    except (KeyError, IndexError, TypeError, ValueError, AttributeError) as e:
        raise SceneError(f"{path}: invalid glTF camera or node: {one_line(e) or type(e).__name__}") from None
    return None, None


def _node_matrix(node: dict) -> np.ndarray:
    """A glTF node's local 4x4 transform: ``matrix`` (column-major), or T * R * S."""
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = (float(c) for c in node.get("rotation", [0, 0, 0, 1]))
    r = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip
    m = np.eye(4)
    m[:3, :3] = r * np.asarray(node.get("scale", [1, 1, 1]), dtype=np.float64)
    m[:3, 3] = np.asarray(node.get("translation", [0, 0, 0]), dtype=np.float64)
    return m


def _framing_camera(vertices: np.ndarray) -> Camera:
    """A camera on +z looking down -z at the bounding-box centre, seeing the whole bounding sphere (fov 45)."""
    lo, hi = vertices.min(0), vertices.max(0)
    centre = (lo + hi) / 2
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    distance = 1.05 * radius / math.sin(math.radians(FRAMING_FOV / 2))
    return Camera(origin=tuple(centre + [0.0, 0.0, distance]), target=tuple(centre), up=(0, 1, 0), fov=FRAMING_FOV, fov_axis="smaller")


# ---------------------------------------------------------------- mesh files of other formats' shapes


def mesh_arrays(path: Path):
    """(vertices, faces, uvs, normals) of a mesh file, all its parts merged in world space.

    ``normals`` (V, 3) are the file's vertex normals (world space, on the front side), or None
    when no part has any: the mesh is flat. When only some parts have them, the faces of the
    others get their own three corners each, carrying the face's geometric normal (so they still
    shade flat); the triangles are the same either way."""
    parts = _trimesh_parts(path)
    smooth = any(n is not None for _, _, n in parts)
    vs, fs, uvs, ns = [], [], [], []
    offset = 0
    for mesh, _, normals in parts:
        v, f, uv = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64), _uv(mesh)
        if smooth and normals is None:
            v, f, uv, normals = _flat_corners(v, f, uv)
        vs.append(v)
        fs.append(f + offset)
        uvs.append(uv)
        ns.append(normals)
        offset += len(v)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(uvs), (np.concatenate(ns) if smooth else None)


def _flat_corners(v: np.ndarray, f: np.ndarray, uv: np.ndarray):
    """A flat mesh as unshared corners with their face's geometric normal: (vertices, faces, uvs, normals)."""
    corners = v[f]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    n = cross / np.maximum(np.linalg.norm(cross, axis=1, keepdims=True), 1e-300)
    return corners.reshape(-1, 3), np.arange(3 * len(f), dtype=np.int64).reshape(-1, 3), uv[f].reshape(-1, 2), np.repeat(n, 3, axis=0)
