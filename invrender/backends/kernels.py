"""Fused per-bounce kernels (NVIDIA Warp) for the steps of a bounce that never carry a gradient.

A bounce in eager torch is a few hundred small operations, each a pass over megabytes of (N,) and
(N, 3) tensors; the steps below are pure geometry and random numbers (no parameter enters them:
sampling and hit geometry are detached by design), so each is one Warp kernel
(:mod:`invrender.backends.warp_kernels`, imported on first use: without warp-lang, ``import
invrender`` works and the torch expressions run), one pass over its inputs, compiled for the CPU
and for CUDA from the same source and cached on disk by Warp (``~/.cache/warp``) after the first
compile. The torch expressions they replace stay beside them as
the reference: they run on devices Warp has no backend for, with ``INVRENDER_KERNELS=torch``, and
in the tests that check the two agree (the random numbers bit for bit, the geometry to float
rounding).

- :func:`hash_uniforms`: the counter-based uniforms of :func:`invrender.core.sampler.uniform`;
- :func:`hit_geometry`: position, facing normal, side, cosine and texture coordinates of hits
  (:func:`invrender.core.surface.surface_at`);
- :func:`emitter_geometry`: points sampled on emitters as seen from surface points, the shadow ray
  towards each and its solid-angle pdf (:meth:`invrender.plugins.emitters.area.Area.geometry`);
- :func:`cosine_directions`: the diffuse BSDF's cosine-weighted directions and their pdf;
- :func:`offset_origins`: the origins of rays leaving surfaces (``TransportContext.spawn``).

Tensors are shared with Warp without copies (``wp.from_torch``); on CUDA the kernels run on torch's
current stream. Warp's CPU launches run in the calling thread without the GIL, so the render's
worker threads run theirs side by side.
"""

from __future__ import annotations

import os
import sys
import threading

import torch

from invrender.errors import ParameterError
from invrender import first_use
from invrender.backends import packages

#: set INVRENDER_KERNELS=torch to run the torch reference expressions instead of the Warp kernels,
#: INVRENDER_KERNELS=steps for the kernels of single steps without the fused bounce
ENV = "INVRENDER_KERNELS"
#: the values INVRENDER_KERNELS takes (default: warp)
CHOICES = ("warp", "steps", "torch")

#: the module of the Warp kernels (:mod:`invrender.backends.warp_kernels`), imported on first use
KERNELS = "invrender.backends.warp_kernels"


def warp_kernels():
    """:mod:`invrender.backends.warp_kernels` (and so ``warp``), imported on first call; None when
    warp-lang cannot be imported."""
    if packages.find("warp") is None:
        return None
    return packages.find(KERNELS)


def enabled(device: torch.device) -> bool:
    """Do renders on ``device`` use the Warp kernels (CPU or CUDA, warp-lang importable, not
    switched off by ``INVRENDER_KERNELS=torch``)? Another value of the variable than ``warp``,
    ``steps`` (the kernels of single steps, not the fused bounce: :func:`fused_bounce`) or ``torch``
    is a one-line :class:`~invrender.errors.ParameterError` (first met when a render's context is
    built, before any work)."""
    choice = os.environ.get(ENV, "warp")
    if choice not in CHOICES:
        raise ParameterError(f"{ENV} must be 'warp', 'steps' or 'torch', got {choice!r}")
    if choice == "torch" or device.type not in ("cpu", "cuda"):
        return False
    if warp_kernels() is None:
        packages.note_once(f"warp-lang is not installed: the fused kernels run as their torch expressions ({packages.install_hint('warp')} for the kernels)")
        return False
    return True


def fused_bounce(device: torch.device) -> bool:
    """May renders on ``device`` trace with the fused bounce (:mod:`invrender.core.fused`):
    the kernels are :func:`enabled` and ``INVRENDER_KERNELS`` is not ``steps``?"""
    return enabled(device) and os.environ.get(ENV, "warp") != "steps"


