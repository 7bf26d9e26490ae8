"""pyrender rasterization of an invrender Scene: the independent baseline of the Utah approximation.

What pyrender 0.1.45 computes (``pyrender/shaders/mesh.frag``, metallic-roughness materials), per
pixel, in linear RGB, before its output encoding::

    color = sum_lights nl * radiance_i * ((1 - F) * c_diff / pi + F * G * D / (4 nl nv + 0.001))
          + base_color * ambient_light                      # ambient: rho eps0, no 1/pi, no occlusion
          + emissive_factor * emissive_factor               # sic: the factor is applied twice
    out   = clamp(pow(color, 1 / 2.2), 0, 1)               # gamma 2.2, not the sRGB curve

with ``c_diff = 0.96 base_color`` (``1 - F0``, F0 = 0.04 for a dielectric), Schlick's
``F = 0.04 + 0.96 (1 - v.h)^5``, Smith-Schlick ``G`` with ``k = (roughness + 1)^2 / 8`` and GGX
``D`` with ``alpha = roughness^2`` (= 1/pi at roughness 1), ``nl = clamp(n.l, 0.001, 1)``. Light
radiance at the receiver is ``intensity * color / d^2`` for point lights and additionally times
``clamp(cos_e * las + lao, 0, 1)^2`` for spot lights (``las = 1 / max(0.001, cos(inner) -
cos(outer))``, ``lao = -cos(outer) las``), so ``intensity`` is a radiant intensity (W/sr) and the
diffuse part of the shading is ``0.96 (1 - F) rho / pi * I cos_r / d^2``. :func:`pyrender_brdf_cos`
evaluates the whole bracket so that tests can compare with a Lambertian renderer analytically.

How a Scene is converted:

- geometry: one pyrender primitive per (material, emitter, side), flat-shaded (vertices duplicated
  per triangle, normals = face normals). invrender surfaces are two-sided, pyrender shades with the
  stored normal, so every triangle is drawn twice, front and a flipped back copy, with back-face
  culling on. Emitters emit from their front copy only.
- reflectance rho -> ``baseColorFactor`` (metallic 0, roughness 1), or an 8-bit sRGB
  ``baseColorTexture`` (pyrender stores textures as 8-bit and decodes sRGB in the shader).
- emission eps -> ``emissiveFactor = sqrt(s eps)`` (because the shader squares it), textures as an
  8-bit sRGB ``emissiveTexture`` of ``eps / max(eps)`` with ``emissiveFactor = sqrt(s max(eps))``.
- emitters -> lights (:func:`emitter_lights`): a Lambertian emitter of radiance L and area A has
  radiant intensity ``I(theta) = L A cos(theta)`` about its normal. pyrender's spot cone gives
  ``clamp(...)^2``, i.e. ``cos^2`` for inner 0 / outer 90 degrees, never ``cos``; the ``"cosine"``
  lobe therefore sums three spot lights at the same point, ``w1 f(a, 1) + w2 f(b, 1) + w3 step(a)``
  with ``f(c0, c1) = clamp((c - c0) / (c1 - c0), 0, 1)^2``, weights chosen so that the sum is exactly
  ``cos`` for ``cos >= b`` (b = cos 78.8 deg) and zero beyond 80 degrees (3% of a Lambertian
  emitter's power lies beyond 80 degrees). Spot lights get shadow maps (pyrender has none for point
  lights); the ``"point"`` lobe is the classic isotropic point light ``I = L A`` without shadows.
- ambient eps0 -> ``ambient_light``: pyrender adds ``rho eps0``, exactly the Utah ambient term.
- camera: the same pinhole, ``yfov = 2 atan(tan_half_fov_y)``, aspect ``width / height``.

Readback: pyrender's colour buffer is 8-bit RGBA. The renderer here is a subclass whose main
framebuffer is RGBA32F and read as float, so the only loss is pyrender's clamp to [0, 1] after the
gamma: every pass is rendered with lights, emission and ambient scaled by an exposure ``s`` chosen
so that no pixel reaches 1 (lowered and re-rendered until none does), then ``out ** 2.2 / s`` is the
linear radiance. The film is rendered at 4 x 4 sub-pixels per pixel without MSAA and averaged after
linearization (a box filter, as invrender's; MSAA would average gamma-encoded values). pyrender
shades at most a few lights per draw (4 without shadows, one per free texture unit with shadows), so
lights are split over several additive passes.
"""

