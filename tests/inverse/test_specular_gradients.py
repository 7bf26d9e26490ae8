"""Gradients through every material and every integrator: each estimator against central finite
differences with common random numbers, and path replay against autodiff.

Sampling never depends on a parameter (cosine and GGX visible-normal sampling read the roughness
only, glass picks reflection with the Fresnel term of its constant ior, emitters are picked by
detached power), so below the roulette start the estimate is a polynomial in the parameters and
finite differences with the same seed are exact up to O(h^2) and float rounding.
"""

import pytest

import invrender as ir

PARAMS = ["white.reflectance", "red.reflectance", "light.emission", "mirror.specular_reflectance", "glossy.specular_reflectance"]


@pytest.fixture(scope="module")
def specular_rows():
    scene = ir.load_scene("cornell_specular", resolution=(24, 24), subdivisions=2)
    return ir.gradcheck(scene, PARAMS, spp=32, max_depth=4, seed=3)


def test_specular_cornell_gradients_match_finite_differences(specular_rows):
    """Diffuse reflectance, emission and specular reflectance of the mirror and the glossy block,
    through the path tracer: within 2% of central differences for both estimators."""
    assert {r.name for r in specular_rows} == set(PARAMS)
    for r in specular_rows:
        for estimator, err in r.rel_errors.items():
            assert err < 0.02, (r.name, r.index, estimator, r.fd, r.gradients)


def test_specular_cornell_replay_equals_autodiff(specular_rows):
    for r in specular_rows:
        a, b = r.gradients["autodiff"], r.gradients["replay"]
        assert abs(a - b) <= 1e-5 * max(abs(a), 1e-3), (r.name, r.index, a, b)


@pytest.mark.parametrize("integrator", ["whitted", "distributed", "utah", "random_walk"])
def test_every_integrator_is_differentiable(integrator):
    """Whitted's split paths (replay gives each branch its own film index), distributed's ended
    diffuse paths and the ambient term: replay = autodiff, and both match finite differences."""
    scene = ir.load_scene("cornell_specular", resolution=(16, 16), subdivisions=1, ambient=0.05)
    params = ["white.reflectance", "light.emission", "mirror.specular_reflectance"]
    if integrator != "random_walk":
        params.append("ambient.emission")
    if integrator in ("distributed", "random_walk"):
        params.append("glossy.specular_reflectance")
    rows = ir.gradcheck(scene, params, spp=16, max_depth=4, seed=5, integrator=integrator)
    for r in rows:
        if abs(r.fd) < 1e-3:  # components no pixel depends on measurably
            continue
        assert r.rel_errors["autodiff"] < 0.02 and r.rel_errors["replay"] < 0.02, (r.name, r.index, r.fd, r.gradients)
        a, b = r.gradients["autodiff"], r.gradients["replay"]
        assert abs(a - b) <= 1e-5 * max(abs(a), 1e-3), (r.name, r.index, a, b)