_loaded: set[tuple[str, str]] = set()
_loading = threading.Lock()  # one thread at a time redirects stderr and compiles


def load(device: torch.device, module: str = KERNELS) -> None:
    """Compile (or load from Warp's cache) the kernels of ``module`` (default: the fused kernels',
    when they are :func:`enabled`) for ``device``, once per process, before render threads launch
    them. Warp's own output, compiler warnings included, is silenced; a compile (not a load from
    the cache) is announced in one line and its time counted (:mod:`invrender.first_use`)."""
    key = (module, str(device))
    if key in _loaded or (module == KERNELS and not enabled(device)):
        return
    wk = warp_kernels()
    with _loading:
        if key in _loaded:
            return
        wp_device = wk.wp.device_from_torch(device)
        what = f"the {'render' if module == KERNELS else module.rsplit('.', 1)[-1]} kernels (Warp, {device.type})"
        with first_use.compiling(what, _cached(wk.wp, module, wp_device)):
            with wk.quiet_stderr():
                wk.wp.load_module(sys.modules[module], device=wp_device)
        _loaded.add(key)


def _cached(wp, module: str, device) -> bool:
    """Is ``module`` compiled for ``device`` in Warp's kernel cache already? Warp keeps each build
    in a folder named by the module's identifier (a hash of its code and its block size, 1 on the
    CPU); True where that cannot be told (nothing is announced then)."""
    try:
        identifier = wp.get_module(module).get_module_identifier(block_dim=1 if device.is_cpu else None)
        return os.path.isdir(os.path.join(wp.config.kernel_cache_dir, identifier))
    except Exception:  # another Warp's internals: say nothing rather than something false
        return True


def launch(kernel, n: int, inputs: list, device: torch.device) -> None:
    """Run ``kernel`` over ``n`` threads on ``device`` (on torch's current stream on CUDA).

    ``inputs``: torch tensors (passed as Warp arrays of their dtype and shape, made contiguous:
    outputs must be contiguous already, or the kernel writes into a copy), :class:`Vec3` and :class:`Vec2` tensors,
    and scalars. Tensors go to Warp as launch descriptors, not ``wp.array``
    objects (which cost tens of microseconds each to build); the tensors they point to are held
    here until the launch returns (on CUDA, torch's allocator orders their reuse after the kernel).
    """
    if not n:
        return
    wk = warp_kernels()
    wp = wk.wp
    held, args = [], []
    for x in inputs:
        if isinstance(x, Vec3):  # or Vec2
            vector = getattr(wp, x.vector)
            x = x.tensor.to(torch.float32).contiguous()
            args.append(wp.from_torch(x, dtype=vector, return_ctype=True))
        elif isinstance(x, torch.Tensor):
            x = x.contiguous()
            args.append(wp.from_torch(x, return_ctype=True))
        else:
            args.append(x)
        held.append(x)
    stream = wp.stream_from_torch(torch.cuda.current_stream(device)) if device.type == "cuda" else None
    wp.launch(kernel, dim=n, inputs=args, device=wp.device_from_torch(device), stream=stream)


class Vec3:
    """A (N, 3) tensor to be passed to a kernel as an array of ``wp.vec3`` (see :func:`launch`)."""

    __slots__ = ("tensor",)
    #: the Warp vector type of the array
    vector = "vec3"

    def __init__(self, tensor: torch.Tensor):
        self.tensor = tensor


class Vec2(Vec3):
    """A (N, 2) tensor to be passed to a kernel as an array of ``wp.vec2``."""

    __slots__ = ()
    vector = "vec2"


def hash_uniforms(keys: torch.Tensor, salts: torch.Tensor) -> torch.Tensor:
    """(N, D) float32 uniforms: lowbias32 of ``(keys & ~1) ^ salt_j`` (N,) x (D,) int32, all bits
    flipped for odd (mirrored) keys, low 24 bits / 2^24 (the kernel of ``sampler.uniform``)."""
    out = torch.empty(keys.shape[0], salts.shape[0], dtype=torch.float32, device=keys.device)
    launch(warp_kernels().uniform_kernel, keys.shape[0], [keys, salts, out], keys.device)
    return out


