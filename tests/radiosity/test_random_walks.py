"""Neumann-Ulam random walks (docs/closed_forms.md#random-walks): their means against the direct
solve, and the variance condition (spectral radius of m_ij^2 / p_ij below 1) enforced before a walk."""

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.radiosity_solver import neumann_ulam, transition_matrix, variance_radius
from tests.radiosity.conftest import sphere_closed_form, sphere_system


def walk_problem(n=12):
    """The sphere interior with exact form factors: M = diag(rho) F per channel, (3, n, n)."""
    a, F, rho, E = sphere_system(n=n, seed=2)
    return a, rho.T[:, :, None] * F[None], E.T.contiguous(), sphere_closed_form(a, rho, E).T


@pytest.mark.parametrize("estimator", ["collision", "absorption"])
@pytest.mark.parametrize("transition", ["analog", "uniform", "matrix"])
def test_walk_means_agree_with_the_direct_solve(estimator, transition):
    """Every state's estimate within 4.5 standard errors (36 of them), and the area-weighted mean
    B_bar within 3."""
    a, M, E, x = walk_problem()
    P = torch.full_like(M[0], 0.7 / M.shape[1]) if transition == "matrix" else transition  # survive with 0.7
    est = neumann_ulam(M, E, P, estimator, walks=3000, seed=3)
    assert est.mean.shape == est.stderr.shape == (3, 12)
    assert (est.variance_radius < 1).all()
    z = (est.mean - x) / est.stderr
    assert z.abs().max() < 4.5, z
    mean, se = (a * est.mean).sum(1), ((a * est.stderr) ** 2).sum(1).sqrt()
    assert ((mean - (a * x).sum(1)).abs() < 3 * se).all()


def test_analog_walk_has_unit_weights_and_the_matrix_itself_as_variance_matrix():
    _, M, _, _ = walk_problem()
    P = transition_matrix(M, "analog")
    assert torch.equal(P, M)
    assert torch.allclose(variance_radius(M, P), torch.linalg.eigvals(M).abs().amax(-1))


def test_a_transition_matrix_with_infinite_variance_is_refused_before_walking():
    _, M, E, _ = walk_problem()
    n = M.shape[1]
    P = torch.full((n, n), 0.9 / n, dtype=torch.float64)
    P[:, 0] = 1e-4  # state 0 hardly ever visited: its weight m/p is huge
    P = P / P.sum(1, keepdim=True) * 0.9
    with pytest.raises(ParameterError, match=r"infinite variance: spectral radius of m_ij\^2/p_ij is [0-9.]+ >= 1 in channel [RGB]"):
        neumann_ulam(M, E, P)
    assert (variance_radius(M, P.expand_as(M)) > 1).any()


def test_bad_transition_matrices_are_one_line_errors():
    _, M, E, _ = walk_problem(n=4)
    cases = [
        (torch.full((3, 3), 0.1), r"must have shape \(4, 4\) or \(3, 4, 4\), got \(3, 3\)"),
        (torch.full((4, 4), 0.1) - torch.eye(4) * 0.2, "negative entries"),
        (torch.full((4, 4), 0.3), "row 0 sums to 1.2 > 1"),
        (torch.full((4, 4), 0.1) * (1 - torch.eye(4)), r"p\[0, 0\] is 0 where m\[0, 0\]"),
    ]
    for P, message in cases:
        with pytest.raises(ParameterError, match=message) as err:
            neumann_ulam(M, E, P)
        assert "\n" not in str(err.value)
    with pytest.raises(ParameterError, match="unknown random-walk estimator 'track'"):
        neumann_ulam(M, E, estimator="track")
    with pytest.raises(ParameterError, match="unknown transition 'greedy'"):
        neumann_ulam(M, E, "greedy")


def test_radiosity_solution_walks_agree_with_its_solve():
    """The Cornell box coarsely meshed: walks on its own system (M = diag(rho) F) against its B."""
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    sol = ir.radiosity(scene, subdivision=1, rays=64)
    est = sol.random_walk(walks=400, seed=1)
    B = sol.B.detach().T
    a = sol.area.double() / sol.area.double().sum()
    mean, se = (a * est.mean).sum(1), ((a * est.stderr) ** 2).sum(1).sqrt()
    assert ((mean - (a * B).sum(1)).abs() < 3 * se).all(), (mean, (a * B).sum(1), se)
    # uniform transitions over a row's very unequal form factors: m_ij^2 / p_ij has radius 1.3 here
    with pytest.raises(ParameterError, match=r"spectral radius of m_ij\^2/p_ij is 1\.[0-9]+ >= 1 in channel R"):
        sol.random_walk(transition="uniform")
