"""What one configuration of a gradient study is, and its spec strings.

A configuration fixes everything that makes one gradient estimator differ from another, for a
scene, a loss and a target shared by the whole study:

- ``integrator``: which estimator of the Neumann series is differentiated (``path``,
  ``random_walk``, ...);
- ``estimator``: how it is differentiated (``replay`` or ``autodiff``; the same estimate, so the
  same statistics, at different costs);
- ``gradient``: how the loss's adjoint ``dl/dI`` is paired with the differentiated image
  (``correlated``: from the same render; ``decorrelated``: from an independent one; the pairings
  are registered in :data:`invrender.study.loss_gradients.LOSS_GRADIENTS`);
- ``options``: any further keyword of :func:`invrender.render`: ``rr_depth``, ``max_depth``,
  ``sampler``, the integrator's own settings, and whatever sampling choices ``render`` grows later.
  They are passed through unchanged, so a new render option is a new configuration without any
  change here. A pairing may declare options of its own (``control_variate``: ``cv_steps``,
  ``cv_step``); those go to the pairing, not to the render.

A spec string names one configuration in parts separated by ``/``, in any order::

    path/replay/decorrelated
    random_walk/replay/correlated/max_depth=-1/rr_depth=1
    path/autodiff/decorrelated/sampler=antithetic
    path/replay/control_variate/cv_steps=8/cv_step=0.01

Each bare part must be an integrator, an estimator or a loss-gradient name; each ``KEY=VALUE`` part
is an option (VALUE read as an int, a float, true/false, else a string). Parts left out take the
defaults ``path``, ``replay``, ``decorrelated``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from invrender.estimators import ESTIMATORS
from invrender.estimators.defaults import scene_integrator
from invrender.errors import ParameterError, did_you_mean
from invrender.registry import integrator_spec
from invrender.study.loss_gradients import LOSS_GRADIENTS
from invrender.core.driver import RenderSettings
from invrender.plugins.integrators import INTEGRATORS, Integrator, make_integrator

#: RenderSettings fields a study sets itself; a configuration may not
STUDY_SETTINGS = ("spp", "seed", "terms", "progress")

#: options that do not change the expected image, so configurations differing only in them share
#: a reference gradient: Russian roulette, the pixel sampler, the hemisphere sampling of diffuse
#: BSDFs and the path tracer's direct-light strategy are all unbiased choices
UNBIASED_OPTIONS = ("rr_depth", "sampler", "hemisphere", "strategy")


@dataclass(frozen=True)
class GradientConfig:
    """One gradient estimator of a study.

    Attributes:
        integrator: a registered integrator name; also accepted: any integrator spec (a
            ``{"type": name, ...}`` mapping or an integrator object), whose settings become
            ``options`` (an object's: those that differ from the defaults).
        estimator: ``"replay"`` or ``"autodiff"``.
        gradient: a :data:`~invrender.study.loss_gradients.LOSS_GRADIENTS` name, ``"correlated"`` or
            ``"decorrelated"`` (how ``dl/dI`` is paired with the differentiated image).
        options: further :func:`invrender.render` keywords as sorted ``(key, value)`` pairs
            (``rr_depth``, ``max_depth``, integrator settings, later sampling choices).
    """

    integrator: str = "path"
    estimator: str = "replay"
    gradient: str = "decorrelated"
    options: tuple[tuple[str, object], ...] = ()

    def __post_init__(self):
        if not isinstance(self.integrator, str):  # a spec with settings: they become options
            name, settings = _spec_settings(self.integrator)
            given = dict(self.options)
            clash = next((k for k, v in settings.items() if k in given and given[k] != v), None)
            if clash:
                raise ParameterError(f"configuration: {clash!r} is given in the integrator spec and as an option, differently")
            object.__setattr__(self, "integrator", name)
            object.__setattr__(self, "options", tuple({**given, **settings}.items()))
        if self.integrator not in INTEGRATORS:
            raise ParameterError(f"unknown integrator {self.integrator!r}{did_you_mean(self.integrator, INTEGRATORS)} in a configuration (known: {', '.join(INTEGRATORS)})")
        if self.estimator not in ESTIMATORS:
            raise ParameterError(f"unknown estimator {self.estimator!r}{did_you_mean(self.estimator, ESTIMATORS)} in a configuration (known: {', '.join(ESTIMATORS)})")
        if self.gradient not in LOSS_GRADIENTS:
            raise ParameterError(f"unknown loss gradient {self.gradient!r}{did_you_mean(self.gradient, LOSS_GRADIENTS)} in a configuration (known: {', '.join(LOSS_GRADIENTS)})")
        object.__setattr__(self, "options", tuple(sorted(dict(self.options).items())))
        clash = [k for k, _ in self.options if k in STUDY_SETTINGS or k in ("integrator", "estimator")]
        if clash:
            raise ParameterError(f"configuration {self.label!r}: {clash[0]!r} is set by the study, not by a configuration")
        own = LOSS_GRADIENTS[self.gradient].options
        for key, _ in self.options:
            other = next((name for name, cls in LOSS_GRADIENTS.items() if key in cls.options and key not in own), None)
            if other:
                raise ParameterError(f"configuration {self.label!r}: option {key!r} belongs to the {other} pairing, not to {self.gradient}")
        LOSS_GRADIENTS[self.gradient].check_options(self.label, self.pairing_options)
        self.integrator_and_settings(spp=1, seed=0)  # unknown or out-of-range options fail here, before any work

    @property
    def label(self) -> str:
        """The canonical spec string, e.g. ``"random_walk/replay/correlated/max_depth=-1/rr_depth=1"``."""
        return "/".join([self.integrator, self.estimator, self.gradient] + [f"{k}={_format(v)}" for k, v in self.options])

    @property
    def render_options(self) -> dict:
        """The options that go to the render (all but the pairing's own)."""
        own = LOSS_GRADIENTS[self.gradient].options
        return {k: v for k, v in self.options if k not in own}

    @property
    def pairing_options(self) -> dict:
        """The pairing's own options, with its defaults for those not given."""
        own = LOSS_GRADIENTS[self.gradient].options
        return {**own, **{k: v for k, v in self.options if k in own}}

    def render_kwargs(self) -> dict:
        """Keywords of :func:`invrender.render` for this configuration (without spp and seed)."""
        return {"integrator": self.integrator, "estimator": self.estimator, **self.render_options}

    def integrator_and_settings(self, spp: int, seed: int, scene=None) -> tuple[Integrator, RenderSettings]:
        """What :func:`invrender.estimators.backpropagate` takes: the options split into the integrator's
        settings and the render settings (:class:`RenderSettings` fields such as ``backend``);
        with ``scene``, its file's integrator settings fill in as :func:`invrender.render`'s do."""
        render_fields = {f.name for f in dataclasses.fields(RenderSettings)}
        options = self.render_options
        settings = RenderSettings(spp=spp, seed=seed, progress=False, **{k: v for k, v in options.items() if k in render_fields})
        given = {k: v for k, v in options.items() if k not in render_fields}
        spec = scene_integrator(scene, self.integrator, given)[0] if scene is not None else {"type": self.integrator, **given}
        return make_integrator(spec), settings

    def replace(self, **changes) -> GradientConfig:
        return dataclasses.replace(self, **changes)

    def with_options(self, **changes) -> GradientConfig:
        """The same configuration with options added or changed (None removes one)."""
        options = {**dict(self.options), **changes}
        return self.replace(options=tuple((k, v) for k, v in options.items() if v is not None))

    @property
    def model(self) -> GradientConfig:
        """The configuration's model: without :data:`UNBIASED_OPTIONS`, ``replay``, ``decorrelated``.
        Configurations with the same model have the same expected image and so share a reference;
        a rendered target and the reference are drawn with it."""
        drop = {k: None for k in (*UNBIASED_OPTIONS, *LOSS_GRADIENTS[self.gradient].options)}
        return self.with_options(**drop).replace(estimator="replay", gradient="decorrelated")


def parse_config(spec) -> GradientConfig:
    """A :class:`GradientConfig` from a spec string (see the module docstring); a config passes through."""
    if isinstance(spec, GradientConfig):
        return spec
    if not isinstance(spec, str) or not spec.strip():
        raise ParameterError(f"a configuration must be a spec string such as 'path/replay/decorrelated', got {spec!r}")
    fields: dict = {}
    options: dict = {}
    for part in (p.strip() for p in spec.strip().split("/")):
        key, sep, value = part.partition("=")
        if sep:
            if not key.strip() or not value.strip():
                raise ParameterError(f"configuration {spec!r}: option {part!r} must read KEY=VALUE")
            if key.strip() in options:
                raise ParameterError(f"configuration {spec!r}: option {key.strip()!r} is given twice")
            options[key.strip()] = _value(value.strip())
            continue
        field = "integrator" if part in INTEGRATORS else "estimator" if part in ESTIMATORS else "gradient" if part in LOSS_GRADIENTS else None
        if field is None:
            raise ParameterError(
                f"configuration {spec!r}: unknown part {part!r} (expected an integrator: {', '.join(INTEGRATORS)}; "
                f"an estimator: {', '.join(ESTIMATORS)}; a loss gradient: {', '.join(LOSS_GRADIENTS)}; or KEY=VALUE)"
            )
        if field in fields:
            raise ParameterError(f"configuration {spec!r}: two {field}s ({fields[field]!r} and {part!r})")
        fields[field] = part
    return GradientConfig(**fields, options=tuple(options.items()))


def parse_configs(specs) -> list[GradientConfig]:
    """Configurations from spec strings (a list, or one string with specs separated by commas)."""
    if isinstance(specs, (str, GradientConfig)):
        specs = [s for s in specs.split(",") if s.strip()] if isinstance(specs, str) else [specs]
    configs = [parse_config(s) for s in specs]
    if not configs:
        raise ParameterError("no configurations were given")
    labels = [c.label for c in configs]
    twice = next((lab for lab in labels if labels.count(lab) > 1), None)
    if twice:
        raise ParameterError(f"configuration {twice!r} is given twice")
    return configs


def _spec_settings(spec) -> tuple[str, dict]:
    """(name, settings) of an integrator spec; an object's settings that differ from its defaults."""
    if isinstance(spec, Integrator):
        defaults = type(spec).Settings()
        return spec.name, {k: v for k, v in dataclasses.asdict(spec.settings).items() if getattr(defaults, k) != v}
    return integrator_spec(spec, "configuration integrator")


def _value(text: str):
    """A spec option's value: int, float, bool, else the string."""
    lowered = text.lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _format(value) -> str:
    return str(value).lower() if isinstance(value, bool) else str(value)
