"""render(): the wavefront over (pixel, sample) ids, in chunks sized by a memory budget.

Each chunk is a flat batch of path ids ``pixel * spp + sample``. Camera rays are generated from
counter-based numbers, the integrator runs its bounce loop over the batch, and contributions
accumulate in the film; chunks only add, so any spp fits in bounded memory and the image does not
depend on the chunk size (DESIGN.md decisions 2 and 3).

On the CPU, one worker thread per core traces its own chunks single-threaded (torch ops and Embree
release the GIL): this keeps both cores busy through the many small per-bounce tensor operations,
which intra-op threading parallelizes poorly. Each worker has its own film; they are summed at the
end in float64, so the image is the same whatever the number of workers.
"""

from __future__ import annotations

import math
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import torch
from tqdm.auto import tqdm

from invrender.errors import ParameterError
from invrender.scene.scene import Scene
from invrender.transport.context import PathState, RenderSettings, TransportContext
from invrender.transport.film import Film
from invrender.transport.integrators import INTEGRATOR_MODULES
from invrender.transport.sampler import path_keys, uniform

#: working-set estimate per path in a chunk (state, hits, temporaries, backend copies), bytes
BYTES_PER_PATH = 2048


ESTIMATORS = ("autodiff", "replay")


def render(
    scene: Scene,
    integrator: str = "path",
    spp: int = 64,
    max_depth: int = 8,
    seed: int = 0,
    *,
    terms: bool = False,
    rr_depth: int = 5,
    estimator: str | None = None,
    backend: str | None = None,
    device=None,
    chunk_paths: int | None = None,
    memory_mb: float = 512.0,
    progress: bool = True,
) -> torch.Tensor:
    """Render ``scene`` by Monte Carlo estimation of ``I = g eps + gMg eps + g(Mg)^2 eps + ...``.

    Args:
        scene: from :func:`invrender.load_scene`; its ``params`` are read at this call.
        integrator: ``"path"`` or ``"random_walk"``.
        spp: samples per pixel.
        max_depth: Neumann terms kept (1 = emitters seen directly, 2 = + direct light, ...; -1 =
            unbounded, ended by Russian roulette).
        seed: the image is a pure function of the seed (and the scene and settings).
        terms: return one image per Neumann term instead of their sum.
        rr_depth: Russian roulette starts after this many terms.
        estimator: how the image is differentiated when a parameter requires grad:
            ``"replay"`` (default; path-replay backpropagation, memory flat in spp and depth) or
            ``"autodiff"`` (torch records the whole wavefront).
        backend: ``"embree"`` (CPU) or ``"torch"`` (any device); None = the device's default.
        device: where to render; None = the scene's device. Parameters are moved differentiably.
        chunk_paths: paths per chunk; None = from ``memory_mb``.
        memory_mb: memory budget of a chunk's working set, MiB.
        progress: show a progress bar with rate and ETA when the render takes over a second.
    Returns:
        float32 linear radiance, (H, W, 3) with row 0 at the top; (K, H, W, 3) with ``terms``.
        Differentiable in any ``scene.params`` entry that requires grad.
    """
    settings = RenderSettings(
        integrator=integrator, spp=spp, max_depth=max_depth, seed=seed, rr_depth=rr_depth, terms=terms,
        backend=backend, chunk_paths=chunk_paths, memory_mb=memory_mb, progress=progress,
    )  # fmt: skip
    if estimator is not None and estimator not in ESTIMATORS:
        raise ParameterError(f"unknown estimator {estimator!r} (known: {', '.join(ESTIMATORS)})")
    device = torch.device(device) if device is not None else scene.device
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ParameterError("device 'cuda' requested but torch has no CUDA device here")
    differentiable = [k for k, v in scene.params.items() if v.requires_grad] if torch.is_grad_enabled() else []
    if differentiable and (estimator or "replay") == "replay":
        if terms:
            raise ParameterError("terms=True is not available with estimator='replay'; use estimator='autodiff'")
        from invrender.inverse.replay import replay_render

        return replay_render(scene, settings, device, differentiable)
    return render_image(scene, settings, device)


