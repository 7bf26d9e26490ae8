"""Relighting as a product: a recovered environment map put into another scene
(:func:`relight`, ``ir.lighting.relight``), its images compared with targets
(:func:`relighting_error`) and the figure of a map fit (:func:`relighting_figure`: the true and
recovered maps, their standard errors and identifiability, and views target against relit), which
``invrender fit`` and ``bench/transport_matrix.py`` write.
"""

from __future__ import annotations

import dataclasses
import math
import textwrap
from pathlib import Path

import torch

from invrender.estimators.transport_matrix import envmap_of
from invrender.errors import InvRenderError, ParameterError, did_you_mean
from invrender.inverse.fit import FitResult
from invrender.inverse.map_fit import MapFit
from invrender.registry import EMITTERS
from invrender.scene.emitters import Emitter
from invrender.scene.scene import Scene, check_param_value

#: the name an environment added to a scene that had none takes, unless the map's source names one
DEFAULT_EMITTER = "sky"


def environment_maps(scene: Scene) -> list[str]:
    """The names of ``scene``'s environment maps: emitters with a texel lookup and an (h, w, 3) map."""
    return [e for i, e in enumerate(scene.emitters) if getattr(EMITTERS[scene.emitter_spec(i).type], "texel_lookup", False) and scene.params[f"{e}.emission"].ndim == 3]


def _source(lighting) -> tuple[torch.Tensor, Emitter | None, str | None]:
    """(the map (h, w, 3), the emitter spec it belongs to or None, its emitter's name or None) of
    anything :func:`relight` takes."""
    if isinstance(lighting, FitResult):
        names = [n for n in lighting.params if n.endswith(".emission") and n.rpartition(".")[0] in environment_maps(lighting.scene)]
        if len(names) != 1:
            fitted = ", ".join(lighting.params) or "nothing"
            raise ParameterError(f"relight takes a fit of one environment map's texels; this fit recovered {fitted}")
        return _of(lighting.scene, names[0].rpartition(".")[0])
    if isinstance(lighting, Scene):
        maps = environment_maps(lighting)
        if len(maps) != 1:
            raise ParameterError(f"relight takes the lighting of a scene with one environment map; {lighting.name} has {len(maps)} ({', '.join(maps) or 'none'})")
        return _of(lighting, maps[0])
    if isinstance(lighting, MapFit):
        return lighting.texels.detach(), None, None
    if isinstance(lighting, (str, Path)):
        from invrender.io import read_image

        return read_image(lighting), None, None
    if isinstance(lighting, torch.Tensor):
        return lighting.detach(), None, None
    raise ParameterError(f"relight takes a FitResult, a MapFit, a Scene, an (h, w, 3) tensor or an EXR/HDR file of the map, got {type(lighting).__name__}")


def _of(scene: Scene, emitter: str) -> tuple[torch.Tensor, Emitter, str]:
    k = envmap_of(scene, emitter)
    return scene.params[f"{emitter}.emission"].detach(), scene.emitter_spec(k), emitter


def relight(scene, lighting, emitter: str | None = None) -> Scene:
    """``scene`` lit by the environment ``lighting``, ready for :func:`invrender.render`::

        res = ir.fit(scene, targets, ["sky.emission"], cameras=views)       # or ir.lighting.fit_map
        ir.render(ir.lighting.relight("other.toml", res), spp=256)          # a new object under it

    Args:
        scene: the scene to light: a :class:`~invrender.scene.scene.Scene` or what
            :func:`~invrender.scene.load_scene` takes (a built-in name, a scene file).
        lighting: a :class:`~invrender.inverse.fit.FitResult` of one environment map's texels, a
            :class:`Scene` with one environment map (e.g. ``res.scene``), a
            :class:`~invrender.inverse.map_fit.MapFit`, an (h, w, 3) tensor or an EXR/HDR file.
            From a fit or a scene the map comes with its emitter's constants (``scale`` and the
            ``to_world`` rotation), so its radiance arrives from the same world directions; a bare
            map (MapFit, tensor, file) is taken in the receiving emitter's constants (for a MapFit:
            those of the scene it was fitted in, if it is the same emitter).
        emitter: the environment map of ``scene`` to replace; None: its only one, or, when it has
            none, a new one (named as the fitted emitter, else ``"sky"``). Other emitters stay.
    Returns:
        a new scene (sharing geometry and the other parameters) whose environment map is the
        recovered one (a detached copy, any size: the map need not match the one it replaces).
    Raises:
        ParameterError: ``lighting`` is not one map, ``emitter`` is not an environment map of
            ``scene``, or ``scene`` has several and ``emitter`` is not given (one line).
    """
    if not isinstance(scene, Scene):
        from invrender.scene import load_scene

        scene = load_scene(scene)
    texels, spec, source_name = _source(lighting)
    maps = environment_maps(scene)
    if emitter is None:
        if len(maps) > 1:
            raise ParameterError(f"{scene.name} has {len(maps)} environment maps ({', '.join(maps)}): name the one to replace (emitter=...)")
        emitter = maps[0] if maps else (source_name or DEFAULT_EMITTER)
    elif emitter not in maps:
        raise ParameterError(f"{scene.name} has no environment map {emitter!r}{did_you_mean(emitter, maps)} (environment maps: {', '.join(maps) or 'none'})")
    name = f"{emitter}.emission"
    try:
        value = check_param_value(name, texels.float().clone())
    except InvRenderError as e:
        raise ParameterError(f"relight: {e}") from None
    if value.ndim != 3:
        raise ParameterError(f"relight: the map must be (h, w, 3), got shape {tuple(texels.shape)}")
    specs = list(scene.emitter_specs) or [scene.emitter_spec(i) for i in range(len(scene.emitters))]
    emitters = list(scene.emitters)
    if emitter in emitters:
        k = emitters.index(emitter)
        specs[k] = spec if spec is not None else specs[k]
    else:  # a scene without an environment: one more emitter (no triangles name it)
        emitters.append(emitter)
        specs.append(spec if spec is not None else Emitter.of("envmap", where=f"relight {emitter}", emission=(1.0, 1.0, 1.0)))
    params = {**scene.params, name: value}
    return dataclasses.replace(scene, emitters=tuple(emitters), emitter_specs=tuple(specs), params=params)