def hit_geometry(packed: torch.Tensor, tri: torch.Tensor, u: torch.Tensor, v: torch.Tensor, d: torch.Tensor, with_uv: bool):
    """Hits of rays ``d`` (N, 3) on triangles ``tri`` (N,) at barycentrics ``u``, ``v`` (N,) (the
    weights of corners 1 and 2), from the (T, 18) packed table (``Triangles.packed``).

    Returns:
        p (N, 3), n (N, 3) the geometric normal turned towards the ray's origin, front (N,) bool,
        cos_o (N,) |cos| between them, uv (N, 2) (zeros unless ``with_uv``).
    """
    count, dev = tri.shape[0], tri.device
    p, n = (torch.empty(count, 3, device=dev) for _ in range(2))
    front = torch.empty(count, dtype=torch.bool, device=dev)
    cos_o = torch.empty(count, device=dev)
    uv = torch.empty(count, 2, device=dev) if with_uv else torch.zeros(1, 2, device=dev)
    inputs = [packed.reshape(-1), tri, u, v, Vec3(d), int(with_uv), Vec3(p), Vec3(n), front, cos_o, uv]
    launch(warp_kernels().hit_kernel, count, inputs, dev)
    return p, n, front, cos_o, uv if with_uv else uv.expand(count, 2)


def emitter_geometry(packed, light_tri, cdf, pdf_area, u: torch.Tensor, x: torch.Tensor, nx: torch.Tensor, offset: float, with_uv: bool):
    """Emitter samples seen from points ``x`` (N, 3) with normals ``nx`` (N, 3), from uniforms ``u``
    (N, 3) (pick, then the point), the area lights' tables (:class:`~invrender.plugins.emitters.area.Area`) and the (T, 18) packed
    triangles.

    Returns:
        tri (N,) int64, o (N, 3) shadow-ray origins ``x + offset nx``, wl (N, 3) unit directions to
        the points, tmax (N,) their distance minus ``offset``, facing (N,) bool (the point is in
        front of ``nx`` and ``x`` in front of the emitter), pdf (N,) solid-angle density of the
        sample at ``o``, uv (N, 2) at the points (zeros unless ``with_uv``).
    """
    count, dev = x.shape[0], x.device
    tri = torch.empty(count, dtype=torch.int64, device=dev)
    o, wl = (torch.empty(count, 3, device=dev) for _ in range(2))
    tmax, pdf = (torch.empty(count, device=dev) for _ in range(2))
    facing = torch.empty(count, dtype=torch.bool, device=dev)
    uv = torch.empty(count, 2, device=dev) if with_uv else torch.zeros(1, 2, device=dev)
    inputs = [
        packed.reshape(-1),
        light_tri,
        cdf,
        pdf_area,
        u,
        Vec3(x),
        Vec3(nx),
        float(offset),
        int(with_uv),
        tri,
        Vec3(o),
        Vec3(wl),
        tmax,
        facing,
        pdf,
        uv,
    ]
    launch(warp_kernels().emitter_kernel, count, inputs, dev)
    return tri, o, wl, tmax, facing, pdf, uv if with_uv else uv.expand(count, 2)


