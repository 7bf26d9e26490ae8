"""The chunked wavefront driver: (pixel, sample) paths in chunks sized by a memory budget.

Each chunk is a flat batch of path ids ``pixel * spp + sample``. Camera rays are generated from
counter-based numbers, the integrator runs its bounce loop over the batch, and contributions
accumulate in the film; chunks only add, so any spp fits in bounded memory and the image does not
depend on the chunk size (``docs/architecture.md``: wavefront, counter-based random numbers).

On the CPU, one worker thread per core traces its own chunks single-threaded (torch ops and Embree
release the GIL): this keeps both cores busy through the many small per-bounce tensor operations,
which intra-op threading parallelizes poorly. Each worker has its own film; they are summed at the
end in float64, so the image is the same whatever the number of workers.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from invrender.errors import ParameterError
from invrender.scene.camera import Camera
from invrender.scene.scene import Scene
from invrender.core import compiled, ranks
from invrender.core.context import PathState
from invrender.core.memory import keep_freed_blocks
from invrender.core.camera_samples import camera_samples, pinhole_constants
from invrender.validate import MAX_SPP, check_bool, check_choice, check_float, check_int

#: working-set estimate per path in a chunk (state, hits, temporaries, backend copies), bytes
BYTES_PER_PATH = 2048
#: the same for path replay's passes (and the forward pass that keeps radiance for them): on top of
#: a path's state, its float64 adjoints and the factors autograd saves at each vertex
BYTES_PER_REPLAYED_PATH = 5120


#: how a pixel's samples are drawn (RenderSettings.sampler)
SAMPLERS = ("stratified", "independent", "antithetic", "stratified_direct")
#: intersection backends (RenderSettings.backend)
BACKENDS = ("embree", "warp", "torch")


@dataclass(frozen=True)
class RenderSettings:
    """How to run a render, whatever the integrator.

    Attributes:
        spp: samples (paths) per pixel, > 0.
        seed: seed of the counter-based random numbers, >= 0.
        terms: return one image per Neumann term, shape (K, H, W, 3), summing to the full image.
        backend: intersection backend ``"embree"`` (CPU), ``"warp"`` (CUDA or CPU) or ``"torch"``
            (any device, brute force); None = the device's default (embree on the CPU, warp on CUDA).
        chunk_paths: paths traced per chunk; None = sized by ``memory_mb``.
        memory_mb: memory budget for one chunk's working set, MiB.
        progress: show a progress bar (rate, ETA) on renders that take longer than a second.
        sampler: how a pixel's samples are drawn (:data:`SAMPLERS`): ``"stratified"``
            (correlated multi-jittered: every count stratified on both axes and in 2-D, the default), ``"independent"`` (each uniform over the pixel)
            or ``"antithetic"`` (pairs: the second path of each pair draws ``1 - u`` for every
            number ``u`` of the first, pixel jitter, lens, light samples, BSDF samples and
            roulette; the pairs are stratified) or ``"stratified_direct"`` (as ``"stratified"``, and the
            first vertex's BSDF and emitter samples stratified as well, a pattern per pair of
            dimensions: the path tracer's direct light and first bounce with less noise for the
            same spp; :func:`camera_paths`).
        plan: which samples each pixel traces (:class:`SamplePlan`, the passes of adaptive
            sampling); None = samples ``0 .. spp - 1`` in every pixel.
        sampling_params: parameter values (name -> tensor, all or some) the emitters' sampling
            (choice by power, environment-map densities) and the BSDFs' (a glossy material's
            roughness: its visible normals and pdf) are built from instead of the render's own;
            None = its own, detached. Finite differences with common random numbers give the
            perturbed renders the unperturbed values, so every render draws the same paths.
    """

    spp: int = 64
    seed: int = 0
    terms: bool = False
    backend: str | None = None
    chunk_paths: int | None = None
    memory_mb: float = 512.0
    progress: bool = True
    sampler: str = "stratified"
    plan: SamplePlan | None = dataclasses.field(default=None, compare=False)
    sampling_params: dict | None = dataclasses.field(default=None, compare=False)

    def __post_init__(self):
        check_int("", "spp", self.spp, 1, MAX_SPP)
        check_choice("", "sampler", self.sampler, SAMPLERS)
        check_int("", "seed", self.seed, 0)
        check_bool("", "terms", self.terms)
        check_bool("", "progress", self.progress)
        if self.backend is not None:
            check_choice("intersection ", "backend", self.backend, BACKENDS)
        if self.chunk_paths is not None:
            check_int("", "chunk_paths", self.chunk_paths, 1)
        check_float("", "memory_mb", self.memory_mb, positive=True)

    def replace(self, **changes) -> RenderSettings:
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class SamplePlan:
    """A pass of samples with a count of its own in every pixel (adaptive sampling's rounds).

    Pixel p traces the samples with indices ``first[p] .. first[p] + count[p] - 1``: its random
    numbers are those of these sample indices, so passes with disjoint index ranges are
    independent. Within a pass the pixel's ``count[p]`` samples are stratified as ``count[p]``
    samples of a uniform render are (``RenderSettings.sampler``).

    Attributes:
        count: (P,) int64 samples of each pixel in this pass, >= 0 (P = width * height).
        first: (P,) int64 index of each pixel's first sample.
    """

    count: torch.Tensor
    first: torch.Tensor

    @property
    def total(self) -> int:
        """Paths in the pass."""
        return int(self.count.sum())

    def locate(self, ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flat path ids (N,) in ``[0, total)`` -> (pixel (N,), index of the sample within the
        pixel's pass (N,)); ids run through pixel 0's samples, then pixel 1's, ..."""
        ends = torch.cumsum(self.count.to(ids.device), 0)
        pixel = torch.searchsorted(ends, ids, right=True)
        return pixel, ids - (ends[pixel] - self.count.to(ids.device)[pixel])


def for_each_chunk(
    scene: Scene, settings: RenderSettings, device: torch.device, work, grad: bool | None = None, across_ranks: bool = False, with_start: bool = False,
    bytes_per_path: int = BYTES_PER_PATH, max_chunk: int | None = None, with_positions: bool = False,
) -> None:  # fmt: skip
    """Call ``work(worker, camera_paths)`` for every chunk of the (pixel, sample) paths
    (``work(worker, camera_paths, start)`` with ``with_start``: ``start`` the chunk's first path id,
    the same for the same settings whatever the workers and ranks).

    On the CPU, one worker thread per core takes chunks ``w, w + workers, ...`` (a fixed split, so
    results do not depend on timing) and runs single-threaded; a progress bar shows rate and ETA.
    ``grad``: autograd on or off inside the workers (default: the caller's mode).
    ``across_ranks``: inside a torch.distributed group, trace only this rank's chunks (chunk c
    belongs to rank ``c mod world``; :mod:`invrender.core.ranks`): the caller sums the ranks'
    results. Otherwise every chunk is traced here.
    ``bytes_per_path``: the working set of a path, which sizes the chunks from ``settings.memory_mb``
    (unless ``settings.chunk_paths`` is given); ``max_chunk``: at most that many paths a chunk then.
    ``with_positions``: ``work`` also receives the chunk's film positions (N, 2) float32 (pixel
    units), last: a filter's splat needs them (:mod:`invrender.core.rfilter`).
    """
    if device.type == "cpu":
        keep_freed_blocks()  # chunk-sized temporaries reused, not page-faulted in anew
    workers = cpu_workers(device)
    rank, world = ranks.world() if across_ranks else (0, 1)
    total = total_paths(scene, settings)
    chunk = settings.chunk_paths or max(1024, min(int(settings.memory_mb * 2**20 // bytes_per_path) // workers, -(-total // (workers * world)), max_chunk or total))
    starts = range(0, total, chunk)[rank::world]
    grad = torch.is_grad_enabled() if grad is None else grad
    mine = sum(min(total, s + chunk) - s for s in starts)
    bar = tqdm(total=mine, unit="path", unit_scale=True, delay=1.0, disable=not settings.progress or not ranks.is_main(), desc=f"render {scene.name}", file=sys.stderr, leave=False)
    stop = threading.Event()

    def run(w: int) -> None:
        if workers > 1:
            torch.set_num_threads(1)  # per thread (OpenMP): the workers, not the ops, use the cores
        with torch.set_grad_enabled(grad):  # grad mode is thread-local
            for start in starts[w::workers]:
                if stop.is_set():
                    return
                ids = torch.arange(start, min(total, start + chunk), dtype=torch.int64, device=device)
                state, xy = camera_paths(scene, settings, ids, positions=True)
                args = (w, state, start) if with_start else (w, state)
                work(*args, xy) if with_positions else work(*args)
                bar.update(ids.numel())

    with bar, compiled.in_calling_threads(device):
        if workers == 1:
            run(0)
            return
        with ThreadPoolExecutor(workers) as pool:
            jobs = [pool.submit(run, w) for w in range(workers)]
            try:
                for job in jobs:
                    job.result()
            except BaseException:
                stop.set()
                raise


def total_paths(scene: Scene, settings: RenderSettings) -> int:
    """Camera paths a render traces: every sampled pixel's spp (the image's pixels and, with the
    film's ``sample_border``, a border around them: :func:`sampled_size`), or the paths of
    ``settings.plan``."""
    if settings.plan is not None:
        return settings.plan.total
    width, height = sampled_size(scene)
    return width * height * settings.spp


def sampled_size(scene: Scene) -> tuple[int, int]:
    """(width, height) of the grid of pixels whose samples are traced: the image's, grown by the
    film's border on each side (``scene.film.border``: the filter's border size with
    ``sample_border``, as Mitsuba samples it)."""
    b = scene.film.border
    return scene.width + 2 * b, scene.height + 2 * b


def film_weights(scene: Scene, settings: RenderSettings, device: torch.device) -> torch.Tensor:
    """(W * H,) float64: the sum of the filter weights every pixel receives from the samples of a
    render (what its film divides by; :mod:`invrender.core.rfilter`), from the samples' film
    positions alone (nothing is traced). For the adjoint of a filtered film (path replay)."""
    rfilter = scene.film.filter
    weights = torch.zeros(scene.width * scene.height, dtype=torch.float64, device=device)
    total = total_paths(scene, settings)
    step = max(1024, int(settings.memory_mb * 2**20 // (64 * rfilter.taps**2)))
    border = float(scene.film.border)
    for start in range(0, total, step):
        ids = torch.arange(start, min(total, start + step), dtype=torch.int64, device=device)
        samples = _camera_samples(scene, settings, ids)
        rfilter.footprint(samples[2] - border, scene.width, scene.height).weights_into(weights)
    return weights


def check_filter_supported(scene: Scene, what: str) -> None:
    """A one-line :class:`ParameterError` when ``scene``'s film has a filter other than the box and
    ``what`` (a consumer of films that follows only the box) cannot follow it."""
    if not scene.film.is_box:
        raise ParameterError(f"{what} supports the box filter only, and scene {scene.name!r} has the {scene.film.filter.type_name!r} filter: render with filter='box'")


def available_memory_bytes() -> int | None:
    """Memory the OS can still give this process (``MemAvailable``), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def check_film_memory(width: int, height: int, device: torch.device, images: int = 1) -> None:
    """A one-line :class:`ParameterError` before any work when the films of a ``width x height``
    render (float64 RGB sums per CPU worker, ``images`` of them each, e.g. one per Neumann term)
    cannot fit in the memory available."""
    need = width * height * 3 * 8 * images * cpu_workers(device)
    have = available_memory_bytes() if device.type == "cpu" else None
    if have is not None and need > have:
        raise ParameterError(
            f"a {width}x{height} render needs {need / 2**30:.1f} GiB for its films ({images} image(s) of float64 RGB sums per worker), "
            f"more than the {have / 2**30:.1f} GiB available: lower the resolution"
        )


@contextlib.contextmanager
def one_thread(on: bool = True):
    """Inside (where ``on``): this thread's torch ops single-threaded (OpenMP's thread count is
    per thread), so a render started here also traces its chunks in this thread
    (:func:`cpu_workers`) and splits no Embree query across threads (``Integrator.context``: two
    halves of a transport matrix traced side by side were 20% faster so); the count before is
    restored after."""
    threads = torch.get_num_threads()
    if on:
        torch.set_num_threads(1)
    try:
        yield
    finally:
        if on:
            torch.set_num_threads(threads)


def cpu_workers(device: torch.device) -> int:
    """Chunks traced at once: one per core on the CPU (each single-threaded), one on a GPU."""
    if device.type != "cpu":
        return 1
    return max(1, min(len(os.sched_getaffinity(0)), torch.get_num_threads()))


def camera_paths(scene: Scene, settings: RenderSettings, ids: torch.Tensor, positions: bool = False):
    """Camera rays for flat path ids (N,) = ``pixel * spp + sample`` (or the ids of
    ``settings.plan``, each pixel with its own count).

    ``settings.sampler`` ``"stratified"``: a pixel's spp samples are correlated multi-jittered
    (:func:`~invrender.core.sampler.multijitter`: every count stratified, a pattern per pixel
    and pass), so every sample's film position is uniform over the pixel on average (a box filter,
    unbiased);
    ``"independent"``: every sample uniform over the pixel; ``"antithetic"``: samples 2k and 2k + 1
    share their counters, the second mirrored (``sampler.mirrored``), and the pairs are stratified
    as samples are; ``"stratified_direct"``: as ``"stratified"``, and the numbers of the first
    vertex's BSDF direction and emitter sample (:data:`~invrender.core.lanes.DIRECT_PAIRS`)
    multi-jittered per pixel too, each pair by a pattern of its own (``PathState.strata``; each
    number still uniform, so estimates stay unbiased). A thin lens draws its lens point from
    dimensions 2 and 3 of the same counters.
    With a plan, spp is the pixel's count in the pass and sample k has the index ``first + k``.
    With the film's ``sample_border`` the pixels are those of the grown grid (:func:`sampled_size`),
    ``pixel`` indexes that grid, and film positions run from ``-border`` to ``width + border``.
    Returns the :class:`PathState`, or (state, film positions (N, 2) float32) with ``positions``.
    """
    camera = scene.camera
    border = scene.film.border
    if type(camera) is Camera and camera.is_pinhole and Camera.generate_rays is _GENERATE_RAYS:  # the rays in the samples' kernel
        pixel, keys, film_xy, lens, d, *strata = _camera_samples(scene, settings, ids, pinhole_constants(camera, scene.width, scene.height, border))
        o = torch.tensor(camera.origin, dtype=torch.float32, device=ids.device).expand_as(d)
    else:
        pixel, keys, film_xy, lens, *strata = _camera_samples(scene, settings, ids)
        d = None
    if border:
        film_xy = film_xy - float(border)  # the grown grid's origin is border pixels up and left of the image's
    if d is None:
        o, d = camera.generate_rays(film_xy, scene.width, scene.height, lens)
    n_paths = ids.shape[0]
    beta = torch.ones(3, n_paths, device=ids.device).t()  # (N, 3) by columns, as the compiled bounce keeps its 3-vectors
    state = PathState(
        keys=keys, pixel=pixel, o=o.contiguous(), d=d, beta=beta,
        pdf_dir=torch.ones(n_paths, device=ids.device), delta=torch.ones(n_paths, dtype=torch.bool, device=ids.device),
        strata=strata[0] if strata else None,
    )  # fmt: skip
    return (state, film_xy) if positions else state


def _camera_samples(scene: Scene, settings: RenderSettings, ids: torch.Tensor, pinhole=None):
    """(pixel (N,) int64, keys (N,) int32, film positions (N, 2) in pixels, lens uniforms (N, 2) or
    None for a pinhole camera), then with ``pinhole`` the rays' directions (N, 3), of path ids (N,)
    (:mod:`invrender.core.camera_samples`)."""
    width = sampled_size(scene)[0]
    return camera_samples(ids, settings.spp, width, settings.sampler, settings.seed, not scene.camera.is_pinhole, settings.plan, pinhole)


#: the perspective camera's own ray generation: where a pinhole uses it (not a subclass's, nor a
#: replacement's), its rays are computed in the camera samples' kernel by the same expressions
#: (:func:`~invrender.core.camera_samples.pinhole_directions`: 3 ms of torch per 131k rays saved)
_GENERATE_RAYS = Camera.generate_rays

