"""The Scene: triangles as tensors, named materials and emitters, camera, resolution, parameters.

Geometry is never differentiated (docs/architecture.md#geometry-is-never-differentiated), so positions are plain float32 tensors.
What can be differentiated lives in ``scene.params``, a flat dict of dotted names to leaf tensors
(kinds, ranges and reparametrizations in :mod:`invrender.scene.kinds`):

- ``"<material>.reflectance"``: diffuse albedo rho, shape (3,) for a constant or (h, w, 3) for a
  texture over the mesh UVs, values in [0, 1];
- ``"<material>.specular_reflectance"``: a mirror's or glossy conductor's k_s, shape (3,), in [0, 1];
- ``"<emitter>.emission"``: emitted radiance eps, shape (3,) or (h, w, 3), values >= 0;
- ``"ambient.emission"`` (only when the scene sets one): the ambient radiance eps0 of the Utah,
  Whitted and distributed models, shape (3,), values >= 0;
- ``"<material>.normals"``: the vertex normals of the meshes of a material whose every mesh has
  them, shape (V, 3), unit vectors (rows: those meshes' vertices, meshes in order);
- ``"<material>.normalmap"``: the texels of the normal map a material is wrapped in, (h, w, 3) in
  [0, 1] (the tangent-space normal 2 c - 1).

Material types and their constants (``ior``, ``roughness``) are in ``scene.material_specs``
(:mod:`invrender.scene.materials`).

``render`` reads these tensors at every call, so changing one in place (under ``torch.no_grad()``)
changes the next render.
"""

from __future__ import annotations

import dataclasses
import functools
import threading
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from invrender import validate
from invrender.errors import ParameterError, SceneError, UnknownParameterError, did_you_mean
from invrender.scene.camera import Camera
from invrender.scene.kinds import MIN_NORMAL, NORMALS, kind_of, param_name
from invrender.scene.emitters import Emitter
from invrender.scene.film import FilmOptions
from invrender.scene.materials import Material
from invrender.scene.shapes import Mesh
from invrender.scene.textures import SampledTexture, TextureSampling, VertexAttribute

_DERIVED_LOCK = threading.RLock()

#: largest magnitude of a vertex coordinate: triangles are float32, whose edges and normals overflow
#: or lose every digit far sooner, and Embree traces no ray beyond about 1.8e18 (FLT_LARGE)
MAX_COORDINATE = 1e18

#: the parameter holding the ambient radiance eps0 of the Utah approximation ("ambient" is reserved)
AMBIENT = "ambient.emission"


