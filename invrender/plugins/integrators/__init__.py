"""Integrators: estimators of the Neumann series ``g eps + gMg eps + g(Mg)^2 eps + ...``.

Each is a class registered by name (:data:`INTEGRATORS`), with its own settings. Kajiya's ladder:

- ``random_walk``: the plain Markov-chain estimator (BSDF sampling only), the reference;
- ``path``: + next-event estimation with multiple importance sampling (the default).

Beside it, the older methods, each a truncation or approximation of the series:

- ``utah``: ``g eps + g M g eps + rho eps0``, what a rasterizer computes;
- ``whitted``: direct light + ambient at diffuse vertices, mirrors and glass followed recursively;
- ``distributed``: Cook's distribution ray tracing: glossy lobes followed, soft shadows, ambient.
"""

from invrender.plugins.integrators.base import INTEGRATORS, DepthSettings, Integrator, RouletteSettings, make_integrator
from invrender.plugins.integrators.distributed import Distributed
from invrender.plugins.integrators.path import Path
from invrender.plugins.integrators.radiosity import Radiosity
from invrender.plugins.integrators.random_walk import RandomWalk
from invrender.plugins.integrators.utah import Utah
from invrender.plugins.integrators.whitted import Whitted

__all__ = [
    "INTEGRATORS", "Integrator", "DepthSettings", "RouletteSettings", "make_integrator",
    "RandomWalk", "Path", "Utah", "Whitted", "Distributed", "Radiosity",
]  # fmt: skip
