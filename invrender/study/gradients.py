"""``gradient_study``: the variance, bias and cost of gradient estimators over independent trials.

For every configuration (:mod:`invrender.study.configs`) and every spp in a list, a study draws
``trials`` gradients of one loss from independent seeds and keeps them all; statistics
(:mod:`invrender.study.statistics`) are computed from the kept samples. The bias of a configuration
is measured against a reference gradient: the mean of ``reference_repeats`` decorrelated gradients
at ``reference_spp`` each, one reference per *model* (configurations that differ only in the
estimator, the pairing or Russian roulette have the same expected image and share it), with its own
standard error from the spread of the repeats.

Seeds: trial t renders with seed ``base + 2t`` in every configuration and at every spp (the
decorrelated pairing's second render takes ``base + 2t + 1``), so configurations are compared on the
same random numbers and ``replay`` and ``autodiff`` give the same samples; references and the target
take seeds beyond the trials'.

Workers: trials are drawn ``workers`` at a time (default: one per core), each in a thread of its
own, pinned to a core of its own where the OS allows it, that traces single-threaded (torch and
Embree) with an objective of its own. A gradient of a small image is a few thousand paths, one
chunk of the driver, so one render cannot use two cores; two trials at once can, and without the
driver's per-render thread pool each gradient also costs less CPU (about half on the 16x16 Cornell
box). The samples do not depend on ``workers``.

Cost: a gradient's ``seconds`` are the CPU seconds of the thread that traced it. All of its work
runs in that thread, so they are its whole cost, and they change less than wall time when other
jobs load the machine (wall seconds are kept beside them, ``wall``); efficiency uses them. At each
spp the configurations are interleaved trial by trial (trial 0 of each, then trial 1, ...), so
what load there is falls on all of them alike.
"""

from __future__ import annotations

import itertools
import math
import os
import queue
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from invrender.errors import ParameterError, did_you_mean
from invrender.scene.scene import check_names
from invrender.scene.scene import Scene
from invrender.study.configs import GradientConfig, parse_configs
from invrender.study.loss_gradients import Objective
from invrender.study.setup import move_to, study_target
from invrender.study.statistics import Moments, log_slope, moments
from invrender.study.trials import gradient_sample, pixel_contributions
from invrender.validate import MAX_SPP, check_int, check_paths
from invrender.core.ranks import refuse

#: the configurations of a default study: both pairings with one estimator, both estimators with
#: the pairing fit uses (autodiff is the cheaper one for a correlated gradient of a small image);
#: independent pixel samples, so that the variance measures the estimator: stratified samples
#: resolve the light's edge pixels faster than 1/N, and the slope would measure the stratification
DEFAULT_CONFIGS = (
    "path/autodiff/correlated/sampler=independent",
    "path/autodiff/decorrelated/sampler=independent",
    "path/replay/decorrelated/sampler=independent",
)
#: samples per pixel of a default study: from 8, where the Cornell box's variance is in its 1/N
#: regime (below, the product of the residual's and the derivative's noises, a 1/N^2 term, still
#: shows: docs/gradient_variance.md#reading-the-figures)
DEFAULT_SPP = (8, 16, 32, 64)
#: loss of a default study: fit's, which weighs every pixel relative to its brightness; under l2
#: a few bright pixels on the light's edge carry a heavy-tailed share of every gradient's variance
DEFAULT_LOSS = "relative_l2"
#: losses a study offers: those whose gradient is a sum of per-pixel terms
LOSSES = ("l2", "relative_l2", "l1")


@dataclass(frozen=True)
class Seeds:
    """Seeds of a study's renders; all even, so that ``seed + 1`` (a decorrelated pairing's second
    render) is never another render's seed."""

    base: int
    trials: int
    repeats: int

    def trial(self, t: int) -> int:
        return self.base + 2 * t

    def reference(self, r: int) -> int:
        return self.base + 2 * (self.trials + r)

    @property
    def target(self) -> int:
        return self.base + 2 * (self.trials + self.repeats)

    @property
    def warm_up(self) -> int:
        return self.target + 2


@dataclass(frozen=True)
class Reference:
    """The expected gradient of one model: estimated at high spp, or known exactly.

    Attributes:
        config: the configuration it was drawn with (decorrelated, replay) or is exact for.
        spp: samples per pixel of each repeat; None when exact.
        samples: (R, C) float64, one decorrelated gradient per repeat; (1, C) the exact gradient
            when ``spp`` is None.
    """

    config: GradientConfig
    spp: int | None
    samples: torch.Tensor

    @property
    def exact(self) -> bool:
        return self.spp is None

    def moments(self, reduce=lambda x: x) -> Moments:
        """Mean and standard error of ``reduce(samples)`` (zero error when exact)."""
        x = reduce(self.samples)
        if not self.exact:
            return moments(x)
        zero = torch.zeros_like(x[0])
        return Moments(x[0], zero, zero, zero, 1)