@dataclass(frozen=True)
class Triangles:
    """Per-triangle geometry, detached, on one device.

    Attributes:
        p0: (T, 3) first vertex.
        e1: (T, 3) edge p1 - p0.
        e2: (T, 3) edge p2 - p0.
        normal: (T, 3) unit geometric normal, on the front side (counter-clockwise winding).
        area: (T,) area.
        uv: (T, 3, 2) texture coordinates at the three vertices.
        material: (T,) int64 index into ``Scene.materials``.
        emitter: (T,) int64 index into ``Scene.emitters``, -1 where the triangle does not emit.
        vertex_normal: (T, 3, 3) unit shading normals at the three vertices, on the front side
            (the geometric normal, three times, where the mesh has none).
        smooth: (T,) bool, True where the triangle shades with interpolated vertex normals.
        sphere: (T,) int64 index into ``spheres`` of the analytic sphere the triangle's mesh is
            inscribed in (:attr:`Mesh.sphere <invrender.scene.shapes.Mesh.sphere>`), -1 for others.
        spheres: (S, 4) float32 rows ``[cx, cy, cz, radius]`` of those spheres, world units.
        vertex: (T, 3) int64 row of each corner in per-vertex parameters (scene vertices numbered
            mesh after mesh, :class:`~invrender.scene.textures.VertexAttribute`).
        normal_row: (T, 3) int64 row of each corner in the scene's vertex normals parameters
            (``"<material>.normals"``, one after another in the order of ``Scene.materials``), -1
            where its material has none; None where no material has them.
    """

    p0: torch.Tensor
    e1: torch.Tensor
    e2: torch.Tensor
    normal: torch.Tensor
    area: torch.Tensor
    uv: torch.Tensor
    material: torch.Tensor
    emitter: torch.Tensor
    vertex_normal: torch.Tensor
    smooth: torch.Tensor
    sphere: torch.Tensor
    spheres: torch.Tensor
    vertex: torch.Tensor
    normal_row: torch.Tensor | None = None

    @property
    def count(self) -> int:
        return int(self.p0.shape[0])

    def to(self, device) -> "Triangles":
        """These triangles on ``device``: ``self`` where they already are, else a copy made once
        and kept (geometry never changes, so a scene rendered on a GPU uploads it once)."""
        device = torch.device(device)
        if device.type == "cuda" and device.index is None:
            device = torch.device("cuda", torch.cuda.current_device())
        if self.p0.device == device:
            return self
        return self.derived(("to", str(device)), lambda: Triangles(*(None if getattr(self, f) is None else getattr(self, f).to(device) for f in self.__dataclass_fields__)))

    def derived(self, key, build):
        """What ``build()`` computes from this geometry, computed once per ``key`` and kept with
        it: copies on other devices, acceleration structures (thread-safe)."""
        cache = self.__dict__.setdefault("_derived", {})  # not a field: frozen, never compared
        if key not in cache:
            with _DERIVED_LOCK:
                if key not in cache:
                    cache[key] = build()
        return cache[key]

    @functools.cached_property
    def packed(self) -> torch.Tensor:
        """(T, 18) float32 rows ``[p0, e1, e2, normal, uv0, uv1, uv2]``: one gather per hit batch."""
        return torch.cat([self.p0, self.e1, self.e2, self.normal, self.uv.reshape(-1, 6)], dim=1)

    @functools.cached_property
    def any_smooth(self) -> bool:
        """Does any triangle shade with vertex normals (else shading skips interpolating them)?"""
        return bool(self.smooth.any())

    def corners(self) -> torch.Tensor:
        """(T, 3, 3) vertex positions."""
        return torch.stack([self.p0, self.p0 + self.e1, self.p0 + self.e2], dim=1)


