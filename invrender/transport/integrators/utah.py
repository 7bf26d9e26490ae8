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

from invrender.transport.context import PathState, TransportContext
from invrender.transport.film import Film
from invrender.transport.integrators import path

#: Neumann terms the Utah approximation keeps (Mitsuba's count: emitters seen, + direct light)
MAX_TERMS = 2


def trace(ctx: TransportContext, state: PathState, film: Film) -> None:
    """Add ``g eps`` (term 0) and ``g M g eps + rho eps0`` (term 1) of ``state``'s paths to ``film``."""
    assert ctx.settings.max_depth in (1, MAX_TERMS), "render() clips max_depth to 2 for utah"
    path.trace(ctx, state, film, ambient=ctx.ambient if ctx.settings.max_depth == MAX_TERMS else None)
