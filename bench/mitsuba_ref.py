"""Mitsuba 3 as an optional reference: the Cornell box, and any invrender scene converted to
Mitsuba, rendered and timed by Mitsuba.

Nothing here is needed by invrender or its tests, and nothing here imports invrender (the converter
reads a ``Scene``'s attributes). The module imports without Mitsuba; ``available()`` says whether it
can be used (``False`` on any failure).

Install (Debian bookworm; Mitsuba's LLVM CPU variant needs a libLLVM newer than bookworm's default
15, whose code generator aborts the process on Mitsuba 3.9.1's kernels)::

    apt-get update && apt-get install -y libllvm19
    pip install mitsuba==3.9.1 drjit           # drjit 1.5.0 came with it; do not reinstall torch
    export DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so   # optional: set below if unset

API (all renders use the ``llvm_ad_rgb`` variant, independent sampler, box pixel filter)::

    available() -> bool
    version() -> str
    label() -> str                                  "Mitsuba 3.9.1 llvm_ad_rgb", for printed headers
    cornell_scene(width, height, spp, max_depth, filter="box", integrator="path") -> mi.Scene
        Mitsuba's own cornell_box()
    scene_dict(scene, spp, max_depth, filter="box", integrator="path") -> dict for mi.load_dict
        any invrender Scene (meshes, materials, area lights, pinhole or thin-lens camera)
    load_scene(scene, spp, max_depth, filter="box", integrator="path") -> mi.Scene
    plugin_dict(plugin_class, values, constants) -> dict;  sensor_dict(camera, width, height, spp) -> dict
    render(scene, spp, seed=0) -> np.ndarray float32 (H, W, 3), linear RGB
    render_cornell(width, height, spp, max_depth, seed=0) -> np.ndarray float32 (H, W, 3)
    time_render(scene, spp, seed=0) -> seconds of one render
    time_forward(width, height, spp, max_depth, repeats) -> [seconds per render]
    gradient_in_process(width, height, spp, max_depth, integrator, params, repeats, seed, perturb)
        -> dict(seconds=..., peak_rss_mib=..., ...), in this process
    time_gradient(width=128, height=128, spp=64, max_depth=8, integrator="prb",
                  params=("white", "red", "green", "light")) -> the same dict, from a fresh subprocess

Command line (from the repository root)::

    python bench/mitsuba_ref.py forward [--resolution 128 --spp 64 --max-depth 8 --repeats 5]
    python bench/mitsuba_ref.py means [--resolution 64 --spp 4096 --max-depth 8 2 1 --write PATH]
    python bench/mitsuba_ref.py grad [--integrator prb|path --resolution 128 --spp 64 --max-depth 8]

The converter (``scene_dict``) maps each invrender material by its type's ``to_mitsuba`` (in the
material's module of ``invrender/plugins/bsdfs/``: the two-sided ones wrapped in ``twosided``, colours
as ``rgb``, textures as linear ``bitmap`` (raw, bilinear, repeat)), and the rest as follows:

    emitter     -> area(radiance = rgb) on the mesh (one-sided, the front = counter-clockwise side);
                   emitters that are not surfaces (constant, envmap, point, spot, projector,
                   directional) by their type's to_mitsuba, at the scene's top level
    camera      -> perspective or thinlens (aperture_radius, focus_distance), fov and fov_axis,
                   to_world = look_at(origin, target, up); hdrfilm with the scene's resolution

Validated on the Cornell box against ``cornell_scene`` (channel means agree to +0.03..+0.05% +- 0.03..0.06%
at max_depth 8, 2, 1; red wall on the left in both) and, with a texture on the white walls, for
texture orientation (bench/README.md).

Dr.Jit evaluates lazily and asynchronously, so every render and every timing ends with
``dr.eval(...); dr.sync_thread()`` before the result is read or the clock is stopped.
"""

from __future__ import annotations

import contextlib

import glob
import json
import os
import re
import statistics
import sys
import time

