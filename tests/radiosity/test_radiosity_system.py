"""The radiosity system's solvers and exact gradients against the sphere interior's closed forms
(docs/closed_forms.md#sphere-interior): with the exact form factors ``F_ij = a_j`` and non-uniform
per-patch rho and E,

    B_i = E_i + rho_i E_bar / (1 - rho_bar)
    dB_i/dE_k   = delta_ik + rho_i a_k / (1 - rho_bar)
    dB_i/drho_k = delta_ik B_bar + rho_i E_bar a_k / (1 - rho_bar)^2

per colour channel (no coupling between channels).
"""

import pytest
import torch

from invrender.errors import ParameterError
from invrender.radiosity_solver.system import SolverSettings, neumann_terms, solve
from tests.radiosity.conftest import sphere_closed_form, sphere_system

METHODS = ["direct", "jacobi", "gauss_seidel", "neumann"]


@pytest.mark.parametrize("method", METHODS)
def test_solve_matches_the_sphere_closed_form(method):
    a, F, rho, E = sphere_system()
    B, report = solve(F, rho, E, SolverSettings(method=method))
    expected = sphere_closed_form(a, rho, E)
    assert ((B - expected).abs() / expected).max() < 1e-6
    assert report.method == method and float(report.residual.max()) < 1e-9
    assert (report.iterations == 0) == (method == "direct")


@pytest.mark.parametrize("method", METHODS)
def test_gradients_match_the_closed_form_derivatives(method):
    """The full Jacobians dB/dE and dB/drho, by the adjoint system, against the closed forms."""
    a, F, rho, E = sphere_system(n=10)
    settings = SolverSettings(method=method)
    J_E, J_rho = torch.autograd.functional.jacobian(lambda r, e: solve(F, r, e, settings)[0], (rho, E))[::-1]
    # J[i, c, k, d] = dB_ic / dx_kd: zero unless c == d
    rho_bar = (a[:, None] * rho).sum(0)
    E_bar = (a[:, None] * E).sum(0)
    B_bar = E_bar / (1 - rho_bar)
    eye = torch.eye(len(a), dtype=torch.float64)
    for c in range(3):
        dB_dE = eye + rho[:, c, None] * a[None, :] / (1 - rho_bar[c])
        dB_drho = eye * B_bar[c] + rho[:, c, None] * E_bar[c] * a[None, :] / (1 - rho_bar[c]) ** 2
        for J, expected in ((J_E, dB_dE), (J_rho, dB_drho)):
            assert (J[:, c, :, c] - expected).abs().max() / expected.abs().max() < 1e-6
            others = [d for d in range(3) if d != c]
            assert J[:, c][:, :, others].abs().max() == 0


@pytest.mark.parametrize("method", ["direct", "gauss_seidel"])
def test_adjoint_gradient_passes_gradcheck(method):
    _, F, rho, E = sphere_system(n=6, seed=1)
    F = F * torch.linspace(0.5, 1.0, 6, dtype=torch.float64)[:, None]  # rows no longer alike, not closed
    rho.requires_grad_(True)
    E.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda r, e: solve(F, r, e, SolverSettings(method=method))[0], (rho, E))


def test_neumann_terms_sum_to_the_solution():
    _, F, rho, E = sphere_system(n=8)
    terms = neumann_terms(F, rho, E, 200)
    assert torch.allclose(terms[1], rho * (F @ E))
    B, _ = solve(F, rho, E)
    assert torch.allclose(terms.sum(0), B, rtol=1e-9)


def test_solver_settings_are_checked():
    _, F, rho, E = sphere_system(n=8)
    with pytest.raises(ParameterError, match="unknown radiosity solver method 'cg'"):
        SolverSettings(method="cg")
    with pytest.raises(ParameterError, match=r"tolerance must be a number in \(0, 1\)"):
        SolverSettings(tolerance=0)
    with pytest.raises(ParameterError, match="did not reach tolerance 1e-12 in 3 iterations"):
        solve(F, rho, E, SolverSettings(method="jacobi", tolerance=1e-12, max_iterations=3))
    with pytest.raises(ParameterError, match="shapes must be"):
        solve(F, rho[:4], E)
