"""The built-in check of a gradient study: measured bias and variance in the furnace against the
closed forms (:mod:`invrender.study.closed_forms`, docs/closed_forms.md#gradient-statistics-in-the-furnace).

The study runs on the built-in ``furnace`` (grey rho, eps) with the exact radiance ``eps / (1 - rho)``
as the target and the gradient taken at the scene's own values, against exact references. Where the
closed forms hold (``random_walk`` with any ``max_depth`` and ``rr_depth``, cosine hemisphere
samples and independent paths; losses ``l2`` and ``relative_l2``) every row has a predicted mean and
variance; otherwise (``path``, or other sampling choices) only the true gradient is known (the
expected image is the same truncated series), so a decorrelated row has a predicted mean and a
correlated one is measured only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from invrender.errors import ParameterError
from invrender.scene import load_scene
from invrender.study.closed_forms import CLOSED_FORM_LOSSES, FurnaceWalk, analog_eps_bias, furnace_radiance, furnace_walk, predict_gradient
from invrender.study.configs import GradientConfig, parse_configs
from invrender.study.gradients import GradientStudy, gradient_study

#: the configurations of the check: the analog walk (where the textbook bias form holds) both
#: ways, the random walk at its defaults, and the path tracer at its defaults (measured only)
FURNACE_CONFIGS = (
    "random_walk/replay/correlated/max_depth=-1/rr_depth=1",
    "random_walk/replay/decorrelated/max_depth=-1/rr_depth=1",
    "random_walk/replay/correlated",
    "path/replay/correlated",
)
FURNACE_SPP = (1, 4, 16)
#: the furnace's parameters: its emitter and its wall
FURNACE_PARAMS = ("glow.emission", "wall.reflectance")
KIND = {"glow.emission": "emission", "wall.reflectance": "reflectance"}
#: options under which a random_walk configuration keeps the closed forms: independent paths with
#: cosine-sampled weights exactly rho (antithetic pairs are not independent, uniform hemisphere
#: samples weigh 2 rho cos)
CLOSED_FORM_OPTIONS = {"max_depth": None, "rr_depth": None, "backend": None, "chunk_paths": None, "memory_mb": None,
                       "sampler": ("stratified", "independent"), "hemisphere": ("cosine",)}  # fmt: skip


def has_closed_form(config: GradientConfig) -> bool:
    """Do the closed forms give this configuration's mean and variance (not only its true gradient)?"""
    if config.integrator != "random_walk":
        return False
    for key, value in config.options:
        if key not in CLOSED_FORM_OPTIONS or (CLOSED_FORM_OPTIONS[key] is not None and value not in CLOSED_FORM_OPTIONS[key]):
            return False
    return True


@dataclass(frozen=True)
class CheckRow:
    """One configuration, spp and parameter (the sum of its three identical channels).

    Attributes:
        config: configuration label.
        spp: N.
        parameter: ``"glow.emission"`` or ``"wall.reflectance"``.
        truth: the exact gradient of the loss at the expected image.
        mean, mean_se: the measured mean gradient and its standard error.
        variance, variance_se: the measured variance and its standard error.
        predicted_mean, predicted_variance: the closed forms, None where there is none.
    """

    config: str
    spp: int
    parameter: str
    truth: float
    mean: float
    mean_se: float
    variance: float
    variance_se: float
    predicted_mean: float | None
    predicted_variance: float | None

    @property
    def bias(self) -> float:
        return self.mean - self.truth

    @property
    def mean_z(self) -> float | None:
        """(measured - predicted mean) in standard errors."""
        return None if self.predicted_mean is None else (self.mean - self.predicted_mean) / self.mean_se if self.mean_se > 0 else math.inf

    @property
    def variance_z(self) -> float | None:
        """(measured - predicted variance) in standard errors of the measured variance."""
        return None if self.predicted_variance is None else (self.variance - self.predicted_variance) / self.variance_se if self.variance_se > 0 else math.inf