import _measure

VARIANT = "llvm_ad_rgb"
MIN_LLVM = 16  # libLLVM 15.0.6 (bookworm's default) aborts in instruction selection on Mitsuba 3.9.1

# Names of the differentiable Cornell-box parameters and their keys in ``mi.traverse(scene)``.
# mi.traverse(mi.load_dict(mi.cornell_box())).keys() with Mitsuba 3.9.1 (llvm_ad_rgb):
#   allow_thread_reordering, sensor.near_clip, sensor.far_clip, sensor.shutter_open,
#   sensor.shutter_open_time, sensor.film.size, sensor.film.crop_size, sensor.film.crop_offset,
#   sensor.x_fov, sensor.principal_point_offset_x, sensor.principal_point_offset_y, sensor.to_world,
#   white.reflectance.value, green.reflectance.value, red.reflectance.value,
#   red-wall.silhouette_sampling_weight, red-wall.to_world, green-wall.silhouette_sampling_weight,
#   green-wall.to_world, object_<id>.{silhouette_sampling_weight,faces,vertex_positions,
#   vertex_normals,vertex_texcoords}, light.emitter.sampling_weight, light.emitter.radiance.value,
#   light.silhouette_sampling_weight, light.to_world
PARAM_KEYS = {
    "white": "white.reflectance.value",
    "red": "red.reflectance.value",
    "green": "green.reflectance.value",
    "light": "light.emitter.radiance.value",
}

_mi = _dr = None


def _llvm_candidates() -> list[str]:
    """Shared libLLVM files on this machine, newest version first."""
    found = glob.glob("/usr/lib/llvm-*/lib/libLLVM*.so*") + glob.glob("/usr/lib/x86_64-linux-gnu/libLLVM*.so*")
    ranked = []
    for path in set(found):
        name = os.path.basename(path)
        # libLLVM-19.so, libLLVM.so.19.1, libLLVM-14.0.6.so.1; a bare libLLVM.so takes its folder's version.
        m = re.match(r"libLLVM(?:-(\d+)[.\d]*\.so(?:\.[\d.]+)?|\.so\.(\d+)[.\d]*)$", name)
        if m:
            major = int(m.group(1) or m.group(2))
        elif name == "libLLVM.so" and (d := re.search(r"llvm-(\d+)", path)):
            major = int(d.group(1))
        else:
            continue  # static archives of components (libLLVMX86CodeGen.a ...) and the like
        ranked.append((major, len(name), path))
    ranked.sort(key=lambda t: (-t[0], t[1], t[2]))  # newest first; for one version, the shortest name
    return [p for _, _, p in ranked]


def available() -> bool:
    """True when Mitsuba 3 imports and its ``llvm_ad_rgb`` variant can be set; never raises.

    Sets ``DRJIT_LIBLLVM_PATH`` to the newest libLLVM found when it is unset (before importing
    Mitsuba), and answers False when Dr.Jit ends up on a libLLVM older than ``MIN_LLVM``.
    """
    global _mi, _dr
    if _mi is not None:
        return True
    try:
        if not os.environ.get("DRJIT_LIBLLVM_PATH"):
            candidates = _llvm_candidates()
            if candidates:
                os.environ["DRJIT_LIBLLVM_PATH"] = candidates[0]
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(VARIANT)
        llvm = getattr(getattr(dr, "detail", None), "llvm_version", None)
        if llvm is not None and llvm()[0] < MIN_LLVM:
            return False
    except BaseException:  # ImportError, missing libLLVM, anything: Mitsuba is optional
        return False
    _mi, _dr = mi, dr
    return True


def version() -> str:
    return _mi.__version__ if available() else "unavailable"


def label() -> str:
    """``"Mitsuba <version> llvm_ad_rgb"``: how the scripts name this reference in their output."""
    return f"Mitsuba {version()} {VARIANT}"


def _require():
    if not available():
        raise RuntimeError("Mitsuba 3 (llvm_ad_rgb) is not available; see bench/mitsuba_ref.py for the install steps")
    return _mi, _dr


