"""fit(): recover emission eps and reflectance rho from target images.

The solver (``solver="auto"``, the default) is chosen from what the parameters are
(solver_choice.py): the transport-matrix solve for an environment map alone (map_fit.py),
Levenberg-Marquardt on path records (least_squares.py) or on re-traced renders (retraced.py), or
Adam; the result says which and why (:attr:`FitResult.solver_reason`) and whether it converged
(:attr:`FitResult.converged`; a fit that did not warns, :class:`~invrender.inverse.convergence.ConvergenceWarning`).

With Adam each step renders every view, back-propagates the loss through the Monte Carlo estimate (estimator
``auto`` by default: autodiff where the recorded render fits in memory, else path replay,
``diff.resolve_estimator``; decorrelated by default: see losses.py) and takes an Adam step on reparametrized
values: rho = sigmoid(x), eps = exp(x) (params.py). Every random number is a
pure function of (seed, step, view), so a fit is deterministic, and a fit resumed from a checkpoint
ends exactly where the uninterrupted one does.

Targets may be photographs (targets.py: a camera response, masks, clipped pixels excluded) and
the model image of view v is ``exposure_v * white_balance_v * I_v`` (sensor.py), the sensor's
parameters fitted when named (``sensor.exposure``, ``sensor.white_balance``); docs/photographs.md.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import torch
from tqdm.auto import tqdm

from invrender.estimators import ESTIMATOR_CHOICES, backpropagate, render
from invrender.estimators.defaults import fit_settings
from invrender.estimators.finite import check_params, nonfinite_params
from invrender.errors import NonFiniteError, ParameterError, did_you_mean
from invrender.inverse import params as P
from invrender.inverse.control_variates import RecursiveControlVariate
from invrender.inverse.convergence import ConvergenceWarning, adam_losses, check_adam, check_least_squares, plateau
from invrender.inverse.solver_choice import SOLVERS, choose_solver
from invrender.inverse.rounds_bar import RoundsBar
from invrender.inverse.losses import LOSSES, loss_and_gradient, loss_gradient
from invrender.inverse.map_fit import fit_map
from invrender.inverse.sensor import NAMES as SENSOR_NAMES, Sensor, is_sensor
from invrender.inverse.targets import Target, load_targets, load_views, make_targets  # noqa: F401  (load_views: fit's targets, as lighting and studies load them)
from invrender.io.atomic import atomic_file
from invrender.scene.camera import Camera
from invrender.scene.kinds import kind_of
from invrender.scene.scene import Scene, check_names, unknown_parameter
from invrender.core.driver import RenderSettings
from invrender.registry import INTEGRATORS, integrator_spec
from invrender.plugins.integrators import Integrator, make_integrator
from invrender.core.ranks import is_main
from invrender.validate import MAX_SPP, check_float, check_int

CHECKPOINT_FORMAT = 1
#: least-squares rounds end when no parameter channel moved by more than this many standard errors
#: of the difference between two rounds' estimates (not significantly, for 12 channels at ~95%)
CONVERGED_MOVE = 2.5
#: least-squares rounds before the rounds may end (the first rounds' standard errors are too wide
#: for a move to be significant)
MIN_ROUNDS = 3
#: Neumann terms a fit's renders keep unless its integrator spec (or ``max_depth``) says otherwise
FIT_MAX_DEPTH = 8
#: most steps (or rounds, or steps between checkpoints) a fit may be asked for
MAX_STEPS = 10**7


@dataclass(frozen=True)
class FitSettings:
    """How to fit.

    Attributes:
        steps: Adam's steps, at most (it stops earlier on a plateau of the loss: ``plateau_window``).
        lr: Adam step size for [0, 1] parameters (reflectance, specular reflectance), in logit
            units (about a relative step for dark channels: 0.05 = 5% per step).
        lr_emission: Adam step size for emissions, in log(eps) units (0.05 = 5% per step).
        lr_sensor: Adam step size for the sensor's exposure and white balance, in log units
            (sensor.py).
        lr_normals: Adam step size for shading normals (``NAME.normals``, ``NAME.normalmap``),
            on the unnormalized normal, so about radians (0.05: about 3 degrees a step); the
            normals are normalized after each step.
        lr_final: the step sizes decay along a cosine to this fraction of themselves.
        beta2: Adam's second-moment decay. Shorter than the usual 0.999 so that the step size does
            not stay scaled down by the large gradients of the first steps (a fit is a few hundred
            steps, not tens of thousands).
        spp: samples per pixel of each render in the first half of the steps.
        spp_final: samples per pixel in the second half (less noise where the steps are small);
            the transport-matrix solve traces each of its two halves at this count.
        max_depth: a shortcut for the integrator spec's ``max_depth`` (Neumann terms kept by the
            renders, Mitsuba's count); None = the spec's, else :data:`FIT_MAX_DEPTH` (8) for an
            integrator with a depth. Giving both, different, is an error.
        integrator: the model fitted, as an integrator spec (:mod:`invrender.registry`): a name
            (``"path"``, ``"random_walk"``, ``"utah"``, ``"whitted"``, ``"distributed"`` or
            ``"radiosity"``: Adam only, not a polynomial, see records.py), a mapping with its
            settings (``{"type": "path", "rr_depth": 3, "strategy": "emitter"}``) or an integrator
            object (kept as its mapping, so settings stay plain data in checkpoints and reports).
            :attr:`model` is the integrator every render of the fit uses.
        loss: ``"l2"``, ``"l1"``, ``"relative_l2"`` or ``"ssim"``.
        estimator: ``"auto"`` (default: ``"autodiff"`` where the recorded render fits in the
            memory budget, 512 MiB, about 128 bytes a path and term; else ``"replay"``; the same
            gradient either way, to float rounding), ``"replay"`` or ``"autodiff"``.
        decorrelate: take ``dl/dI`` from an independent render (unbiased gradient; losses.py).
        seed: seed of every render's random numbers.
        checkpoint_every: steps between checkpoints (when a checkpoint path is given).
        solver: ``"auto"`` (the default: chosen from what the parameters are and the settings
            given, solver_choice.py: ``"transport_matrix"`` for one environment map alone,
            ``"joint"`` for one environment map with material reflectances, ``"lm"``
            for parameters that are polynomial factors of the path weights or a roughness, else
            ``"adam"``; the result says which and why), ``"adam"`` (gradient steps on re-traced
            renders), ``"lm"`` (Levenberg-Marquardt) or ``"gauss_newton"`` on path records
            (least_squares.py), or, when a fitted parameter is one records cannot represent (a
            roughness), on re-traced renders with forward-mode Jacobian columns (retraced.py), or
            ``"transport_matrix"`` (one environment map's texels: one non-negative regularized
            linear solve, map_fit.py), or ``"joint"`` (one environment map's texels and material
            reflectances: the map's solve alternated with lm on records, joint_fit.py).
        rounds: least-squares solvers: at most this many outer rounds; on path records round r
            traces two independent passes (A and B) at the current estimate and adds them to the
            earlier rounds' (so it solves on ``spp * 4^r`` samples a pixel per set, three quarters
            of them new); on re-traced renders it renders afresh at ``spp * 4^r``; the
            rounds end early, after at least three, once no parameter channel moved significantly
            (by more than 2.5 standard errors of the difference of two rounds' estimates: of
            nested estimates on records, the round's squared standard error times 3) and,
            when ``precision`` is set, every channel's standard error is below ``precision``
            times its value.
        precision: least-squares solvers: a relative standard error the rounds must reach
            before they stop (None: no such requirement).
        prior_weight: least-squares solvers: the weight lambda of the Tikhonov prior on
            environment maps (textured emissions), residual rows ``sqrt(lambda) (v - p) / p`` per
            texel channel toward the fit's starting value p, so that texels the targets cannot see
            stay at p instead of noise (least_squares.py, ``Prior``). None (default): by the rule
            lambda = 1e-3 times the mean diagonal of the images' ``J^T J`` over the map's channels
            in relative units (each column times its value), at each round's start; 0: no prior.
        smoothness: least-squares solvers: the weight mu of the smoothness prior on environment
            maps, residual rows ``sqrt(mu) (v_i - v_j) / sqrt(p_i p_j)`` per pair of neighbouring
            texels (``Prior``), so that texels the targets see poorly take their neighbours'
            values instead of noise or the start (for maps that vary smoothly, as skies do; it
            biases a map of independent texels). None: by the rule mu = 1e-2 times the same mean
            diagonal; 0 (default): none.
        sampler: how each render's or record's pixel samples are drawn: ``"stratified"``,
            ``"independent"`` or ``"antithetic"`` (mirrored pairs; see ``invrender.render``).
        control_variate: Adam with ``decorrelate``: take ``dl/dI`` at the recursive control-variate
            estimate of each view's image (control_variates.py: one more render per view and step,
            at the previous parameters with the same numbers) instead of at a plain render.
        plateau_window: Adam: steps in each of the two windows the plateau rule compares (the mean
            loss at ``spp_final`` of the last window against the one before: the fit stops once it
            fell by less than twice its noise, measured from the loss's step-to-step fluctuation,
            or 0.1%; convergence.py); when the steps run out first it warns. 0: no rule, no warning.
    """

    steps: int = 200
    lr: float = 0.15
    lr_emission: float = 0.15
    lr_sensor: float = 0.05
    lr_normals: float = 0.05
    lr_final: float = 0.05
    beta2: float = 0.95
    spp: int = 16
    spp_final: int = 64
    max_depth: int | None = None
    integrator: str | dict = "path"
    loss: str = "relative_l2"
    estimator: str = "auto"
    decorrelate: bool = True
    seed: int = 0
    checkpoint_every: int = 20
    solver: str = "auto"
    rounds: int = 5
    precision: float | None = None
    prior_weight: float | None = None
    smoothness: float | None = 0.0
    sampler: str = "stratified"
    control_variate: bool = False
    plateau_window: int = 20

    def __post_init__(self):
        check_int("fit setting ", "plateau_window", self.plateau_window, 0, MAX_STEPS)
        for name in ("steps", "spp", "spp_final", "seed", "checkpoint_every", "rounds") + (("max_depth",) if self.max_depth is not None else ()):
            check_int("fit setting ", name, getattr(self, name))
        if self.steps <= 0 or self.spp <= 0 or self.spp_final <= 0 or self.checkpoint_every <= 0 or self.rounds <= 0:
            raise ParameterError("fit settings steps, spp, spp_final, checkpoint_every and rounds must be positive")
        for name in ("steps", "checkpoint_every", "rounds"):
            check_int("fit setting ", name, getattr(self, name), 1, MAX_STEPS)
        for name in ("spp", "spp_final"):
            check_int("fit setting ", name, getattr(self, name), 1, MAX_SPP)
        if isinstance(self.integrator, Integrator):  # plain data from here on
            object.__setattr__(self, "integrator", {"type": self.integrator.name, **dataclasses.asdict(self.integrator.settings)})
        elif not isinstance(self.integrator, str):
            name, options = integrator_spec(self.integrator, "fit setting integrator")
            object.__setattr__(self, "integrator", {"type": name, **options})
        model = self.model  # validates the spec and max_depth together
        if self.control_variate and not (self.decorrelate and self.solver in ("adam", "auto")):
            raise ParameterError("control_variate needs solver 'adam' with decorrelate (it replaces the render dl/dI is taken at)")
        if self.solver not in SOLVERS:
            raise ParameterError(f"unknown solver {self.solver!r}{did_you_mean(self.solver, SOLVERS)} (known: {', '.join(SOLVERS)})")
        if self.solver not in ("adam", "auto") and (model.terms_kept < 1 or self.loss != "relative_l2"):
            raise ParameterError(f"solver {self.solver!r} needs a finite max_depth >= 1 and the relative_l2 loss (got max_depth {model.terms_kept}, loss {self.loss!r})")
        for name in ("lr", "lr_emission", "lr_sensor", "lr_normals", "lr_final", "precision"):
            if name == "precision" and self.precision is None:
                continue
            check_float("fit setting ", name, getattr(self, name), positive=True)
        check_float("fit setting ", "beta2", self.beta2, 0.0, 1.0)
        for name in ("prior_weight", "smoothness"):
            if getattr(self, name) is not None:
                check_float("fit setting ", name, getattr(self, name), 0.0, math.inf)
        RenderSettings(sampler=self.sampler)  # validates the sampler
        if self.loss not in LOSSES:
            raise ParameterError(f"unknown loss {self.loss!r}{did_you_mean(self.loss, LOSSES)} (known: {', '.join(LOSSES)})")
        if self.estimator not in ESTIMATOR_CHOICES:
            raise ParameterError(f"unknown estimator {self.estimator!r}{did_you_mean(self.estimator, ESTIMATOR_CHOICES)} (known: {', '.join(ESTIMATOR_CHOICES)})")

    @property
    def model(self) -> Integrator:
        """The integrator of every render: :attr:`integrator` with :attr:`max_depth` (or the fit's
        default depth, :data:`FIT_MAX_DEPTH`) where the spec gives none."""
        name, options = integrator_spec(self.integrator, "fit setting integrator")
        has_depth = "max_depth" in {f.name for f in dataclasses.fields(INTEGRATORS[name].Settings)}
        if self.max_depth is not None:
            if options.get("max_depth", self.max_depth) != self.max_depth:
                raise ParameterError(f"fit settings max_depth {self.max_depth} and the integrator's max_depth {options['max_depth']} differ: give one of them")
            options["max_depth"] = self.max_depth
        elif has_depth:
            options.setdefault("max_depth", FIT_MAX_DEPTH)
        return make_integrator({"type": name, **options})

    def spp_at(self, step: int) -> int:
        return self.spp if step < self.steps // 2 else self.spp_final

    def lr_factor(self, step: int) -> float:
        """Cosine decay from 1 to ``lr_final``."""
        return self.lr_final + (1 - self.lr_final) * 0.5 * (1 + math.cos(math.pi * step / self.steps))


@dataclass
class FitResult:
    """What a fit recovered.

    Attributes:
        params: name -> recovered value (detached tensors).
        history: one dict per step: ``step``, ``loss``, ``spp``, ``seconds`` (since the start),
            ``params`` (name -> list), and ``errors`` (name -> largest relative error) when the
            ground truth is known; a least-squares round on path records also ``timing``: its
            seconds in ``records`` (tracing the round's passes) and in the solve's phases
            (:attr:`~invrender.inverse.least_squares.LeastSquaresSolution.seconds`).
        scene: the input scene with the recovered values in its params.
        settings: the settings used.
        initial: name -> starting value.
        truth: name -> ground truth, when given.
        std_error: name -> standard error of each recovered channel (least-squares solvers).
        resolution: name -> how much of each recovered channel the images set, ``diag(M^-1 H)``
            (the transport matrix: 1 set by the images, 0 by the prior; map_fit.py).
        targets: per view what the fit used of its target (targets.py): response, pixels
            excluded as saturated or dark, pixels counting.
        pixels: per view, the (H, W, 3) image of which pixels counted
            (:meth:`~invrender.inverse.targets.Target.pixels_image`), where a mask or the automatic
            exclusion left any out; None for a view where every pixel counted.
        solver: the solver that ran (``"adam"``, ``"lm"``, ``"gauss_newton"``,
            ``"transport_matrix"``; ``settings.solver`` too).
        solver_reason: why, in one line (solver_choice.py).
        converged: whether the fit reached its stopping rule (Adam: a plateau of the loss; the
            least-squares rounds: no significant move, and ``precision``; the transport matrix: a
            direct solve, always) rather than its cap of steps or rounds; None where Adam's rule
            was switched off (``plateau_window=0``). A fit that did not converge warns.
    """

    params: dict[str, torch.Tensor]
    history: list[dict]
    scene: Scene
    settings: FitSettings
    initial: dict[str, torch.Tensor]
    truth: dict[str, torch.Tensor] = field(default_factory=dict)
    std_error: dict[str, torch.Tensor] = field(default_factory=dict)
    targets: list[dict] = field(default_factory=list)
    pixels: list = field(default_factory=list)
    solver: str = ""
    solver_reason: str = ""
    converged: bool | None = None
    resolution: dict[str, torch.Tensor] = field(default_factory=dict)

    @property
    def errors(self) -> dict[str, float]:
        """name -> largest relative error against the ground truth (empty without one)."""
        return {k: P.relative_error(self.params[k], v) for k, v in self.truth.items() if k in self.params}


def fit(
    scene: Scene,
    target,
    params,
    *,
    cameras: list[Camera] | None = None,
    truth: dict | None = None,
    checkpoint=None,
    resume: bool = False,
    progress: bool = True,
    mask=None,
    response=None,
    sensor: dict | None = None,
    exclude_clipped: bool = True,
    **settings,
) -> FitResult:
    """Recover ``params`` of ``scene`` from target image(s).

    Args:
        scene: the known geometry, with starting values in ``scene.params`` (left unchanged).
        target: an (H, W, 3) tensor or image path (PNG 8/16-bit, JPEG, EXR, HDR), or a list of
            them (one per view); the size of the scene's renders (targets.py).
        params: names to fit (list or comma-separated string), e.g. ``["red.reflectance", "light.emission"]``;
            ``"sensor.exposure"`` and ``"sensor.white_balance"`` fit the camera's (sensor.py).
        cameras: one camera per target for several views (default: the scene's camera).
        truth: name -> ground-truth value, to record errors in the history.
        checkpoint: path of a checkpoint file written every ``checkpoint_every`` steps, on Ctrl-C
            and at the end.
        resume: continue from ``checkpoint`` (which must come from the same scene and parameters),
            with the settings stored in it except those given anew in ``settings`` (e.g. more
            ``steps``); with the stored settings unchanged, it ends exactly where the
            uninterrupted fit does.
        progress: show a progress bar with step, loss and ETA.
        mask: pixel weights in [0, 1]: an image path or an (H, W) tensor, or a list with one per
            view (None: the target's alpha channel, if any); masked pixels count for nothing.
        response: the targets' camera response (``"linear"``, ``"srgb"``, ``"gamma:G"``, a CSV
            curve; one, or a list per view); None: each file's default (``srgb`` for 8/16-bit
            files, ``linear`` for float files and tensors).
        sensor: sensor options (sensor.py): ``exposure`` and ``white_balance`` starting (or, when
            not fitted, fixed) values, one or one per view; ``shared``: which of the two one value
            serves every view for.
        exclude_clipped: leave out an 8/16-bit target's saturated pixels and pixels at 0
            (counted per view in :attr:`FitResult.targets`).
        settings: any :class:`FitSettings` field, e.g. ``steps=300, loss="l1"`` or
            ``integrator={"type": "path", "rr_depth": 3, "strategy": "emitter"}``; all are checked
            (one-line :class:`ParameterError`) before any target is read or any render starts.
            The scene file's integrator and its settings are the default of ``integrator``
            (:func:`invrender.estimators.defaults.fit_settings`; not its sample count).
    """
    known = {f.name for f in dataclasses.fields(FitSettings)}
    unknown = set(settings) - known
    if unknown:
        raise ParameterError(f"unknown fit setting {sorted(unknown)[0]!r}{did_you_mean(sorted(unknown)[0], known)} (known: {', '.join(sorted(known))})")
    names = check_fit_names(scene, params)
    given = set(settings)  # the settings the call gave (the solver's choice reads them)
    check_params(scene.params)  # the starting values (and the fixed ones): a NaN would be every step's
    checkpoint = Path(checkpoint) if checkpoint is not None else None
    state = None
    if resume:
        if checkpoint is None or not checkpoint.is_file():
            raise ParameterError(f"cannot resume: no checkpoint at {checkpoint}")
        state = _read_checkpoint(checkpoint, scene, names)
        settings = {**{k: v for k, v in state["settings"].items() if k in known}, **settings}  # stored, unless given anew
    cfg = FitSettings(**(settings if state is not None else fit_settings(scene, settings)))  # the scene file's integrator unless given
    choice = choose_solver(scene, names, cfg, given)
    cfg = dataclasses.replace(cfg, solver=choice.solver)
    views = load_targets(scene, target, cameras, mask=mask, response=response, exclude_clipped=exclude_clipped)
    sensor = Sensor.make(len(views), names, sensor)
    truth = _checked_truth(scene, truth)
    if state is not None and ("raw" in state) != (cfg.solver == "adam"):
        raise ParameterError(f"checkpoint {checkpoint} was written by another solver than {cfg.solver!r}")
    if progress and is_main():
        print(f"fit: solver {choice.solver}: {choice.reason}", file=sys.stderr)
    if cfg.solver == "transport_matrix":
        return _chosen(_fit_transport_matrix(scene, views, names, cfg, truth, checkpoint, state, progress, sensor, cameras), choice)
    if cfg.solver == "joint":
        return _chosen(_fit_joint(scene, views, names, cfg, truth, checkpoint, state, progress, sensor, cameras), choice)
    if cfg.solver != "adam":
        return _chosen(_fit_least_squares(scene, views, names, cfg, truth, checkpoint, state, progress, sensor), choice)

    scene_names = [n for n in names if not is_sensor(n)]
    raw = {n: P.to_raw(n, scene.params[n]).requires_grad_(True) for n in scene_names}
    groups = [{"params": [raw[n]], "lr": getattr(cfg, kind_of(n).lr_setting)} for n in scene_names]
    if sensor.size:
        raw[SENSOR_RAW] = sensor.to_raw().float().requires_grad_(True)
        groups.append({"params": [raw[SENSOR_RAW]], "lr": cfg.lr_sensor})
    optimizer = torch.optim.Adam(groups, betas=(0.9, cfg.beta2))
    base_lr = [g["lr"] for g in optimizer.param_groups]
    initial = {n: v.detach().clone() for n, v in _values(raw, scene_names, sensor, names).items()}
    history: list[dict] = []
    start = 0
    if state is not None:
        start, history = _restore(state, list(raw), raw, optimizer)
    variates = [_control_variate(view_scene, cfg) if cfg.control_variate else None for view_scene, _ in views]
    for cv, cv_state in zip(variates, (state or {}).get("control_variates") or []):
        cv.load(cv_state)

    clock = time.perf_counter() - (history[-1]["seconds"] if history else 0.0)
    bar = tqdm(total=cfg.steps, initial=start, unit="step", disable=not progress or not is_main(), desc="fit", file=sys.stderr, dynamic_ncols=True)
    step = start
    try:
        with bar:
            for step in range(start, cfg.steps):
                reached = plateau(adam_losses(history, cfg.steps), cfg.plateau_window)
                if reached is not None and reached.reached:  # the loss's plateau (a resumed fit's too)
                    break
                for group, lr in zip(optimizer.param_groups, base_lr):
                    group["lr"] = lr * cfg.lr_factor(step)
                optimizer.zero_grad(set_to_none=True)
                try:
                    loss = float(
                        sum(
                            _view_loss(view_scene, {n: P.from_raw(n, raw[n]) for n in scene_names}, view_target, cfg, step, v, len(views), variates[v], _gain(raw, sensor, v))  # a fresh graph per view
                            for v, (view_scene, view_target) in enumerate(views)
                        )
                    )
                    what = _nonfinite_step(loss, {n: raw[n].grad for n in raw if raw[n].grad is not None}, names)
                except NonFiniteError as e:  # a render with non-finite pixels
                    what = str(e)
                if what is None:
                    if step == 0:
                        P.warn_unused({n: raw[n].grad for n in scene_names})
                    grad_norm = math.sqrt(sum(float(raw[n].grad.double().pow(2).sum()) for n in raw if raw[n].grad is not None))
                    before = copy.deepcopy((_leaves(raw), optimizer.state_dict())) if checkpoint is not None else None
                    optimizer.step()
                    for n in scene_names:
                        kind_of(n).renormalize_(raw[n])  # a normal back to unit length
                    values = _values(raw, scene_names, sensor, names)
                    bad = nonfinite_params(values) or nonfinite_params(raw)  # a value exp() overflowed, or a leaf
                    if bad:  # the update itself overflowed (a learning rate far too large): undo it
                        what = f"Adam's step made {_named(bad, names)} not finite (learning rate too large?)"
                        if before is not None:
                            _load_adam(*before, raw, optimizer)
                if what is not None:  # the state after the last step, which was good, is kept
                    if checkpoint is not None:
                        _save_checkpoint(checkpoint, scene, names, cfg, len(history), history, **_adam_state(raw, optimizer, variates))
                    raise _stopped(step, what, checkpoint, len(history))
                record = _record(step, loss, cfg.spp_at(step), time.perf_counter() - clock, values, truth)
                record["grad_norm"] = grad_norm  # of the unconstrained values, before the step
                history.append(record)
                bar.set_postfix(loss=f"{record['loss']:.4g}", refresh=False)
                bar.update(1)
                if checkpoint is not None and (step + 1) % cfg.checkpoint_every == 0:
                    _save_checkpoint(checkpoint, scene, names, cfg, step + 1, history, **_adam_state(raw, optimizer, variates))
    except KeyboardInterrupt:
        if checkpoint is not None:
            _save_checkpoint(checkpoint, scene, names, cfg, len(history), history, **_adam_state(raw, optimizer, variates))
        raise
    if checkpoint is not None:
        _save_checkpoint(checkpoint, scene, names, cfg, len(history), history, **_adam_state(raw, optimizer, variates))

    recovered = {n: v.detach().clone() for n, v in _values(raw, scene_names, sensor, names).items()}
    out_scene = scene.with_params({n: recovered[n] for n in scene_names}, detach=True)
    result = FitResult(recovered, history, out_scene, cfg, initial, {k: v for k, v in truth.items() if k in names}, targets=[t.report() for _, t in views], pixels=_pixels(views))
    result.converged = check_adam(history, cfg.steps, cfg.plateau_window, adam_only=any(kind_of(n).adam_only for n in scene_names))
    return _chosen(result, choice)


def _chosen(result: FitResult, choice) -> FitResult:
    """``result`` with the solver's choice (:func:`~invrender.inverse.solver_choice.choose_solver`) in it."""
    result.solver, result.solver_reason = choice.solver, choice.reason
    return result


def _fit_joint(scene: Scene, views, names, cfg: FitSettings, truth, checkpoint: Path | None, state: dict | None, progress: bool, sensor: Sensor, cameras) -> FitResult:
    """One environment map's texels and material reflectances by the alternation of
    :func:`invrender.inverse.joint_fit.fit_joint` (``spp_final`` samples a pixel per half and
    record set): one history entry per round, the last with the scale's anchor. The targets are
    passed linear, divided by a fixed sensor's gains, with their masks."""
    from invrender.inverse.joint_fit import fit_joint, joint_names

    map_name, materials = joint_names(scene, names)
    initial = {n: scene.params[n].detach().clone() for n in names}
    if state is not None:  # a resumed fit that had solved: its result stands
        history, values = list(state["history"]), {n: v.float() for n, v in state["values"].items()}
    else:
        targets, masks = _linear_targets(views, sensor)
        found = fit_joint(
            scene, targets, map_name.rpartition(".")[0], materials, cameras=cameras, integrator=_integrator_spec(cfg.model, without_depth=True),
            spp=cfg.spp_final, max_depth=cfg.model.terms_kept, seed=cfg.seed, mask=masks, progress=progress,
        )  # fmt: skip
        values = {map_name: found.texels.float(), **found.values}
        std_error = {map_name: found.map.stderr, **found.std_error}
        history = []
        for entry in found.history:
            last = entry is found.history[-1]
            record = {"step": entry["round"], "loss": entry["loss"], "spp": cfg.spp_final, "seconds": entry["seconds"],
                      "params": {**({map_name: values[map_name].tolist()} if last else {}), **entry["values"]}, "moved_in_std_errors": entry["moved"], "on": "transport matrix + path records"}  # fmt: skip
            if last:
                record.update({"std_error": {n: v.tolist() for n, v in std_error.items()}, "transport_matrix": found.map.describe(), "scale": found.scale, "converged": found.converged})
                if truth:
                    record["errors"] = {n: P.relative_error(values[n], truth[n]) for n in names if n in truth}
            history.append(record)
        if checkpoint is not None:
            _save_checkpoint(checkpoint, scene, names, cfg, len(history), history, values=values)
    std_error = {n: torch.tensor(v, dtype=torch.float32) for n, v in history[-1]["std_error"].items()}
    out_scene = scene.with_params(values, detach=True)
    result = FitResult(values, history, out_scene, cfg, initial, {k: v for k, v in truth.items() if k in names}, std_error, [t.report() for _, t in views], _pixels(views))
    result.converged = bool(history[-1]["converged"])
    if not result.converged:
        warnings.warn(f"the joint fit did not converge in {len(history)} rounds: the last moved a reflectance by {history[-1]['moved_in_std_errors']:.2g} standard errors (converged below 1)", ConvergenceWarning, stacklevel=3)
    return result


def _linear_targets(views, sensor: Sensor) -> tuple[list[torch.Tensor], list[torch.Tensor] | None]:
    """The linear solves' targets: each view's linear image (H, W, 3) divided by a fixed sensor's
    gains (per view and channel), and the views' masks (H, W) (None where every pixel counts)."""
    gains = sensor.gains(sensor.to_raw()).float() if sensor.active else torch.ones(len(views), 3)
    targets = [t.linear / gains[v].to(t.linear.device) for v, (_, t) in enumerate(views)]
    masks = None if all(bool((t.mask == 1).all()) for _, t in views) else [t.mask for _, t in views]
    return targets, masks


def _integrator_spec(model: Integrator, without_depth: bool = False) -> dict:
    """The spec of the fit's integrator ``model`` (its name and settings), for the solvers that
    build their own renders; ``without_depth``: max_depth left out (given to them apart)."""
    settings = dataclasses.asdict(model.settings)
    if without_depth:
        settings.pop("max_depth", None)
    return {"type": model.name, **settings}


def _fit_transport_matrix(scene: Scene, views, names, cfg: FitSettings, truth, checkpoint: Path | None, state: dict | None, progress: bool, sensor: Sensor, cameras) -> FitResult:
    """One environment map's texels by one non-negative regularized linear solve on its transport
    matrix (:func:`invrender.inverse.map_fit.fit_map`, two halves of ``spp_final`` samples a
    pixel, the prior's weight by the discrepancy principle): one history entry. The targets are
    passed linear, divided by a fixed sensor's gains, with their masks (clipped pixels excluded)."""
    name = names[0]
    initial = {name: scene.params[name].detach().clone()}
    if state is not None:  # a resumed fit that had solved: its result stands
        history, values = list(state["history"]), {name: state["values"][name].float()}
    else:
        targets, masks = _linear_targets(views, sensor)
        clock = time.perf_counter()
        found = fit_map(
            scene, targets, name.rpartition(".")[0], cameras=cameras, integrator=_integrator_spec(cfg.model),
            spp=cfg.spp_final, max_depth=None, seed=cfg.seed, mask=masks, progress=progress,
        )  # fmt: skip
        values = {name: found.texels.float()}
        record = {
            "step": 1, "loss": float((found.residual.double() ** 2).mean()), "spp": cfg.spp_final, "seconds": time.perf_counter() - clock,
            "params": {name: values[name].tolist()}, "std_error": {name: found.stderr.tolist()}, "resolution": {name: found.resolution.tolist()}, "on": "transport matrix",
            "transport_matrix": found.describe(), "converged": True,
        }  # fmt: skip
        if truth and name in truth:
            record["errors"] = {name: P.relative_error(values[name], truth[name])}
        if bool(found.undetermined.any()):
            record["undetermined"] = f"{int(found.undetermined.sum())} of {found.undetermined.numel()} texels of {name} (resolution under 0.5: the prior holds them)"
        history = [record]
        if checkpoint is not None:
            _save_checkpoint(checkpoint, scene, names, cfg, 1, history, values=values)
    if history[-1].get("undetermined"):
        warnings.warn(f"the targets do not determine {history[-1]['undetermined']}", stacklevel=3)
    std_error = {name: torch.tensor(history[-1]["std_error"][name], dtype=torch.float32)}
    out_scene = scene.with_params(values, detach=True)
    result = FitResult(values, history, out_scene, cfg, initial, {k: v for k, v in truth.items() if k in names}, std_error, [t.report() for _, t in views], _pixels(views))
    result.converged = True
    if "resolution" in history[-1]:  # (checkpoints written before it was recorded have none)
        result.resolution = {name: torch.tensor(history[-1]["resolution"][name], dtype=torch.float32)}
    return result


#: the key of the sensor's free log variables among Adam's leaves (and in checkpoints)
SENSOR_RAW = "sensor"


def _named(bad: dict, names: list[str]) -> str:
    """The parameters of ``bad`` (Adam's leaf name -> count of non-finite entries) by their fitted
    names: the sensor's leaf stands for the sensor parameters fitted."""
    out = []
    for leaf, count in bad.items():
        label = ", ".join(repr(n) for n in names if is_sensor(n)) if leaf == SENSOR_RAW else repr(leaf)
        out.append(f"{label} ({count} value{'s' if count > 1 else ''})")
    return ("parameters " if len(out) > 1 else "parameter ") + ", ".join(out)


def _nonfinite_step(loss: float, grads: dict, names: list[str]) -> str | None:
    """What is not finite in a step before Adam's update (the loss, then the gradients by
    parameter), or None when both are."""
    if not math.isfinite(loss):
        return f"the loss is {loss}"
    bad = nonfinite_params(grads)
    return f"the gradient of {_named(bad, names)} is not finite" if bad else None


def _stopped(step: int, what: str, checkpoint: Path | None, saved: int | None, unit: str = "step") -> NonFiniteError:
    """The one-line error that stops a fit at step (or round: ``unit``) ``step`` (0-based) because
    ``what`` is not finite, saying which checkpoint holds the last good state (after ``saved``
    steps; None: none was written)."""
    if checkpoint is None:
        kept = " (no checkpoint: give one to keep the last good state)"
    elif saved is None:
        kept = f"; no {unit} had finished, so no checkpoint was written ({checkpoint} is left as it was)"
    else:
        state = f"after {unit} {saved}" if saved else "the starting values"
        kept = f"; the last good state ({state}) is kept in checkpoint {checkpoint}"
    return NonFiniteError(f"fit stopped at {unit} {step + 1}: {what}{kept}")


def check_fit_names(scene: Scene, params) -> list[str]:
    """``params`` checked against the scene's parameters and the sensor's (:func:`check_names`)."""
    return check_names({**scene.params, **{n: None for n in SENSOR_NAMES}}, params)


def _checked_truth(scene: Scene, truth) -> dict[str, torch.Tensor]:
    """``truth`` (name -> ground-truth value) as float32 tensors, each name a parameter of the
    scene or the sensor and each value finite and, for a scene parameter, of its shape (one number
    or an RGB triple broadcast over it): one-line ParameterErrors before any work, not at the
    end of the fit where the errors are computed."""
    out = {}
    known = [*scene.params, *SENSOR_NAMES]
    for name, value in dict(truth or {}).items():
        if name not in known:
            raise unknown_parameter(name, known, "truth of unknown parameter")
        try:
            t = torch.as_tensor(value, dtype=torch.float32).detach()
        except (TypeError, ValueError, RuntimeError):
            raise ParameterError(f"truth of {name}: expected numbers, got {value!r:.60}") from None
        if not bool(torch.isfinite(t).all()):
            raise ParameterError(f"truth of {name}: values must be finite")
        if not is_sensor(name):
            shape = tuple(scene.params[name].shape)
            try:
                fits = torch.broadcast_shapes(t.shape, shape) == shape
            except RuntimeError:
                fits = False
            if not fits:
                raise ParameterError(f"truth of {name}: a value of shape {tuple(t.shape)} does not fit the parameter's shape {shape}")
        out[name] = t
    return out


def _values(raw: dict, scene_names, sensor: Sensor, names) -> dict:
    """name -> current value of every fitted parameter (Adam's leaves through the kinds'
    reparametrizations; the sensor's from its log variables)."""
    out = {n: P.from_raw(n, raw[n]) for n in scene_names}
    if sensor.size:
        out.update({n: v for n, v in sensor.values(raw[SENSOR_RAW].double()).items() if n in names})
    return {n: out[n] for n in names}


def _gain(raw: dict, sensor: Sensor, view: int) -> torch.Tensor | None:
    """View ``view``'s (3,) gains, differentiable in the sensor's leaf (None: all 1, nothing free)."""
    if not sensor.active:
        return None
    s = raw[SENSOR_RAW] if sensor.size else torch.zeros(0)
    return sensor.gains(s.double())[view].float()


def _fit_least_squares(scene: Scene, views, names, cfg: FitSettings, truth, checkpoint: Path | None, state: dict | None, progress: bool, sensor: Sensor) -> FitResult:
    """Outer rounds of record-and-solve (least_squares.py), or of solves on re-traced renders
    (retraced.py) when a fitted parameter cannot be recorded: one history entry per round."""
    from invrender.inverse import retraced

    scene_names = [n for n in names if not is_sensor(n)]
    if not scene_names:
        raise ParameterError(f"solver {cfg.solver!r} needs a scene parameter among the fitted ones (got only {', '.join(names)}); use solver 'adam'")
    # the rule (retraced.py): any parameter path records cannot represent -> the whole fit on re-traced renders
    retrace = retraced.record_obstacle(scene, scene_names) is not None
    if retrace:
        retraced.check(scene, scene_names, sensor, f"solver {cfg.solver!r}")
    start_sensor = sensor.values(sensor.to_raw())
    initial = {n: (start_sensor[n] if is_sensor(n) else scene.params[n]).detach().clone() for n in names}
    # the prior of environment maps: the starting values
    prior = {n: initial[n].double().clamp(1e-4, None) for n in scene_names if kind_of(n).key == "emission" and initial[n].ndim == 3}
    ambiguities = sensor.ambiguities(names, scene.params)
    model = cfg.model
    current = {n: initial[n].double() if is_sensor(n) else scene.params[n].detach().double().clamp(1e-4, None) for n in names}
    record_point = dict(current)  # round 0's
    history: list[dict] = []
    if state is not None:
        current, history = {n: v.double() for n, v in state["values"].items()}, list(state["history"])
    clock = time.perf_counter() - (history[-1]["seconds"] if history else 0.0)
    std_error = {n: torch.tensor(v, dtype=torch.float64) for n, v in history[-1]["std_error"].items()} if history else {}
    with RoundsBar(cfg.rounds, len(history), cfg.solver, progress and is_main()) as bar:
        done = bool(history) and history[-1].get("converged", False)  # a resumed fit that had converged
        # on path records the rounds accumulate (least_squares.py: two independent accumulations,
        # A and B); a resumed fit re-records the earlier rounds' passes at their record points
        passes = _RecordPasses(views, scene_names, cfg, model) if not retrace else None
        if passes is not None and not done:
            from invrender.inverse.least_squares import preload

            preload()  # JAX's import overlaps with the first records
        for r in range(len(history) if passes is not None and not done else 0):
            passes.add(r, record_point if r == 0 else {n: torch.tensor(v, dtype=torch.float64) for n, v in history[r - 1]["params"].items()})
        for rnd in range(len(history), 0 if done else cfg.rounds):
            spp = cfg.spp * 4**rnd
            bar.start(rnd, spp)
            round_clock = time.perf_counter()
            if retrace:
                seeds = [(cfg.seed * 1_000_003 + 2 * (rnd * len(views) + v), cfg.seed * 1_000_003 + 2 * (rnd * len(views) + v) + 1) for v in range(len(views))]
                sol = retraced.solve([s for s, _ in views], [t for _, t in views], {n: current[n] for n in scene_names}, model=model, spp=spp, seeds=seeds, sampler=cfg.sampler, sensor=sensor, solver=cfg.solver)
                # independent rounds: the difference's variance is the sum of theirs
                spread = {n: sol.std_error[n] ** 2 + (std_error[n] ** 2 if std_error else 0.0) for n in names}
            else:
                tick = time.perf_counter()
                passes.add(rnd, current)
                traced = time.perf_counter() - tick
                try:
                    sol = _solve_on_records(views, passes, current, cfg, prior, sensor, ambiguities)
                except NonFiniteError as e:  # the round's solve diverged: the rounds before it stand
                    raise _stopped(rnd, str(e), checkpoint, len(history) if history else None, "round") from None
                # nested rounds (round rnd holds every sample of round rnd - 1): the difference of
                # their estimates is a weighted difference of the new samples' mean and the old ones',
                # with variance se^2 (spp / previous spp - 1) (docs/fitting.md)
                # (the Monte Carlo standard errors: the targets' own error is common to both rounds)
                mc = sol.identifiability.monte_carlo_std_error or sol.std_error
                spread = {n: mc[n] ** 2 * ((4 - 1) if std_error else 1) for n in names}
            # how far each channel moved, in standard errors of the difference of two rounds
            moved = max(float(((sol.values[n] - current[n]).abs() / spread[n].sqrt().clamp_min(1e-12)).max()) for n in names)
            current, std_error = sol.values, sol.std_error
            record = {
                "step": rnd + 1, "loss": sol.loss, "spp": spp, "seconds": time.perf_counter() - clock, "inner_steps": sol.steps,
                "params": {n: current[n].tolist() for n in names}, "std_error": {n: std_error[n].tolist() for n in names},
                "moved_in_std_errors": moved, "on": "re-traced renders" if retrace else "path records",
            }  # fmt: skip
            if not retrace:  # where the round's wall time went (least_squares.LeastSquaresSolution.seconds)
                record["timing"] = {"records": traced, **sol.seconds}
            if truth:
                record["errors"] = {n: P.relative_error(current[n].float(), truth[n]) for n in names if n in truth}
            record["correlation"] = {"channels": sol.identifiability.channels, "matrix": sol.identifiability.correlation.tolist()}
            if sol.identifiability.undetermined:
                record["undetermined"] = sol.identifiability.describe()
            if sol.identifiability.loose:
                record["loose"] = sol.identifiability.describe_loose()
            record["converged"] = rnd >= MIN_ROUNDS - 1 and moved < CONVERGED_MOVE and (
                cfg.precision is None or all(bool((std_error[n] <= cfg.precision * current[n].abs()).all()) for n in names)
            )
            history.append(record)
            # the round's seconds that grow with its samples (tracing; all of them when re-traced) and
            # those that do not (the solve, less the one-off imports): the bar's time left
            solving = 0.0 if retrace else sum(v for k, v in sol.seconds.items() if k != "import")
            bar.finish(time.perf_counter() - round_clock if retrace else traced, solving, loss=f"{sol.loss:.4g}", lm_steps=sol.steps, moved=f"{moved:.2g} se")
            if checkpoint is not None:
                _save_checkpoint(checkpoint, scene, names, cfg, len(history), history, values=current)
            if record["converged"]:
                if rnd + 1 < cfg.rounds:
                    bar.converged()
                break
    if history and history[-1].get("undetermined"):
        warnings.warn(f"the targets do not determine these parameter combinations: {history[-1]['undetermined']}", stacklevel=3)
    recovered = {n: current[n].float().clone() for n in names}
    out_scene = scene.with_params({n: recovered[n] for n in scene_names}, detach=True)
    result = FitResult(recovered, history, out_scene, cfg, initial, {k: v for k, v in truth.items() if k in names}, {n: std_error[n].float() for n in names}, [t.report() for _, t in views], _pixels(views))
    result.converged = check_least_squares(history, cfg.solver, cfg.rounds, cfg.precision, CONVERGED_MOVE)
    return result


class _RecordPasses:
    """The path records of a least-squares fit's rounds, two independent accumulations per view
    (A: the residual's, B: the Jacobian's). Round r traces samples ``spp * 4^(r-1) .. spp * 4^r - 1``
    of each set's seed at the round's start values (round 0: ``0 .. spp - 1``) and adds them to
    the earlier rounds' (:func:`~invrender.estimators.records.accumulate`): every record is an unbiased
    estimate of the polynomial at any values, so round r solves on all ``spp * 4^r`` samples
    while tracing only the new three quarters."""

    def __init__(self, views, scene_names, cfg: FitSettings, model):
        self.views, self.names, self.cfg, self.model = views, scene_names, cfg, model
        self.sets = {half: [None] * len(views) for half in (0, 1)}

    def add(self, rnd: int, values: dict) -> None:
        """Trace round ``rnd``'s passes at ``values`` and accumulate them."""
        from invrender.estimators.records import accumulate, record_paths

        cfg = self.cfg
        first = 0 if rnd == 0 else cfg.spp * 4 ** (rnd - 1)
        for half in (0, 1):
            for v, (view_scene, _) in enumerate(self.views):
                rec = record_paths(
                    view_scene.with_params({n: values[n].float() for n in self.names}),
                    self.names, spp=cfg.spp * 4**rnd - first, first_sample=first, max_depth=self.model.terms_kept,
                    seed=cfg.seed * 1_000_003 + 2 * v + half, integrator=self.model.name, progress=False, sampler=cfg.sampler,
                    **_settings_besides_depth(self.model),
                )  # fmt: skip
                self.sets[half][v] = rec if self.sets[half][v] is None else accumulate([self.sets[half][v], rec])


def _solve_on_records(views, passes: _RecordPasses, current, cfg: FitSettings, prior: dict, sensor: Sensor, ambiguities):
    """One round on path records: the accumulated record sets A (residual) and B (Jacobian),
    solved by least_squares.solve from ``current``."""
    from invrender.inverse.least_squares import Prior, solve

    recs = passes.sets
    targets = [t for _, t in views]
    regularizer = Prior.by_rule(prior, recs[1], targets, current, cfg.prior_weight, cfg.smoothness) if prior and (cfg.prior_weight != 0 or cfg.smoothness != 0) else None
    return solve(recs[0], recs[1], targets, current, solver=cfg.solver, prior=regularizer, sensor=sensor, ambiguities=ambiguities)


def _pixels(views) -> list:
    """FitResult.pixels of the views' targets."""
    return [None if bool((t.mask == 1).all()) else t.pixels_image() for _, t in views]


def _control_variate(view_scene: Scene, cfg: FitSettings) -> RecursiveControlVariate:
    """One view's recursive control variate, rendering with the fit's integrator and sampler."""
    integrator = cfg.model

    def render_at(values: dict, seed: int, spp: int) -> torch.Tensor:
        with torch.no_grad():
            work = view_scene.with_params({k: v.detach() for k, v in values.items()})
            return render(work, integrator, spp=spp, seed=seed, progress=False, sampler=cfg.sampler)

    return RecursiveControlVariate(render_at)


def _view_loss(view_scene: Scene, values, target, cfg: FitSettings, step: int, view: int, n_views: int, cv: RecursiveControlVariate | None = None, gain: torch.Tensor | None = None) -> torch.Tensor:
    """Render one view, back-propagate its share of the loss, return the loss value (with ``cv``,
    ``dl/dI`` is taken at its estimate of the image). ``gain``: the view's (3,) sensor gains (the
    model image is ``gain * I``), differentiable when the sensor is fitted (its gradient is then
    taken with the render of the scene's, independent of the one ``dl/dI`` comes from)."""
    work = view_scene.with_params(values)
    spp = cfg.spp_at(step)
    seed = cfg.seed * 1_000_003 + 2 * (step * n_views + view)
    integrator = cfg.model
    kw = dict(spp=spp, progress=False, sampler=cfg.sampler)
    if not cfg.decorrelate:
        image = render(work, integrator, seed=seed, estimator=cfg.estimator, **kw)
        if gain is not None:
            image = image * gain
        return loss_and_gradient(cfg.loss, target, image, image / n_views) / n_views
    # dl/dI from one render, differentiated through another (independent seed): unbiased (losses.py)
    if cv is not None:
        residual = cv(values, seed + 1, spp)
    else:
        with torch.no_grad():
            residual = render(work, integrator, seed=seed + 1, **kw)
    if gain is None:
        dl_dI, value = loss_gradient(cfg.loss, target, residual)
        backpropagate(work, dl_dI / n_views, integrator, RenderSettings(seed=seed, **kw), cfg.estimator)
        return value / n_views
    dl_dM, value = loss_gradient(cfg.loss, target, residual * gain.detach())
    if not gain.requires_grad:
        backpropagate(work, dl_dM * gain / n_views, integrator, RenderSettings(seed=seed, **kw), cfg.estimator)
    else:  # the scene's and the sensor's gradients from one differentiable render
        image = render(work, integrator, seed=seed, estimator=cfg.estimator, **kw)
        (dl_dM * image * gain).sum().div(n_views).backward()
    return value / n_views


def _settings_besides_depth(model: Integrator) -> dict:
    """The integrator's settings other than ``max_depth`` (path records take that apart)."""
    return {k: v for k, v in dataclasses.asdict(model.settings).items() if k != "max_depth"}


def _record(step, loss, spp, seconds, values, truth) -> dict:
    values = {n: v.detach() for n, v in values.items()}
    record = {"step": step + 1, "loss": loss, "spp": spp, "seconds": seconds, "params": {n: v.tolist() for n, v in values.items()}}
    if truth:
        record["errors"] = {n: P.relative_error(values[n], truth[n]) for n in values if n in truth}
    return record


def _signature(scene: Scene, names: list[str]) -> dict:
    return {
        "scene": scene.name,
        "triangles": scene.triangles.count,
        "resolution": list(scene.resolution),
        "params": {n: [] if is_sensor(n) else list(scene.params[n].shape) for n in names},
    }


def _save_checkpoint(path: Path, scene, names, cfg, step: int, history: list[dict], **solver_state) -> None:
    """Atomically write the fit state after ``step`` completed steps (or rounds); ``solver_state``
    is the solver's own: Adam's ``raw`` leaves and ``optimizer`` state, or the least-squares
    rounds' current ``values``."""
    state = {"format": CHECKPOINT_FORMAT, "signature": _signature(scene, names), "settings": dataclasses.asdict(cfg), "step": step, "history": history, **solver_state}
    with atomic_file(path) as f:
        torch.save(state, f)


def _leaves(raw: dict) -> dict:
    """Copies of Adam's leaves (name -> tensor), detached."""
    return {n: v.detach().clone() for n, v in raw.items()}


def _adam_state(raw, optimizer, variates) -> dict:
    state = {"raw": _leaves(raw), "optimizer": optimizer.state_dict()}
    if any(cv is not None for cv in variates):
        state["control_variates"] = [cv.state() for cv in variates]
    return state


def _restore(state: dict, names, raw, optimizer) -> tuple[int, list[dict]]:
    """Adam's state from a checkpoint: the leaves and moments; returns (steps done, history)."""
    _load_adam({n: state["raw"][n] for n in names}, state["optimizer"], raw, optimizer)
    return int(state["step"]), list(state["history"])


def _load_adam(leaves: dict, optimizer_state: dict, raw: dict, optimizer) -> None:
    """Set Adam's leaves ``raw`` to ``leaves`` (name -> tensor) and its moments to ``optimizer_state``."""
    with torch.no_grad():
        for n, v in leaves.items():
            raw[n].copy_(v)
    optimizer.load_state_dict(optimizer_state)


def _read_checkpoint(path: Path, scene, names) -> dict:
    """The checkpoint at ``path``, checked to come from this scene and these parameters."""
    try:
        state = torch.load(path, weights_only=False)
    except Exception as e:
        raise ParameterError(f"cannot read checkpoint {path}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ParameterError(f"{path} is not an invrender fit checkpoint")
    if state["signature"] != _signature(scene, names):
        raise ParameterError(f"checkpoint {path} comes from another scene or parameter set ({state['signature']['scene']}: {', '.join(state['signature']['params'])})")
    return state