def relighting_error(target: torch.Tensor, relit: torch.Tensor) -> tuple[torch.Tensor, float]:
    """(channel-mean relative differences (3,), pooled relative RMSE ``||relit - target|| /
    ||target||``) of a view ``relit`` (H, W, 3) against its ``target`` (H, W, 3)."""
    t, r = target.detach().double(), relit.detach().double()
    means = (r.mean((0, 1)) - t.mean((0, 1))) / t.mean((0, 1)).clamp_min(1e-300)
    return means.float(), float((r - t).norm() / t.norm().clamp_min(1e-300))


def relighting_figure(path, recovered: torch.Tensor, *, stderr: torch.Tensor | None = None, resolution: torch.Tensor | None = None, truth: torch.Tensor | None = None, views=(), title: str = "") -> None:
    """A PNG of labelled panels: in the first row the true map (when known) and the recovered map
    (log10 luminance on one scale: the truth's range, else the recovered map's), the standard
    error relative to the recovered map and the identifiability (the resolution, smallest over
    the channels: 1 set by the images, 0 by the prior), those given; below, per view, its target
    and its render under the recovered map side by side (sRGB at one exposure per view, the
    panel naming the pooled relative RMSE), two views a row.

    Args:
        recovered, stderr, resolution, truth: (h, w, 3) maps.
        views: ``(label, target (H, W, 3), relit (H, W, 3))`` per view, e.g. ``"training view 1"``,
            ``"held-out view"``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from invrender.io.images import to_srgb
    from invrender.io.reports import save_figure

    log = lambda m: torch.log10(m.detach().float().mean(2).clamp_min(1e-4))  # noqa: E731
    reference = log(truth if truth is not None else recovered)
    scale = dict(vmin=float(reference.min()), vmax=float(reference.max()), cmap="magma")
    maps = [("true map, log10 luminance", log(truth), scale)] if truth is not None else []
    maps.append(("recovered map, log10 luminance", log(recovered), scale))
    if stderr is not None:
        ratio = (stderr.float().mean(2) / recovered.float().mean(2).clamp_min(1e-6)).clamp(0, 1)
        maps.append(("standard error / recovered", ratio, dict(vmin=0, vmax=1, cmap="viridis")))
    if resolution is not None:
        maps.append(("identifiability (resolution, min over channels)", resolution.float().amin(2), dict(vmin=0, vmax=1, cmap="viridis")))
    cols = max(len(maps), 4 if len(views) > 1 else 2)
    rows = 1 + math.ceil(len(views) / (cols // 2))
    fig, axes = plt.subplots(rows, cols, figsize=(3.3 * cols, 2.9 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, (label, image, style) in zip(axes[0], maps):
        shown = ax.imshow(image.numpy(), **style)
        fig.colorbar(shown, ax=ax, fraction=0.03)
        _label(ax, label)
    for i, (label, target, relit) in enumerate(views):
        row, col = 1 + i // (cols // 2), 2 * (i % (cols // 2))
        exposure = 0.8 / max(float(target.detach().float().mean(2).quantile(0.95)), 1e-12)
        rmse = relighting_error(target, relit)[1]
        for ax, (what, image) in zip(axes[row, col : col + 2], ((f"{label}: target", target), (f"{label}: relit ({100 * rmse:.1f}% RMSE)", relit))):
            ax.imshow(to_srgb(image.detach().float() * exposure).numpy())
            _label(ax, what)
    if title:
        fig.suptitle(textwrap.fill(title, 30 * cols), fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def _label(ax, text: str) -> None:
    ax.axis("on")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(text, fontsize=8)


def fitted_environment(scene: Scene, params) -> str | None:
    """The parameter name when ``params`` (a name or a list) is one environment map's texels of
    ``scene`` alone (``"sky.emission"``), else None."""
    names = [params] if isinstance(params, str) else list(params)
    if len(names) != 1 or not str(names[0]).endswith(".emission"):
        return None
    return names[0] if names[0].rpartition(".")[0] in environment_maps(scene) else None
