"""Path-replay backpropagation (Vicini, Speierer and Jakob 2021), as a torch.autograd.Function.

The forward pass renders without recording anything. The backward pass receives ``dl/dI`` and, chunk
by chunk, regenerates the very same paths from the counter-based sampler twice:

1. primal: each path's total radiance ``L`` (no autograd). The forward pass keeps these per-path
   totals when they fit in :data:`KEEP_SHARE` of the memory budget (12 bytes a path, float32
   until the backward pass takes them up in float64; with the answers of their shadow rays, a bit
   a ray), and the
   backward pass then skips this step: a ``loss(render(...)).backward()`` costs two traces, not
   three. A gradient taken without a forward render of the same seed (:func:`replay_gradient`, the
   decorrelated gradient of a fit) traces it;
2. adjoint: the path is followed again with the throughput ``beta`` detached (after a primal pass
   of its own, the chunk's ray queries are answered from that pass: :class:`RepeatedQueries`). Every contribution
   (``beta w eps(x_k)``, ``beta f(x_i) eps(y) / pdf``, ``beta k_d eps0``) is differentiated locally
   in its own factors; at each scattering vertex x_i whose sample weight is ``w_i = f cos / pdf``,
   the radiance the path still gathers beyond it, ``L_rem`` (= L minus what was added so far),
   contains ``w_i`` exactly once as a factor, so its derivative is ``<dl/dI, L_rem / w_i> d w_i``
   (Mitsuba 3's ``prb``: ``L_rem * f / detach(f)``). Sampling never depends on the parameters, so
   only f carries a derivative: the same adjoint serves every material, and every parameter kind,
   polynomial or not (a roughness: ``w_i = f(alpha) cos / pdf(detached alpha)``, differentiated by
   autograd at the vertex like any other).

Paths that split (Whitted's glass) give each branch a film index of its own (``Film.branch``): the
primal pass sums each branch's radiance into its parent's, so ``L_rem`` at a vertex counts exactly
what lies beyond it on its own branch.

Each local derivative is taken at once (a tiny autograd graph of one gather), so memory is one
chunk's working set: independent of ``max_depth`` and of spp. The gradient equals autodiff's for
the same seed up to float rounding, except in a colour channel where a weight is exactly 0 (there
``L_rem / w`` is 0/0 and replay returns 0 for that channel).
"""

from __future__ import annotations

import dataclasses
import sys

import torch

from invrender.scene.scene import Scene
from invrender.core import fused
from invrender.backends.accel import QueriesDiverged, RepeatedQueries
from invrender.core.context import PathState
from invrender.core.driver import BYTES_PER_REPLAYED_PATH, RenderSettings, cpu_workers, film_weights, for_each_chunk, total_paths
from invrender.core.film import Film, PathFilm
from invrender.plugins.integrators import Integrator
from invrender.core.ranks import sum_gradients

#: chunks each worker replays between two releases of freed heap memory (see release_freed_memory)
TRIM_EVERY = 2
#: the forward pass keeps every path's radiance for the backward pass (which then skips its primal
#: pass: two traces per gradient instead of three) when they fit in this share of ``memory_mb``
KEEP_SHARE = 0.25


class AdjointFilm(Film):
    """The adjoint pass's "film": turns contributions into parameter gradients.

    Attributes:
        g: (size, 3) float32 ``dl/dL`` of each path: ``dl/dI`` at its pixel divided by spp (a path
            is 1/spp of it), or with a filter ``sum_j w_j dl/dI_j / W_j`` over the pixels j its
            footprint reaches (weights w_j, the pixels' sums of weights W_j: the adjoint of the
            normalized splat).
        L_rem: (size, 3) float64 radiance each path (branch) has yet to gather (float64: it is what
            is left after subtracting every contribution from the path's total).
        grads: name -> accumulated gradient for each differentiable leaf in ``leaves``.

    The local objectives are float32, as the factors they differentiate are: the gradient of
    ``sum(a * f)`` with respect to ``f`` is ``a`` itself, so nothing is lost to their sums.
    """

    detach_throughput = True

    def __init__(self, g: torch.Tensor, totals: torch.Tensor, leaves: dict[str, torch.Tensor]):
        """``g`` (paths, 3) ``dl/dI`` of each camera path's pixel; ``totals`` (size, 3): each path's
        and branch's radiance (:meth:`PathFilm.totals`), taken over as ``L_rem`` (float64 totals
        are not copied)."""
        self.L_rem = totals.to(torch.float64)
        g = g.to(torch.float32)
        self.g = g if g.shape[0] == totals.shape[0] else torch.cat([g, g.new_zeros(totals.shape[0] - g.shape[0], 3)])
        self.size = g.shape[0]
        self.names, self.leaves = list(leaves), list(leaves.values())
        self.grads = {k: torch.zeros_like(v) for k, v in leaves.items()}

    def _backprop(self, objective: torch.Tensor) -> None:
        if not objective.requires_grad:
            return
        grads = torch.autograd.grad(objective, self.leaves, allow_unused=True, retain_graph=True)  # factors may feed two objectives
        for name, grad in zip(self.names, grads):
            if grad is not None:
                self.grads[name] += grad

    def add(self, term: int, path: torch.Tensor, radiance: torch.Tensor) -> None:
        """A contribution of paths ``path`` (N,): differentiate its local factors, then strike it off."""
        self._backprop((self.g.index_select(0, path) * radiance).sum())
        self.L_rem.index_add_(0, path, radiance.detach().double().neg_())  # (alpha=-1 takes a per-row path: 8x slower)

    def scatter(self, path: torch.Tensor, weight: torch.Tensor) -> None:
        """The vertex adjoint: everything still to come carries the weight once,
        ``d <g, L_rem> = <g, L_rem / w> d w``."""
        if not weight.requires_grad:
            return
        w = weight.detach()
        zero = w == 0
        a = self.g.index_select(0, path) * self.L_rem.index_select(0, path).float() / w.masked_fill(zero, 1.0)
        self._backprop((a.masked_fill_(zero, 0.0) * weight).sum())

    def branch(self, pixel: torch.Tensor) -> torch.Tensor:
        new = torch.arange(self.size, self.size + pixel.numel(), device=pixel.device)
        self.g[new] = self.g[pixel]  # a branch's radiance lands in its root's pixel
        self.size += pixel.numel()
        return new


