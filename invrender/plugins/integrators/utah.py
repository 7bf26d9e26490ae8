"""Kajiya's Utah approximation: emitters seen directly, direct light, and a constant ambient term.

    I ~ g eps + g M g eps + rho eps0

Light from the emitters reflected once (shadowed, estimated exactly as the path tracer estimates
its second Neumann term: next-event estimation and BSDF sampling combined by multiple importance
sampling), plus a constant ambient radiance eps0 (``scene.params["ambient.emission"]``, zero when
the scene has none) arriving from every direction and reflected as ``rho eps0``, which stands in for
all interreflection. It is what a rasterizer computes (see :mod:`invrender.baseline`), and it is the
path tracer at ``max_depth`` 2 plus the ambient term: terms beyond 2 are never kept. Differentiable
in rho, eps and eps0.
"""

from __future__ import annotations

from dataclasses import dataclass

from invrender.plugins.integrators.base import DepthSettings
from invrender.plugins.integrators.path import Path
from invrender.plugins.integrators.vertex import add_ambient

#: Neumann terms the Utah approximation keeps (Mitsuba's count: emitters seen, + direct light)
MAX_TERMS = 2


@dataclass(frozen=True)
class UtahSettings(DepthSettings):
    """Settings of the Utah approximation.

    Attributes:
        max_depth: 1 = emitters seen directly only; any larger value (or -1) keeps both of its
            terms, emitters seen and direct light + ambient (default 2).
    """

    max_depth: int = MAX_TERMS

    @property
    def rr_depth(self) -> int:
        return MAX_TERMS + 1  # never reached: no roulette

    def continues_after(self, depth: int) -> bool:
        return depth == 0 and self.max_depth != 1


class Utah(Path):
    name = "utah"
    Settings = UtahSettings
    summary = "Utah approximation: emitters + direct light + ambient rho*eps0 (at most 2 terms)"

    @property
    def terms_kept(self) -> int:
        return 1 if self.settings.max_depth == 1 else MAX_TERMS

    def at_vertex(self, ctx, state, s, sp, u, depth, film):
        add_ambient(ctx, state, sp, depth + 1, film)  # term 1: rho eps0
        return super().at_vertex(ctx, state, s, sp, u, depth, film)
