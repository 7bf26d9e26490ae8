"""The sampling strategies an ablation compares: the path tracer's defaults, and one variant per
choice that changes exactly that choice (docs/sampling.md)."""

from __future__ import annotations

from dataclasses import dataclass, field

from invrender.errors import ParameterError


@dataclass(frozen=True)
class Variant:
    """One configuration of the renderer.

    Attributes:
        name: short name (table rows, CSV, plot legend, ``--strategies``).
        choice: the choice it makes, e.g. ``"pixel samples: independent"``.
        options: keywords of :func:`invrender.render` that differ from the defaults.
    """

    name: str
    choice: str
    options: dict = field(default_factory=dict)


#: the defaults (stratified pixel samples, cosine-weighted hemisphere, MIS, roulette, every pixel
#: the same spp) and one variant per choice
VARIANTS = (
    Variant("default", "stratified, cosine, MIS, roulette, uniform allocation"),
    Variant("independent", "pixel samples: independent", {"sampler": "independent"}),
    Variant("antithetic", "pixel samples: antithetic pairs", {"sampler": "antithetic"}),
    Variant("uniform_hemisphere", "diffuse sampling: uniform hemisphere", {"hemisphere": "uniform"}),
    Variant("bsdf_only", "direct light: BSDF samples only", {"strategy": "bsdf"}),
    Variant("emitter_only", "direct light: emitter samples only", {"strategy": "emitter"}),
    Variant("no_roulette", "Russian roulette: off", {"rr_depth": -1}),
    Variant("adaptive", "allocation: adaptive", {"adaptive": True}),
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