def backpropagate(scene: Scene, grad_image: torch.Tensor, settings: RenderSettings, estimator: str = "replay", device=None) -> None:
    """Add ``<grad_image, dI/dtheta>`` to the gradient of every ``scene.params`` entry that requires
    grad, I being the image :func:`render` returns for ``settings``.

    What ``render(...).backward(grad_image)`` does, without the image: ``replay`` re-traces the
    paths in its backward pass only, so no forward render is spent (a decorrelated loss gradient
    takes ``grad_image = dl/dI`` from another render); ``autodiff`` has to record a forward render.
    ``grad_image``: (H, W, 3).
    """
    if estimator not in ESTIMATORS:
        raise ParameterError(f"unknown estimator {estimator!r} (known: {', '.join(ESTIMATORS)})")
    device = torch.device(device) if device is not None else scene.device
    if estimator == "autodiff":
        render_image(scene, settings, device).backward(grad_image)
        return
    from invrender.inverse.replay import replay_gradient

    values = {k: v for k, v in scene.params.items() if v.requires_grad}
    grads = replay_gradient(scene, settings, device, {k: v.detach() for k, v in values.items()}, grad_image)
    torch.autograd.backward(list(values.values()), [grads[k].to(v.device, v.dtype) for k, v in values.items()])


def render_image(scene: Scene, settings: RenderSettings, device: torch.device, params: dict | None = None) -> torch.Tensor:
    """The image of :func:`render`, recording autograd where a parameter requires grad
    (``params`` overrides ``scene.params`` values)."""
    ctx = TransportContext.build(scene, settings, device, embree_threads=1 if cpu_workers(device) > 1 else None, params=params)
    trace = INTEGRATOR_MODULES[settings.integrator].trace
    films = [Film(scene.width, scene.height, settings.terms, device) for _ in range(cpu_workers(device))]

    def chunk(worker: int, state: PathState) -> None:
        trace(ctx, state, films[worker])

    for_each_chunk(scene, settings, device, chunk)
    return Film.merge(films).develop(settings.spp)


def for_each_chunk(scene: Scene, settings: RenderSettings, device: torch.device, work, grad: bool | None = None) -> None:
    """Call ``work(worker, camera_paths)`` for every chunk of the (pixel, sample) paths.

    On the CPU, one worker thread per core takes chunks ``w, w + workers, ...`` (a fixed split, so
    results do not depend on timing) and runs single-threaded; a progress bar shows rate and ETA.
    ``grad``: autograd on or off inside the workers (default: the caller's mode).
    """
    workers = cpu_workers(device)
    total = scene.width * scene.height * settings.spp
    chunk = settings.chunk_paths or max(1024, min(int(settings.memory_mb * 2**20 // BYTES_PER_PATH) // workers, -(-total // workers)))
    starts = range(0, total, chunk)
    grad = torch.is_grad_enabled() if grad is None else grad
    bar = tqdm(total=total, unit="path", unit_scale=True, delay=1.0, disable=not settings.progress, desc=f"render {scene.name}", file=sys.stderr, leave=False)
    stop = threading.Event()

    def run(w: int) -> None:
        if workers > 1:
            torch.set_num_threads(1)  # per thread (OpenMP): the workers, not the ops, use the cores
        with torch.set_grad_enabled(grad):  # grad mode is thread-local
            for start in starts[w::workers]:
                if stop.is_set():
                    return
                ids = torch.arange(start, min(total, start + chunk), dtype=torch.int64, device=device)
                work(w, camera_paths(scene, settings, ids))
                bar.update(ids.numel())

    with bar:
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


def cpu_workers(device: torch.device) -> int:
    """Chunks traced at once: one per core on the CPU (each single-threaded), one on a GPU."""
    if device.type != "cpu":
        return 1
    return max(1, min(len(os.sched_getaffinity(0)), torch.get_num_threads()))


def camera_paths(scene: Scene, settings: RenderSettings, ids: torch.Tensor) -> PathState:
    """Camera rays for flat path ids (N,) = ``pixel * spp + sample``.

    Pixel samples are stratified: with n = floor(sqrt(spp)), samples 0 .. n^2 - 1 each jitter in
    their own cell of an n x n grid over the pixel and the remaining ones are uniform, so every
    sample's film position is uniform over the pixel on average (a box filter, unbiased).
    """
    spp = settings.spp
    pixel, sample = ids // spp, ids % spp
    keys = path_keys(settings.seed, pixel, sample)
    u = uniform(keys, 0, 2)
    n = math.isqrt(spp)
    grid = sample < n * n
    fx = torch.where(grid, ((sample % n).float() + u[:, 0]) / n, u[:, 0])
    fy = torch.where(grid, ((sample // n).float() + u[:, 1]) / n, u[:, 1])
    film_xy = torch.stack([(pixel % scene.width).float() + fx, (pixel // scene.width).float() + fy], dim=1)
    o, d = scene.camera.generate_rays(film_xy, scene.width, scene.height)
    n_paths = ids.shape[0]
    beta = torch.ones(n_paths, 3, device=ids.device)
    return PathState(keys=keys, pixel=pixel, o=o.contiguous(), d=d, beta=beta, pdf_dir=torch.ones(n_paths, device=ids.device))