def cornell_scene(width: int, height: int, spp: int, max_depth: int, filter: str = "box", integrator: str = "path"):
    """Mitsuba's own ``cornell_box()``: ``width`` x ``height`` film with a ``filter`` pixel filter,
    independent sampler at ``spp``, integrator ``{'type': integrator, 'max_depth': max_depth}``."""
    mi, _ = _require()
    d = mi.cornell_box()
    film = d["sensor"]["film"]
    film["width"], film["height"] = int(width), int(height)
    film["rfilter"] = {"type": filter}
    d["sensor"]["sampler"]["sample_count"] = int(spp)
    d["integrator"] = {"type": integrator, "max_depth": int(max_depth)}
    return mi.load_dict(d)


# ---------------------------------------------------------------------------------------------
# invrender Scene -> Mitsuba scene dict (duck-typed: reads the Scene's attributes, imports nothing
# of invrender)
# ---------------------------------------------------------------------------------------------


def _np(t):
    """A torch tensor (or anything array-like) as a float64/int numpy array on the CPU."""
    import numpy as np

    if hasattr(t, "detach"):
        t = t.detach().cpu().numpy()
    return np.asarray(t)


def _rgb_or_bitmap(value, what: str):
    """A Mitsuba texture dict for an invrender colour: (3,) -> ``rgb``; (h, w, 3) -> a linear
    ``bitmap`` (``raw=True``: no sRGB decoding; bilinear, repeat wrapping, as invrender's lookup)."""
    mi, _ = _require()
    import numpy as np

    v = _np(value).astype(np.float32)
    if v.ndim == 1:
        return {"type": "rgb", "value": [float(x) for x in v]}
    if v.ndim == 3 and v.shape[2] == 3:
        # Row 0 of invrender's texture is its top (v = 1); Mitsuba's bitmap puts row 0 at v = 0, so
        # the meshes carry v' = 1 - v (see _mesh) and the image is passed unflipped.
        bitmap = mi.Bitmap(np.ascontiguousarray(v))
        return {"type": "bitmap", "bitmap": bitmap, "raw": True, "filter_type": "bilinear", "wrap_mode": "repeat"}
    raise ValueError(f"{what}: expected an RGB triple or an (h, w, 3) texture, got shape {v.shape}")


def plugin_dict(plugin, values: dict, constants: dict, name: str = "material") -> dict:
    """The Mitsuba dict of one invrender material or emitter.

    ``plugin``: the type's class (``scene.material_spec(i).spec``, ``scene.emitter_spec(i).spec``),
    whose ``to_mitsuba(values, constants)`` gives the dict with invrender's values in it;
    ``values``: parameter key -> tensor ((3,) or (h, w, 3)); ``constants``: constant key -> float.
    Each tensor in the dict becomes an ``rgb`` or ``bitmap`` texture, and a ``to_world`` matrix
    (4, 4) a ``ScalarTransform4f``.
    """
    to_mitsuba = getattr(plugin, "to_mitsuba", None)
    if to_mitsuba is None:
        raise ValueError(f"{name!r}: no Mitsuba counterpart for type {getattr(plugin, 'type_name', plugin)!r}")

    def convert(k: str, v):
        if isinstance(v, dict):
            return textures(v)
        if k == "bitmap" and hasattr(v, "shape"):  # an envmap's map: an mi.Bitmap itself, row 0 at the top (theta = 0) as invrender's
            import numpy as np

            mi, _ = _require()
            return mi.Bitmap(np.ascontiguousarray(_np(v).astype(np.float32)))
        if k == "to_world":  # a (4, 4) matrix or nested list (an envmap's rotation, a spot light's frame)
            mi, _ = _require()
            return mi.ScalarTransform4f([[float(x) for x in row] for row in _np(v)])
        return _rgb_or_bitmap(v, f"{name}.{k}") if hasattr(v, "shape") else v

    def textures(d: dict) -> dict:
        return {k: convert(k, v) for k, v in d.items()}

    return textures(to_mitsuba(values, constants))


