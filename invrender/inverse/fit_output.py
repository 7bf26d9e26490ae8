"""A fit into an output folder: what ``invrender fit`` writes, as a library call.

:func:`fit_into` runs :func:`~invrender.inverse.fit.fit` with its checkpoint in the folder and
writes, beside it, ``report.json`` (initial, recovered and, when known, true values with errors),
``loss.png`` (loss and parameter error per step), ``correlation.png`` (least-squares solvers) and
the recovered scene rendered from each view (``final.exr`` / ``final.png``, or ``final_NN.*``),
every recovered map (a fitted parameter that varies over a surface: a texture, a normal map) as
``NAME.exr`` (its values) and ``NAME.png`` (a picture: a colour map sRGB-encoded, a normal map its
codes ``c`` as a normal-map file stores them), and, where a mask or the automatic exclusion of
clipped pixels left pixels out, ``pixels.png`` (or ``pixels_NN.png``): the target where it counted,
saturated pixels red, pixels at 0 blue, masked ones dark.

A fit of one environment map's texels alone also writes the relighting product
(:mod:`invrender.inverse.relighting`): ``map.exr`` the recovered map, ``stderr.exr`` its standard
errors, ``resolution.png`` its identifiability (the transport matrix's; the last two where the
solver gives them), the held-out views (cameras not fitted, each with its target) relit
(``heldout.exr`` / ``.png``, or ``heldout_NN.*``), and ``relighting.png``: the true map (when the
truth is known), the recovered one, its standard errors and identifiability, and every training
and held-out view's target beside its render under the recovered map; each view's channel-mean
differences and pooled relative RMSE go into ``report.json`` under ``relighting``.
Every file is written atomically; an interrupted fit (Ctrl-C) leaves its checkpoint, from which
``resume=True`` continues to the same result.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from kornia.color import rgb_to_linear_rgb

from invrender.estimators import render
from invrender.inverse.fit import FitResult, fit
from invrender.errors import ParameterError
from invrender.inverse.relighting import fitted_environment, relighting_error, relighting_figure
from invrender.inverse.report import plot_correlation, plot_history, report_dict
from invrender.inverse.targets import load_targets
from invrender.io.maps import write_environment
from invrender.io.reports import write_json
from invrender.io import write_image
from invrender.scene.camera import Camera
from invrender.scene.kinds import kind_of
from invrender.scene.scene import Scene

#: the final render's samples per pixel, as a multiple of the fit's ``spp_final``
FINAL_SPP_FACTOR = 4


@dataclass(frozen=True)
class FitOutput:
    """A fit written into a folder.

    Attributes:
        result: the fit's :class:`~invrender.inverse.fit.FitResult`.
        report: the report written to ``report.json``.
        written: the files written (besides the checkpoint), in order.
    """

    result: FitResult
    report: dict
    written: tuple[Path, ...]


def write_map(out: Path, name: str, value) -> list[Path]:
    """``OUT/NAME.exr`` (the (h, w, 3) values) and ``OUT/NAME.png`` (a picture of them: sRGB-encoded
    colours, or a normal map's codes ``c`` as they are: written through the sRGB decoding that the
    PNG's encoding undoes)."""
    value = value.detach().float().cpu()
    picture = rgb_to_linear_rgb(value.clamp(0.0, 1.0).permute(2, 0, 1)).permute(1, 2, 0) if kind_of(name).unit == "texel" else value
    paths = [out / f"{name}.exr", out / f"{name}.png"]
    write_image(paths[0], value)
    write_image(paths[1], picture)
    return paths


def fit_into(
    out,
    scene: Scene,
    target,
    params,
    *,
    cameras: list[Camera] | None = None,
    truth: dict | None = None,
    held_out: list[tuple[Camera, object]] | None = None,
    labels: list[str] | None = None,
    resume: bool = False,
    progress: bool = True,
    report: dict | None = None,
    **settings,
) -> FitOutput:
    """Fit ``params`` of ``scene`` to ``target`` (as :func:`~invrender.inverse.fit.fit` takes
    them) with the checkpoint ``out/checkpoint.pt``, then write the report, the figures and the
    final renders into ``out`` (module docstring).

    Args:
        out: the output folder (made if absent).
        held_out: (camera, target: an (H, W, 3) tensor or image path) per view left out of the
            fit, relit under the recovered map (a fit of one environment map's texels only).
        labels: the views' names in relighting.png and the report, the fitted ones then the
            held-out ones (default ``"training view i"``, ``"held-out view i"``).
        report: further entries of ``report.json`` (e.g. ``recipe``, ``targets``, ``variant``).
        settings: :class:`~invrender.inverse.fit.FitSettings` fields.
    Returns:
        :class:`FitOutput`. ``KeyboardInterrupt`` propagates after the checkpoint is saved.
    """
    out = Path(out)
    environment = fitted_environment(scene, params)
    if held_out and environment is None:
        raise ParameterError(f"held-out views are relit under a recovered environment map: fit one environment map's texels alone, not {params!r}")
    held = load_targets(scene, [t for _, t in held_out], [c for c, _ in held_out]) if held_out else []  # bad input fails before the fit
    fitted = len(cameras) if cameras else 1
    if labels is not None and len(labels) != fitted + len(held):
        raise ParameterError(f"fit_into: {len(labels)} labels for {fitted} fitted and {len(held)} held-out views")
    result = fit(scene, target, params, cameras=cameras, truth=truth, checkpoint=out / "checkpoint.pt", resume=resume, progress=progress, **settings)
    s = result.settings
    written = []

    def rendered(stem: str, views: list[Camera], seed: int) -> list:
        images = []
        for i, camera in enumerate(views):
            name = stem if len(views) == 1 else f"{stem}_{i:02d}"
            images.append(render(result.scene.with_camera(camera), s.model, spp=FINAL_SPP_FACTOR * s.spp_final, seed=seed, progress=progress))
            for suffix in (".exr", ".png"):
                write_image(out / f"{name}{suffix}", images[-1])
                written.append(out / f"{name}{suffix}")
        return images

    views = cameras or [result.scene.camera]
    finals = rendered("final", views, s.seed + 1)
    for name, value in result.params.items():
        if name != environment and value.ndim == 3:  # a map over a surface (the environment's: below)
            written += write_map(out, name, value)
    for i, image in enumerate(result.pixels):  # which pixels counted, where some did not
        if image is not None:
            path = out / ("pixels.png" if len(result.pixels) == 1 else f"pixels_{i:02d}.png")
            write_image(path, image)
            written.append(path)
    extra = dict(report or {})
    if environment is not None:
        written += write_environment(out, result.params[environment], result.std_error.get(environment), result.resolution.get(environment))
        relit = finals + rendered("heldout", [v.camera for v, _ in held], s.seed + 2)
        trained = [t.linear for _, t in load_targets(scene, target, cameras)]
        labels = labels or [f"training view {i}" for i in range(len(trained))] + [f"held-out view {i}" for i in range(len(held))]
        pairs = list(zip(labels, trained + [t.linear for _, t in held], relit))
        extra["relighting"] = {}
        for label, goal, image in pairs:
            means, rmse = relighting_error(goal, image)
            extra["relighting"][label] = {"channel_means": [float(m) for m in means], "rmse": rmse}
        title = f"{environment}: {result.history[-1].get('transport_matrix', result.solver) if result.history else result.solver}"
        relighting_figure(out / "relighting.png", result.params[environment], stderr=result.std_error.get(environment), resolution=result.resolution.get(environment), truth=result.truth.get(environment), views=pairs, title=title)
        written.append(out / "relighting.png")
    data = report_dict(result, **extra)
    write_json(out / "report.json", data)
    plot_history(result, out / "loss.png")
    written += [out / "report.json", out / "loss.png"]
    if plot_correlation(result, out / "correlation.png"):
        written.append(out / "correlation.png")
    return FitOutput(result, data, tuple(written))