@dataclass(frozen=True)
class Trials:
    """The gradients one configuration drew at one spp.

    Attributes:
        config: the configuration.
        spp: samples per pixel.
        samples: (T, C) float64, the gradient of each trial, components flattened over the
            study's parameters in order.
        seconds: (T,) float64 CPU seconds of each gradient (its thread's; module docstring).
        reference: the reference of the configuration's model, or None.
        wall: (T,) float64 wall seconds of each gradient.
    """

    config: GradientConfig
    spp: int
    samples: torch.Tensor
    seconds: torch.Tensor
    reference: Reference | None
    wall: torch.Tensor | None = None


@dataclass(frozen=True)
class Summary:
    """Statistics of one :class:`Trials` for K quantities: the gradient's components, or the sum of
    each parameter's components (its derivative along all channels together).

    Attributes:
        config: configuration label.
        spp: samples per pixel.
        labels: K names, e.g. ``"red.reflectance.R"`` or ``"red.reflectance"`` (a sum).
        moments: mean, variance and standard errors of the K quantities.
        seconds: mean CPU seconds per gradient.
        reference: the reference's moments for the same K quantities, or None.
        wall: mean wall seconds per gradient (each on one core, beside the other workers).
    """

    config: str
    spp: int
    labels: list[str]
    moments: Moments
    seconds: float
    reference: Moments | None
    wall: float = math.nan

    @property
    def bias(self) -> torch.Tensor | None:
        """(K,) mean minus the reference's mean."""
        return None if self.reference is None else self.moments.mean - self.reference.mean

    @property
    def bias_se(self) -> torch.Tensor | None:
        """(K,) standard error of :attr:`bias` (the trials' and the reference's)."""
        return None if self.reference is None else (self.moments.std_error**2 + self.reference.std_error**2).sqrt()

    @property
    def efficiency(self) -> torch.Tensor:
        """(K,) ``1 / (variance x seconds per gradient)``."""
        return 1.0 / (self.moments.variance * self.seconds)


@dataclass(frozen=True)
class PixelVariance:
    """Where the noise of one parameter's gradient comes from, pixel by pixel.

    Attributes:
        configs: labels of the configurations it describes (they differ only in the estimator,
            which does not change the estimate).
        parameter: the parameter; the derivative is along all its components together.
        spp: samples per pixel.
        mean: (H, W) float64 mean contribution of each pixel (channels summed).
        variance: (H, W) float64 variance of each pixel's contribution; pixels are independent, so
            the sum is the variance of the derivative.
        trials: T.
    """

    configs: tuple[str, ...]
    parameter: str
    spp: int
    mean: torch.Tensor
    variance: torch.Tensor
    trials: int

    @property
    def total(self) -> float:
        """Sum of the per-pixel variances: the variance of the parameter's derivative."""
        return float(self.variance.sum())