from __future__ import annotations

import importlib.util
import math
import os
import threading
from dataclasses import dataclass

import numpy as np
import torch

from invrender.errors import BaselineError, ParameterError
from invrender.io.images import to_srgb
from invrender.scene.scene import AMBIENT, Scene, scene_extent
from invrender.core.bsdfs import Lobe
from invrender.core.textures import lookup
from invrender.vec import dot, normalize

#: Debian (bookworm) packages for headless rendering through EGL with Mesa's llvmpipe
DEBIAN_PACKAGES_EGL = "libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri"
#: Debian package for the OSMesa fallback (PYOPENGL_PLATFORM=osmesa); pyrender's OSMesa platform
#: also needs PyOpenGL >= 3.1.5 (OSMesaCreateContextAttribs), newer than the 3.1.0 pyrender pins
DEBIAN_PACKAGES_OSMESA = "libosmesa6"
OSMESA_PYOPENGL = "PyOpenGL>=3.1.5"

POINT_LIGHT_MODES = ("center", "triangles")
LOBES = ("cosine", "point")

#: spot cone of the cosine lobe: zero beyond COS_A (80 deg), exactly cos from COS_B on
COS_A = math.cos(math.radians(80.0))
COS_B = COS_A + 0.02
#: (outer angle, inner angle, weight) of the three spot lights summing to the cosine lobe
COSINE_LOBE = (
    (math.acos(COS_A), 0.0, (1.0 - COS_A) ** 2 / (2.0 * (COS_B - COS_A))),  # (c - a)^2 / (2 delta)
    (math.acos(COS_B), 0.0, -((1.0 - COS_B) ** 2) / (2.0 * (COS_B - COS_A))),  # -(c - b)^2 / (2 delta)
    (math.acos(COS_A), math.acos(COS_A), 0.5 * (COS_A + COS_B)),  # (a + b) / 2 for c > a (a step)
)
#: shadow-map camera of the spot lights: full angle (covers the 80 degree cone) and texels
SHADOW_FOV = 2.0 * math.radians(82.0)
SHADOW_SIZE = 2048
#: encoded values at or above this count as clipped by pyrender's clamp to [0, 1]
SATURATED = 0.999
GAMMA = 2.2
#: sub-pixels per pixel side: each pixel is the mean of SUPERSAMPLE^2 linear sub-pixel values (a box
#: filter, as invrender's). Not MSAA: pyrender's shader encodes colour before the MSAA resolve, so the
#: resolve would average gamma-encoded values and darken every partly covered pixel.
SUPERSAMPLE = 4


@dataclass(frozen=True)
class LightPoint:
    """Small lights standing in for emitters.

    Attributes:
        position: (K, 3) float64 light positions, world units.
        normal: (K, 3) float64 unit emission axes (the emitters' front normals).
        intensity: (K, 3) float64 on-axis radiant intensity ``L A`` per RGB channel, W/sr.
    """

    position: np.ndarray
    normal: np.ndarray
    intensity: np.ndarray

    @property
    def count(self) -> int:
        return int(self.position.shape[0])