def sensor_dict(camera, width: int, height: int, spp: int, filter: str = "box", extent: float = 10.0) -> dict:
    """The Mitsuba sensor of an invrender ``Camera``: ``perspective`` (pinhole) or ``thinlens``.

    ``look_at(origin, target, up)`` gives the camera frame (left = up x forward, up, forward);
    Mitsuba's image x grows along local -x = forward x up, which is invrender's image x, and its
    rows grow downwards, as invrender's do (checked on the Cornell box: the red wall on the left).
    """
    mi, _ = _require()
    if float(getattr(camera, "pixel_aspect", 1.0)) != 1.0:
        raise ValueError(f"Mitsuba's sensors have square pixels: cannot convert pixel_aspect {camera.pixel_aspect:g}")
    d = {
        "type": "perspective" if float(camera.aperture_radius) == 0.0 else "thinlens",
        "fov": float(camera.fov),
        "fov_axis": str(camera.fov_axis),
        "to_world": mi.ScalarTransform4f().look_at(origin=list(camera.origin), target=list(camera.target), up=list(camera.up)),
        "near_clip": 1e-4,
        "far_clip": max(1e4, 100.0 * extent),
        "sampler": {"type": "independent", "sample_count": int(spp)},
        "film": {
            "type": "hdrfilm",
            "width": int(width),
            "height": int(height),
            "rfilter": {"type": filter},
            "pixel_format": "rgb",
            "component_format": "float32",
        },
    }
    if d["type"] == "thinlens":
        d["aperture_radius"] = float(camera.aperture_radius)
        d["focus_distance"] = float(camera.focus_distance)
    ox, oy = (float(x) for x in getattr(camera, "principal_point_offset", (0.0, 0.0)))
    if (ox, oy) != (0.0, 0.0):  # the same meaning in both (docs/cameras.md); thinlens has none
        d["principal_point_offset_x"], d["principal_point_offset_y"] = ox, oy
    return d


def _mesh(name: str, corners, normals, uvs, bsdf: dict, emitter: dict | None):
    """A ``mi.Mesh`` of T triangles with unshared vertices (3 per triangle, in corner order).

    ``corners`` (T, 3, 3) positions; ``normals`` (T, 3, 3) per-corner shading normals or None (flat:
    Mitsuba then shades with the face normal); ``uvs`` (T, 3, 2) invrender UVs or None (stored as
    (u, 1 - v), see _rgb_or_bitmap).
    """
    mi, _ = _require()
    import numpy as np

    t = corners.shape[0]
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    if emitter is not None:
        props["emitter"] = mi.load_dict(emitter)
    mesh = mi.Mesh(name, 3 * t, t, has_vertex_normals=normals is not None, has_vertex_texcoords=uvs is not None, props=props)
    p = mi.traverse(mesh)
    p["vertex_positions"] = mi.Float(np.ascontiguousarray(corners.reshape(-1), dtype=np.float32))
    p["faces"] = mi.UInt32(np.arange(3 * t, dtype=np.uint32))
    if normals is not None:
        p["vertex_normals"] = mi.Float(np.ascontiguousarray(normals.reshape(-1), dtype=np.float32))
    if uvs is not None:
        uv = np.array(uvs, dtype=np.float32).reshape(-1, 2)
        uv[:, 1] = 1.0 - uv[:, 1]
        p["vertex_texcoords"] = mi.Float(np.ascontiguousarray(uv.reshape(-1)))
    p.update()
    return mesh


