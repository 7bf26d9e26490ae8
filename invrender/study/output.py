"""A gradient study as tables: rows for a CSV file, a JSON document, and a text summary.

Each row is one configuration at one spp for one quantity: a gradient component
(``red.reflectance.R``) or a parameter's derivative along all its components together
(``red.reflectance``, the sum of its components). Files are written atomically.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import torch

from invrender.io.reports import write_json, write_text
from invrender.io.atomic import atomic_file
from invrender.study.fits import FitStudy, finite, fit_rows, fit_study_dict
from invrender.study.gradients import GradientStudy
from invrender.study.plots import plot_fits

COLUMNS = (
    "config", "integrator", "estimator", "gradient", "options", "spp", "trials", "quantity", "kind",
    "mean", "std_error", "variance", "variance_se", "reference", "reference_se", "bias", "bias_se",
    "seconds", "wall_seconds", "efficiency",
)  # fmt: skip


def study_rows(study: GradientStudy) -> list[dict]:
    """One dict per configuration, spp and quantity, with the keys of :data:`COLUMNS`."""
    rows = []
    for run in study.runs:
        c = run.config
        for per in ("parameter", "component"):
            s = study.summary(c, run.spp, per)
            for k, label in enumerate(s.labels):
                m = s.moments
                rows.append({
                    "config": c.label, "integrator": c.integrator, "estimator": c.estimator, "gradient": c.gradient,
                    "options": " ".join(f"{key}={value}" for key, value in c.options), "spp": run.spp, "trials": m.count,
                    "quantity": label, "kind": per,
                    "mean": float(m.mean[k]), "std_error": float(m.std_error[k]), "variance": float(m.variance[k]), "variance_se": float(m.variance_se[k]),
                    "reference": _item(s.reference.mean, k) if s.reference else None, "reference_se": _item(s.reference.std_error, k) if s.reference else None,
                    "bias": _item(s.bias, k), "bias_se": _item(s.bias_se, k),
                    "seconds": s.seconds, "wall_seconds": s.wall, "efficiency": float(s.efficiency[k]),
                })  # fmt: skip
    return rows


def _item(t: torch.Tensor | None, k: int) -> float | None:
    return None if t is None else float(t[k])


def study_dict(study: GradientStudy) -> dict:
    """The study as plain data: settings, slopes, references, per-pixel maps and every row."""
    return {
        "scene": study.scene,
        "resolution": list(study.resolution),
        "params": list(study.params),
        "loss": study.loss,
        "spp": list(study.spp),
        "trials": study.trials,
        "seed": study.seed,
        "at": study.at,
        "target": study.target,
        "configs": [c.label for c in study.configs],
        "slopes": {c.label: {p: dict(zip(("slope", "slope_se"), study.slope(c, p))) for p in study.params} for c in study.configs},
        "references": {label: {"config": r.config.label, "spp": r.spp, "exact": r.exact, "repeats": r.samples.shape[0]} for label, r in study.references.items()},
        "pixel_maps": [
            {"configs": list(m.configs), "parameter": m.parameter, "spp": m.spp, "trials": m.trials, "total_variance": m.total,
             "variance": m.variance.tolist(), "mean": m.mean.tolist()}
            for m in study.pixel_maps
        ],
        "rows": study_rows(study),
    }


def write_study(study: GradientStudy, out) -> list[Path]:
    """Write ``results.csv``, ``results.json`` and ``samples.pt`` (every trial's gradient) into
    ``out``; returns the paths."""
    out = Path(out)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(study_rows(study))
    write_text(out / "results.csv", buffer.getvalue())
    write_json(out / "results.json", study_dict(study))
    samples = {
        "components": study.component_labels,
        "runs": {f"{r.config.label} @ {r.spp}": {"samples": r.samples, "seconds": r.seconds, "wall": r.wall} for r in study.runs},
    }
    with atomic_file(out / "samples.pt") as f:
        torch.save(samples, f)
    return [out / "results.csv", out / "results.json", out / "samples.pt"]


def summary_text(study: GradientStudy) -> str:
    """A plain-text table of each parameter's derivative per configuration and spp, and the slopes."""
    title = (
        f"{study.scene}: {study.resolution[0]}x{study.resolution[1]}, loss {study.loss}, {study.trials} trials; "
        f"target {study.target}; derivative along all components of each parameter"
    )
    lines = [title]
    head = f"{'configuration':<44} {'spp':>5} {'parameter':<22} {'mean':>11} {'variance':>11} {'± se':>9} {'bias':>11} {'± se':>9} {'cpu s':>7} {'efficiency':>10}"
    lines.append(head)
    for run in study.runs:
        s = study.summary(run.config, run.spp, "parameter")
        for k, label in enumerate(s.labels):
            m = s.moments
            bias = "-" if s.bias is None else f"{float(s.bias[k]):+.4g}"
            bias_se = "-" if s.bias_se is None else f"{float(s.bias_se[k]):.2g}"
            lines.append(
                f"{run.config.label:<44} {run.spp:>5} {label:<22} {float(m.mean[k]):>11.4g} {float(m.variance[k]):>11.4g} {float(m.variance_se[k]):>9.2g} "
                f"{bias:>11} {bias_se:>9} {s.seconds:>7.3f} {float(s.efficiency[k]):>10.4g}"
            )
    lines.append("slope of log variance vs log spp (-1: variance ~ 1/N):")
    for c in study.configs:
        parts = []
        for p in study.params:
            slope, se = study.slope(c, p)
            parts.append(f"{p} {slope:+.3f} ± {se:.3f}" if math.isfinite(slope) else f"{p} -")
        lines.append(f"  {c.label}: " + ", ".join(parts))
    for m in study.pixel_maps:
        lines.append(f"per-pixel variance of {m.parameter} at {m.spp} spp ({', '.join(m.configs)}): sum {m.total:.4g}")
    return "\n".join(lines)


def write_fit_study(study: FitStudy, out) -> list:
    """Write ``fits.csv`` (every step of every fit), ``fits_summary.csv`` (per configuration),
    ``fits.json`` and ``fits.png`` into ``out``; returns the paths."""
    out = Path(out)
    paths = []
    for name, rows in (("fits.csv", fit_rows(study)), ("fits_summary.csv", [finite(study.summary(c)) for c in study.configs])):
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        write_text(out / name, buffer.getvalue())
        paths.append(out / name)
    write_json(out / "fits.json", fit_study_dict(study))
    plot_fits(study, out / "fits.png")
    return paths + [out / "fits.json", out / "fits.png"]
