"""A fit into an output folder: what ``invrender fit`` writes, as a library call.

:func:`fit_into` runs :func:`~invrender.inverse.fit.fit` with its checkpoint in the folder and
writes, beside it, ``report.json`` (initial, recovered and, when known, true values with errors),
``loss.png`` (loss and parameter error per step), ``correlation.png`` (least-squares solvers) and
the recovered scene rendered from each view (``final.exr`` / ``final.png``, or ``final_NN.*``), and,
where a mask or the automatic exclusion of clipped pixels left pixels out, ``pixels.png`` (or
``pixels_NN.png``): the target where it counted, saturated pixels red, pixels at 0 blue, masked
ones dark.
Every file is written atomically; an interrupted fit (Ctrl-C) leaves its checkpoint, from which
``resume=True`` continues to the same result.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from invrender.diff import render
from invrender.inverse.fit import FitResult, fit
from invrender.inverse.report import plot_correlation, plot_history, report_dict
from invrender.io.reports import write_json
from invrender.io import write_image
from invrender.scene.camera import Camera
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


def fit_into(
    out,
    scene: Scene,
    target,
    params,
    *,
    cameras: list[Camera] | None = None,
    truth: dict | None = None,
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
        report: further entries of ``report.json`` (e.g. ``recipe``, ``targets``, ``variant``).
        settings: :class:`~invrender.inverse.fit.FitSettings` fields.
    Returns:
        :class:`FitOutput`. ``KeyboardInterrupt`` propagates after the checkpoint is saved.
    """
    out = Path(out)
    result = fit(scene, target, params, cameras=cameras, truth=truth, checkpoint=out / "checkpoint.pt", resume=resume, progress=progress, **settings)
    s = result.settings
    written = []
    views = cameras or [result.scene.camera]
    for i, camera in enumerate(views):
        stem = "final" if len(views) == 1 else f"final_{i:02d}"
        image = render(result.scene.with_camera(camera), s.model, spp=FINAL_SPP_FACTOR * s.spp_final, seed=s.seed + 1, progress=progress)
        for suffix in (".exr", ".png"):
            write_image(out / f"{stem}{suffix}", image)
            written.append(out / f"{stem}{suffix}")
    for i, image in enumerate(result.pixels):  # which pixels counted, where some did not
        if image is not None:
            path = out / ("pixels.png" if len(result.pixels) == 1 else f"pixels_{i:02d}.png")
            write_image(path, image)
            written.append(path)
    data = report_dict(result, **(report or {}))
    write_json(out / "report.json", data)
    plot_history(result, out / "loss.png")
    written += [out / "report.json", out / "loss.png"]
    if plot_correlation(result, out / "correlation.png"):
        written.append(out / "correlation.png")
    return FitOutput(result, data, tuple(written))
