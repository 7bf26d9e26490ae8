"""Estimators: how an image is rendered and differentiated.

- ``autodiff``: torch records the whole wavefront (memory grows with spp x depth);
- ``replay``: path-replay backpropagation (:mod:`invrender.estimators.replay`; memory flat in spp and depth);
- ``auto``: replay where the fused bounce carries the derivatives forward (one trace), else
  autodiff where the recorded render fits in the memory budget, else replay
  (:func:`resolve_estimator`; fits use it by default);
- decorrelated loss gradients: :func:`backpropagate` takes ``dl/dI`` from any image (an independent
  render) and differentiates the render of ``settings`` with it.

This is the one layer that knows about estimators: the transport core below it knows none, the
inverse-rendering layer above it (fits, gradient checks) calls :func:`render` and
:func:`backpropagate`.
"""

from __future__ import annotations

import dataclasses

import torch

from invrender import registry
from invrender.estimators.autodiff import autodiff_render
from invrender.estimators.defaults import report, scene_integrator, scene_spp
from invrender.estimators.finite import check_image, check_params
from invrender.errors import ParameterError, did_you_mean
from invrender.scene.scene import Scene
from invrender.core.adaptive import AdaptiveSettings
from invrender.core.driver import RenderSettings, total_paths
from invrender.plugins.integrators import Integrator, make_integrator
from invrender.validate import check_device, check_paths

ESTIMATORS = ("autodiff", "replay")
#: what ``render``, ``backpropagate`` and fits accept: the estimators, or ``"auto"`` (:func:`resolve_estimator`)
ESTIMATOR_CHOICES = ("auto", *ESTIMATORS)
#: bytes autograd keeps for each camera path and Neumann term of a recorded render (measured on the
#: Cornell box: 530-780 bytes a path at max_depth 8; rounded up)
AUTODIFF_BYTES_PER_PATH_TERM = 128


def _check_estimator(estimator: str) -> str:
    if estimator not in ESTIMATOR_CHOICES:
        raise ParameterError(f"unknown estimator {estimator!r}{did_you_mean(estimator, ESTIMATOR_CHOICES)} (known: {', '.join(ESTIMATOR_CHOICES)})")
    return estimator


def resolve_estimator(estimator: str, scene: Scene, integrator: Integrator, settings: RenderSettings, device=None, names: list[str] | None = None) -> str:
    """The estimator ``"auto"`` stands for: ``"replay"`` where the fused bounce carries the
    derivatives of every parameter of ``names`` forward on ``device`` (one trace, no recording:
    :func:`invrender.estimators.replay.tangent_slots`; both given), else ``"autodiff"`` when the recorded render of ``settings``
    (about :data:`AUTODIFF_BYTES_PER_PATH_TERM` bytes a camera path and term) fits in
    ``settings.memory_mb``, else ``"replay"`` (memory flat in spp and depth; also for unbounded
    depth). The two give the same gradient to float rounding; autodiff traces once, replay twice
    (three times for a decorrelated gradient, whose forward render has another seed), so small
    renders are faster recorded. Other names are returned as they are."""
    if estimator != "auto":
        return estimator
    if device is not None and names:
        from invrender.estimators.replay import tangent_slots

        if tangent_slots(scene, integrator, settings, torch.device(device), names) is not None:
            return "replay"
    terms = integrator.terms_kept
    if terms == -1:
        return "replay"
    need = total_paths(scene, settings) * AUTODIFF_BYTES_PER_PATH_TERM * terms
    return "autodiff" if need <= settings.memory_mb * 2**20 else "replay"