def cosine_directions(n: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Cosine-weighted directions about unit normals ``n`` (N, 3) from uniforms ``u`` (N, 2), as
    ``normalize(n + s)`` with ``s`` uniform on the sphere (``z = 1 - 2 u_0``, ``phi = 2 pi u_1``):
    (wi (N, 3), their pdf ``max(cos, 0) / pi`` (N,))."""
    count = n.shape[0]
    wi, pdf = torch.empty(count, 3, device=n.device), torch.empty(count, device=n.device)
    launch(warp_kernels().cosine_kernel, count, [Vec3(n), u, Vec3(wi), pdf], n.device)
    return wi, pdf


def offset_origins(p: torch.Tensor, n: torch.Tensor, wi: torch.Tensor, offset: float) -> torch.Tensor:
    """Ray origins (N, 3) ``p +- offset n``, on the side of ``n`` (N, 3) that ``wi`` (N, 3) points to."""
    o = torch.empty(p.shape[0], 3, device=p.device)
    launch(warp_kernels().spawn_kernel, p.shape[0], [Vec3(p), Vec3(n), Vec3(wi), float(offset), Vec3(o)], p.device)
    return o


def tangents_add(pixel, counts, rho, emitted, tangents: tuple, direct, occluded, scatter: bool, jacobian: torch.Tensor | None = None, places: torch.Tensor | None = None):
    """One bounce's contributions in the scene's constant parameters (the kernel's docstring):
    their derivatives added to ``jacobian`` (P, 3, S) float64 (pixel, channel, slot: the M
    materials' rho, then the emitters' eps) and/or, with ``places`` (S,) int64, their monomial
    codes; then each path's vertex material counted in ``counts`` (N, M) int32 (its throughput's
    factors of each rho) when the paths ``scatter`` on.

    Args:
        pixel: (N,) int64 film index; rho (M, 3); emitted, direct (N, 3) the bounce's contributions
            (``direct`` before occlusion); tangents: the extra outputs of ``invrender.core.fused.vertex``;
        occluded: (N,) bool the shadow rays' answers (None: no emitter samples).
    Returns:
        (codes of the emission (N,), of the direct light (N,)) int64 with ``places`` (-1: no
        contribution), else None.
    """
    n, dev = pixel.shape[0], pixel.device
    emitted_factor, emitter_hit, direct_factor, emitter_sampled, material_hit = tangents
    blocked = occluded if occluded is not None else torch.ones(n, dtype=torch.bool, device=dev)
    none64 = torch.zeros(0, dtype=torch.float64, device=dev)
    codes = [torch.empty(n if places is not None else 0, dtype=torch.int64, device=dev) for _ in range(2)]
    inputs = [
        pixel, counts.view(-1), Vec3(rho), Vec3(emitted), Vec3(emitted_factor), emitter_hit, Vec3(direct), Vec3(direct_factor), emitter_sampled, blocked, material_hit,
        int(scatter), int(jacobian.shape[2]) if jacobian is not None else 0, jacobian.view(-1) if jacobian is not None else none64,
        places if places is not None else torch.zeros(0, dtype=torch.int64, device=dev), *codes,
    ]  # fmt: skip
    launch(warp_kernels().tangent_kernel, n, inputs, dev)
    return tuple(codes) if places is not None else None


def camera_samples(ids: torch.Tensor, spp: int, width: int, mode: int, key_salt: int, pattern_salt: int, cells: int, m: int, salts, lens: bool):
    """The camera samples of path ids ``ids`` (N,) int64 (``pixel * spp + sample``, no plan): mode
    0 stratified, 1 independent, 2 antithetic; ``key_salt`` / ``pattern_salt`` the hashed seeds of the path keys and the pixel patterns, ``cells`` samples (pairs) per pattern
    factored ``m x cells / m``, ``salts`` (4,) those of the camera's numbers (bounce 0).

    Returns:
        pixel (N,) int64, keys (N,) int32, film positions (N, 2) float32 in pixels, lens uniforms
        (N, 2) (``lens``; else None): the values of ``driver.camera_paths``'s torch expressions.
    """
    count, device = ids.shape[0], ids.device
    pixel = torch.empty(count, dtype=torch.int64, device=device)
    keys = torch.empty(count, dtype=torch.int32, device=device)
    film = torch.empty(count, 2, device=device)
    uv = torch.empty(count if lens else 1, 2, device=device)
    inputs = [ids, int(spp), int(width), int(mode), key_salt, pattern_salt, cells, m, salts, int(lens), pixel, keys, Vec2(film), Vec2(uv)]
    launch(warp_kernels().camera_samples_kernel, count, inputs, device)
    return pixel, keys, film, uv if lens else None