@dataclass(frozen=True)
class GradientStudy:
    """The result of :func:`gradient_study`.

    Attributes:
        scene: the scene's name.
        resolution: (width, height).
        params: the studied parameters, in the order their components are flattened.
        shapes: name -> the parameter's shape.
        loss: the loss.
        spp: the samples-per-pixel list, ascending.
        trials: trials per configuration and spp.
        configs: the configurations.
        at: name -> the values where the gradient was taken.
        target: how the target was made: ``"given"`` or how it was rendered.
        target_image: (H, W, 3) the target.
        runs: one :class:`Trials` per configuration and spp.
        references: configuration label -> its model's :class:`Reference` (empty without references).
        pixel_maps: one :class:`PixelVariance` per group of configurations differing only in the
            estimator.
        seed: the study's seed.
    """

    scene: str
    resolution: tuple[int, int]
    params: tuple[str, ...]
    shapes: dict
    loss: str
    spp: tuple[int, ...]
    trials: int
    configs: tuple[GradientConfig, ...]
    at: dict
    target: str
    target_image: torch.Tensor
    runs: tuple[Trials, ...]
    references: dict
    pixel_maps: tuple[PixelVariance, ...]
    seed: int

    @property
    def component_labels(self) -> list[str]:
        """One label per gradient component: ``name.R/G/B`` for RGB parameters, ``name[i]`` otherwise."""
        labels = []
        for name in self.params:
            shape = tuple(self.shapes[name])
            labels += [f"{name}.{c}" for c in "RGB"] if shape == (3,) else [f"{name}[{i}]" for i in range(math.prod(shape))]
        return labels

    def run(self, config, spp: int) -> Trials:
        label = config.label if isinstance(config, GradientConfig) else config
        for r in self.runs:
            if r.config.label == label and r.spp == spp:
                return r
        raise ParameterError(f"the study has no configuration {label!r} at {spp} spp")

    def _parameter_sums(self, samples: torch.Tensor) -> torch.Tensor:
        """(T, C) -> (T, P): each parameter's components summed."""
        sizes = [math.prod(self.shapes[n]) for n in self.params]
        return torch.stack([part.sum(1) for part in samples.split(sizes, dim=1)], dim=1)

    def summary(self, config, spp: int, per: str = "component") -> Summary:
        """:class:`Summary` of one configuration at one spp, ``per`` ``"component"`` or ``"parameter"``."""
        run = self.run(config, spp)
        if per not in ("component", "parameter"):
            raise ParameterError(f"per must be 'component' or 'parameter', got {per!r}")
        reduce = (lambda x: x) if per == "component" else self._parameter_sums
        labels = self.component_labels if per == "component" else list(self.params)
        reference = run.reference.moments(reduce) if run.reference is not None else None
        wall = float(run.wall.mean()) if run.wall is not None else math.nan
        return Summary(run.config.label, spp, labels, moments(reduce(run.samples)), float(run.seconds.mean()), reference, wall)

    def slope(self, config, parameter: str) -> tuple[float, float]:
        """Slope (and standard error) of log variance against log spp for the derivative along all
        of ``parameter``'s components: -1 for an estimator whose variance falls as 1/N."""
        k = list(self.params).index(parameter)
        rows = [self.summary(config, n, "parameter") for n in self.spp]
        return log_slope(list(self.spp), [float(r.moments.variance[k]) for r in rows], [float(r.moments.variance_se[k]) for r in rows])