@dataclass
class Scene:
    """A renderable scene.

    Attributes:
        triangles: per-triangle geometry (see :class:`Triangles`).
        materials: material names; ``triangles.material`` indexes this tuple.
        emitters: emitter names; ``triangles.emitter`` indexes this tuple.
        camera: the camera (pinhole or thin lens).
        resolution: (width, height) in pixels.
        params: ``{"<material>.reflectance": rho, "<emitter>.emission": eps, ...}``, leaf tensors
            (a :class:`Params`: an unknown name raises a ParameterError naming the known ones).
        name: a label for messages and reports.
        material_specs: one :class:`~invrender.scene.materials.Material` per material (type and
            constants; its values live in ``params``); empty = every material diffuse.
        defaults: render settings the scene file suggests, e.g. ``{"spp": 64, "max_depth": 8}``
            (a Mitsuba XML file's ``sample_count``, ``max_depth``, ``rr_depth``); empty = none.
        emitter_specs: one :class:`~invrender.scene.emitters.Emitter` per emitter (type and
            constants; its values live in ``params``); empty = every emitter an area light.
        film: the reconstruction filter and ``sample_border``
            (:class:`~invrender.scene.film.FilmOptions`); the default is the box filter.
        texture_sampling: parameter name -> how its texture is read
            (:class:`~invrender.scene.textures.TextureSampling`: Mitsuba's bitmap ``to_uv``,
            ``filter_type``, ``wrap_mode``); a textured parameter not named reads bilinearly with
            repeat wrapping.
    """

    triangles: Triangles
    materials: tuple[str, ...]
    emitters: tuple[str, ...]
    camera: Camera
    resolution: tuple[int, int]
    params: dict[str, torch.Tensor] = field(default_factory=dict)
    name: str = "scene"
    material_specs: tuple[Material, ...] = ()
    defaults: dict = field(default_factory=dict)
    emitter_specs: tuple[Emitter, ...] = ()
    film: FilmOptions = field(default_factory=FilmOptions)
    texture_sampling: dict[str, TextureSampling] = field(default_factory=dict)

    def __setattr__(self, name, value):
        if name == "params" and not isinstance(value, Params):
            value = Params(value)  # an unknown name's lookup names the closest known one
        super().__setattr__(name, value)

    @property
    def device(self) -> torch.device:
        return self.triangles.p0.device

    @property
    def width(self) -> int:
        return self.resolution[0]

    @property
    def height(self) -> int:
        return self.resolution[1]

    def to(self, device) -> "Scene":
        """This scene on ``device`` (parameters moved as new leaf tensors keeping requires_grad)."""
        params = {k: v.detach().to(device).requires_grad_(v.requires_grad) for k, v in self.params.items()}
        return dataclasses.replace(self, triangles=self.triangles.to(device), params=params)

    def with_resolution(self, resolution) -> "Scene":
        """The same scene (sharing geometry and parameter tensors) at another resolution."""
        return dataclasses.replace(self, resolution=check_resolution(resolution))

    def with_camera(self, camera: Camera) -> "Scene":
        """The same scene (sharing geometry and parameter tensors) seen from another camera."""
        return dataclasses.replace(self, camera=camera)

    def with_ambient(self, eps0) -> "Scene":
        """The same scene (sharing geometry and the other parameters) with ambient radiance ``eps0``
        (an RGB triple or one number, >= 0) in ``params["ambient.emission"]``; None removes it."""
        params = {k: v for k, v in self.params.items() if k != AMBIENT}
        if eps0 is not None:
            params[AMBIENT] = check_param_value(AMBIENT, eps0)
            if params[AMBIENT].ndim != 1:
                raise ParameterError(f"{AMBIENT} must be an RGB triple or one number, not a texture")
        return dataclasses.replace(self, params=params)

    def with_params(self, values: Mapping[str, object] | None = None, *, detach: bool = False) -> "Scene":
        """The same scene (sharing geometry, camera and materials) with some parameters replaced.

        Args:
            values: parameter name -> new value; each name one of ``params`` (the parameters come
                from the scene's materials and emitters; the ambient radiance from
                :meth:`with_ambient`). A floating-point tensor is used as it is, keeping its
                autograd graph, dtype and device (a fit renders at the values it differentiates);
                anything else (an RGB triple, one number, an (h, w, 3) nested list) becomes a float32
                tensor. Either way it is checked as :func:`build_scene` checks a value: shape (3,)
                or (h, w, 3) (one number stands for three), finite, in its kind's range.
            detach: give the new scene parameters of its own: every value, replaced or not, is a
                detached copy (a new leaf that does not require grad), so changing or fitting one
                scene's parameters leaves the other's alone. Without it the parameters not replaced
                are this scene's tensors.
        Raises:
            ParameterError: an unknown name, or a value of the wrong shape, not finite or out of
                its range (one line, naming the parameter).
        """
        values = dict(values or {})
        if values:
            check_names(self.params, list(values), differentiated=False)
        replaced = {k: _checked_value(k, v, self.params[k] if self.params[k].ndim == 2 else None) for k, v in values.items()}
        params = {**self.params, **replaced}
        if detach:
            params = {k: v.detach().clone() for k, v in params.items()}
        return dataclasses.replace(self, params=params)

    def material_spec(self, material: int) -> Material:
        """Type and constants of material ``material`` (an index into ``materials``)."""
        return self.material_specs[material] if self.material_specs else Material()

    def emitter_spec(self, emitter: int) -> Emitter:
        """Type and constants of emitter ``emitter`` (an index into ``emitters``)."""
        return self.emitter_specs[emitter] if self.emitter_specs else Emitter()

    def reflectance_of(self, material: int) -> torch.Tensor:
        """The diffuse reflectance rho of material ``material``; zero for materials without one."""
        key = f"{self.materials[material]}.reflectance"
        return self.params[key] if key in self.params else torch.zeros(3)

    def emission_of(self, emitter: int) -> torch.Tensor:
        return self.params[f"{self.emitters[emitter]}.emission"]