def scene_dict(scene, spp: int, max_depth: int, filter: str = "box", integrator: str = "path") -> dict:
    """A Mitsuba scene dict (``mi.load_dict`` it) for an invrender ``Scene``.

    One ``mi.Mesh`` per (material, emitter, smooth) group of ``scene.triangles``, with unshared
    vertices ``p0, p0 + e1, p0 + e2`` (the winding, hence the front side, kept); smooth triangles
    carry their per-corner ``vertex_normal`` and flat ones none (Mitsuba meshes have per-vertex
    normals or none, so the two kinds go in different meshes); UVs only where the material has a
    texture. Materials and emitters map as ``plugin_dict`` says (area lights one-sided, with an RGB
    ``radiance`` (emission textures are not converted: ``ValueError``), the camera as
    ``sensor_dict`` says, with an ``hdrfilm`` of the scene's resolution and a ``filter`` pixel
    filter, an ``independent`` sampler at ``spp`` and ``{'type': integrator, 'max_depth': ...}``.
    The ambient radiance (``ambient.emission``) of invrender's Utah-style models has no
    counterpart and is ignored (the ``path`` integrator ignores it too).
    """
    import numpy as np

    _require()
    tris = scene.triangles
    corners = np.stack([_np(tris.p0), _np(tris.p0) + _np(tris.e1), _np(tris.p0) + _np(tris.e2)], axis=1).astype(np.float64)
    vnormal = _np(tris.vertex_normal)
    uv = _np(tris.uv)
    material = _np(tris.material).astype(np.int64)
    emitter = _np(tris.emitter).astype(np.int64)
    smooth = _np(tris.smooth).astype(bool)
    params = scene.params

    bsdfs, textured = [], []
    for i, name in enumerate(scene.materials):
        spec = scene.material_spec(i)
        values = {key: params[f"{name}.{key}"] for key in spec.spec.params}
        bsdf = plugin_dict(spec.spec, values, dict(spec.constants), name)
        if spec.one_sided and bsdf.get("type") == "twosided":  # black from behind, as the XML file said
            bsdf = bsdf["bsdf"]
        bsdfs.append(bsdf)
        textured.append(any(_np(v).ndim == 3 for v in values.values()))
    emitters = []  # per scene emitter (indexed by triangles.emitter)
    for i, name in enumerate(scene.emitters):
        spec = scene.emitter_spec(i)
        values = {key: params[f"{name}.{key}"] for key in spec.spec.params}
        if spec.spec.surface and any(_np(v).ndim != 1 for v in values.values()):  # an envmap's map is a bitmap
            raise ValueError(f"emitter {name!r}: emission textures are not converted to Mitsuba (give an RGB emission)")
        emitters.append(plugin_dict(spec.spec, values, dict(spec.constants), name))

    extent = float(np.ptp(corners.reshape(-1, 3), axis=0).max())
    d = {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": int(max_depth)},
        "sensor": sensor_dict(scene.camera, scene.width, scene.height, spp, filter, extent),
    }
    for i, name in enumerate(scene.emitters):
        if not scene.emitter_spec(i).spec.surface:  # emitters of the scene itself (skies), not of a mesh
            d[name] = emitters[i]
    groups = sorted({(int(m), int(e), bool(s)) for m, e, s in zip(material, emitter, smooth)})
    for m, e, s in groups:
        sel = (material == m) & (emitter == e) & (smooth == s)
        label = f"{scene.materials[m]}" + (f"+{scene.emitters[e]}" if e >= 0 else "") + ("-smooth" if s else "")
        d[label] = _mesh(
            label,
            corners[sel],
            vnormal[sel] if s else None,
            uv[sel] if textured[m] else None,
            bsdfs[m],
            emitters[e] if e >= 0 else None,
        )
    return d


def load_scene(scene, spp: int, max_depth: int, filter: str = "box", integrator: str = "path"):
    """``mi.load_dict(scene_dict(...))``: the loaded Mitsuba scene of an invrender ``Scene``."""
    mi, _ = _require()
    return mi.load_dict(scene_dict(scene, spp, max_depth, filter, integrator))