def render(
    scene: Scene,
    integrator=None,
    spp: int | None = None,
    max_depth: int | None = None,
    seed: int = 0,
    *,
    terms: bool = False,
    rr_depth: int | None = None,
    estimator: str | None = None,
    backend: str | None = None,
    device=None,
    chunk_paths: int | None = None,
    memory_mb: float = 512.0,
    progress: bool = True,
    sampler: str = "stratified",
    adaptive=None,
    return_counts: bool = False,
    sampling_params: dict | None = None,
    filter=None,
    **options,
):
    """Render ``scene`` by Monte Carlo estimation of ``I = g eps + gMg eps + g(Mg)^2 eps + ...``.

    Args:
        scene: from :func:`invrender.load_scene`; its ``params`` are read at this call, and its
            ``defaults`` (the render settings its file states: a Mitsuba ``<integrator>`` and
            ``<sampler>``) are the defaults of ``integrator``, its settings and ``spp``
            (:mod:`invrender.estimators.defaults`: settings given win, and those that differ from the
            file's are reported in one :class:`~invrender.estimators.defaults.SettingOverridden` warning).
        integrator: None (the scene file's integrator and settings, else ``"path"``) or an
            integrator spec (:mod:`invrender.registry`): a name (``"path"``,
            ``"random_walk"``, ``"utah"``, ``"whitted"``, ``"distributed"``, ``"radiosity"``), a
            mapping ``{"type": "path", "max_depth": 8, "rr_depth": 3}`` or an
            :class:`~invrender.plugins.integrators.Integrator` object (used as it is). Settings
            given as keywords beside a name or mapping (``max_depth``, ``rr_depth``, ``options``)
            are added to it. A name or mapping naming the file's integrator keeps the file's
            settings not given; another integrator starts from its own defaults.
        spp: samples per pixel; None = the scene file's sample count, else 64.
        max_depth: Neumann terms kept (1 = emitters seen directly, 2 = + direct light, ...; -1 =
            unbounded, ended by Russian roulette); None = the scene file's, else the integrator's
            default (8; utah 2).
        seed: the image is a pure function of the seed (and the scene and settings).
        terms: return one image per Neumann term instead of their sum.
        rr_depth: Russian roulette starts after this many terms (None = the scene file's, else the
            integrator's default, 5).
        estimator: how the image is differentiated when a parameter requires grad:
            ``"replay"`` (default; path-replay backpropagation, memory flat in spp and depth),
            ``"autodiff"`` (torch records the whole wavefront) or ``"auto"`` (autodiff where the
            recorded render fits in ``memory_mb``, else replay: :func:`resolve_estimator`).
        backend: ``"embree"`` (CPU), ``"warp"`` (NVIDIA Warp's BVH: CUDA or CPU) or ``"torch"``
            (brute force, any device); None = the device's default (embree on the CPU, warp on CUDA).
        device: where to render; None = the scene's device. Parameters are moved differentiably.
        chunk_paths: paths per chunk; None = from ``memory_mb``.
        memory_mb: memory budget of a chunk's working set, MiB.
        progress: show a progress bar with rate and ETA when the render takes over a second.
        sampler: how each pixel's samples are drawn: ``"stratified"`` (default), ``"independent"``
            or ``"antithetic"`` (mirrored pairs; see :class:`~invrender.core.driver.RenderSettings`).
        adaptive: adaptive sampling (docs/sampling.md#adaptive-sampling): True, a dict of
            :class:`~invrender.core.adaptive.AdaptiveSettings` fields or such an object; then
            ``spp`` is the average number of samples per pixel, spent where the estimated relative
            error is high (the image stays unbiased). None/False: ``spp`` in every pixel.
        return_counts: with ``adaptive``, return an
            :class:`~invrender.core.adaptive.AdaptiveResult` (image, samples per pixel,
            estimated relative error) instead of the image alone.
        sampling_params: values (name -> tensor, all or some) the emitters' and BSDFs' sampling is built from
            instead of ``scene.params`` (see :class:`~invrender.core.driver.RenderSettings`):
            for finite differences whose renders must draw the same paths.
        filter: the film's reconstruction filter for this render, overriding the scene's
            (``scene.film``: a Mitsuba file's ``<rfilter>``, else the box): a name (``"box"``,
            ``"tent"``, ``"gaussian"``, ``"mitchell"``, ``"catmullrom"``, ``"lanczos"``), a mapping
            ``{"type": "gaussian", "stddev": 0.5}`` or a filter object
            (:mod:`invrender.plugins.filters`; docs/rendering.md#reconstruction-filters). None = the scene's.
        options: further settings of the integrator, e.g. for ``path`` ``strategy`` (``"mis"``,
            ``"bsdf"``, ``"emitter"``) and ``hemisphere`` (``"cosine"``, ``"uniform"``).
    Returns:
        float32 linear radiance, (H, W, 3) with row 0 at the top; (K, H, W, 3) with ``terms``.
        Differentiable in any ``scene.params`` entry that requires grad. With ``return_counts``
        an :class:`~invrender.core.adaptive.AdaptiveResult`.
    Raises:
        ParameterError: a ``scene.params`` (or ``sampling_params``) value holds a NaN or inf (named;
            checked before any work).
        NonFiniteError: the image has pixels that are not finite (their count; docs/rendering.md).
    """
    check_params(scene.params)
    check_params(sampling_params or {}, "sampling parameter")
    if filter is not None:
        scene = dataclasses.replace(scene, film=dataclasses.replace(scene.film, filter=registry.make_filter(filter, "render filter")))
    for key, value in (("max_depth", max_depth), ("rr_depth", rr_depth)):
        if value is not None:
            options[key] = value
    spec, overridden = scene_integrator(scene, integrator, options)
    model = make_integrator(integrator, **options) if isinstance(spec, Integrator) else make_integrator(spec)
    report(scene, overridden)
    spp = scene_spp(scene, spp)
    settings = RenderSettings(spp=spp, seed=seed, terms=terms, backend=backend, chunk_paths=chunk_paths, memory_mb=memory_mb, progress=progress, sampler=sampler, sampling_params=sampling_params)
    check_paths(scene.width, scene.height, spp)  # before any work, whichever estimator runs
    device = _device(scene, device)
    differentiable = [k for k, v in scene.params.items() if v.requires_grad] if torch.is_grad_enabled() else []
    estimator = resolve_estimator(_check_estimator(estimator or "replay"), scene, model, settings, device, differentiable)
    adaptive = AdaptiveSettings.make(adaptive)
    if return_counts and adaptive is None:
        raise ParameterError("return_counts=True needs adaptive sampling (adaptive=True or its settings): without it every pixel has spp samples")
    if adaptive is not None:
        from invrender.estimators.adaptive import render_adaptive

        result = render_adaptive(scene, model, settings, adaptive, device, differentiable, estimator)
        check_image(result.image)
        return result if return_counts else result.image
    if differentiable and estimator == "replay":
        if terms:
            raise ParameterError("terms=True is not available with estimator='replay'; use estimator='autodiff'")
        from invrender.estimators.replay import replay_render

        return check_image(replay_render(scene, model, settings, device, differentiable))
    if differentiable:
        return check_image(autodiff_render(scene, model, settings, device, differentiable))
    return check_image(model.render(scene, settings, device))