def check_resolution(resolution) -> tuple[int, int]:
    """Validate ``(width, height)``: two positive integers, an image a machine can hold
    (:func:`invrender.validate.check_resolution`)."""
    try:
        w, h = (int(r) for r in resolution)
        ok = all(float(r) == int(r) for r in resolution) and len(tuple(resolution)) == 2
    except (TypeError, ValueError):
        ok = False
    if not ok or w <= 0 or h <= 0:
        raise SceneError(f"resolution must be two positive integers (width, height), got {resolution!r}")
    validate.check_resolution(w, h)
    return w, h


def check_param_value(name: str, value) -> torch.Tensor:
    """Validate one parameter value: shape (3,) or (h, w, 3), finite, in its kind's range. Returns
    it as a new float32 tensor (one number becomes an RGB triple)."""
    try:
        exact = torch.as_tensor(value, dtype=torch.float64).detach()
    except (TypeError, ValueError, RuntimeError):
        raise ParameterError(f"{name}: expected an RGB triple or an (h, w, 3) texture, got {_short(value)}") from None
    if bool(torch.isfinite(exact).all()) and exact.numel() and float(exact.abs().max()) > validate.FLOAT32_MAX:
        raise ParameterError(f"{name}: value {float(exact.abs().max()):g} is beyond float32's range (|x| <= {validate.FLOAT32_MAX:.4g}): a render would compute with infinity")
    t = exact.to(torch.float32)
    if t.ndim == 0:
        t = t.expand(3).clone()
    t = _grey_map(name, t).clone()
    _check_tensor(name, t)
    return t


def _checked_value(name: str, value, per_vertex: torch.Tensor | None = None) -> torch.Tensor:
    """``value`` checked as :func:`check_param_value` checks it; a floating-point tensor is kept as
    it is (its graph, dtype and device; one number is expanded to three), anything else converted.
    ``per_vertex``: the current value of a per-vertex parameter, whose shape the new one keeps."""
    if per_vertex is not None:
        t = value if isinstance(value, torch.Tensor) and value.is_floating_point() else torch.as_tensor(value, dtype=torch.float32)
        if t.shape != per_vertex.shape:
            raise ParameterError(f"{name}: a per-vertex parameter keeps its shape {tuple(per_vertex.shape)}, got {tuple(t.shape)}")
        _check_tensor(name, t.detach(), per_vertex=True)
        return kind_of(name).normalized(t)
    if not (isinstance(value, torch.Tensor) and value.is_floating_point()):
        return check_param_value(name, value)
    t = value.expand(3) if value.ndim == 0 else _grey_map(name, value)
    _check_tensor(name, t.detach())
    return t


def _grey_map(name: str, t: torch.Tensor) -> torch.Tensor:
    """An (h, w) map of a grey kind (a roughness) as its (h, w, 3) texels; anything else as it is."""
    return t[:, :, None].expand(-1, -1, 3) if t.ndim == 2 and kind_of(name).grey and kind_of(name).texture else t