@dataclass(frozen=True)
class FurnaceCheck:
    """The result of :func:`furnace_check`: the study and one :class:`CheckRow` per configuration,
    spp and parameter."""

    study: GradientStudy
    rows: tuple[CheckRow, ...]
    rho: float
    eps: float

    def worst_z(self) -> float:
        """The largest |z| of any predicted mean or variance."""
        zs = [abs(z) for r in self.rows for z in (r.mean_z, r.variance_z) if z is not None]
        return max(zs, default=0.0)

    def table(self) -> str:
        """A Markdown table of the rows and the settings under which the closed forms hold."""
        head = (
            f"Furnace check: rho = {self.rho:g}, eps = {self.eps:g}, {self.study.resolution[0]}x{self.study.resolution[1]} pixels, "
            f"{self.study.trials} trials, loss {self.study.loss}, target eps/(1-rho) = {furnace_radiance(self.rho, self.eps):g}, "
            "gradients summed over the three channels.\n"
            "Closed forms hold for random_walk (any max_depth, rr_depth; cosine hemisphere samples, independent paths); "
            "elsewhere (path, other sampling) only the true gradient is known.\n"
            f"Textbook form 2 eps rho/((1-rho)^2 N) (analog walk: random_walk, max_depth -1, rr_depth 1): "
            + ", ".join(f"N={n}: {analog_eps_bias(self.rho, self.eps, n):.4g}" for n in self.study.spp) + "\n\n"
        )
        lines = ["| configuration | spp | parameter | bias (measured) | bias (closed form) | z | variance (measured) | variance (closed form) | z |", "|---|---|---|---|---|---|---|---|---|"]
        for r in self.rows:
            pb = "-" if r.predicted_mean is None else f"{r.predicted_mean - r.truth:.4g}"
            pv = "-" if r.predicted_variance is None else f"{r.predicted_variance:.4g}"
            zm = "-" if r.mean_z is None else f"{r.mean_z:+.2f}"
            zv = "-" if r.variance_z is None else f"{r.variance_z:+.2f}"
            lines.append(f"| {r.config} | {r.spp} | {r.parameter} | {r.bias:.4g} ± {r.mean_se:.2g} | {pb} | {zm} | {r.variance:.4g} ± {r.variance_se:.2g} | {pv} | {zv} |")
        return head + "\n".join(lines) + "\n"

    def predictions(self) -> dict:
        """The closed forms for :func:`invrender.study.plots.plot_study`:
        ``{"variance": {(config, parameter): {spp: value}}, "bias": {...}}``."""
        out: dict = {"variance": {}, "bias": {}}
        for r in self.rows:
            if r.predicted_variance is not None:
                out["variance"].setdefault((r.config, r.parameter), {})[r.spp] = r.predicted_variance
            if r.predicted_mean is not None:
                out["bias"].setdefault((r.config, r.parameter), {})[r.spp] = r.predicted_mean - r.truth
        return out

    def to_dict(self) -> dict:
        return {
            "rho": self.rho, "eps": self.eps, "worst_z": self.worst_z(),
            "rows": [{**r.__dict__, "bias": r.bias, "mean_z": r.mean_z, "variance_z": r.variance_z} for r in self.rows],
        }  # fmt: skip


def furnace_check(
    configs=FURNACE_CONFIGS,
    spp=FURNACE_SPP,
    trials: int = 200,
    *,
    rho: float = 0.5,
    eps: float = 1.0,
    resolution=(16, 16),
    loss: str = "l2",
    params=FURNACE_PARAMS,
    seed: int = 0,
    workers: int | None = None,
    progress: bool = True,
) -> FurnaceCheck:
    """Run a gradient study in the furnace and compare it with the closed forms.

    Args:
        configs: configurations (spec strings or :class:`GradientConfig`); integrators
            ``random_walk`` (closed forms) or ``path`` (true gradient only).
        spp, trials: as :func:`invrender.study.gradient_study`.
        rho, eps: the furnace's grey albedo (0 < rho < 1) and emission.
        resolution: (width, height).
        loss: ``"l2"`` or ``"relative_l2"``.
        params: any of ``glow.emission``, ``wall.reflectance``.
        workers: trials drawn at once (as :func:`invrender.study.gradient_study` takes it).
    """
    if loss not in CLOSED_FORM_LOSSES:
        raise ParameterError(f"the furnace check needs a loss with a closed form ({', '.join(CLOSED_FORM_LOSSES)}), got {loss!r}")
    configs = parse_configs(configs)
    for c in configs:
        if c.integrator not in ("random_walk", "path"):
            raise ParameterError(f"the furnace check knows the exact gradients of random_walk and path, not of {c.integrator!r} ({c.label})")
    names = [params] if isinstance(params, str) else list(params)
    unknown = [n for n in names if n not in KIND]
    if unknown:
        raise ParameterError(f"the furnace check covers {', '.join(FURNACE_PARAMS)}, not {unknown[0]!r}")
    scene = load_scene("furnace", resolution=resolution, rho=rho, eps=eps)
    target = torch.full((scene.height, scene.width, 3), furnace_radiance(rho, eps))
    pixels = scene.width * scene.height

    def walk(config: GradientConfig) -> FurnaceWalk:
        settings = config.integrator_and_settings(1, 0)[0].settings
        # every configuration's expected image is the analog walk's series at its depth, whatever its sampling
        return furnace_walk(rho, eps, settings.max_depth, getattr(settings, "rr_depth", 5))

    def truth(config: GradientConfig) -> torch.Tensor:
        w = walk(config)
        return torch.cat([torch.full((3,), predict_gradient(w, KIND[n], 1, pixels, target[0, 0, 0].item(), loss, False).truth) for n in names])

    study = gradient_study(scene, names, configs, spp, trials, loss=loss, target=target, at=1.0, reference=truth, pixel_maps=False, seed=seed, workers=workers, progress=progress)
    rows = []
    for c in configs:
        w = walk(c)
        for n in study.spp:
            summary = study.summary(c, n, "parameter")
            for k, name in enumerate(study.params):
                exact = predict_gradient(w, KIND[name], n, pixels, target[0, 0, 0].item(), loss, c.gradient == "correlated").scaled(3)
                closed = has_closed_form(c)
                rows.append(CheckRow(
                    c.label, n, name, exact.truth,
                    float(summary.moments.mean[k]), float(summary.moments.std_error[k]),
                    float(summary.moments.variance[k]), float(summary.moments.variance_se[k]),
                    exact.mean if closed or c.gradient == "decorrelated" else None, exact.variance if closed else None,
                ))  # fmt: skip
    return FurnaceCheck(study, tuple(rows), rho, eps)
