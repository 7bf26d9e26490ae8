"""``fit_study``: what a gradient estimator's variance buys a fit. Every configuration runs the same
fit (``ir.fit``, Adam) from the same perturbed start against the same target, and the parameters'
largest relative error is recorded against wall time.

**From a configuration to fit settings** (:func:`fit_settings`). A gradient configuration
(:mod:`invrender.study.configs`) becomes :class:`~invrender.inverse.fit.FitSettings` by what each of
its parts is, not by a table: its integrator and the integrator's settings among its options
(``rr_depth``, ``hemisphere``, ``strategy``, ...) become the fit's integrator spec
(``{"type": "path", "rr_depth": 2}``; the name alone when it has none); ``max_depth`` becomes the
fit's ``max_depth``; its estimator the fit's ``estimator``; its pairing the fit settings the pairing
declares (``LossGradient.fit_settings``: ``correlated`` is ``decorrelate=False``, ``decorrelated``
``decorrelate=True``, ``control_variate`` adds ``control_variate=True``); the render option
``sampler`` the fit's ``sampler``. Anything else has no fit setting and is refused with a one-line
error before any work: the other render settings (``backend``, ``memory_mb``, ...) and the
control-variate pairing's ``cv_steps`` and ``cv_step`` (in a fit the chain is the fit's own steps).

**What is measured.** Each fit's history gives, per step, the wall seconds since its start and the
largest relative error over every channel of every fitted parameter (against the scene's own
values, which rendered the target). From it: the time (and step) at which the error first reaches a
threshold (1%, 2%), and the time from which it stays below it to the end of the fit ("settled":
Adam's steps are noisy, so an error can dip below a threshold and leave it again). With several
repeats (fit seeds), the medians. Fits run one after another with the configurations interleaved
(repeat 0 of every configuration, then repeat 1, ...), so a change in the machine's load spreads
over all of them; each fit's CPU seconds are kept beside its wall seconds.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import sys
import time
from dataclasses import dataclass

import torch
from tqdm.auto import tqdm

from invrender.errors import ParameterError
from invrender.inverse.fit import FitSettings, fit
from invrender.scene.scene import check_names
from invrender.scene.scene import Scene
from invrender.study.configs import GradientConfig, parse_configs
from invrender.study.loss_gradients import LOSS_GRADIENTS
from invrender.study.setup import move_to, study_target
from invrender.core.driver import RenderSettings
from invrender.validate import MAX_SPP, check_int

#: the fit studies' configurations: fit's defaults (decorrelated replay, stratified samples), then
#: each variance reduction alone and both together
DEFAULT_FIT_CONFIGS = (
    "path/replay/decorrelated",
    "path/replay/decorrelated/sampler=antithetic",
    "path/replay/control_variate",
    "path/replay/control_variate/sampler=antithetic",
)
#: relative errors a fit study reports the time to
THRESHOLDS = (0.02, 0.01)
#: FitSettings fields set by a configuration (a fit study's ``settings`` may not set them)
CONFIG_FIELDS = ("integrator", "estimator", "decorrelate", "control_variate", "max_depth", "sampler")
#: FitSettings fields a fit study sets itself
STUDY_FIELDS = ("loss", "seed", "solver")
#: render options (RenderSettings fields) a fit takes from a configuration; the others it has not
FIT_RENDER_OPTIONS = ("sampler",)


def fit_settings(config) -> dict:
    """The :class:`FitSettings` fields a configuration sets (the module docstring says how); a
    one-line :class:`ParameterError` for a part no fit setting expresses."""
    config = parse_configs(config)[0] if not isinstance(config, GradientConfig) else config
    pairing = LOSS_GRADIENTS[config.gradient]
    if pairing.fit_settings is None:
        fitted = ", ".join(name for name, cls in LOSS_GRADIENTS.items() if cls.fit_settings is not None)
        raise ParameterError(f"configuration {config.label!r}: a fit has no setting for the {config.gradient} pairing (fits take: {fitted})")
    settings = {"estimator": config.estimator, **pairing.fit_settings}
    own = config.pairing_options
    render_fields = {f.name for f in dataclasses.fields(RenderSettings)}
    integrator_settings = {}
    for key, value in config.options:
        if key in own:
            raise ParameterError(f"configuration {config.label!r}: {key} does not apply to a fit (its control variate is carried along the fit's own steps)")
        if key == "max_depth" or key in FIT_RENDER_OPTIONS:
            settings[key] = value
        elif key in render_fields:
            raise ParameterError(
                f"configuration {config.label!r}: option {key!r} has no fit setting (a fit takes the integrator and its settings, the estimator, "
                f"the pairing and {', '.join(FIT_RENDER_OPTIONS)})"
            )
        else:
            integrator_settings[key] = value  # the integrator checks them (FitSettings)
    settings["integrator"] = {"type": config.integrator, **integrator_settings} if integrator_settings else config.integrator
    return {k: settings[k] for k in ("integrator", *[k for k in settings if k != "integrator"])}


@dataclass(frozen=True)
class FitRun:
    """One fit of a study.

    Attributes:
        config: the configuration's label.
        repeat: which repeat (fit seed ``seed + repeat``).
        settings: the FitSettings fields it ran with.
        seconds: (S,) wall seconds since the fit's start after each step.
        errors: (S, P) largest relative error of each parameter after each step.
        loss: (S,) the loss of each step.
        spp: (S,) samples per pixel of each step.
        cpu_seconds: CPU seconds of the whole fit (all threads), beside its wall seconds
            ``seconds[-1]``: their ratio says how many cores it had.
        recovered: name -> the recovered values.
    """

    config: str
    repeat: int
    settings: dict
    seconds: torch.Tensor
    errors: torch.Tensor
    loss: torch.Tensor
    spp: torch.Tensor
    cpu_seconds: float
    recovered: dict

    @property
    def error(self) -> torch.Tensor:
        """(S,) the largest relative error over all fitted parameters after each step."""
        return self.errors.max(1).values

    def reached(self, threshold: float) -> int | None:
        """Index of the first step whose error is <= ``threshold`` (None: never)."""
        below = (self.error <= threshold).nonzero()
        return int(below[0]) if below.numel() else None

    def settled(self, threshold: float) -> int | None:
        """Index of the first step from which the error stays <= ``threshold`` to the end (None: never)."""
        above = (self.error > threshold).nonzero()
        if not above.numel():
            return 0
        last = int(above[-1])
        return last + 1 if last + 1 < len(self.error) else None

    def time_to(self, threshold: float, settled: bool = False) -> float:
        """Wall seconds to :meth:`reached` (or :meth:`settled`); ``inf`` when never."""
        k = self.settled(threshold) if settled else self.reached(threshold)
        return math.inf if k is None else float(self.seconds[k])


@dataclass(frozen=True)
class FitStudy:
    """The result of :func:`fit_study`.

    Attributes:
        scene: the scene's name.
        resolution: (width, height).
        params: the fitted parameters.
        loss: the fits' loss.
        configs: the configurations.
        settings: FitSettings fields shared by every fit (steps, spp, ...).
        truth: name -> the values the target was rendered with.
        start: name -> the starting values.
        target: how the target was made.
        runs: every fit, configurations interleaved per repeat.
        repeats: fits per configuration.
        seed: the study's seed.
    """

    scene: str
    resolution: tuple[int, int]
    params: tuple[str, ...]
    loss: str
    configs: tuple[GradientConfig, ...]
    settings: dict
    truth: dict
    start: dict
    target: str
    runs: tuple[FitRun, ...]
    repeats: int
    seed: int

    def runs_of(self, config) -> list[FitRun]:
        label = config.label if isinstance(config, GradientConfig) else config
        runs = [r for r in self.runs if r.config == label]
        if not runs:
            raise ParameterError(f"the fit study has no configuration {label!r}")
        return runs

    def summary(self, config) -> dict:
        """Medians over the repeats of one configuration: seconds per step, time and steps to each
        threshold (first reached and settled; ``inf`` when the median fit never gets there), the
        final error, and how many repeats reached each threshold."""
        runs = self.runs_of(config)
        out = {
            "config": runs[0].config,
            "repeats": len(runs),
            "seconds_per_step": statistics.median(float(r.seconds[-1]) / len(r.seconds) for r in runs),
            "cpu_per_wall": statistics.median(r.cpu_seconds / max(float(r.seconds[-1]), 1e-9) for r in runs),
            "final_error": statistics.median(float(r.error[-1]) for r in runs),
        }
        for t in THRESHOLDS:
            key = _percent(t)
            for kind, settled in (("reached", False), ("settled", True)):
                steps = [(r.settled(t) if settled else r.reached(t)) for r in runs]
                out[f"seconds_to_{key}_{kind}"] = statistics.median(r.time_to(t, settled) for r in runs)
                out[f"steps_to_{key}_{kind}"] = statistics.median(math.inf if k is None else k + 1 for k in steps)
                out[f"repeats_{key}_{kind}"] = sum(k is not None for k in steps)
        return out


def fit_study(
    scene: Scene,
    params,
    configs=DEFAULT_FIT_CONFIGS,
    *,
    repeats: int = 1,
    steps: int = 200,
    spp: int = 16,
    spp_final: int = 64,
    loss: str = "relative_l2",
    target=None,
    target_spp: int = 4096,
    at=0.5,
    settings: dict | None = None,
    seed: int = 0,
    progress: bool = True,
) -> FitStudy:
    """Run ``ir.fit`` with each configuration from the same start against the same target and
    record the parameters' error against wall time.

    Every argument and every configuration's mapping onto fit settings (:func:`fit_settings`) is
    checked before any rendering; bad ones raise a one-line :class:`ParameterError`.

    Args:
        scene: from :func:`invrender.load_scene`; its own values are the truth (not modified).
        params: the fitted parameters (names, list or comma-separated).
        configs: configurations (spec strings or :class:`GradientConfig`), each mapped onto fit
            settings by :func:`fit_settings`.
        repeats: fits per configuration, with seeds ``seed + r`` (medians are reported).
        steps, spp, spp_final: as :class:`FitSettings` takes them (the first half of the steps at
            ``spp``, the second at ``spp_final``).
        loss: the fits' loss (any of fit's).
        target: an (H, W, 3) tensor or image path (then the scene's values are still the truth);
            None = render the scene at ``target_spp`` with the first configuration's model.
        target_spp: spp of the rendered target.
        at: the start: a factor for every fitted parameter's values (default 0.5), or a dict of
            values (names or kinds, as ``fit``'s ``--init`` takes them).
        settings: further FitSettings fields shared by every fit (``lr``, ``beta2``, ...), not
            those a configuration sets (:data:`CONFIG_FIELDS`) or the study sets (:data:`STUDY_FIELDS`).
        seed: the study's seed (targets and fits derive theirs from it).
        progress: a progress bar over the fits (and each fit's own bar over its steps).
    Returns:
        :class:`FitStudy`.
    """
    names = check_names(scene.params, params)
    configs = parse_configs(configs)
    check_int("", "repeats", repeats, 1)
    check_int("", "target_spp", target_spp, 1, MAX_SPP)
    check_int("", "seed", seed, 0)
    settings = dict(settings or {})
    taken = [k for k in settings if k in CONFIG_FIELDS or k in STUDY_FIELDS]
    if taken:
        raise ParameterError(f"fit setting {taken[0]!r} is set by each configuration or by the study, not by shared settings")
    shared = {"steps": steps, "spp": spp, "spp_final": spp_final, **settings}
    per_config = {c.label: {**shared, **fit_settings(c), "loss": loss} for c in configs}
    for label, s in per_config.items():  # every fit's settings valid before any work
        try:
            FitSettings(**s)
        except TypeError as e:
            raise ParameterError(f"unknown fit setting in {sorted(settings)}: {e}") from None
        except ParameterError as e:
            raise ParameterError(f"configuration {label!r}: {e}") from None
    start = scene.with_params(detach=True)
    move_to(start, names, at)
    truth = {n: scene.params[n].detach().clone() for n in names}
    target_image, target_label = study_target(scene, target, target_spp, seed * 1_000_003 + 999_999, configs[0])

    runs = []
    bar = tqdm(total=repeats * len(configs), unit="fit", desc=f"fits {scene.name}", file=sys.stderr, disable=not progress, dynamic_ncols=True)
    with bar:
        for r in range(repeats):
            for c in configs:
                bar.set_postfix_str(f"{c.label} #{r}", refresh=True)
                cpu = time.process_time()
                result = fit(start, target_image, names, truth=truth, progress=progress, seed=seed + r, **per_config[c.label])
                cpu = time.process_time() - cpu
                history = result.history
                runs.append(FitRun(
                    config=c.label, repeat=r, settings=per_config[c.label],
                    seconds=torch.tensor([h["seconds"] for h in history], dtype=torch.float64),
                    errors=torch.tensor([[h["errors"][n] for n in names] for h in history], dtype=torch.float64),
                    loss=torch.tensor([h["loss"] for h in history], dtype=torch.float64),
                    spp=torch.tensor([h["spp"] for h in history]),
                    cpu_seconds=cpu, recovered={n: v.tolist() for n, v in result.params.items()},
                ))  # fmt: skip
                bar.update(1)
    return FitStudy(
        scene=scene.name, resolution=tuple(scene.resolution), params=tuple(names), loss=loss, configs=tuple(configs), settings=shared,
        truth={n: v.tolist() for n, v in truth.items()}, start={n: start.params[n].tolist() for n in names}, target=target_label,
        runs=tuple(runs), repeats=repeats, seed=seed,
    )  # fmt: skip


def _percent(t: float) -> str:
    return f"{100 * t:g}pct"


def fit_rows(study: FitStudy) -> list[dict]:
    """One row per fit and step: configuration, repeat, step, spp, wall seconds, loss, the largest
    error and each parameter's."""
    rows = []
    for run in study.runs:
        for k in range(len(run.seconds)):
            row = {"config": run.config, "repeat": run.repeat, "step": k + 1, "spp": int(run.spp[k]), "seconds": float(run.seconds[k]),
                   "loss": float(run.loss[k]), "error": float(run.error[k])}  # fmt: skip
            row.update({f"error {n}": float(run.errors[k, i]) for i, n in enumerate(study.params)})
            rows.append(row)
    return rows


def fit_summary_text(study: FitStudy) -> str:
    """A plain-text table: per configuration the medians of :meth:`FitStudy.summary`."""
    lines = [
        (
            f"{study.scene}: {study.resolution[0]}x{study.resolution[1]}, fits of {', '.join(study.params)} from {_start_text(study)}, loss {study.loss}, "
            f"{study.settings['steps']} steps at {study.settings['spp']}/{study.settings['spp_final']} spp, {study.repeats} repeat(s); target {study.target}"
        ),
        "largest relative error over every channel; medians over repeats; 'reached': first step at or below, 'settled': below from then on",
    ]
    head = f"{'configuration':<48} {'s/step':>7} " + " ".join(f"{'to ' + format(100 * t, 'g') + '% ' + kind:>18}" for t in THRESHOLDS for kind in ("reached", "settled")) + f" {'final':>8}"
    lines.append(head)
    for c in study.configs:
        s = study.summary(c)
        cells = []
        for t in THRESHOLDS:
            for kind in ("reached", "settled"):
                seconds, step = s[f"seconds_to_{_percent(t)}_{kind}"], s[f"steps_to_{_percent(t)}_{kind}"]
                cells.append(f"{'never' if math.isinf(seconds) else f'{seconds:.1f} s (step {step:g})':>18}")
        lines.append(f"{c.label:<48} {s['seconds_per_step']:>7.3f} " + " ".join(cells) + f" {100 * s['final_error']:>7.2f}%")
    return "\n".join(lines)


def _start_text(study: FitStudy) -> str:
    return "; ".join(f"{n} = {[round(v, 4) for v in vals] if isinstance(vals, list) else vals}" for n, vals in study.start.items())


def fit_study_dict(study: FitStudy) -> dict:
    """The fit study as plain data: settings, per-configuration summaries and every fit's history."""
    return {
        "scene": study.scene, "resolution": list(study.resolution), "params": list(study.params), "loss": study.loss,
        "configs": [c.label for c in study.configs], "settings": study.settings, "truth": study.truth, "start": study.start,
        "target": study.target, "repeats": study.repeats, "seed": study.seed,
        "fit_settings": {run.config: run.settings for run in study.runs},
        "summaries": [finite(study.summary(c)) for c in study.configs],
        "runs": [{"config": r.config, "repeat": r.repeat, "cpu_seconds": r.cpu_seconds, "recovered": r.recovered,
                  "seconds": r.seconds.tolist(), "error": r.error.tolist()} for r in study.runs],
    }  # fmt: skip


def finite(d: dict) -> dict:
    """JSON has no infinity: ``None`` for never."""
    return {k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in d.items()}
