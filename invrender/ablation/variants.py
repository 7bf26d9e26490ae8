"""The sampling strategies an ablation compares: the path tracer's defaults, and one variant per
choice that changes exactly that choice (docs/sampling.md).

A variant changes the integrator's settings (merged into the ablation's integrator spec,
:mod:`invrender.registry`), the render's settings (``sampler``, ``adaptive``), or both."""

from __future__ import annotations

from dataclasses import dataclass, field

from invrender.errors import ParameterError
from invrender.registry import integrator_spec


@dataclass(frozen=True)
class Variant:
    """One configuration of the renderer.

    Attributes:
        name: short name (table rows, CSV, plot legend, ``--strategies``).
        choice: the choice it makes, e.g. ``"pixel samples: independent"``.
        integrator: integrator settings that differ from the ablation's spec (``rr_depth``,
            ``hemisphere``, ``strategy``, ...), merged into it.
        render: other keywords of :func:`invrender.render` that differ from the defaults
            (``sampler``, ``adaptive``).
    """

    name: str
    choice: str
    integrator: dict = field(default_factory=dict)
    render: dict = field(default_factory=dict)

    @property
    def options(self) -> dict:
        """Everything the variant changes: its integrator settings and render keywords."""
        return {**self.integrator, **self.render}

    def integrator_spec(self, base="path") -> dict:
        """The integrator spec of this variant's renders: ``base`` (a spec) with its settings."""
        name, settings = integrator_spec(base, "ablation integrator")
        return {"type": name, **settings, **self.integrator}


#: the defaults (stratified pixel samples, cosine-weighted hemisphere, MIS, roulette, every pixel
#: the same spp) and one variant per choice
VARIANTS = (
    Variant("default", "stratified, cosine, MIS, roulette, uniform allocation"),
    Variant("independent", "pixel samples: independent", render={"sampler": "independent"}),
    Variant("antithetic", "pixel samples: antithetic pairs", render={"sampler": "antithetic"}),
    Variant("stratified_direct", "pixel samples and the first vertex's BSDF and emitter samples: stratified", render={"sampler": "stratified_direct"}),
    Variant("uniform_hemisphere", "diffuse sampling: uniform hemisphere", integrator={"hemisphere": "uniform"}),
    Variant("bsdf_only", "direct light: BSDF samples only", integrator={"strategy": "bsdf"}),
    Variant("emitter_only", "direct light: emitter samples only", integrator={"strategy": "emitter"}),
    Variant("no_roulette", "Russian roulette: off", integrator={"rr_depth": -1}),
    Variant("adaptive", "allocation: adaptive", render={"adaptive": True}),
)


def select_variants(names: str | list[str] | None) -> tuple[Variant, ...]:
    """The variants named (comma-separated or a list; None = all), ``default`` always first."""
    if names is None:
        return VARIANTS
    wanted = [n.strip() for n in names.split(",")] if isinstance(names, str) else list(names)
    known = {v.name: v for v in VARIANTS}
    unknown = [n for n in wanted if n not in known]
    if unknown or not wanted:
        raise ParameterError(f"unknown strategy {unknown[0] if unknown else ''!r} (known: {', '.join(known)})")
    return tuple(v for v in VARIANTS if v.name == "default" or v.name in wanted)
