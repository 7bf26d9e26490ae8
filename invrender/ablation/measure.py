"""Measure sampling strategies: RMSE against a high-spp reference at equal samples and equal time.

Every variant renders the scene at each spp for a few seeds; its error is the root of the mean
squared difference to the reference over pixels, channels and seeds, and its cost the CPU time of
one render (all its threads; unlike wall-clock time it does not count what other processes take
from the cores, which on a shared machine varies from render to render by 2x; the wall-clock time
is kept too). The variants take turns and each keeps its fastest seed. Equal time compares
variants at the CPU time T the defaults take at the largest spp: a variant's cost per sample (its
CPU seconds over its samples, summed over its measurements) says how many samples T buys it,
and its RMSE at the largest spp is moved there along the Monte Carlo rate ``RMSE ~ spp^(-1/2)``:
the classic efficiency ``1 / (MSE x time)``.
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
        seconds: wall-clock seconds of one render, the fastest of the trials.
        cpu_seconds: CPU seconds of one render (all threads), the fewest of the trials: the cost
            the equal-time comparison uses.
        trials: renders (seeds) averaged.
    """

    variant: str
    spp: int
    rmse: float
    rel_rmse: float
    seconds: float
    cpu_seconds: float
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

    def seconds_per_sample(self, name: str) -> float:
        """Variant ``name``'s CPU seconds per sample per pixel: its CPU seconds over its samples,
        summed over its measurements (so mostly those at the largest spp, where a render's fixed
        overhead matters least)."""
        rows = self.of(name)
        return sum(r.cpu_seconds for r in rows) / sum(r.spp for r in rows)

    @property
    def time_budget(self) -> float:
        """The equal-time comparison's budget, CPU seconds: what the defaults' largest spp costs."""
        return self.seconds_per_sample("default") * self.of("default")[-1].spp

    def rmse_at_time(self, name: str, seconds: float | None = None) -> float:
        """Variant ``name``'s RMSE in ``seconds`` of CPU time (default: :attr:`time_budget`): its
        RMSE at its largest spp moved along the Monte Carlo rate ``RMSE ~ spp^(-1/2)`` to the spp
        its cost per sample affords (the classic efficiency ``1 / (MSE x time)``; interpolating
        between measured spp would follow the steps stratification makes at square spp)."""
        seconds = self.time_budget if seconds is None else seconds
        top = self.of(name)[-1]
        return top.rmse * math.sqrt(top.spp * self.seconds_per_sample(name) / seconds)

    def efficiency(self, name: str) -> float:
        """The defaults' MSE over the variant's at equal time (:attr:`time_budget`): how many
        times longer the defaults must run to match it (> 1: the variant is better)."""
        return (self.rmse_at_time("default") / self.rmse_at_time(name)) ** 2


def ablation(
    scene: Scene,
    strategies: str | list[str] | None = None,
    spp: tuple[int, ...] = (8, 16, 32, 64),
    trials: int = 2,
    reference_spp: int = 4096,
    max_depth: int | None = 8,
    seed: int = 0,
    progress: bool = True,
    integrator="path",
) -> AblationResult:
    """Render ``scene`` with each sampling strategy at each ``spp`` and measure its error.

    Args:
        scene: any scene the path tracer renders (its resolution as loaded).
        strategies: variant names (:data:`~invrender.ablation.variants.VARIANTS`), comma-separated
            or a list; None = all. ``default`` is always included.
        spp: samples per pixel (ascending); adaptive sampling needs at least 6.
        trials: seeds per variant and spp (their squared errors are averaged).
        reference_spp: samples per pixel of the reference (the defaults, independent seeds).
        max_depth: Neumann terms kept by every render (set in the integrator spec; None = the spec's).
        seed: offsets every seed of the study.
        progress: a progress bar over the renders.
        integrator: the integrator spec of the defaults (:mod:`invrender.registry`; default
            ``"path"``), whose settings each variant changes; every spec is checked before any work.
    """
    variants = select_variants(strategies)
    from invrender.plugins.integrators import make_integrator

    base = variants[0].integrator_spec(integrator)
    if max_depth is not None:
        base["max_depth"] = max_depth
    models = {v.name: make_integrator(v.integrator_spec(base)) for v in variants}  # checked here, before any work
    max_depth = models["default"].terms_kept
    spp = tuple(spp)
    if not spp or any(isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in spp) or list(spp) != sorted(set(spp)):
        raise ParameterError(f"spp must be ascending positive integers, got {', '.join(map(str, spp)) or 'none'}")
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise ParameterError(f"trials must be a positive integer, got {trials!r}")
    if isinstance(reference_spp, bool) or not isinstance(reference_spp, int) or reference_spp < REFERENCE_PARTS * max(spp):
        raise ParameterError(f"reference_spp must be an integer >= {REFERENCE_PARTS} x the largest spp ({REFERENCE_PARTS * max(spp)}), got {reference_spp!r}")
    from invrender.estimators import render

    renders = REFERENCE_PARTS + 1 + len(variants) * len(spp) * trials
    with tqdm(total=renders, desc=f"ablation {scene.name}", unit="render", disable=not progress, file=sys.stderr) as bar:
        parts = []
        for k in range(REFERENCE_PARTS):
            parts.append(render(scene, models["default"], spp=reference_spp // REFERENCE_PARTS, seed=seed + REFERENCE_SEED + k, progress=False).double())
            bar.update()
        parts = torch.stack(parts)
        reference = parts.mean(0)
        reference_rmse = math.sqrt(float(parts.var(0).mean()) / REFERENCE_PARTS)
        render(scene, models["default"], spp=1, seed=seed, progress=False)  # warm-up: the timings start warm
        bar.update()
        denominator = (reference.mean(-1, keepdim=True) + reference.mean()).clamp_min(1e-30)
        cells = [(v, n) for v in variants for n in spp if not (v.render.get("adaptive") and n < 6)]  # adaptive: a pilot and a sample per round
        bar.update(trials * (len(variants) * len(spp) - len(cells)))
        squared = {(v.name, n): 0.0 for v, n in cells}
        relative = dict(squared)
        seconds = {key: math.inf for key in squared}
        cpu_seconds = dict(seconds)
        for t in range(trials):  # variants interleaved, so that other processes' load slows them alike
            for variant, n in cells:
                start, cpu_start = time.perf_counter(), time.process_time()
                image = render(scene, models[variant.name], spp=n, seed=seed + 1 + t, progress=False, **variant.render)
                key = (variant.name, n)
                seconds[key] = min(seconds[key], time.perf_counter() - start)
                cpu_seconds[key] = min(cpu_seconds[key], time.process_time() - cpu_start)
                error = image.double() - reference
                squared[key] += float((error**2).mean())
                relative[key] += float(((error / denominator) ** 2).mean())
                bar.update()
        rows = [Measurement(name, n, math.sqrt(squared[key] / trials), math.sqrt(relative[key] / trials), seconds[key], cpu_seconds[key], trials) for key in squared for name, n in [key]]
    return AblationResult(scene.name, (scene.width, scene.height), max_depth, reference_spp, reference_rmse, variants, tuple(rows))
