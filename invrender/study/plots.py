"""Figures of a gradient study (PNG, matplotlib):

- :func:`plot_variance`: variance against spp, log-log, one line per configuration, with a ``1/N``
  guide (Monte Carlo's rate; a steeper line means a term falling faster, e.g. the ``1/N^2`` of a
  product of two independent noises, or stratified pixel samples at an edge);
- :func:`plot_bias`: bias against spp with error bars, correlated (filled) vs decorrelated (open);
- :func:`plot_pixel_variance`: the per-pixel variance of one parameter's gradient, per pairing;
- :func:`plot_fits`: a fit study's largest parameter error against wall time and against steps.

Each panel shows one parameter's derivative along all its components together (the sum of its
components). Optional ``predictions`` (closed forms) are drawn as dotted lines in the line's colour.
"""

from __future__ import annotations

import math

import torch

from invrender.io.reports import save_figure
from invrender.io.images import to_srgb
from invrender.study.gradients import GradientStudy


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _panels(study: GradientStudy, title: str):
    plt = _pyplot()
    n = len(study.params)
    fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 4.2), squeeze=False)
    fig.suptitle(f"{title}: {study.scene} {study.resolution[0]}x{study.resolution[1]}, loss {study.loss}, {study.trials} trials", fontsize=10)
    return fig, axes[0]


def _style(config) -> dict:
    return {"marker": "o" if config.gradient == "correlated" else "s", "ls": "-" if config.gradient == "correlated" else "--"}


def plot_variance(study: GradientStudy, path, predictions: dict | None = None) -> None:
    """Variance of each parameter's derivative against spp, log-log, per configuration.

    ``predictions``: ``{(config label, parameter): {spp: variance}}`` drawn dotted.
    """
    fig, axes = _panels(study, "gradient variance")
    spp = list(study.spp)
    for k, (ax, name) in enumerate(zip(axes, study.params)):
        top = 0.0
        for i, c in enumerate(study.configs):
            rows = [study.summary(c, n, "parameter") for n in spp]
            v = [float(r.moments.variance[k]) for r in rows]
            se = [float(r.moments.variance_se[k]) for r in rows]
            slope, _ = study.slope(c, name)
            label = f"{c.label} (slope {slope:+.2f})" if math.isfinite(slope) else c.label
            line = ax.errorbar(spp, v, yerr=se, capsize=2, lw=1, ms=4, color=f"C{i}", label=label, **_style(c))
            if predictions and (c.label, name) in predictions:
                p = predictions[(c.label, name)]
                ax.plot(spp, [p[n] for n in spp], ":", color=line[0].get_color(), lw=1.5)
            top = max(top, v[0])
        if top > 0:
            ax.plot(spp, [top * spp[0] / n for n in spp], color="grey", lw=3, alpha=0.35, label="1/N")
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel("samples per pixel N")
        ax.set_ylabel("variance of one gradient")
        ax.set_title(name, fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6)
    fig.tight_layout()
    save_figure(fig, path)


def plot_bias(study: GradientStudy, path, predictions: dict | None = None) -> None:
    """Bias of each parameter's derivative (mean minus reference) against spp, with error bars
    (trials' and reference's standard errors), per configuration.

    ``predictions``: ``{(config label, parameter): {spp: bias}}`` drawn dotted.
    """
    fig, axes = _panels(study, "gradient bias")
    spp = list(study.spp)
    for k, (ax, name) in enumerate(zip(axes, study.params)):
        scale = []
        for i, c in enumerate(study.configs):
            rows = [study.summary(c, n, "parameter") for n in spp]
            if rows[0].bias is None:
                continue
            b = [float(r.bias[k]) for r in rows]
            e = [float(r.bias_se[k]) for r in rows]
            scale += [x for x in e if x > 0]
            style = _style(c)
            line = ax.errorbar(spp, b, yerr=e, capsize=2, lw=1, ms=4, color=f"C{i}", label=c.label, mfc="none" if c.gradient != "correlated" else None, **style)
            if predictions and (c.label, name) in predictions:
                p = predictions[(c.label, name)]
                ax.plot(spp, [p[n] for n in spp], ":", color=line[0].get_color(), lw=1.5)
        ax.axhline(0, color="black", lw=0.8)
        if scale:
            ax.set_yscale("symlog", linthresh=min(scale))  # linear within the error bars' size, logarithmic beyond
        else:
            ax.text(0.5, 0.5, "no reference: no bias measured", transform=ax.transAxes, ha="center", fontsize=8)
        ax.set_xscale("log", base=2)
        ax.set_xlabel("samples per pixel N")
        ax.set_ylabel("bias (mean - reference)")
        ax.set_title(name, fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6)
    fig.tight_layout()
    save_figure(fig, path)


