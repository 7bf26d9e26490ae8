"""Measure sampling strategies: RMSE against a high-spp reference at equal samples and equal time.

Every variant renders the scene at each spp for a few seeds; its error is the root of the mean
squared difference to the reference over pixels, channels and seeds, and its cost the mean
wall-clock time of one render. Equal time compares variants at the time the defaults take at the
largest spp: a variant's RMSE there is read off its own measurement nearest in time, moved along
the Monte Carlo rate ``RMSE ~ time^(-1/2)`` (``rmse_j sqrt(t_j / T)``).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from invrender.ablation.variants import Variant, select_variants
from invrender.errors import ParameterError
from invrender.scene.scene import Scene

#: seeds of the reference's independent parts (far from the trials' seeds 1, 2, ...)
REFERENCE_SEED = 1_000_000
#: independent parts of the reference, for an estimate of its own noise
REFERENCE_PARTS = 4


@dataclass(frozen=True)
class Measurement:
    """One variant at one spp, over its trials.

    Attributes:
        variant: the variant's name.
        spp: samples per pixel (the average, for adaptive sampling).
        rmse: root mean squared error against the reference over pixels, channels and trials.
        rel_rmse: the same for errors relative to ``ref_p + mean(ref)`` (``ref_p`` the pixel's
            channel mean): noise in dark pixels counts as much as in bright ones, down to the
            image's mean.
        seconds: mean wall-clock seconds of one render.
        trials: renders (seeds) averaged.
    """

    variant: str
    spp: int
    rmse: float
    rel_rmse: float
    seconds: float
    trials: int


@dataclass(frozen=True)
class AblationResult:
    """What :func:`ablation` measured.

    Attributes:
        scene: the scene's name; resolution (width, height); max_depth of every render.
        reference_spp: samples per pixel of the reference.
        reference_rmse: estimated RMSE of the reference itself (from its independent parts): the
            floor below which no measured RMSE can go.
        variants: the variants, ``default`` first.
        rows: one :class:`Measurement` per variant and spp.
    """

    scene: str
    resolution: tuple[int, int]
    max_depth: int
    reference_spp: int
    reference_rmse: float
    variants: tuple[Variant, ...]
    rows: tuple[Measurement, ...]

    def of(self, name: str) -> list[Measurement]:
        """The measurements of variant ``name``, by increasing spp."""
        return sorted((r for r in self.rows if r.variant == name), key=lambda r: r.spp)

    @property
    def time_budget(self) -> float:
        """Seconds the defaults took at the largest spp: the equal-time comparison's budget."""
        return self.of("default")[-1].seconds

    def rmse_at_time(self, name: str, seconds: float | None = None) -> float:
        """Variant ``name``'s RMSE at ``seconds`` (default: :attr:`time_budget`), from its
        measurement nearest in time scaled by ``sqrt(t_j / seconds)``."""
        seconds = self.time_budget if seconds is None else seconds
        nearest = min(self.of(name), key=lambda r: abs(math.log(r.seconds / seconds)))
        return nearest.rmse * math.sqrt(nearest.seconds / seconds)

    def efficiency(self, name: str) -> float:
        """``1 / (MSE x seconds)`` at the largest spp, relative to the defaults' (> 1: better)."""
        top, base = self.of(name)[-1], self.of("default")[-1]
        return (base.rmse**2 * base.seconds) / (top.rmse**2 * top.seconds)


def ablation(
    scene: Scene,
    strategies: str | list[str] | None = None,
    spp: tuple[int, ...] = (8, 16, 32, 64),
    trials: int = 2,
    reference_spp: int = 4096,
    max_depth: int = 8,
    seed: int = 0,
    progress: bool = True,
) -> AblationResult:
    """Render ``scene`` with each sampling strategy at each ``spp`` and measure its error.

    Args:
        scene: any scene the path tracer renders (its resolution as loaded).
        strategies: variant names (:data:`~invrender.ablation.variants.VARIANTS`), comma-separated
            or a list; None = all. ``default`` is always included.
        spp: samples per pixel (ascending); adaptive sampling needs at least 6.
        trials: seeds per variant and spp (their squared errors are averaged).
        reference_spp: samples per pixel of the reference (the defaults, independent seeds).
        max_depth: Neumann terms kept by every render.
        seed: offsets every seed of the study.
        progress: a progress bar over the renders.
    """
    variants = select_variants(strategies)
    spp = tuple(spp)
    if not spp or any(isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in spp) or list(spp) != sorted(set(spp)):
        raise ParameterError(f"spp must be ascending positive integers, got {', '.join(map(str, spp)) or 'none'}")
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise ParameterError(f"trials must be a positive integer, got {trials!r}")
    if isinstance(reference_spp, bool) or not isinstance(reference_spp, int) or reference_spp < REFERENCE_PARTS * max(spp):
        raise ParameterError(f"reference_spp must be an integer >= {REFERENCE_PARTS} x the largest spp ({REFERENCE_PARTS * max(spp)}), got {reference_spp!r}")
    from invrender.diff import render

    renders = REFERENCE_PARTS + 1 + len(variants) * len(spp) * trials
    with tqdm(total=renders, desc=f"ablation {scene.name}", unit="render", disable=not progress, file=sys.stderr) as bar:
        parts = []
        for k in range(REFERENCE_PARTS):
            parts.append(render(scene, spp=reference_spp // REFERENCE_PARTS, max_depth=max_depth, seed=seed + REFERENCE_SEED + k, progress=False).double())
            bar.update()
        parts = torch.stack(parts)
        reference = parts.mean(0)
        reference_rmse = math.sqrt(float(parts.var(0).mean()) / REFERENCE_PARTS)
        render(scene, spp=1, max_depth=max_depth, seed=seed, progress=False)  # warm-up: the timings start warm
        bar.update()
        denominator = (reference.mean(-1, keepdim=True) + reference.mean()).clamp_min(1e-30)
        rows = []
        for variant in variants:
            for n in spp:
                if variant.options.get("adaptive") and n < 6:
                    bar.update(trials)
                    continue  # adaptive sampling needs a pilot and a sample per round
                squared, relative, seconds = 0.0, 0.0, 0.0
                for t in range(trials):
                    start = time.perf_counter()
                    image = render(scene, spp=n, max_depth=max_depth, seed=seed + 1 + t, progress=False, **variant.options)
                    seconds += time.perf_counter() - start
                    error = image.double() - reference
                    squared += float((error**2).mean())
                    relative += float(((error / denominator) ** 2).mean())
                    bar.update()
                rows.append(Measurement(variant.name, n, math.sqrt(squared / trials), math.sqrt(relative / trials), seconds / trials, trials))
    return AblationResult(scene.name, (scene.width, scene.height), max_depth, reference_spp, reference_rmse, variants, tuple(rows))
