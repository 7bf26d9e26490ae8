"""The path tracer: BSDF sampling + next-event estimation, combined by multiple importance sampling.

At vertex x_k (k = 0 is the camera ray's hit) the Neumann term k+1 is estimated twice and the two
estimates are blended with the power heuristic (Veach and Guibas 1995): once by sampling a point on
an emitter (next-event estimation, skipped at delta vertices) and once by following the BSDF sample
and seeing whether it hits an emitter. Russian roulette ends paths from ``rr_depth`` on. Sampling
never depends on rho or eps; gradients flow through the BSDF and emission factors only.

``strategy`` keeps one of the two estimates instead of blending them (docs/sampling.md):
``"bsdf"`` counts every emitter a BSDF sample hits and samples no emitters (the random walk);
``"emitter"`` estimates direct light by emitter samples alone and counts emitters hit by BSDF
samples only where no emitter sample was possible (camera rays, after mirrors and glass). All three
estimate the same image.
"""

from __future__ import annotations

from dataclasses import dataclass

from invrender.errors import ParameterError, did_you_mean
from invrender.plugins.integrators.base import MitsubaAlias, SamplingSettings
from invrender.plugins.integrators.random_walk import RandomWalk
from invrender.plugins.integrators.vertex import add_direct

#: how the path tracer estimates direct light (PathSettings.strategy)
STRATEGIES = ("mis", "bsdf", "emitter")


@dataclass(frozen=True)
class PathSettings(SamplingSettings):
    """Settings of the path tracer.

    Attributes:
        max_depth, rr_depth, hemisphere: as :class:`~invrender.plugins.integrators.base.SamplingSettings`.
        strategy: direct light from ``"mis"`` (emitter samples and BSDF samples combined by the
            power heuristic; default), ``"bsdf"`` (BSDF samples only) or ``"emitter"`` (emitter
            samples only, wherever the BSDF is not a delta lobe).
    """

    strategy: str = "mis"

    def __post_init__(self):
        super().__post_init__()
        if self.strategy not in STRATEGIES:
            raise ParameterError(f"unknown strategy {self.strategy!r}{did_you_mean(self.strategy, STRATEGIES)} (known: {', '.join(STRATEGIES)})")


class Path(RandomWalk):
    name = "path"
    Settings = PathSettings
    summary = "path tracer: BSDF sampling + next-event estimation with MIS, Russian roulette (default)"
    #: the Mitsuba integrator plugins it stands for (scene files' ``<integrator type=...>``)
    mitsuba_plugins = ("path",)
    #: Mitsuba's ``direct`` (emitters seen + direct light, emitter and BSDF samples combined by the
    #: power heuristic, no roulette) is this path tracer at max_depth 2: the same terms, the same
    #: MIS (delta lights weight 1, BSDF samples after delta lobes weight 1), so the same expectation
    #: (docs/rendering.md#mitsubas-direct-integrator)
    mitsuba_aliases = {
        "direct": MitsubaAlias(
            {"max_depth": 2},
            counts={
                "shading_samples": (0, None, "a sample count is >= 0"),
                "emitter_samples": (0, None, "a sample count is >= 0"),
                "bsdf_samples": (0, None, "a sample count is >= 0"),
            },
        )
    }

    def __init__(self, **options):
        super().__init__(**options)
        if self.strategy != "mis" and type(self).at_vertex is not Path.at_vertex:
            raise ParameterError(f"integrator {self.name!r} samples emitters its own way: its strategy must be 'mis', got {self.strategy!r}")

    @property
    def strategy(self) -> str:
        """The settings' strategy (``"mis"`` for subclasses whose settings have none, e.g. utah)."""
        return getattr(self.settings, "strategy", "mis")

    @property
    def samples_emitters(self) -> bool:
        return self.strategy != "bsdf"

    @property
    def emitter_mis(self) -> bool:
        return self.strategy == "mis"

    @property
    def emitter_nee_only(self) -> bool:
        return self.strategy == "emitter"

    @property
    def fused_direct(self):
        """The strategy, for the fused primal bounce (``False`` for ``"bsdf"``: no emitter samples);
        None where a subclass samples emitters its own way."""
        if type(self).at_vertex is not Path.at_vertex:
            return None
        return False if self.strategy == "bsdf" else self.strategy

    def at_vertex(self, ctx, state, s, sp, u, depth, film):
        if self.strategy != "bsdf":
            add_direct(ctx, state, s, sp, u, depth + 1, film, mis=self.strategy == "mis")  # term depth + 1, light strategy
        return None
