"""Integrators: estimators of the Neumann series ``g eps + gMg eps + g(Mg)^2 eps + ...``.

Each exposes ``trace(ctx, state, film)``, which follows the paths in ``state`` bounce by bounce and
adds their contributions to ``film``. The ladder, simplest first:

- ``random_walk``: Kajiya's plain Markov-chain estimator (BSDF sampling only), the reference;
- ``path``: + next-event estimation with multiple importance sampling.

Beside the ladder, truncations of the series that older methods compute:

- ``utah``: the Utah approximation ``g eps + g M eps + rho eps0``, what a rasterizer computes.
"""

from invrender.transport.integrators import path, random_walk, utah

INTEGRATOR_MODULES = {"path": path, "random_walk": random_walk, "utah": utah}