class _ReplayRender(torch.autograd.Function):
    @staticmethod
    def forward(fctx, scene: Scene, integrator: Integrator, settings: RenderSettings, device, names: list[str], *values):
        fctx.scene, fctx.integrator, fctx.settings, fctx.device, fctx.names = scene, integrator, settings, device, names
        fctx.save_for_backward(*values)
        params = dict(zip(names, values))
        fctx.slots = tangent_slots(scene, integrator, settings, device, names, params)
        fctx.kept = {} if fctx.slots is None and _can_keep(scene, settings) else None
        fctx.tangents = {} if fctx.slots is not None else None
        carried = {} if fctx.tangents is None else {"tangents": fctx.tangents}  # (integrators with a render of their own take no tangents)
        image = integrator.render(scene, settings, device, params=params, keep=fctx.kept, **carried)
        if fctx.kept is not None:
            release_freed_memory(device)  # the forward chunks' heap, before the backward pass's
        return image

    @staticmethod
    def backward(fctx, grad_image):
        values = dict(zip(fctx.names, fctx.saved_tensors))
        if fctx.tangents is not None:
            grads = contract(fctx.tangents["jacobian"], fctx.slots, grad_image)
        else:
            grads = replay_gradient(fctx.scene, fctx.integrator, fctx.settings, fctx.device, values, grad_image, kept=fctx.kept)
        fctx.kept = fctx.tangents = None
        return (None, None, None, None, None, *(grads[n].to(v.device, v.dtype) for n, v in values.items()))


def tangent_slots(scene: Scene, integrator: Integrator, settings: RenderSettings, device, names: list[str], params: dict | None = None) -> dict[str, int] | None:
    """name -> slot of the fused bounce's per-pixel Jacobian (:class:`~invrender.core.fused.TangentFilm`)
    when it answers the gradient of every parameter of ``names``: the fused bounce applies to the
    render, each name is a material's ``reflectance`` or an emitter's ``emission``, and the
    Jacobian (8 bytes a pixel, channel and slot, per worker) fits in :data:`KEEP_SHARE` of the
    memory budget; else None (the paths are replayed)."""
    if settings.terms or not scene.film.is_box:  # the Jacobian is per pixel: a filter spreads a path over several
        return None
    with torch.no_grad():
        scene_tables = integrator.fused_scene(integrator.context(scene, settings, device, params))
    if scene_tables is None:
        return None
    slot_of = fused.slot_index(scene, scene_tables)
    if any(n not in slot_of for n in names):
        return None
    size = scene.width * scene.height * 3 * fused.slots(scene_tables) * 8 * cpu_workers(device)
    if size > settings.memory_mb * 2**20 * KEEP_SHARE:
        return None
    return {n: slot_of[n] for n in names}


def contract(jacobian: torch.Tensor, slots: dict[str, int], grad_image: torch.Tensor) -> dict[str, torch.Tensor]:
    """``sum_pixels <grad_image, dI/dtheta>`` per name from the per-pixel Jacobian (P, 3, S) of the
    image (:meth:`Integrator.render` with ``tangents``): (3,) per name."""
    g = grad_image.detach().reshape(-1, 3).to(jacobian.device, torch.float64)
    return {n: (g * jacobian[:, :, k]).sum(0).float() for n, k in slots.items()}


def _can_keep(scene: Scene, settings: RenderSettings) -> bool:
    """Do the per-path radiances of this render fit in :data:`KEEP_SHARE` of its memory budget
    (float32 RGB per camera path; paths that split, Whitted's, keep their branches' entries too,
    beyond this estimate)?"""
    return total_paths(scene, settings) * 12 <= settings.memory_mb * 2**20 * KEEP_SHARE


