"""What ignoring interreflection costs: pyrender, ``utah``, ``path`` at max_depth 2 and the full ``path``.

The four images estimate ever longer truncations of ``I = g eps + gMg eps + g(Mg)^2 eps + ...``:

- pyrender rasterizes the Utah approximation (point lights, no interreflection, ambient eps0);
- ``utah`` computes the same model exactly: ``g eps + g M g eps + rho eps0``;
- ``path`` at max_depth 2 keeps the first two Neumann terms (``utah`` without its ambient term);
- ``path`` unbounded (Russian roulette) is the full solution every other image is compared with.

The ambient radiance eps0 that best stands in for interreflection is found in closed form: the
``utah`` image is affine in eps0, ``U(eps0) = U(0) + R eps0`` per channel with ``R = U(1) - U(0)``
(the reflectance each pixel sees), so the eps0 minimizing ``|U(eps0) - I_path|^2`` is
``<R, I_path - U(0)> / <R, R>`` per channel (clamped at 0). The two renders ``U(0)`` and ``U(1)`` give
every ``utah`` image of the comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from invrender.errors import BaselineError
from invrender.scene.scene import AMBIENT, Scene
from invrender.estimators import render
from invrender.core.driver import RenderSettings
from invrender.plugins.integrators import make_integrator

FULL = "path"


@dataclass(frozen=True)
class Comparison:
    """The images of one scene under each model, and what the Utah approximation drops.

    Attributes:
        images: label -> (H, W, 3) linear radiance; labels ``"pyrender"`` (when available),
            ``"utah"``, ``"path, max_depth 2"``, ``"utah, eps0 fitted"`` and ``"path"`` (the full
            solution, last).
        eps0: (3,) the ambient radiance the scene sets (zero when none), used by pyrender and ``utah``.
        eps0_fit: (3,) the ambient radiance minimizing the squared difference of ``utah`` to ``path``.
        pyrender_error: why there is no pyrender image (None when there is one).
    """

    images: dict[str, torch.Tensor]
    eps0: torch.Tensor
    eps0_fit: torch.Tensor
    pyrender_error: str | None = None

    def means(self) -> dict[str, torch.Tensor]:
        """label -> (3,) channel means."""
        return {k: v.mean(dim=(0, 1)) for k, v in self.images.items()}

    def relative_differences(self) -> dict[str, torch.Tensor]:
        """label -> (3,) ``mean / mean(path) - 1``: the share of the full solution's energy each model
        gains (> 0) or drops (< 0), per channel."""
        full = self.images[FULL].mean(dim=(0, 1))
        return {k: m / full - 1 for k, m in self.means().items()}


def utah_affine(scene: Scene, spp: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``(U(0), R)``, each (H, W, 3): the ``utah`` image is ``U(eps0) = U(0) + R eps0`` for every
    eps0 (the same seed, so the same paths), with ``R`` the reflectance each pixel sees."""
    with torch.no_grad():
        u0 = render(scene.with_ambient(0.0), "utah", spp=spp, seed=seed, progress=False)
        R = render(scene.with_ambient(1.0), "utah", spp=spp, seed=seed, progress=False) - u0
    return u0, R


