"""Path-replay backpropagation (Vicini, Speierer and Jakob 2021), as a torch.autograd.Function.

The forward pass renders without recording anything. The backward pass receives ``dl/dI`` and, chunk
by chunk, regenerates the very same paths from the counter-based sampler twice:

1. primal: each path's total radiance ``L`` (no autograd);
2. adjoint: the path is followed again with the throughput ``beta`` detached. Every contribution
   ``beta w eps(x_k)`` or ``beta rho(x_i) f eps(y)`` is differentiated locally in its own factors
   (eps, and rho at a next-event vertex); at each scattering vertex x_i the radiance the path still
   gathers beyond it, ``L_rem`` (= L minus what was added so far), contains rho(x_i) exactly once as a
   factor, so its derivative is ``<dl/dI, L_rem / rho_i> d rho_i``.

Each local derivative is taken at once (a tiny autograd graph of one gather), so memory is one
chunk's working set: independent of ``max_depth`` and of spp. The gradient equals autodiff's for
the same seed up to float rounding, except in a colour channel where rho is exactly 0 (there
``L_rem / rho`` is 0/0 and replay returns 0 for that channel).
"""

from __future__ import annotations

import dataclasses
import sys

import torch

from invrender.scene.scene import Scene
from invrender.transport.context import PathState, RenderSettings, TransportContext
from invrender.transport.film import Film
from invrender.transport.integrators import INTEGRATOR_MODULES
from invrender.transport.render import cpu_workers, for_each_chunk, render_image


#: chunks each worker replays between two releases of freed heap memory (see release_freed_memory)
TRIM_EVERY = 2


class AdjointFilm(Film):
    """The adjoint pass's "film": turns contributions into parameter gradients.

    Attributes:
        g: (N, 3) float64 ``dl/dI`` at each path's pixel, divided by spp (a path is 1/spp of it).
        L_rem: (N, 3) float64 radiance each path has yet to gather.
        grads: name -> accumulated gradient for each differentiable leaf in ``leaves``.
    """

    detach_throughput = True

    def __init__(self, g: torch.Tensor, L: torch.Tensor, leaves: dict[str, torch.Tensor]):
        self.g, self.L_rem = g, L.clone()
        self.names, self.leaves = list(leaves), list(leaves.values())
        self.grads = {k: torch.zeros_like(v) for k, v in leaves.items()}

    def _backprop(self, objective: torch.Tensor) -> None:
        if not objective.requires_grad:
            return
        grads = torch.autograd.grad(objective, self.leaves, allow_unused=True, retain_graph=True)  # rho feeds two objectives
        for name, grad in zip(self.names, grads):
            if grad is not None:
                self.grads[name] += grad

    def add(self, term: int, path: torch.Tensor, radiance: torch.Tensor) -> None:
        """A contribution of paths ``path`` (N,): differentiate its local factors, then strike it off."""
        self._backprop((self.g[path] * radiance.double()).sum())
        self.L_rem.index_add_(0, path, -radiance.detach().double())

    def reflect(self, path: torch.Tensor, rho: torch.Tensor) -> None:
        """The vertex adjoint: everything still to come carries rho once, ``d <g, L_rem> = <g, L_rem / rho> d rho``."""
        rho_d = rho.detach().double()
        a = torch.where(rho_d > 0, self.g[path] * self.L_rem[path] / rho_d.clamp_min(1e-300), 0.0)
        self._backprop((a * rho.double()).sum())


class _ReplayRender(torch.autograd.Function):
    @staticmethod
    def forward(fctx, scene: Scene, settings: RenderSettings, device, names: list[str], *values):
        fctx.scene, fctx.settings, fctx.device, fctx.names = scene, settings, device, names
        fctx.save_for_backward(*values)
        return render_image(scene, settings, device, params=dict(zip(names, values)))

    @staticmethod
    def backward(fctx, grad_image):
        grads = replay_gradient(fctx.scene, fctx.settings, fctx.device, dict(zip(fctx.names, fctx.saved_tensors)), grad_image)
        return (None, None, None, None, *(grads[n].to(v.device, v.dtype) for n, v in zip(fctx.names, fctx.saved_tensors)))


def replay_render(scene: Scene, settings: RenderSettings, device, names: list[str]) -> torch.Tensor:
    """The image of ``render`` whose backward pass is path replay, for the parameters ``names``."""
    return _ReplayRender.apply(scene, settings, device, names, *(scene.params[n] for n in names))


def replay_gradient(scene: Scene, settings: RenderSettings, device, values: dict[str, torch.Tensor], grad_image: torch.Tensor) -> dict[str, torch.Tensor]:
    """``sum_pixels <grad_image, dI/dtheta>`` for each parameter in ``values``, by re-tracing paths.

    Args:
        values: name -> current parameter value (the ones to differentiate).
        grad_image: (H, W, 3) ``dl/dI``.
    Returns:
        name -> gradient, shaped like the value.
    """
    leaves = {k: v.detach().to(device).requires_grad_(True) for k, v in values.items()}
    workers = cpu_workers(device)
    ctx = TransportContext.build(scene, settings, device, embree_threads=1 if workers > 1 else None, params=leaves)
    trace = INTEGRATOR_MODULES[settings.integrator].trace
    g_image = grad_image.detach().reshape(-1, 3).to(device, torch.float64) / settings.spp
    per_worker = [{k: torch.zeros_like(v) for k, v in leaves.items()} for _ in range(workers)]
    chunks_done = [0] * workers

    def chunk(worker: int, state: PathState) -> None:
        n = state.count
        local = dataclasses.replace(state, pixel=torch.arange(n, device=device))  # film index = path
        primal = Film(n, 1, False, device)
        with torch.no_grad():
            trace(ctx, local, primal)
        adjoint = AdjointFilm(g_image[state.pixel], primal.sums(), leaves)
        with torch.enable_grad():
            trace(ctx, local, adjoint)
        for k, v in adjoint.grads.items():
            per_worker[worker][k] += v
        del primal, adjoint
        chunks_done[worker] += 1
        if chunks_done[worker] % TRIM_EVERY == 0:
            release_freed_memory(device)  # keeps peak memory flat in the number of chunks (spp)

    for_each_chunk(scene, settings.replace(progress=False), device, chunk, grad=True)
    return {k: sum(w[k] for w in per_worker) for k in leaves}


def release_freed_memory(device: torch.device) -> None:
    """Hand the heap pages a finished chunk freed back to the OS (glibc ``malloc_trim``).

    Chunk-sized tensors are allocated and freed over and over; glibc keeps freed blocks of that size
    in its heap, which fragments a little more with every chunk, so without this peak memory creeps
    up with the number of chunks, i.e. with spp (measured: +34% from 16 to 256 spp for a replayed
    gradient at 128x128, +15% with it after every chunk). Returned pages are faulted in again by the
    next chunk, which costs up to 20% of a render's time if done after every chunk, so only path
    replay, whose point is flat memory, calls it, and only every ``TRIM_EVERY`` chunks.
    """
    if device.type == "cpu" and _LIBC is not None:
        _LIBC.malloc_trim(0)


def _load_libc():
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.malloc_trim  # glibc only  # noqa: B018
        return libc
    except (OSError, AttributeError):
        return None


_LIBC = _load_libc() if sys.platform.startswith("linux") else None