def backpropagate(scene: Scene, grad_image: torch.Tensor, integrator: Integrator, settings: RenderSettings, estimator: str = "replay", device=None) -> None:
    """Add ``<grad_image, dI/dtheta>`` to the gradient of every ``scene.params`` entry that requires
    grad, I being the image ``integrator`` renders with ``settings``.

    What ``render(...).backward(grad_image)`` does, without the image: ``replay`` re-traces the
    paths in its backward pass only, so no forward render is spent (a decorrelated loss gradient
    takes ``grad_image = dl/dI`` from another render); ``autodiff`` has to record a forward render;
    ``auto`` picks one by memory (:func:`resolve_estimator`). ``grad_image``: (H, W, 3).
    """
    check_params(scene.params)
    device = _device(scene, device)
    names = [k for k, v in scene.params.items() if v.requires_grad]
    estimator = resolve_estimator(_check_estimator(estimator), scene, integrator, settings, device, names)
    if estimator == "autodiff":
        image = autodiff_render(scene, integrator, settings, device, [k for k, v in scene.params.items() if v.requires_grad])
        if image.requires_grad:  # else no traced path depends on the parameters: their gradient is 0
            image.backward(grad_image)
        return
    from invrender.estimators.replay import replay_gradient

    values = {k: v for k, v in scene.params.items() if v.requires_grad}
    grads = replay_gradient(scene, integrator, settings, device, {k: v.detach() for k, v in values.items()}, grad_image)
    torch.autograd.backward(list(values.values()), [grads[k].to(v.device, v.dtype) for k, v in values.items()])


def _device(scene: Scene, device) -> torch.device:
    check_device(device)
    device = torch.device(device) if device is not None else scene.device
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ParameterError("device 'cuda' requested but torch has no CUDA device here")
    return device


__all__ = ["ESTIMATORS", "ESTIMATOR_CHOICES", "backpropagate", "render", "resolve_estimator"]