def plot_pixel_variance(study: GradientStudy, path) -> None:
    """The target, then per map the variance of each pixel's contribution (log scale)."""
    plt = _pyplot()
    maps = study.pixel_maps
    fig, axes = plt.subplots(1, 1 + len(maps), figsize=(3.6 * (1 + len(maps)), 3.8), squeeze=False)
    axes = axes[0]
    axes[0].imshow(to_srgb(study.target_image.clamp_min(0)).clamp(0, 1).cpu().numpy())
    axes[0].set_title("target", fontsize=9)
    positive = torch.cat([m.variance[m.variance > 0].flatten() for m in maps]) if maps else torch.zeros(0)
    low, high = (math.log10(float(positive.min())), math.log10(float(positive.max()))) if positive.numel() else (0.0, 1.0)
    for ax, m in zip(axes[1:], maps):
        image = torch.log10(m.variance.clamp_min(10**low))
        shown = ax.imshow(image.cpu().numpy(), vmin=low, vmax=high, cmap="magma")
        fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.04, label="log10 variance")
        ax.set_title(f"{m.parameter}, {m.spp} spp\n" + "\n".join(m.configs) + f"\nsum {m.total:.3g}", fontsize=7)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle("where the gradient's variance comes from: variance of each pixel's contribution dl/dI * dI/dtheta", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def plot_fits(study, path) -> None:
    """A :class:`~invrender.study.fits.FitStudy`: the largest relative error of the fitted
    parameters against wall seconds (left) and against steps (right), log scale, one line per
    configuration (the median over repeats at each step, against the median seconds; single
    repeats drawn thin), the thresholds dotted."""
    from invrender.study.fits import THRESHOLDS

    plt = _pyplot()
    fig, (by_time, by_step) = plt.subplots(1, 2, figsize=(11, 4.4))
    fig.suptitle(
        f"fits of {', '.join(study.params)}: {study.scene} {study.resolution[0]}x{study.resolution[1]}, loss {study.loss}, "
        f"{study.settings['steps']} steps, {study.repeats} repeat(s)",
        fontsize=9,
    )
    for i, c in enumerate(study.configs):
        runs = study.runs_of(c)
        steps = min(len(r.seconds) for r in runs)
        seconds = torch.stack([r.seconds[:steps] for r in runs]).median(0).values
        error = torch.stack([r.error[:steps] for r in runs]).median(0).values
        label = c.label + (f" (median of {len(runs)})" if len(runs) > 1 else "")
        by_time.plot(seconds.numpy(), error.numpy(), color=f"C{i}", lw=1.4, label=label)
        by_step.plot(range(1, steps + 1), error.numpy(), color=f"C{i}", lw=1.4, label=label)
        if len(runs) > 1:
            for r in runs:
                by_time.plot(r.seconds.numpy(), r.error.numpy(), color=f"C{i}", lw=0.5, alpha=0.35)
                by_step.plot(range(1, len(r.error) + 1), r.error.numpy(), color=f"C{i}", lw=0.5, alpha=0.35)
    for ax, xlabel in ((by_time, "wall seconds"), (by_step, "step")):
        for t in THRESHOLDS:
            ax.axhline(t, color="grey", ls=":", lw=1)
        ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("largest relative error")
        ax.grid(alpha=0.3, which="both")
    by_time.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def plot_study(study: GradientStudy, out, predictions: dict | None = None) -> list:
    """All figures into the folder ``out``: ``variance.png``, ``bias.png`` and (with per-pixel
    maps) ``pixel_variance.png``. ``predictions``: ``{"variance": {...}, "bias": {...}}``
    as :func:`plot_variance` and :func:`plot_bias` take them. Returns the paths."""
    from pathlib import Path

    out = Path(out)
    predictions = predictions or {}
    plot_variance(study, out / "variance.png", predictions.get("variance"))
    plot_bias(study, out / "bias.png", predictions.get("bias"))
    paths = [out / "variance.png", out / "bias.png"]
    if study.pixel_maps:
        plot_pixel_variance(study, out / "pixel_variance.png")
        paths.append(out / "pixel_variance.png")
    return paths