@contextlib.contextmanager
def whole_pool():
    """Within the block, Dr.Jit's thread pool has one thread per core, whatever a caller left it
    at (invrender empties it while one of its renders runs, and gives it back after:
    :func:`invrender.core.compiled.in_calling_threads`)."""
    _, dr = _require()
    before = dr.thread_count()
    dr.set_thread_count(len(os.sched_getaffinity(0)))
    try:
        yield
    finally:
        dr.set_thread_count(before)


def _render_synced(scene, spp: int, seed: int):
    """``mi.render`` of a loaded scene (a Dr.Jit tensor), evaluated and finished (:func:`whole_pool`)."""
    mi, dr = _require()
    with whole_pool():
        img = mi.render(scene, spp=spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
    return img


def render(scene, spp: int, seed: int = 0):
    """(H, W, 3) numpy float32 linear RGB of a loaded scene, evaluated and synchronized."""
    return _render_synced(scene, spp, seed).numpy()[..., :3].astype("float32", copy=False)


def render_cornell(width: int, height: int, spp: int, max_depth: int, seed: int = 0):
    """(H, W, 3) numpy float32 linear RGB of the box-filtered Cornell box (``path`` integrator)."""
    return render(cornell_scene(width, height, spp, max_depth), spp, seed)


def time_render(scene, spp: int, seed: int = 0) -> float:
    """Seconds for one forward render of a loaded scene, the clock stopped after Dr.Jit has finished."""
    start = time.perf_counter()
    _render_synced(scene, spp, seed)
    return time.perf_counter() - start


def time_forward(width: int, height: int, spp: int, max_depth: int, repeats: int) -> list[float]:
    """Seconds of each of ``repeats`` forward renders (seeds 1..repeats) after one warm-up render
    (seed 0), which compiles the kernels. Path samples per second: width*height*spp / seconds."""
    scene = cornell_scene(width, height, spp, max_depth)
    time_render(scene, spp, seed=0)
    return [time_render(scene, spp, seed=i + 1) for i in range(repeats)]


def cuda_forward(n: int, spp: int, max_depth: int, repeats: int) -> str:
    """One line: Mitsuba's own Cornell box on ``cuda_ad_rgb`` (median of ``repeats`` after a
    warm-up), or why it could not run. Switches this process's variant to ``cuda_ad_rgb`` and back."""
    mi, dr = _require()
    try:
        mi.set_variant("cuda_ad_rgb")
    except BaseException as e:  # no CUDA driver, a build without the variant
        return f"  Mitsuba cuda_ad_rgb unavailable: {e}"
    try:
        scene = cornell_scene(n, n, spp, max_depth)
        time_render(scene, spp, seed=0)
        t = sorted(time_render(scene, spp, seed=i + 1) for i in range(repeats))[repeats // 2]
        return f"  Mitsuba {version()} cuda_ad_rgb path:   {t:7.3f} s  {n * n * spp / t / 1e6:.3f} M path samples/s"
    finally:
        mi.set_variant(VARIANT)


def gradient_in_process(width, height, spp, max_depth, integrator, params, repeats, seed, perturb) -> dict:
    """Gradient of mean((render - target)^2) w.r.t. the named parameters, timed in this process.

    The target is rendered once at the same settings (seed ``seed + 1000``) with the scene's own
    values; the differentiated values are then multiplied by ``perturb`` (1.0: unchanged). One
    warm-up gradient compiles the kernels; ``repeats`` timed ones follow (seeds seed+1, ...).
    ``peak_rss_mib`` is this process's peak so far (``_measure.peak_rss_mib``), so it counts whatever
    the caller held before; ``time_gradient`` runs this in a fresh process and describes the dict.
    """
    mi, dr = _require()
    scene = cornell_scene(width, height, spp, max_depth, integrator=integrator)
    target = _render_synced(scene, spp, seed + 1000)
    p = mi.traverse(scene)
    unknown = [n for n in params if n not in PARAM_KEYS or PARAM_KEYS[n] not in p]
    if unknown:
        raise KeyError(f"unknown Cornell-box parameters {unknown}; known: {sorted(PARAM_KEYS)}")
    keys = [PARAM_KEYS[n] for n in params]
    for k in keys:
        if perturb != 1.0:
            p[k] = p[k] * perturb
        dr.enable_grad(p[k])
    p.update()

    def once(s):
        for k in keys:
            dr.clear_grad(p[k])
        start = time.perf_counter()
        with whole_pool():
            img = mi.render(scene, p, spp=spp, seed=s)
            loss = dr.mean(dr.square(img - target), axis=None)
            dr.backward(loss)
            grads = [dr.grad(p[k]) for k in keys]
            dr.eval(loss, *grads)
            dr.sync_thread()
        seconds = time.perf_counter() - start
        return seconds, float(loss.array[0] if hasattr(loss, "array") else loss[0]), grads

    warmup, _, _ = once(seed)
    runs = [once(seed + 1 + i) for i in range(repeats)]
    times = [r[0] for r in runs]
    _, loss, grads = runs[-1]
    return {
        "seconds": statistics.median(times),
        "all_seconds": times,
        "warmup_seconds": warmup,
        "peak_rss_mib": _measure.peak_rss_mib(),
        "loss": loss,
        "grads": {n: [float(v) for v in g.numpy().ravel()] for n, g in zip(params, grads)},
        "integrator": integrator,
        "width": width,
        "height": height,
        "spp": spp,
        "max_depth": max_depth,
        "mitsuba": mi.__version__,
        "variant": VARIANT,
    }


def time_gradient(
    width: int = 128,
    height: int = 128,
    spp: int = 64,
    max_depth: int = 8,
    integrator: str = "prb",
    params=("white", "red", "green", "light"),
    repeats: int = 1,
    seed: int = 0,
    perturb: float = 1.0,
    timeout: float = 1800,
) -> dict:
    """Time one gradient of an L2 loss against a fixed target w.r.t. the white, red, green
    reflectances and the light's radiance, in a fresh subprocess so that ``peak_rss_mib`` (the
    child's ``VmHWM``) counts this gradient, Mitsuba and Python, not the caller.

    ``integrator``: ``"prb"`` (``mi.ad.integrators`` path replay) or ``"path"`` (plain AD through
    the C++ path tracer). Returns ``dict(seconds=median of the timed gradients, peak_rss_mib=...,
    warmup_seconds=..., all_seconds=[...], loss=..., grads={name: [r, g, b]}, ...)``; raises
    RuntimeError when the child fails or times out.
    """
    cmd = [
        sys.executable, os.path.abspath(__file__), "grad", "--json",
        "--width", str(width), "--height", str(height), "--spp", str(spp), "--max-depth", str(max_depth),
        "--integrator", integrator, "--params", *params, "--repeats", str(repeats), "--seed", str(seed),
        "--perturb", repr(float(perturb)),
    ]  # fmt: skip
    if not os.environ.get("DRJIT_LIBLLVM_PATH"):
        available()  # picks the libLLVM so that the child inherits DRJIT_LIBLLVM_PATH
    try:
        return _measure.run_json_child(cmd, timeout)
    except _measure.ChildError as e:
        raise RuntimeError(f"Mitsuba gradient subprocess failed ({e}):\n{e.stdout[-2000:]}\n{e.stderr[-2000:]}") from None


def channel_means(width: int, height: int, spp: int, max_depths=(8, 2, 1), seed: int = 0) -> dict[int, list[float]]:
    """{max_depth: [R, G, B] image means} of box-filtered renders."""
    return {d: [float(v) for v in render_cornell(width, height, spp, d, seed).mean(axis=(0, 1), dtype="float64")] for d in max_depths}


def _main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(description="Mitsuba 3 reference for the Cornell box (see the module docstring).")
    sub = parser.add_subparsers(dest="cmd", required=True)
    f = sub.add_parser("forward", help="forward throughput: path samples per second")
    f.add_argument("--resolution", type=int, default=128)
    f.add_argument("--spp", type=int, default=64)
    f.add_argument("--max-depth", type=int, default=8)
    f.add_argument("--repeats", type=int, default=5)
    m = sub.add_parser("means", help="channel means of box-filtered renders")
    m.add_argument("--resolution", type=int, default=64)
    m.add_argument("--spp", type=int, default=4096)
    m.add_argument("--max-depth", type=int, nargs="+", default=[8, 2, 1])
    m.add_argument("--seed", type=int, default=0)
    m.add_argument("--write", help="write the means as JSON to this path")
    g = sub.add_parser("grad", help="gradient timing and peak RSS (in a fresh subprocess unless --json)")
    g.add_argument("--width", type=int, default=128)
    g.add_argument("--height", type=int, default=128)
    g.add_argument("--spp", type=int, default=64)
    g.add_argument("--max-depth", type=int, default=8)
    g.add_argument("--integrator", default="prb", choices=["prb", "path", "prb_basic"])
    g.add_argument("--params", nargs="+", default=list(PARAM_KEYS), choices=list(PARAM_KEYS))
    g.add_argument("--repeats", type=int, default=1)
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--perturb", type=float, default=1.0)
    g.add_argument("--json", action="store_true", help="run in this process and print one tagged JSON line")
    args = parser.parse_args(argv)

    if not available():
        print("Mitsuba 3 (llvm_ad_rgb) is not available; see the install steps in bench/mitsuba_ref.py", file=sys.stderr)
        return 1
    if args.cmd == "forward":
        n = args.resolution
        times = time_forward(n, n, args.spp, args.max_depth, args.repeats)
        t = statistics.median(times)
        print(f"{label()} path, Cornell box {n}x{n}, {args.spp} spp, max_depth {args.max_depth}")
        print(f"  times: {' '.join(f'{x:.3f}' for x in times)} s; median {t:.4f} s = {n * n * args.spp / t / 1e6:.4g} M path samples/s")
    elif args.cmd == "means":
        n = args.resolution
        means = channel_means(n, n, args.spp, args.max_depth, args.seed)
        print(f"{label()} path, Cornell box {n}x{n}, {args.spp} spp, box filter, seed {args.seed}")
        for d, rgb in means.items():
            print(f"  max_depth {d}: R {rgb[0]:.6g}  G {rgb[1]:.6g}  B {rgb[2]:.6g}")
        if args.write:
            out = {
                f"{n}x{n}": {f"max_depth_{d}": [float(f"{v:.6g}") for v in rgb] for d, rgb in means.items()},
                "spp": args.spp,
                "mitsuba": version(),
                "variant": VARIANT,
                "rfilter": "box",
                "seed": args.seed,
            }
            with open(args.write, "w") as fh:
                json.dump(out, fh, indent=2)
                fh.write("\n")
            print(f"  written to {args.write}")
    else:
        kw = dict(width=args.width, height=args.height, spp=args.spp, max_depth=args.max_depth, integrator=args.integrator,
                  params=tuple(args.params), repeats=args.repeats, seed=args.seed, perturb=args.perturb)  # fmt: skip
        if args.json:
            _measure.print_json(gradient_in_process(**kw))
        else:
            res = time_gradient(**kw)
            print(f"Mitsuba {res['mitsuba']} {VARIANT} {res['integrator']} gradient, Cornell box {res['width']}x{res['height']}, "
                  f"{res['spp']} spp, max_depth {res['max_depth']}, params {', '.join(args.params)}")  # fmt: skip
            print(f"  {res['seconds']:.3f} s (warm-up {res['warmup_seconds']:.3f} s), peak RSS {res['peak_rss_mib']:.0f} MiB, "
                  f"loss {res['loss']:.6g}")  # fmt: skip
            for name, grad in res["grads"].items():
                print(f"  d loss / d {name}: {' '.join(f'{v:+.4e}' for v in grad)}")
    return 0


if __name__ == "__main__":
    sys.exit(_main())