def least_squares_ambient(u0: torch.Tensor, R: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """The (3,) eps0 >= 0 minimizing ``sum_pixels |u0 + R eps0 - reference|^2`` per channel."""
    num = (R * (reference - u0)).sum(dim=(0, 1))
    den = (R * R).sum(dim=(0, 1)).clamp_min(1e-30)
    return (num / den).clamp_min(0.0)


def fit_ambient(scene: Scene, reference: torch.Tensor, spp: int, seed: int) -> torch.Tensor:
    """The (3,) eps0 >= 0 minimizing ``sum_pixels |utah(eps0) - reference|^2`` per channel (closed form)."""
    return least_squares_ambient(*utah_affine(scene, spp, seed), reference)


def compare(scene: Scene, spp: int = 64, seed: int = 0, max_depth: int = -1, pyrender: bool = True, progress: bool = True) -> Comparison:
    """Render ``scene`` under each model (see the module docstring).

    Args:
        scene: its ``params["ambient.emission"]`` (if any) is the eps0 of pyrender and ``utah``.
        spp: samples per pixel of the Monte Carlo images.
        max_depth: of the full ``path`` image (-1: unbounded, ended by Russian roulette).
        pyrender: include the rasterized baseline (needs pyrender and an EGL/OSMesa context); if it
            cannot run, the comparison goes on without it and says why.
    Raises:
        ParameterError: bad ``spp``, ``seed`` or ``max_depth`` (checked before anything is rendered).
    """
    RenderSettings(spp=spp, seed=seed)  # validates before the first render
    make_integrator("path", max_depth=max_depth)
    eps0 = scene.params[AMBIENT].detach() if AMBIENT in scene.params else torch.zeros(3)
    with torch.no_grad():
        images, error = {}, None
        if pyrender:
            from invrender.baseline.pyrender_baseline import pyrender_render

            try:
                images["pyrender"] = pyrender_render(scene, ambient=eps0).cpu()
            except BaselineError as e:
                error = str(e)
        u0, R = (x.cpu() for x in utah_affine(scene, spp, seed))
        images["utah"] = u0 + R * eps0.cpu()
        images["path, max_depth 2"] = render(scene, "path", max_depth=2, spp=spp, seed=seed, progress=progress).cpu()
        full = render(scene, "path", max_depth=max_depth, spp=spp, seed=seed, progress=progress).cpu()
        eps0_fit = least_squares_ambient(u0, R, full)
        images["utah, eps0 fitted"] = u0 + R * eps0_fit
        images[FULL] = full
    return Comparison(images, eps0.cpu(), eps0_fit, error)


def format_table(c: Comparison) -> str:
    """The channel means of each image and their relative differences to the full ``path``."""
    rel = c.relative_differences()
    lines = [f"{'model':<20} {'mean R':>9} {'mean G':>9} {'mean B':>9}   {'vs path R':>9} {'G':>8} {'B':>8}"]
    for label, mean in c.means().items():
        r = rel[label]
        lines.append(f"{label:<20} {mean[0]:9.4f} {mean[1]:9.4f} {mean[2]:9.4f}   {100 * r[0]:+8.2f}% {100 * r[1]:+7.2f}% {100 * r[2]:+7.2f}%")
    dropped = -rel["path, max_depth 2"]  # = utah without ambient
    lines.append("energy the Utah approximation drops without ambient (interreflection, terms >= 3): "
                 + ", ".join(f"{100 * x:.1f}%" for x in dropped.tolist()) + " (R, G, B)")  # fmt: skip
    lines.append("eps0 fitted to minimize |utah - path|^2: (" + ", ".join(f"{x:.4f}" for x in c.eps0_fit.tolist()) + ")")
    if c.pyrender_error:
        lines.append(f"pyrender: not rendered ({c.pyrender_error})")
    return "\n".join(lines)


def plot_comparison(c: Comparison, path) -> None:
    """One PNG: the images side by side (sRGB, clipped) over their luminance differences to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from invrender.io.reports import save_figure
    from invrender.io.images import to_srgb

    labels = list(c.images)
    Y = torch.tensor([0.2126, 0.7152, 0.0722])  # linear-RGB luminance (Rec. 709)
    full_y = c.images[FULL] @ Y
    diffs = {k: c.images[k] @ Y - full_y for k in labels}
    limit = max(float(torch.quantile(d.abs().flatten(), 0.99)) for d in diffs.values()) or 1.0
    rel = c.relative_differences()
    fig, axes = plt.subplots(2, len(labels), figsize=(2.6 * len(labels) + 0.8, 5.8), squeeze=False, layout="constrained")
    for i, label in enumerate(labels):
        top, bottom = axes[0][i], axes[1][i]
        top.imshow(to_srgb(c.images[label]).numpy(), interpolation="nearest")
        top.set_title(label, fontsize=9)
        im = bottom.imshow(diffs[label].numpy(), cmap="RdBu_r", vmin=-limit, vmax=limit, interpolation="nearest")
        bottom.set_title("reference" if label == FULL else f"- path: {100 * float(rel[label].mean()):+.1f}% mean", fontsize=8)
        for ax in (top, bottom):
            ax.set_xticks([])
            ax.set_yticks([])
    fig.colorbar(im, ax=axes[1].tolist(), shrink=0.8, label="luminance difference to path")
    fig.suptitle("what ignoring interreflection costs: eps0 fitted = (" + ", ".join(f"{x:.3f}" for x in c.eps0_fit.tolist()) + ")", fontsize=10)
    save_figure(fig, path)