def replay_render(scene: Scene, integrator: Integrator, settings: RenderSettings, device, names: list[str]) -> torch.Tensor:
    """The image of ``render`` whose backward pass is path replay, for the parameters ``names``."""
    return _ReplayRender.apply(scene, integrator, settings, device, names, *(scene.params[n] for n in names))


def replay_gradient(
    scene: Scene, integrator: Integrator, settings: RenderSettings, device, values: dict[str, torch.Tensor], grad_image: torch.Tensor, kept: dict | None = None,
) -> dict[str, torch.Tensor]:  # fmt: skip
    """``sum_pixels <grad_image, dI/dtheta>`` for each parameter in ``values``, by re-tracing paths.

    Args:
        values: name -> current parameter value (the ones to differentiate).
        grad_image: (H, W, 3) ``dl/dI``.
        kept: each chunk's per-path radiance and shadow-ray answers from a render with the same
            settings and values (``Integrator.render(..., keep=...)``): those chunks skip the
            primal pass and their shadow rays.
    Returns:
        name -> gradient, shaped like the value.
    """
    slots = tangent_slots(scene, integrator, settings, device, list(values), values) if kept is None else None
    if slots is not None:  # one trace, derivatives carried forward in the fused kernels
        tangents: dict = {}
        integrator.render(scene, settings.replace(progress=False), device, params={k: v.detach() for k, v in values.items()}, tangents=tangents)
        return contract(tangents["jacobian"], slots, grad_image)  # the Jacobian is summed across ranks already
    leaves = {k: v.detach().to(device).requires_grad_(True) for k, v in values.items()}
    workers = cpu_workers(device)
    ctx = integrator.context(scene, settings, device, params=leaves)
    g_image = grad_image.detach().reshape(-1, 3).to(device, torch.float32)
    if scene.film.is_box:
        g_image = g_image / settings.spp
    else:  # the image is normalize(splat): dI_j/dL_path = w_j(path) / W_j, so a path's adjoint gathers g_j / W_j
        weights = film_weights(scene, settings, device)
        g_image = (g_image.double() / weights.masked_fill(weights == 0, 1.0)[:, None]).float()
    rfilter = None if scene.film.is_box else scene.film.filter

    def adjoint_pass(local: PathState, g: torch.Tensor, totals: torch.Tensor | None, queries: RepeatedQueries | None, torch_bounce: bool = False) -> AdjointFilm:
        """The adjoint pass of one chunk's paths ``local`` (after their primal pass, unless its
        ``totals`` and shadow-ray ``queries`` are given; with ``torch_bounce`` that pass is traced
        by the adjoint's own bounce, not the fused one, whose float rounding may decide a path
        differently)."""
        if totals is None:
            queries = RepeatedQueries(ctx.accel)  # the adjoint pass casts the primal pass's rays again
            primal = PathFilm(local.count, device)
            primal.fused_bounce = not torch_bounce
            with torch.no_grad():
                integrator.trace(dataclasses.replace(ctx, accel=queries), local, primal)
            totals = primal.totals()
            del primal
        adjoint = AdjointFilm(g, totals, leaves)
        del totals  # the film holds them now (as L_rem)
        with torch.enable_grad():
            integrator.trace(dataclasses.replace(ctx, accel=queries.repeat(ctx.accel)), local, adjoint)
        return adjoint
    per_worker = [{k: torch.zeros_like(v) for k, v in leaves.items()} for _ in range(workers)]
    chunks_done = [0] * workers

    def chunk(worker: int, state: PathState, start: int, xy: torch.Tensor) -> None:
        n = state.count
        local = state.replace(pixel=torch.arange(n, device=device))  # film index = path
        g = g_image[state.pixel] if rfilter is None else rfilter.footprint(xy, scene.width, scene.height).gather(g_image)
        totals, queries = kept.pop(start) if kept is not None and start in kept else (None, None)
        try:
            adjoint = adjoint_pass(local, g, totals, queries)
        except QueriesDiverged:
            # the primal pass's bounce (the fused one, compiled) and the adjoint's (torch) took a
            # decision differently (float rounding: a roulette draw against a throughput a last
            # bit apart): this chunk's primal pass is traced again by the adjoint's bounce
            adjoint = adjoint_pass(local, g, None, None, torch_bounce=True)
        for k, v in adjoint.grads.items():
            per_worker[worker][k] += v
        del adjoint
        chunks_done[worker] += 1
        if chunks_done[worker] % TRIM_EVERY == 0:
            release_freed_memory(device)  # keeps peak memory flat in the number of chunks (spp)

    for_each_chunk(
        scene,
        settings.replace(progress=False),
        device,
        chunk,
        grad=True,
        across_ranks=True,
        with_start=True,
        bytes_per_path=BYTES_PER_REPLAYED_PATH,
        with_positions=True,
    )
    return sum_gradients({k: sum(w[k] for w in per_worker) for k in leaves})


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