def emitter_lights(scene: Scene, point_lights="center") -> LightPoint:
    """The lights replacing ``scene``'s emitters.

    Args:
        point_lights: ``"center"`` (default): one light per emitter at its area-weighted centroid,
            axis = mean normal, intensity ``sum_t L_t A_t max(0, n_t . axis)`` (= L A for a flat
            emitter); ``"triangles"``: one light per emissive triangle at its centroid with its own
            ``L_t A_t``; an integer k >= 1: k lights per emitter at stratified points spread over
            its area by area, each ``L(x) A / k``.
    Raises:
        ParameterError: unknown ``point_lights``; ``"center"`` on a closed emitter (no mean normal).
    """
    mode = _check_point_lights(point_lights)
    tri = scene.triangles
    corners = tri.corners().double().cpu().numpy()  # (T, 3, 3)
    normal = tri.normal.double().cpu().numpy()
    area = tri.area.double().cpu().numpy()
    uv = tri.uv.double().cpu()  # (T, 3, 2)
    emitter = tri.emitter.cpu().numpy()
    parts = []  # per emitter: (position, axis, intensity), each (K_j, 3)
    for j, name in enumerate(scene.emitters):
        ids = np.nonzero(emitter == j)[0]
        eps = scene.emission_of(j).detach().cpu().double()
        if ids.size == 0 or float(eps.max()) <= 0.0:
            continue
        if not isinstance(mode, str):
            parts.append(_sampled_lights(mode, eps, corners[ids], normal[ids], area[ids], uv[ids]))
            continue
        L = _mean_emission(eps, uv[ids])  # (n, 3) per triangle
        if mode == "triangles":
            parts.append((corners[ids].mean(1), normal[ids], L * area[ids][:, None]))
        else:
            parts.append(_centre_light(name, L, corners[ids], normal[ids], area[ids]))
    if not parts:
        z = np.zeros((0, 3))
        return LightPoint(z, z, z)
    return LightPoint(*(np.concatenate(column) for column in zip(*parts)))


def _centre_light(name: str, L: np.ndarray, corners: np.ndarray, normal: np.ndarray, area: np.ndarray):
    """One light for a whole emitter of n triangles: radiance L (n, 3), corners (n, 3, 3), normals
    (n, 3), areas (n,) -> (1, 3) centroid, (1, 3) mean normal, (1, 3) on-axis intensity."""
    axis = (area[:, None] * normal).sum(0)
    length = np.linalg.norm(axis)
    if length < 1e-3 * area.sum():
        raise ParameterError(f"emitter {name!r} has no mean normal (closed or folded); use point_lights='triangles' or an integer")
    axis /= length
    cos = np.clip(normal @ axis, 0.0, None)
    position = (area[:, None] * corners.mean(1)).sum(0, keepdims=True) / area.sum()
    return position, axis[None], (L * (area * cos)[:, None]).sum(0, keepdims=True)


def _sampled_lights(k: int, eps: torch.Tensor, corners: np.ndarray, normal: np.ndarray, area: np.ndarray, uv: torch.Tensor):
    """k lights at stratified points of an emitter of n triangles (picked by area, then uniform in
    the triangle): eps (3,) or (h, w, 3), corners (n, 3, 3), normals (n, 3), areas (n,), UVs
    (n, 3, 2) -> (k, 3) positions, (k, 3) normals, (k, 3) intensities ``L(x) A / k``."""
    cdf = np.cumsum(area) / area.sum()
    u = (np.arange(k) + 0.5) / k
    pick = np.minimum(np.searchsorted(cdf, u, side="right"), area.size - 1)
    lo = np.concatenate([[0.0], cdf[:-1]])[pick]
    u1 = np.clip((u - lo) / (cdf[pick] - lo), 0.0, 1.0)  # position within the picked triangle's share
    u2 = (np.arange(k) * 0.6180339887498949 + 0.5) % 1.0  # golden-ratio sequence
    w = _uniform_barycentrics(u1, u2)[:, :, None]  # (k, 3, 1)
    position = (w * corners[pick]).sum(1)
    L = lookup(eps, torch.as_tensor((w * uv[pick].numpy()).sum(1))).numpy()
    return position, normal[pick], L * (area.sum() / k)


def _uniform_barycentrics(u1: np.ndarray, u2: np.ndarray) -> np.ndarray:
    """(n, 3) barycentric weights of (p0, p1, p2) mapping (n,) u1, u2 in [0, 1] uniformly onto a triangle."""
    su = np.sqrt(u1)
    b1, b2 = su * (1.0 - u2), su * u2
    return np.stack([1.0 - b1 - b2, b1, b2], axis=1)


