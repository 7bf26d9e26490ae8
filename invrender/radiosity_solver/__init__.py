"""Radiosity: diffuse scenes as patches, form factors by ray casting, the linear system
``(I - diag(rho) F) B = E`` solved directly or iteratively with exact gradients, and Neumann-Ulam
random walks as its Monte Carlo solvers (docs/radiosity.md).

- :mod:`~invrender.radiosity_solver.patches`: meshing into patches, locating points, per-patch rho and eps;
- :mod:`~invrender.radiosity_solver.form_factors`: stratified ray-cast form factors with standard errors;
- :mod:`~invrender.radiosity_solver.system`: the solvers and the adjoint (implicit) gradient;
- :mod:`~invrender.radiosity_solver.random_walks`: collision and absorption estimators, transition choices,
  the variance condition;
- :mod:`~invrender.radiosity_solver.solution`: the pipeline and its result.

The ``radiosity`` integrator (:mod:`invrender.plugins.integrators.radiosity`: its settings and
``ir.radiosity``) computes and renders a solution; this package is below it and knows no integrator.
"""

from invrender.radiosity_solver.form_factors import FormFactors, FormFactorSettings, form_factors
from invrender.radiosity_solver.patches import Patches, mesh_patches
from invrender.radiosity_solver.random_walks import WalkEstimate, neumann_ulam, transition_matrix, variance_radius
from invrender.radiosity_solver.solution import RadiositySolution
from invrender.radiosity_solver.system import SolveReport, SolverSettings, solve

__all__ = [
    "RadiositySolution", "Patches", "mesh_patches", "FormFactors", "FormFactorSettings",
    "form_factors", "SolverSettings", "SolveReport", "solve", "WalkEstimate", "neumann_ulam", "transition_matrix", "variance_radius",
]  # fmt: skip
