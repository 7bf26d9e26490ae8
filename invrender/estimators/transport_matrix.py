"""The light-transport matrix of an environment map, as a product of one render per view and half.

Every image is exactly linear in an ``envmap``'s texels (sampling never depends on them), ``I_v =
A_v L``: :func:`transport_matrix` renders each view with the map's texels set to 1 and every other
emitter dark into a :class:`~invrender.core.texel_film.TexelFilm`, which scatters each
contribution that ends on the map into its pixel's row and its four texels' columns. It does so
twice, from independent seeds (the halves ``A1``, ``A2``): their mean is the estimate of ``A``,
``sym(A1^T A2)`` an unbiased estimate of ``A^T A`` (the normal equations without the noise's
``E^T E``), and ``(A1 - A2) L / 2`` the Monte Carlo error of ``A L`` for any map ``L``.

The columns are the map's texels or the leaves of a piecewise-constant basis
(:class:`~invrender.estimators.map_basis.MapBasis`, n <= T unknowns). :func:`view_halves` renders one
view's halves at a time (what a streamed solve accumulates and drops); :func:`transport_matrix`
keeps them all. On the CPU a view's two halves are traced at once, each by one worker thread.

Memory: the two halves are dense float32, ``24 P n`` bytes (P pixels of all views, n columns,
3 channels, 4 bytes, 2 halves); :func:`matrix_bytes` states it, and :func:`transport_matrix`
refuses before any work when it (with a solve's ``extra_bytes``) exceeds the memory budget.

Light that does not end on the map (other emitters, the ambient term) does not depend on it: it
is rendered once with the map dark (:attr:`TransportMatrix.offset`), with the same sampling.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from concurrent.futures import ThreadPoolExecutor

import torch

from invrender.estimators.map_basis import MapBasis
from invrender.errors import ParameterError
from invrender.registry import EMITTERS
from invrender.scene.scene import AMBIENT, Scene
from invrender.core.driver import RenderSettings, available_memory_bytes, check_filter_supported, cpu_workers, for_each_chunk, one_thread
from invrender.plugins.integrators import make_integrator
from invrender.core.texel_film import TexelFilm
from invrender.validate import check_int, check_paths

#: bytes of the two dense halves per pixel, texel: 2 halves x 3 channels x float32
BYTES_PER_ENTRY = 24


def matrix_bytes(pixels: int, columns: int) -> int:
    """Bytes of the two halves of a transport matrix of ``pixels`` x ``columns`` (texels or a
    basis' leaves)."""
    return BYTES_PER_ENTRY * pixels * columns


def memory_budget(memory_mb: float | None) -> float:
    """Bytes a transport matrix and its solve may take: ``memory_mb`` MiB, or (None) 90% of the
    memory available (``MemAvailable``; 8 GiB where unknown)."""
    if memory_mb is not None:
        if not (isinstance(memory_mb, (int, float)) and math.isfinite(memory_mb) and memory_mb > 0):
            raise ParameterError(f"memory_mb must be a number > 0, got {memory_mb!r}")
        return memory_mb * 2**20
    have = available_memory_bytes()
    return 0.9 * (have if have is not None else 8 * 2**30)


def envmap_of(scene: Scene, emitter: str) -> int:
    """The index of ``emitter``, an emitter with a texel lookup (``envmap``) and a map (h, w, 3);
    a one-line :class:`ParameterError` otherwise."""
    from invrender.errors import did_you_mean

    if emitter not in scene.emitters:
        raise ParameterError(f"no emitter {emitter!r} in the scene{did_you_mean(emitter, scene.emitters)} (emitters: {', '.join(scene.emitters) or 'none'})")
    k = scene.emitters.index(emitter)
    kind = scene.emitter_spec(k).type
    if not getattr(EMITTERS[kind], "texel_lookup", False):
        raise ParameterError(f"emitter {emitter!r} is of type {kind!r}: the transport matrix is of an environment map (type 'envmap')")
    if scene.params[f"{emitter}.emission"].ndim != 3:
        raise ParameterError(f"{emitter}.emission is one RGB value, not a map: give the emitter an (h, w, 3) map (its size is the fit's)")
    return k


@dataclasses.dataclass
class TransportMatrix:
    """The transport matrix of one environment map over several views, in two independent halves.

    Attributes:
        emitter: the map's emitter name.
        shape: (h, w), the map's texels (T = h w, row-major as ``map.reshape(-1, 3)``).
        halves: (A1, A2), each (3, P, n) float32, already divided by its spp: the image of view v
            under a map L (h, w, 3) of the basis is ``A[c, rows of v] @ x[:, c]`` per channel c,
            x (n, 3) the map's leaf values (n = T, x = L.reshape(-1, 3) for the texels' basis).
        views: per view (height, width); view v's pixels are rows ``starts[v] ..`` (row-major).
        offset: (P, 3) float32 the light that does not end on the map (other emitters), mean of
            the halves' seeds' renders with the map dark; None when there is none.
        spp: samples per pixel of each half.
        seeds: per view, the seeds of its two halves (a render of that view with that seed, spp
            and ``sampler`` equals the half's image to float rounding).
        seconds: the time the renders took.
        basis: the columns' :class:`~invrender.estimators.map_basis.MapBasis` (the texels by default).
        sampler: the renders' ``RenderSettings.sampler``.
    """

    emitter: str
    shape: tuple[int, int]
    halves: tuple[torch.Tensor, torch.Tensor]
    views: list[tuple[int, int]]
    offset: torch.Tensor | None
    spp: int
    seeds: list[tuple[int, int]]
    seconds: float = 0.0
    basis: MapBasis | None = None
    sampler: str = "stratified_direct"

    @property
    def starts(self) -> list[int]:
        """The first row of each view (and the row count last)."""
        out = [0]
        for h, w in self.views:
            out.append(out[-1] + h * w)
        return out

    @property
    def pixels(self) -> int:
        return self.starts[-1]

    @property
    def texels(self) -> int:
        return self.shape[0] * self.shape[1]

    @property
    def columns(self) -> int:
        return int(self.halves[0].shape[2])

    @property
    def mean(self) -> torch.Tensor:
        """(3, P, T) float32 the estimate of A (both halves' mean)."""
        return 0.5 * (self.halves[0] + self.halves[1])

    def images(self, texels, half: int | None = None) -> list[torch.Tensor]:
        """Per view, the image (H, W, 3) float32 under the map ``texels`` ((h, w, 3), or (n, 3)
        leaf values of the basis), light off the map included: of the matrix (both halves' mean)
        or of one ``half`` (0 or 1)."""
        L = torch.as_tensor(texels, dtype=torch.float32).reshape(-1, 3)
        if L.shape[0] != self.columns:
            raise ParameterError(f"the map must be {self.shape[0]} x {self.shape[1]} x 3 (or {self.columns} x 3 leaf values) for this transport matrix, got {tuple(torch.as_tensor(texels).shape)}")
        A = self.mean if half is None else self.halves[half]
        flat = torch.stack([A[c] @ L[:, c] for c in range(3)], dim=1)
        if self.offset is not None:
            flat = flat + self.offset
        s = self.starts
        return [flat[s[v] : s[v + 1]].reshape(h, w, 3) for v, (h, w) in enumerate(self.views)]


@dataclasses.dataclass
class ViewHalves:
    """One view's part of a transport matrix (:func:`view_halves`).

    Attributes:
        index: the view's position among the cameras.
        size: (height, width).
        halves: (A1, A2), each (3, height * width, n) float32, divided by spp.
        offset: (height * width, 3) the light that does not end on the map, or None.
        seeds: the halves' seeds.
    """

    index: int
    size: tuple[int, int]
    halves: tuple[torch.Tensor, torch.Tensor]
    offset: torch.Tensor | None
    seeds: tuple[int, int]


def matrix_views(scene: Scene, emitter: str, cameras, spp: int, seed: int, basis: MapBasis | None) -> tuple[list[Scene], MapBasis]:
    """The views (the scene per camera) and the basis of a transport matrix, its settings checked
    (one-line :class:`ParameterError` each)."""
    check_filter_supported(scene, "the transport matrix")
    envmap_of(scene, emitter)
    current = scene.params[f"{emitter}.emission"]
    h, w = int(current.shape[0]), int(current.shape[1])
    check_int("transport matrix ", "spp", spp, 1)
    check_int("transport matrix ", "seed", seed, 0)
    views = [scene] if cameras is None else [scene.with_camera(c) for c in cameras]
    if not views:
        raise ParameterError("transport_matrix needs at least one camera")
    for v in views:
        check_paths(v.width, v.height, spp)
    if basis is None:
        basis = MapBasis.of_texels(h, w)
    elif basis.shape != (h, w):
        raise ParameterError(f"the basis is of a {basis.shape[0]} x {basis.shape[1]} map, {emitter}.emission is {h} x {w}")
    return views, basis


def view_halves(
    scene: Scene,
    emitter: str = "sky",
    *,
    cameras=None,
    integrator="path",
    spp: int = 64,
    max_depth: int | None = 3,
    seed: int = 0,
    sampling_map=None,
    basis: MapBasis | None = None,
    sampler: str = "stratified_direct",
    progress: bool = False,
):
    """Yields each view's :class:`ViewHalves` in turn (arguments as :func:`transport_matrix`):
    a consumer that accumulates and drops them holds one view's ``24 P_v n`` bytes at a time."""
    views, basis = matrix_views(scene, emitter, cameras, spp, seed, basis)
    k = scene.emitters.index(emitter)
    name = f"{emitter}.emission"
    current = scene.params[name].detach()
    h, w = int(current.shape[0]), int(current.shape[1])
    sample_from = current if sampling_map is None else torch.as_tensor(sampling_map, dtype=current.dtype)
    if sample_from.shape != current.shape:
        raise ParameterError(f"sampling_map must be {h} x {w} x 3 like {name}, got {tuple(sample_from.shape)}")
    if not bool(torch.isfinite(sample_from).all()) or bool((sample_from < 0).any()) or float(sample_from.max()) <= 0:
        raise ParameterError("sampling_map must be finite, >= 0 and not all zero")
    # every other emitter (and the ambient term) dark: their light is the offset, rendered apart
    others = [n for n in scene.params if n != name and (n == AMBIENT or n.rpartition(".")[0] in scene.emitters)]
    lit = [n for n in others if float(scene.params[n].detach().abs().max()) > 0]
    ones = torch.ones_like(current)
    values = {name: ones, **{n: torch.zeros_like(scene.params[n].detach()) for n in others}}
    sampling = {n: scene.params[n].detach() for n in others}
    sampling[name] = sample_from.to(current.device)
    model = make_integrator(integrator, **({} if max_depth is None else {"max_depth": max_depth}))
    device = scene.device
    columns = None if basis.is_texels else basis.columns().to(device)
    V = len(views)
    # on the CPU the two halves are traced at once, each by one worker: twice the paths per chunk,
    # half the chunks' fixed costs (the launches and queries of every bounce)
    together = cpu_workers(device) > 1

    def settings_of(s: int) -> RenderSettings:
        return RenderSettings(spp=spp, seed=s, progress=progress, sampler=sampler, sampling_params=sampling)

    # one render context for every view and half (it holds the geometry, materials and emitters,
    # not the camera): built once, and single-threaded queries where the halves are traced at once
    with torch.no_grad(), one_thread(together):
        ctx = model.context(views[0], settings_of(0), device, params=values)

    def trace_half(view, matrix: torch.Tensor, s: int) -> torch.Tensor | None:
        """Half ``matrix`` (3, P, n) of ``view`` traced with seed ``s``; the image of the light off
        the map (P, 3) where some other emitter is lit, else None."""
        settings = settings_of(s)
        with torch.no_grad(), one_thread(together):
            light = next(light for light in ctx.lights.lights if k in light.emitters)
            slot = light.emitters.index(k)
            film = TexelFilm(matrix, lambda d: light.texels(slot, d), view.width, view.height, 0, columns)
            for_each_chunk(view, settings, device, lambda worker, state: model.trace(ctx, state, film), grad=False)
            matrix /= spp
            if lit:
                return model.render(view, settings.replace(sampling_params={name: sampling[name]}), device, params={name: torch.zeros_like(current)}).reshape(-1, 3)
        return None

    with ThreadPoolExecutor(2) if together else contextlib.nullcontext() as pool:
        for v, view in enumerate(views):
            pair = (2 * (seed * V + v), 2 * (seed * V + v) + 1)
            P = view.width * view.height
            halves = [torch.zeros(3, P, basis.n, dtype=torch.float32, device=device) for _ in range(2)]
            if together:
                darks = list(pool.map(trace_half, (view, view), halves, pair))
            else:
                darks = [trace_half(view, m, s) for m, s in zip(halves, pair)]
            offset = 0.5 * (darks[0] + darks[1]) if lit else None
            yield ViewHalves(v, (view.height, view.width), (halves[0], halves[1]), offset, pair)



def transport_matrix(
    scene: Scene,
    emitter: str = "sky",
    *,
    cameras=None,
    integrator="path",
    spp: int = 64,
    max_depth: int | None = 3,
    seed: int = 0,
    sampling_map=None,
    basis: MapBasis | None = None,
    memory_mb: float | None = None,
    extra_bytes: int = 0,
    sampler: str = "stratified_direct",
    progress: bool = False,
) -> TransportMatrix:
    """The transport matrix of the envmap ``emitter`` of ``scene`` seen by ``cameras`` (one per
    view; None: the scene's own camera), in two halves of ``spp`` samples per pixel each.

    Args:
        integrator: an integrator spec whose vertex steps tell the film each arrival (``path``,
            ``random_walk``, ...); ``max_depth`` as :func:`invrender.render` (None: its default).
        seed: view v's halves use seeds ``2 (seed V + v)`` and ``2 (seed V + v) + 1``.
        sampling_map: the map (h, w, 3) the emitter's sampling density is built from (default:
            the scene's current map). The matrix is unbiased for any density; one close to the
            light's (a sun included) has less noise.
        basis: the columns, a :class:`~invrender.estimators.map_basis.MapBasis` of the map (default:
            its texels).
        memory_mb: the budget (MiB) the two halves plus ``extra_bytes`` (a solve's) must fit in;
            None: 90% of the memory available. Refused before any work otherwise.
        sampler: the renders' ``RenderSettings.sampler``; ``"stratified_direct"`` (the default)
            stratifies each pixel's first-vertex BSDF and emitter samples, the numbers most of a
            matrix's entries are made of: on ``sky_spheres`` the held-out relighting error of a
            fit at 2 x 16 spp fell from 5.5% (``"stratified"``) to 3.6%.
    """
    views, basis = matrix_views(scene, emitter, cameras, spp, seed, basis)
    h, w = basis.shape
    P, n = sum(v.width * v.height for v in views), basis.n
    need, budget = matrix_bytes(P, n) + int(extra_bytes), memory_budget(memory_mb)
    if need > budget:
        raise ParameterError(
            f"the transport matrix of {len(views)} view(s), {P} pixels x {n} columns ({h}x{w} map) needs {need / 2**30:.2f} GiB "
            f"(24 x pixels x columns for its two float32 halves{' + the solve' if extra_bytes else ''}), over the {budget / 2**30:.2f} GiB budget: use fewer or smaller views or a coarser map"
        )
    clock = time.perf_counter()
    halves, offsets, seeds = ([], []), [], []
    stream = view_halves(scene, emitter, cameras=cameras, integrator=integrator, spp=spp, max_depth=max_depth, seed=seed, sampling_map=sampling_map, basis=basis, sampler=sampler, progress=progress)
    for part in stream:
        for half in (0, 1):
            halves[half].append(part.halves[half])
        offsets.append(part.offset)
        seeds.append(part.seeds)
    A1, A2 = (torch.cat(parts, dim=1) if len(parts) > 1 else parts[0] for parts in halves)
    offset = None if offsets[0] is None else torch.cat(offsets)
    return TransportMatrix(emitter, (h, w), (A1, A2), [(v.height, v.width) for v in views], offset, spp, seeds, time.perf_counter() - clock, basis, sampler)