def pyrender_brdf_cos(rho: torch.Tensor, n: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """pyrender's shading ``f(wi, wo) cos`` for metallic 0, roughness 1, as in ``mesh.frag``.

    Args:
        rho: (N, 3) base colour; n: (N, 3) unit normal; wi: (N, 3) unit direction to the light;
            wo: (N, 3) unit direction to the camera.
    Returns:
        (N, 3) ``nl ((1 - F) 0.96 rho / pi + F G D / (4 nl nv + 0.001))``; the Lambertian value is
        ``rho / pi * max(n . wi, 0)``.
    """
    nl = dot(n, wi).clamp(0.001, 1.0)
    nv = dot(n, wo).abs().clamp(0.001, 1.0)
    vh = dot(wo, normalize(wi + wo)).clamp(0.0, 1.0)
    F = 0.04 + 0.96 * (1.0 - vh) ** 5
    k = (1.0 + 1.0) ** 2 / 8.0  # Smith-Schlick, roughness 1
    G = nv / (nv * (1 - k) + k) * nl / (nl * (1 - k) + k)
    D = 1.0 / math.pi  # GGX with alpha^2 = roughness^4 = 1
    diffuse = (1.0 - F)[:, None] * 0.96 * rho / math.pi
    spec = (F * G * D / (4.0 * nl * nv + 0.001))[:, None]
    return nl[:, None] * (diffuse + spec)


def pyrender_render(
    scene: Scene,
    *,
    ambient=None,
    point_lights="center",
    lobe: str = "cosine",
    shadows: bool = True,
    device=None,
) -> torch.Tensor:
    """Rasterize ``scene`` with pyrender: emitters seen directly + direct light + ambient.

    Args:
        scene: any invrender scene (textures allowed); parameters are read, never differentiated.
        ambient: RGB (or scalar) ambient radiance eps0 >= 0 added as ``rho eps0``; None = the
            scene's ``"ambient.emission"`` parameter if present, else zero.
        point_lights: how emitters become lights, see :func:`emitter_lights` (default ``"center"``).
        lobe: ``"cosine"`` (default; three spot lights per light summing to the Lambertian
            ``cos`` lobe, shadowed) or ``"point"`` (isotropic point lights ``I = L A``, unshadowed).
        shadows: shadow maps for the spot lights of the cosine lobe.
        device: torch device of the result; None = the scene's.
    Returns:
        (H, W, 3) float32 linear radiance, row 0 at the top, pixel-aligned with ``invrender.render``.
    Raises:
        ParameterError: bad ``ambient``, ``point_lights`` or ``lobe``.
        BaselineError: pyrender cannot be imported or no OpenGL context can be created.
    """
    if lobe not in LOBES:
        raise ParameterError(f"unknown lobe {lobe!r} (known: {', '.join(LOBES)})")
    for i, name in enumerate(scene.materials):
        if scene.material_spec(i).spec.lobes != Lobe.DIFFUSE:
            raise BaselineError(f"the pyrender baseline rasterizes diffuse materials only (the Utah model); material {name!r} is {scene.material_spec(i).type}")
    for i, name in enumerate(scene.emitters):
        if not scene.emitter_spec(i).spec.surface:
            raise BaselineError(f"the pyrender baseline lights the scene from its emissive shapes only; emitter {name!r} is {scene.emitter_spec(i).type}")
    eps0 = _ambient(scene, ambient)
    lights = emitter_lights(scene, point_lights)
    device = torch.device(device) if device is not None else scene.device
    pr = _pyrender()
    ss = SUPERSAMPLE
    with _LOCK:
        osr = _offscreen(pr, scene.width * ss, scene.height * ss)
        image = _render_passes(pr, osr, scene, lights, eps0, lobe, shadows)  # linear, (H ss, W ss, 3)
    image = image.reshape(scene.height, ss, scene.width, ss, 3).mean(axis=(1, 3))  # box filter
    return torch.as_tensor(image, dtype=torch.float32, device=device)


# --------------------------------------------------------------------------------------------------
# conversion


def _check_point_lights(point_lights):
    if isinstance(point_lights, str) and point_lights in POINT_LIGHT_MODES:
        return point_lights
    if isinstance(point_lights, (int, np.integer)) and not isinstance(point_lights, bool) and point_lights >= 1:
        return int(point_lights)
    raise ParameterError(f"point_lights must be 'center', 'triangles' or an integer >= 1, got {point_lights!r}")


def _ambient(scene: Scene, ambient) -> np.ndarray:
    """eps0 (3,) float64: ``ambient``, else the scene's ``AMBIENT`` parameter, else zero. Validated by
    :meth:`Scene.with_ambient` either way (``scene.params`` may have been edited in place)."""
    if ambient is None:
        ambient = scene.params.get(AMBIENT)
        if ambient is None:
            return np.zeros(3)
    return scene.with_ambient(ambient).params[AMBIENT].cpu().double().numpy()


def _mean_emission(eps: torch.Tensor, uv: torch.Tensor) -> np.ndarray:
    """Mean of eps (3,) or (h, w, 3) over each triangle with UVs (n, 3, 2): (n, 3) float64."""
    n = uv.shape[0]
    if eps.ndim == 1:
        return eps.expand(n, 3).numpy().copy()
    g = (np.arange(4) + 0.5) / 4  # 4 x 4 stratified points per triangle
    u1, u2 = np.meshgrid(g, g, indexing="ij")
    w = torch.from_numpy(_uniform_barycentrics(u1.reshape(-1), u2.reshape(-1)))  # (16, 3)
    pts = torch.einsum("sk,nkc->nsc", w, uv).reshape(-1, 2)
    return lookup(eps, pts).reshape(n, -1, 3).mean(1).numpy()


def _texture(pr, linear: np.ndarray):
    """pyrender texture of linear (h, w, 3) values in [0, 1], stored as 8-bit sRGB (pyrender decodes it
    with ``srgb_to_linear``) plus opaque alpha. RGBA because pyrender uploads with OpenGL's default
    4-byte row alignment, which garbles RGB rows whose length is not a multiple of 4 bytes."""
    srgb = np.round(to_srgb(torch.from_numpy(linear)).double().numpy() * 255.0)
    rgba = np.concatenate([srgb, np.full(srgb.shape[:2] + (1,), 255.0)], axis=2).astype(np.uint8)
    return pr.Texture(source=rgba, source_channels="RGBA", sampler=pr.Sampler())


def _build_scene(pr, scene: Scene):
    """pyrender Scene with meshes and camera; returns it and [(emissive material, (3,) float64 eps, or
    max(eps) per channel for an emission texture)], whose ``emissiveFactor`` is set per exposure."""
    tri = scene.triangles
    corners = tri.corners().cpu().numpy().astype(np.float32)
    normal = tri.normal.cpu().numpy().astype(np.float32)
    uv = tri.uv.cpu().numpy().astype(np.float32)
    mat = tri.material.cpu().numpy()
    emi = tri.emitter.cpu().numpy()
    out = pr.Scene(ambient_light=np.zeros(3), bg_color=np.array([0.0, 0.0, 0.0, 1.0]))
    emissive = []
    base_cache = {}

    def material(m: int, e: int):
        rho = scene.reflectance_of(m).detach().cpu().double().numpy()
        kw = dict(metallicFactor=0.0, roughnessFactor=1.0, alphaMode="OPAQUE", doubleSided=False)
        if rho.ndim == 1:
            kw["baseColorFactor"] = np.append(rho, 1.0)
        else:
            kw["baseColorFactor"] = np.ones(4)
            if m not in base_cache:
                base_cache[m] = _texture(pr, rho)
            kw["baseColorTexture"] = base_cache[m]
        if e >= 0:
            eps = scene.emission_of(e).detach().cpu().double().numpy()
            if eps.ndim == 3:
                top = max(float(eps.max()), 1e-30)
                kw["emissiveTexture"] = _texture(pr, eps / top)
                eps = np.full(3, top)
        m_out = pr.MetallicRoughnessMaterial(**kw)
        if e >= 0:
            emissive.append((m_out, eps))
        return m_out

    # the front copy emits; the back copy (reversed winding, flipped normal) never does
    for side, emitter, order in ((1, emi, [0, 1, 2]), (-1, np.full(tri.count, -1), [0, 2, 1])):
        for m, e in sorted(set(zip(mat.tolist(), emitter.tolist()))):
            sel = np.nonzero((mat == m) & (emitter == e))[0]
            pos = corners[sel][:, order].reshape(-1, 3)
            nrm = np.repeat(side * normal[sel], 3, axis=0)
            tex = uv[sel][:, order].reshape(-1, 2)
            prim = pr.Primitive(positions=pos, normals=nrm, texcoord_0=tex, material=material(m, e), mode=pr.constants.GLTF.TRIANGLES)
            mesh = pr.Mesh([prim])
            mesh._bounds = np.asarray(prim.bounds, dtype=np.float64)  # pyrender 0.1.45 computes it with np.infty (gone in NumPy 2)
            out.add(mesh)

    cam = scene.camera
    right, up, forward = (v.numpy() for v in cam.frame())
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, up, -forward, cam.origin
    _, ty = cam.tan_half_fov(scene.width, scene.height)
    far = float(np.linalg.norm(corners.reshape(-1, 3) - np.asarray(cam.origin, dtype=np.float32), axis=1).max())
    extent = max(scene_extent(tri), 1e-6)
    camera = pr.PerspectiveCamera(yfov=2.0 * math.atan(ty), aspectRatio=scene.width / scene.height,
                                  znear=1e-4 * (far + extent), zfar=2.0 * (far + extent))  # fmt: skip
    out.add(camera, pose=pose)
    return out, emissive


def _light_pose(p: np.ndarray, n: np.ndarray) -> np.ndarray:
    """4x4 pose whose -z axis is ``n`` (pyrender lights shine along -z), at ``p``."""
    z = -n / np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, np.cross(z, x), z, p
    return pose


@dataclass(frozen=True)
class _LightGroup:
    """The pyrender lights standing in for one light point, all at one pose.

    Attributes:
        intensity: (3,) float64 on-axis intensity of the light point, before exposure.
        pose: (4, 4) float64 pose of every light of the group.
        lights: ((pyrender light, weight), ...): one point light of weight 1, or COSINE_LOBE's spots.
    """

    intensity: np.ndarray
    pose: np.ndarray
    lights: tuple

    def expose(self, s: float) -> None:
        """Set each light to ``weight * s * intensity`` (pyrender: a colour times a scalar intensity)."""
        exposed = self.intensity * s
        peak = float(exposed.max())
        for light, weight in self.lights:
            light.color = exposed / peak
            light.intensity = peak * weight


def _light_groups(pr, lights: LightPoint, lobe: str, shadows: bool, offset: float) -> list[_LightGroup]:
    """Per light point (dark ones skipped), the pyrender lights standing in for it, moved ``offset``
    along the normal; their intensities are set per exposure by :meth:`_LightGroup.expose`."""
    classes = _classes(pr)
    groups = []
    for k in range(lights.count):
        if float(lights.intensity[k].max()) <= 0.0:
            continue
        # just in front of the emitter: fragments in the light's own plane would divide by w = 0 in
        # pyrender's shadow lookup and come out NaN (black), the emitter itself included
        pose = _light_pose(lights.position[k] + offset * lights.normal[k], lights.normal[k])
        if lobe == "point":
            members = ((pr.PointLight(), 1.0),)
        else:
            shared = pr.Texture(width=SHADOW_SIZE, height=SHADOW_SIZE, source_channels="D", data_format=classes.GL_FLOAT) if shadows else None
            members = tuple((classes.SpotLight(innerConeAngle=inner, outerConeAngle=outer), w) for outer, inner, w in COSINE_LOBE)
            for light, _ in members:
                light._shadow_texture = shared  # the three spots see the same depths: one map for all
        groups.append(_LightGroup(lights.intensity[k], pose, members))
    return groups


# --------------------------------------------------------------------------------------------------
# rendering


def _render_passes(pr, osr, scene: Scene, lights: LightPoint, eps0: np.ndarray, lobe: str, shadows: bool) -> np.ndarray:
    """Linear (H, W, 3) float64: additive passes at an exposure lowered until nothing clips.

    The pyrender scene and lights are built once; a retry only changes intensities."""
    pscene, emissive = _build_scene(pr, scene)
    spots = lobe == "cosine"
    flags = pr.RenderFlags.OFFSCREEN | (pr.RenderFlags.SHADOWS_SPOT if shadows and spots else 0)
    groups = _light_groups(pr, lights, lobe, shadows, 1e-5 * max(scene_extent(scene.triangles), 1e-6))
    osr._platform.make_current()
    try:
        capacity = pr.constants.MAX_N_LIGHTS  # pyrender's lights per draw: 4, or with shadow maps
        if spots and shadows:  # one free texture unit per shadowed spot light
            classes = _classes(pr)
            capacity = max(3, int(classes.glGetIntegerv(classes.GL_MAX_TEXTURE_IMAGE_UNITS)) - 6)
        per_pass = max(1, capacity // (len(COSINE_LOBE) if spots else 1))
        passes = [groups[i : i + per_pass] for i in range(0, len(groups), per_pass)] or [[]]
        top = max([float(eps0.max()), 1e-30] + [float(e.max()) for _, e in emissive])
        s = 0.25 / top
        for _ in range(12):
            total, clipped = 0.0, False
            for i, chunk in enumerate(passes):
                first = i == 0  # ambient and emission are drawn once, in the first pass
                pscene.ambient_light = (s * eps0 if first else np.zeros(3)).astype(np.float32)
                for m, e in emissive:
                    m.emissiveFactor = np.sqrt(s * e) if first else np.zeros(3)
                for group in chunk:
                    group.expose(s)
                nodes = [pscene.add(light, pose=group.pose) for group in chunk for light, _ in group.lights]
                encoded = osr._renderer.render(pscene, flags)
                for node in nodes:
                    pscene.remove_node(node)
                clipped = bool(encoded.max() >= SATURATED)
                if clipped:
                    break
                total = total + np.power(encoded.astype(np.float64), GAMMA)
            if not clipped:
                return total / s
            s /= 1024.0
        raise BaselineError("pyrender output stays saturated at every exposure (non-finite or huge light intensities?)")
    finally:
        osr._platform.make_uncurrent()


# --------------------------------------------------------------------------------------------------
# pyrender and OpenGL setup

_LOCK = threading.Lock()
_STATE: dict = {}


def _pyrender():
    """Import pyrender headless: PYOPENGL_PLATFORM=egl unless set (osmesa when EGL cannot start)."""
    if "module" in _STATE:
        return _STATE["module"]
    if importlib.util.find_spec("pyrender") is None:  # not installed: say so before probing EGL
        raise BaselineError(f"the pyrender baseline needs the pyrender package, which is not installed: pip install pyrender (and the Debian packages {DEBIAN_PACKAGES_EGL})")
    if "PYOPENGL_PLATFORM" not in os.environ:
        os.environ["PYOPENGL_PLATFORM"] = "egl" if not _osmesa_present() or _egl_works() else "osmesa"
    try:
        import pyrender
    except Exception as exc:  # ImportError, or OpenGL failing to load its platform libraries
        raise BaselineError(
            f"cannot import pyrender with PYOPENGL_PLATFORM={os.environ['PYOPENGL_PLATFORM']} ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else ''}); install it with 'pip install pyrender' and the Debian packages "
            f"{DEBIAN_PACKAGES_EGL} (or {DEBIAN_PACKAGES_OSMESA} with PYOPENGL_PLATFORM=osmesa)"
        ) from None
    _STATE["module"] = pyrender
    return pyrender


def _egl_works() -> bool:
    """Whether pyrender can open an EGL context here, probed in a child process (PyOpenGL binds its
    platform once per process, at import). pyrender uses EGL's device platform, which needs no
    display server, so probing ``eglGetDisplay`` in this process would wrongly fail headless."""
    import subprocess
    import sys

    probe = "import pyrender; r = pyrender.OffscreenRenderer(8, 8); r.delete()"
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl"}
    try:
        return subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, timeout=120).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def _osmesa_present() -> bool:
    import ctypes.util

    return ctypes.util.find_library("OSMesa") is not None


class _Classes:
    """pyrender subclasses, built once pyrender is imported (it binds OpenGL at import)."""

    def __init__(self, pr):
        from OpenGL import GL

        self.GL_FLOAT = GL.GL_FLOAT
        self.GL_MAX_TEXTURE_IMAGE_UNITS = GL.GL_MAX_TEXTURE_IMAGE_UNITS
        self.glGetIntegerv = GL.glGetIntegerv

        class SpotLight(pr.SpotLight):
            """A spot light whose shadow camera covers the 80 degree cone (pyrender's adds pi/16 to
            twice the outer angle, which degenerates at wide cones) with near/far from the scene size."""

            def _get_shadow_camera(self, scene_scale):
                return pr.PerspectiveCamera(znear=1e-3 * scene_scale, zfar=10.0 * scene_scale, yfov=SHADOW_FOV, aspectRatio=1.0)

        class FloatRenderer(pr.Renderer):
            """pyrender's Renderer with RGBA32F colour buffers, returning the encoded colour as float32."""

            def _configure_main_framebuffer(self):
                dims = (self.viewport_width, self.viewport_height)
                if self._main_fb is not None and dims != self._main_fb_dims:
                    self._delete_main_framebuffer()
                if self._main_fb is not None:
                    return
                w, h = dims
                self._main_cb, self._main_db = GL.glGenRenderbuffers(2)
                GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_cb)
                GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA32F, w, h)
                GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_db)
                GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_DEPTH_COMPONENT24, w, h)
                self._main_fb = GL.glGenFramebuffers(1)
                GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
                GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, self._main_cb)
                GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, self._main_db)
                self._main_cb_ms, self._main_db_ms = GL.glGenRenderbuffers(2)
                GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_cb_ms)
                GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, 0, GL.GL_RGBA32F, w, h)  # no MSAA: see SUPERSAMPLE
                GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_db_ms)
                GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, 0, GL.GL_DEPTH_COMPONENT24, w, h)
                self._main_fb_ms = GL.glGenFramebuffers(1)
                GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb_ms)
                GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, self._main_cb_ms)
                GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER, self._main_db_ms)
                self._main_fb_dims = dims

            def _read_main_framebuffer(self, scene, flags):
                w, h = self._main_fb_dims
                GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb_ms)
                GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
                GL.glBlitFramebuffer(0, 0, w, h, 0, 0, w, h, GL.GL_COLOR_BUFFER_BIT, GL.GL_NEAREST)  # a copy (single-sampled)
                GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb)
                buf = GL.glReadPixels(0, 0, w, h, GL.GL_RGB, GL.GL_FLOAT)
                image = np.frombuffer(buf, dtype=np.float32).reshape(h, w, 3)
                return np.flip(image, axis=0).copy()  # OpenGL's row 0 is the bottom

        self.SpotLight = SpotLight
        self.FloatRenderer = FloatRenderer


def _classes(pr) -> _Classes:
    if "classes" not in _STATE:
        _STATE["classes"] = _Classes(pr)
    return _STATE["classes"]


def _offscreen(pr, width: int, height: int):
    """The process's offscreen renderer (one OpenGL context, reused), sized ``width x height``."""
    osr = _STATE.get("renderer")
    if osr is None:
        platform = os.environ.get("PYOPENGL_PLATFORM", "")
        try:
            osr = pr.OffscreenRenderer(width, height)
            osr._platform.make_current()
            osr._renderer.delete()
            osr._renderer = _classes(pr).FloatRenderer(width, height)
            osr._platform.make_uncurrent()
        except Exception as exc:
            fix = f"{DEBIAN_PACKAGES_OSMESA} and pip install '{OSMESA_PYOPENGL}'" if platform == "osmesa" else DEBIAN_PACKAGES_EGL
            raise BaselineError(
                f"pyrender cannot create an OpenGL context with PYOPENGL_PLATFORM={platform} ({type(exc).__name__}: "
                f"{str(exc).splitlines()[0] if str(exc) else ''}); on Debian install {fix}"
            ) from None
        _STATE["renderer"] = osr
    osr._renderer.viewport_width, osr._renderer.viewport_height = width, height
    return osr