def gradient_study(
    scene: Scene,
    params,
    configs=DEFAULT_CONFIGS,
    spp=DEFAULT_SPP,
    trials: int = 200,
    *,
    loss: str = DEFAULT_LOSS,
    target=None,
    target_spp: int = 1024,
    at=0.5,
    reference_spp: int = 128,
    reference_repeats: int = 16,
    reference=None,
    pixel_maps: bool = True,
    pixel_param: str | None = None,
    pixel_spp: int | None = None,
    seed: int = 0,
    workers: int | None = None,
    progress: bool = True,
) -> GradientStudy:
    """Measure the mean, variance, bias and cost of gradient estimators over independent trials.

    Every argument is checked before any rendering; bad ones raise a one-line
    :class:`~invrender.errors.ParameterError` (or ImageError for a target).

    Args:
        scene: from :func:`invrender.load_scene`; not modified.
        params: the parameters differentiated (names, list or comma-separated).
        configs: configurations, as :class:`GradientConfig` objects or spec strings such as
            ``"path/replay/correlated"`` or ``"random_walk/autodiff/decorrelated/rr_depth=1"``
            (:mod:`invrender.study.configs`).
        spp: samples per pixel, one study per value.
        trials: independent gradients per configuration and spp (>= 2); about 200 give the variance
            to 10% (more when the gradient is heavy-tailed: see the variance's standard error).
        loss: ``"relative_l2"`` (fit's default), ``"l2"`` or ``"l1"`` (as ``fit`` computes them).
        target: an (H, W, 3) tensor or an image path; None = render the scene (at its own values,
            before ``at`` is applied) at ``target_spp`` with a seed of its own.
        at: where the gradient is taken: a factor for every studied parameter's values (default 0.5,
            like a fit early on; 1 = at the target's own values, where a rendered target's loss is
            minimal and the gradient is all noise), or a dict of values (parameter name, or a kind
            such as ``"reflectance"`` for all studied of that kind). Away from the target's values
            the residual ``I - T`` has a mean and the variance reaches its ``1/N`` regime at lower
            spp (docs/gradient_variance.md#reading-the-figures).
        reference_spp: spp of each reference repeat; 0 = no reference (no bias is reported).
        reference_repeats: decorrelated gradients averaged into a reference (>= 2).
        reference: the exact expected gradients where they are known: a function from a
            :class:`GradientConfig` to its model's gradient, flattened as the samples, (C,);
            replaces the estimated references (the furnace check passes its closed forms).
        pixel_maps: also measure per-pixel gradient variances (:class:`PixelVariance`; forward-mode
            renders, :mod:`invrender.study.trials`).
        pixel_param: the parameter of the per-pixel maps (default: the first of ``params``).
        pixel_spp: their spp (default: the smallest of ``spp``).
        seed: the study's seed; every render's seed derives from it.
        workers: trials drawn at once, each single-threaded in a thread of its own (default: one
            per core); the samples do not depend on it, the seconds per gradient do (one core's).
        progress: a progress bar with rate and ETA.
    Returns:
        :class:`GradientStudy`.
    """
    refuse("a gradient study")  # its trials run in threads: collectives from them would interleave
    names = check_names(scene.params, params)
    configs = parse_configs(configs)
    spp = _check_spp(spp)
    check_int("", "trials", trials)
    if trials < 2:
        raise ParameterError(f"trials must be >= 2 (a variance needs two samples), got {trials}")
    if loss not in LOSSES:
        raise ParameterError(f"unknown loss {loss!r}{did_you_mean(loss, LOSSES)} for a gradient study (known: {', '.join(LOSSES)})")
    check_int("", "reference_spp", reference_spp, 0, MAX_SPP)
    check_int("", "reference_repeats", reference_repeats)
    if reference_repeats < 2:
        raise ParameterError(f"reference_repeats must be >= 2 (the reference's standard error needs two), got {reference_repeats}")
    check_int("", "target_spp", target_spp, 1, MAX_SPP)
    check_int("", "seed", seed, 0)
    workers = len(os.sched_getaffinity(0)) if workers is None else workers
    check_int("", "workers", workers, 1)
    pixel_param = names[0] if pixel_param is None else pixel_param
    if pixel_param not in names:
        raise ParameterError(f"pixel_param {pixel_param!r} is not one of the studied parameters ({', '.join(names)})")
    pixel_spp = spp[0] if pixel_spp is None else pixel_spp
    check_int("", "pixel_spp", pixel_spp, 1, MAX_SPP)
    for n in (*spp, reference_spp * reference_repeats, target_spp, pixel_spp):
        check_paths(scene.width, scene.height, n)  # every render the study makes, before any of them
    seeds = Seeds(seed * 1_000_003, trials, reference_repeats)

    work = scene.with_params(detach=True)
    move_to(work, names, at)  # checks `at` before the target is rendered
    target_image, target_label = study_target(scene, target, target_spp, seeds.target, configs[0])
    for n in names:
        work.params[n].requires_grad_(True)
    objective = Objective(work, target_image, loss)

    models = list(dict.fromkeys(c.model for c in configs))  # one reference each
    references = {}
    if reference is not None:
        size = sum(work.params[n].numel() for n in names)
        for model in models:
            exact = torch.as_tensor(reference(model), dtype=torch.float64).reshape(1, -1)
            if exact.shape[1] != size:
                raise ParameterError(f"the exact reference of {model.label!r} has {exact.shape[1]} components, the gradient {size}")
            references[model] = Reference(model, None, exact)
    map_groups: dict[GradientConfig, list[str]] = {}
    for c in configs:
        map_groups.setdefault(c.replace(estimator="replay"), []).append(c.label)
    units = len(configs) * (workers + len(spp) * trials) + (len(models) * reference_repeats if reference_spp and reference is None else 0) + (len(map_groups) * trials if pixel_maps else 0)
    bar = tqdm(total=units, unit="grad", desc=f"gradients {scene.name}", file=sys.stderr, disable=not progress, dynamic_ncols=True)
    pool = _Workers(objective, names, workers)

    def draw(config: GradientConfig, n: int, seed_of, count: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        bar.set_postfix_str(f"{config.label} {n} spp", refresh=False)
        drawn = pool.map(lambda own, t: gradient_sample(own, names, config, n, seed_of(t)), count, bar)
        return torch.stack([d[0] for d in drawn]), torch.tensor([d[1] for d in drawn], dtype=torch.float64), torch.tensor([d[2] for d in drawn], dtype=torch.float64)

    with bar, pool:
        for c in configs:  # first calls build caches; their time is not a gradient's
            draw(c, spp[0], lambda t: seeds.warm_up, workers)
        if reference is None and reference_spp:
            for model in models:
                samples, _, _ = draw(model, reference_spp, seeds.reference, reference_repeats)
                references[model] = Reference(model, reference_spp, samples)
        drawn = {}
        for n in spp:  # configurations interleaved trial by trial: a change of the machine's load falls on all alike
            bar.set_postfix_str(f"{n} spp", refresh=False)
            pairs = [(c, t) for t in range(trials) for c in configs]
            for (c, _), d in zip(pairs, pool.map(lambda own, i: gradient_sample(own, names, pairs[i][0], n, seeds.trial(pairs[i][1])), len(pairs), bar)):
                drawn.setdefault((c, n), []).append(d)
        runs = []
        for c in configs:
            for n in spp:
                d = drawn[(c, n)]
                samples, seconds, wall = torch.stack([x[0] for x in d]), torch.tensor([x[1] for x in d], dtype=torch.float64), torch.tensor([x[2] for x in d], dtype=torch.float64)
                runs.append(Trials(c, n, samples, seconds, references.get(c.model), wall))
        maps = []
        if pixel_maps:
            for c, labels in map_groups.items():
                bar.set_postfix_str(f"per-pixel {c.label} {pixel_spp} spp", refresh=False)
                maps.append(_pixel_variance(pool, pixel_param, c, labels, pixel_spp, seeds, trials, bar))

    return GradientStudy(
        scene=scene.name, resolution=tuple(scene.resolution), params=tuple(names), shapes={n: tuple(work.params[n].shape) for n in names},
        loss=loss, spp=tuple(spp), trials=trials, configs=tuple(configs), at={n: work.params[n].detach().tolist() for n in names},
        target=target_label, target_image=target_image, runs=tuple(runs), references={c.label: references[c.model] for c in configs if c.model in references},
        pixel_maps=tuple(maps), seed=seed,
    )  # fmt: skip


class _Workers:
    """Trials drawn side by side: ``workers`` threads, each tracing single-threaded (the driver
    then runs its chunks in the calling thread) with an :class:`Objective` of its own."""

    def __init__(self, objective: Objective, names: list[str], workers: int):
        self.free: queue.SimpleQueue = queue.SimpleQueue()
        for w in range(workers):
            self.free.put(objective if w == 0 else _own_objective(objective, names))
        self.cores = sorted(os.sched_getaffinity(0))
        self.started = itertools.count()
        self.pool = ThreadPoolExecutor(workers, initializer=self._single_core, thread_name_prefix="trial")

    def _single_core(self) -> None:
        """A worker's setup: torch single-threaded, and the thread pinned to one core, so that
        the driver and Embree see one core and trace in this thread (its CPU time is then the
        whole cost of its gradients)."""
        torch.set_num_threads(1)
        w = next(self.started)
        try:
            os.sched_setaffinity(0, {self.cores[w % len(self.cores)]})  # 0: the calling thread (Linux)
        except (AttributeError, OSError):
            pass

    def map(self, work, count: int, bar) -> list:
        """``[work(objective, t) for t in range(count)]``, drawn on the workers."""

        def task(t: int):
            own = self.free.get()
            try:
                return work(own, t)
            finally:
                self.free.put(own)

        futures = [self.pool.submit(task, t) for t in range(count)]
        results = []
        try:
            for f in futures:
                results.append(f.result())
                bar.update(1)
        except BaseException:
            for f in futures:
                f.cancel()
            raise
        return results

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.pool.shutdown(wait=True, cancel_futures=True)


def _own_objective(objective: Objective, names: list[str]) -> Objective:
    """The same objective with leaf tensors of its own (a worker's: gradients must not mix)."""
    scene = objective.scene.with_params(detach=True)
    for n in names:
        scene.params[n].requires_grad_(True)
    return Objective(scene, objective.target, objective.loss)


def _pixel_variance(pool: _Workers, name: str, config: GradientConfig, labels: list[str], spp: int, seeds: Seeds, trials: int, bar) -> PixelVariance:
    """Per-pixel mean and variance of the contributions to ``name``'s derivative over the trials."""
    total = square = None
    contributions = pool.map(lambda own, t: pixel_contributions(own, name, config, spp, seeds.trial(t)).sum(-1), trials, bar)  # (H, W): channels together
    for c in contributions:
        total = c if total is None else total + c
        square = c**2 if square is None else square + c**2
    mean = total / trials
    variance = ((square - trials * mean**2) / (trials - 1)).clamp_min(0)
    return PixelVariance(tuple(labels), name, spp, mean, variance, trials)


def _check_spp(spp) -> list[int]:
    """The spp list: non-empty, positive integers, no repeats; sorted."""
    values = [spp] if isinstance(spp, int) else list(spp)
    if not values:
        raise ParameterError("the spp list is empty: give at least one samples-per-pixel value")
    for v in values:
        check_int("", "spp", v, 1, MAX_SPP)
    if len(set(values)) != len(values):
        raise ParameterError(f"an spp value is given twice: {values}")
    return sorted(values)