def _check_tensor(name: str, t: torch.Tensor, per_vertex: bool = False) -> None:
    """A :class:`ParameterError` naming ``name`` unless ``t`` is (3,) or (h, w, 3) (or, for a
    ``per_vertex`` parameter, (V, 3) of its V rows), finite, in range."""
    if per_vertex:
        if not (t.ndim == 2 and t.shape[1] == 3):
            raise ParameterError(f"{name}: a per-vertex parameter needs shape (V, 3), got {tuple(t.shape)}")
    elif not (t.shape == (3,) or (t.ndim == 3 and t.shape[2] == 3 and t.shape[0] > 0 and t.shape[1] > 0)):
        raise ParameterError(f"{name}: expected shape (3,) or (h, w, 3), got {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ParameterError(f"{name}: values must be finite")
    kind_of(name).check(name, t)


def _short(value) -> str:
    """``repr(value)`` cut to one short line for a message."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 80 else text[:77] + "..."


def unknown_parameter(name, known, what: str = "unknown parameter") -> UnknownParameterError:
    """The one-line error of a parameter name not among ``known``: the closest known name and the
    list of them."""
    return UnknownParameterError(f"{what} {name!r}{did_you_mean(name, known)} (known: {', '.join(known)})")


class Params(dict):
    """A scene's parameters: name -> tensor. A plain dict, except that looking up a name it does
    not have raises :class:`~invrender.errors.UnknownParameterError` (a ``ParameterError`` and a
    ``KeyError``) naming the closest known name and all of them, not a bare ``KeyError``."""

    def __missing__(self, key):
        raise unknown_parameter(key, self)


def check_names(params, names, differentiated: bool = True) -> list[str]:
    """Validate parameter names against ``params`` (a scene's dict): a list or a comma-separated
    string of names, each known, none twice, at least one, and with ``differentiated`` (names to
    fit or differentiate) none of a kind the renderer reads detached (a mask's opacity). Returns
    the names as a list."""
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    try:
        names = list(names)
    except TypeError:
        names = None
    if names is None or not all(isinstance(n, str) for n in names):
        raise ParameterError(f"parameter names must be a list of names or a comma-separated string, got {names!r:.60}")
    if not names:
        raise ParameterError("no parameters to fit were given")
    unknown = [n for n in names if n not in params]
    if AMBIENT in unknown:
        raise ParameterError(f"the scene has no {AMBIENT} to fit: give it a starting value (--init {AMBIENT}=0.05, a recipe's [init], or load_scene(..., ambient=0.05))")
    if unknown:
        raise unknown_parameter(unknown[0], params)
    if len(set(names)) != len(names):
        raise ParameterError("a parameter is named twice")
    if differentiated:
        for n in names:
            kind = kind_of(n)
            if not kind.differentiable:
                raise ParameterError(f"{n}: the {kind.key} is read detached (it decides visibility, which invrender never differentiates): set it with scene.with_params, it cannot be fitted or differentiated")
    return names


def build_scene(
    meshes: Sequence[Mesh],
    materials: dict[str, object],
    emission: dict[str, object],
    camera: Camera,
    resolution,
    name: str = "scene",
    texture_sampling: Mapping[str, TextureSampling] | None = None,
) -> Scene:
    """Assemble a :class:`Scene` from meshes and named materials and emitters.

    Args:
        meshes: the shapes; each names a material in ``materials`` and optionally an emitter in
            ``emission``.
        materials: material name -> a :class:`~invrender.scene.materials.Material`, or just a
            diffuse reflectance rho (an RGB triple, one number or an (h, w, 3) texture).
        emission: emitter name -> an :class:`~invrender.scene.emitters.Emitter`, or just the eps
            of an area light (an RGB triple or an (h, w, 3) texture).
        texture_sampling: parameter name -> how its texture is read (``Scene.texture_sampling``).

    A material's value may be a :class:`~invrender.scene.textures.VertexAttribute`: the parameter
    becomes (V, 3), one row per scene vertex (meshes in order), filled from the attribute of each
    mesh that uses the material (zero elsewhere).
    Raises:
        SceneError: unknown material or emitter names, bad indices, no triangles.
        ParameterError: a value outside its kind's range.
    """
    resolution = check_resolution(resolution)
    overlap = set(materials) & set(emission)
    if "ambient" in set(materials) | set(emission):
        raise SceneError("'ambient' is reserved for the ambient radiance eps0: name the material or emitter otherwise")
    if overlap:
        raise SceneError(f"names used both as material and emitter: {', '.join(sorted(overlap))}")
    specs = {k: v if isinstance(v, Material) else Material(values={"reflectance": v}) for k, v in materials.items()}
    material_names = tuple(materials)
    emitters = tuple(emission)
    texture_sampling = dict(texture_sampling or {})
    per_vertex = {param_name(k, key): (k, v) for k, m in specs.items() for key, v in m.values.items() if isinstance(v, VertexAttribute)}
    texture_sampling.update({param_name(k, key): v.sampling for k, m in specs.items() for key, v in m.values.items() if isinstance(v, SampledTexture)})
    params = {
        param_name(k, key): _plugin_value(m, k, key, v.texels if isinstance(v, SampledTexture) else v)
        for k, m in specs.items() for key, v in m.values.items() if not isinstance(v, VertexAttribute)
    }  # fmt: skip
    emitter_specs = {k: v if isinstance(v, Emitter) else Emitter(values={"emission": v}) for k, v in emission.items()}
    for k, e in emitter_specs.items():
        for key, v in e.values.items():
            if isinstance(v, VertexAttribute):
                raise SceneError(f"{param_name(k, key)}: per-vertex values (vertex attribute {v.name!r}) are supported for material parameters only")
            if isinstance(v, SampledTexture) or param_name(k, key) in texture_sampling:
                raise SceneError(f"{param_name(k, key)}: texture options (to_uv, filter, wrap) are supported for material parameters only; an emitter's texture reads bilinearly with repeat wrapping")
    for n in texture_sampling:
        if n not in params:
            raise SceneError(f"texture options for {n!r}, which is not a textured material parameter")
    params.update({param_name(k, key): _plugin_value(e, k, key, v) for k, e in emitter_specs.items() for key, v in e.values.items()})

    tris, uvs, mats, emits, normals, smooth, sphere_of, spheres, rows = [], [], [], [], [], [], [], [], []
    unit_normals, faces = [], []  # per mesh: its unit vertex normals (V, 3) or None, its faces
    first_vertex = 0
    for mesh in meshes:
        if mesh.material not in materials:
            raise SceneError(f"shape uses unknown material {mesh.material!r} (known: {', '.join(material_names) or 'none'})")
        if mesh.emitter is not None and mesh.emitter not in emission:
            raise SceneError(f"shape uses unknown emitter {mesh.emitter!r} (known: {', '.join(emitters) or 'none'})")
        if mesh.emitter is not None and not emitter_specs[mesh.emitter].spec.surface:
            cls = emitter_specs[mesh.emitter].spec
            what = "emits from outside the scene, not from shapes" if cls.infinite else "is a point or a direction (a delta light), not emitted by shapes"
            raise SceneError(f"shape names emitter {mesh.emitter!r} of type {emitter_specs[mesh.emitter].type!r}, which {what}")
        v = np.asarray(mesh.vertices, dtype=np.float64)
        f = np.asarray(mesh.faces)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise SceneError(f"mesh arrays must be vertices (V, 3) and faces (F, 3), got {v.shape} and {f.shape}")
        if not np.isfinite(v).all():
            raise SceneError("mesh has non-finite vertex positions")
        if v.size and np.abs(v).max() > MAX_COORDINATE:
            raise SceneError(f"mesh of material {mesh.material!r} has vertex coordinates up to {np.abs(v).max():.3g}, beyond +-{MAX_COORDINATE:g} (float32 geometry)")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise SceneError(f"mesh face index out of range: indices must be in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
        uv = np.zeros((len(v), 2)) if mesh.uvs is None else np.asarray(mesh.uvs, dtype=np.float64)
        if uv.shape != (len(v), 2):
            raise SceneError(f"mesh uvs must have shape ({len(v)}, 2), got {uv.shape}")
        tris.append(v[f])
        uvs.append(uv[f])
        rows.append(f + first_vertex)
        first_vertex += len(v)
        if mesh.normals is not None:
            vn = np.asarray(mesh.normals, dtype=np.float64)
            if vn.shape != (len(v), 3) or not np.isfinite(vn).all():
                raise SceneError(f"mesh normals must be finite with shape ({len(v)}, 3), got {vn.shape}")
            unit = vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
            normals.append(unit[f])
            unit_normals.append(unit)
        else:
            normals.append(None)
            unit_normals.append(None)
        faces.append(f)
        smooth.append(np.full(len(f), mesh.normals is not None))
        mats.append(np.full(len(f), material_names.index(mesh.material)))
        emits.append(np.full(len(f), -1 if mesh.emitter is None else emitters.index(mesh.emitter)))
        inscribed = mesh.sphere is not None and np.linalg.norm(v - mesh.sphere[0], axis=1).max() <= mesh.sphere[1] * (1 + 1e-6)
        sphere_of.append(np.full(len(f), len(spheres) if inscribed else -1))
        if inscribed:
            spheres.append([*mesh.sphere[0], mesh.sphere[1]])
    if not tris or sum(len(t) for t in tris) == 0:
        raise SceneError("scene has no triangles")
    for n, (material, attribute) in per_vertex.items():
        params[n] = _vertex_param(n, material, attribute, meshes, first_vertex)
    normal_rows = _normal_params(params, material_names, meshes, unit_normals, faces)
    for k, m in specs.items():
        if m.perturbation is not None and m.perturbation.kind == "normalmap":
            params[param_name(k, "normalmap")] = check_param_value(param_name(k, "normalmap"), m.perturbation.texture)

    corners = np.concatenate(tris)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    extent = np.ptp(corners.reshape(-1, 3), axis=0).max()
    keep = area > 1e-12 * max(extent, 1e-30) ** 2
    if not keep.all():
        warnings.warn(f"dropped {int((~keep).sum())} degenerate triangle(s) of zero area", stacklevel=2)
    if not keep.any():
        raise SceneError("scene has only degenerate (zero-area) triangles")

    def t(a, dtype=torch.float32):
        return torch.as_tensor(np.ascontiguousarray(a[keep]), dtype=dtype)

    geometric = cross / np.maximum(2 * area, 1e-300)[:, None]
    counts = np.cumsum([0] + [len(c) for c in tris])
    vertex_normal = np.repeat(geometric[:, None, :], 3, axis=1)
    for i, vn in enumerate(normals):
        if vn is not None:
            vertex_normal[counts[i] : counts[i + 1]] = vn

    triangles = Triangles(
        p0=t(corners[:, 0]),
        e1=t(corners[:, 1] - corners[:, 0]),
        e2=t(corners[:, 2] - corners[:, 0]),
        normal=t(geometric),
        area=t(area),
        uv=t(np.concatenate(uvs)),
        material=t(np.concatenate(mats), torch.int64),
        emitter=t(np.concatenate(emits), torch.int64),
        vertex_normal=t(vertex_normal),
        smooth=t(np.concatenate(smooth), torch.bool),
        sphere=t(np.concatenate(sphere_of), torch.int64),
        spheres=torch.tensor(spheres, dtype=torch.float32).reshape(-1, 4),
        vertex=t(np.concatenate(rows), torch.int64),
        normal_row=None if normal_rows is None else t(normal_rows, torch.int64),
    )
    specs_only = tuple(dataclasses.replace(m, values={}) for m in specs.values())
    emitters_only = tuple(Emitter(e.type, {}, e.constants) for e in emitter_specs.values())
    if all(e.type == Emitter.default_type and not e.constants for e in emitters_only):
        emitters_only = ()  # every emitter an area light: the default
    return Scene(triangles, material_names, emitters, camera, resolution, params, name, specs_only, emitter_specs=emitters_only, texture_sampling=texture_sampling)


def _vertex_param(name: str, material: str, vertex_attribute: VertexAttribute, meshes: Sequence[Mesh], count: int) -> torch.Tensor:
    """The (count, 3) per-vertex parameter ``name`` of ``material``: the attribute (times its scale)
    of each mesh that uses the material at its vertices' rows, zero elsewhere; checked in its
    kind's range."""
    attribute = vertex_attribute.name
    out = np.zeros((count, 3))
    first = 0
    for mesh in meshes:
        v = len(mesh.vertices)
        if mesh.material == material:
            have = mesh.attributes or {}
            if attribute not in have:
                raise SceneError(f"{name} reads vertex attribute {attribute!r}, which a mesh using material {material!r} lacks (it has: {', '.join(have) or 'none'})")
            a = np.asarray(have[attribute], dtype=np.float64)
            a = a.reshape(len(a), -1)
            if a.shape not in ((v, 1), (v, 3)):
                raise SceneError(f"{name}: vertex attribute {attribute!r} must have 1 or 3 values per vertex for {v} vertices, got shape {a.shape}")
            out[first : first + v] = np.broadcast_to(a, (v, 3)) * vertex_attribute.scale
        first += v
    t = torch.as_tensor(out, dtype=torch.float32)
    _check_tensor(name, t, per_vertex=True)
    return t


def _normal_params(params: dict, materials: Sequence[str], meshes: Sequence[Mesh], unit_normals: list, faces: list) -> np.ndarray | None:
    """Add ``"<material>.normals"`` to ``params`` for each material whose every mesh carries
    vertex normals (each of length >= :data:`~invrender.scene.kinds.MIN_NORMAL`; a mesh file's
    zero normal leaves its material without the parameter): (V, 3) float32, the meshes' unit
    normals one mesh after another, the same floats the triangles' ``vertex_normal`` holds.
    Returns each triangle's corner rows in them (:attr:`Triangles.normal_row`: (T, 3), -1 for
    the other materials), or None where no material has them."""
    corner_rows = [np.full((len(f), 3), -1, dtype=np.int64) for f in faces]
    offset = 0
    for material in materials:
        members = [i for i, mesh in enumerate(meshes) if mesh.material == material]
        if not members or any(unit_normals[i] is None or (np.linalg.norm(unit_normals[i], axis=1) < MIN_NORMAL).any() for i in members):
            continue
        for i in members:
            corner_rows[i] = faces[i] + offset
            offset += len(unit_normals[i])
        params[param_name(material, NORMALS)] = torch.as_tensor(np.concatenate([unit_normals[i] for i in members]), dtype=torch.float32)
    return np.concatenate(corner_rows) if offset else None


def _plugin_value(spec, owner: str, key: str, value) -> torch.Tensor:
    """Parameter ``key`` of the material or emitter ``owner`` (its :class:`PluginSpec` ``spec``),
    checked as :func:`check_param_value` checks it and refused as a texture where its type
    declares it RGB only."""
    name = param_name(owner, key)
    t = check_param_value(name, value)
    declared = spec.spec.params.get(key)
    if t.ndim == 3 and declared is not None and not declared.kind.texture:
        raise ParameterError(f"{name}: a {spec.type} {spec.noun}'s {key} must be an RGB triple, not a texture")
    return t


def scene_extent(triangles: Triangles) -> float:
    """Largest side of the scene's bounding box (for ray offsets; computed once per geometry)."""

    def extent() -> float:
        c = triangles.corners().reshape(-1, 3)
        return float((c.max(0).values - c.min(0).values).max())

    return triangles.derived("extent", extent)
