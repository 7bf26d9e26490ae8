"""Inverse lighting: an environment map recovered from images of known objects.

A diffuse and a glossy sphere on a large floor under a 4 x 8 map, seen from three views with the
map in the background. The images are linear in the texels (path records keep them exactly), so
``fit(..., solver="lm")`` solves for the map by Levenberg-Marquardt on records, with the Tikhonov
prior toward the start (FitSettings.prior_weight): the texels the views determine (standard error
below 2%) come back within 6% (median 2%), and the bottom row (theta 120-180 degrees, below the floor: no path
reaches it) stays at the prior and is reported undetermined, by the fit and by ``identifiability``.
"""

from __future__ import annotations

import math

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.inverse.least_squares import Prior, _Layout, neighbour_pairs
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.materials import Material
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, rectangle, rotate, scale, sphere, translate

PRIOR = 1.0


def lighting_scene(emission: torch.Tensor, resolution=(16, 16)):
    meshes = [
        Mesh(*sphere(2), material="matte").transformed(translate([-0.6, 0, 0]) @ scale(0.5)),
        Mesh(*sphere(2), material="gloss").transformed(translate([0.6, 0, 0]) @ scale(0.5)),
        Mesh(*rectangle(), material="floor").transformed(translate([0, -0.5, 0]) @ rotate([1, 0, 0], -90) @ scale(50.0)),
    ]
    materials = {
        "matte": Material.of(reflectance=[0.7, 0.7, 0.7]),
        "gloss": Material.of("glossy", specular_reflectance=[0.8, 0.8, 0.8], roughness=0.2),
        "floor": Material.of(reflectance=[0.4, 0.4, 0.4]),
    }
    return build_scene(meshes, materials, {"sky": Emitter.of("envmap", emission=emission)}, cameras(1)[0], resolution, name="inverse_lighting")


def cameras(n: int = 3) -> list[Camera]:
    """Views around the spheres, slightly above them, the sky behind."""
    return [Camera(origin=(3.5 * math.sin(2 * math.pi * k / n), 0.6, 3.5 * math.cos(2 * math.pi * k / n)), target=(0, 0.3, 0), up=(0, 1, 0), fov=60.0) for k in range(n)]


@pytest.fixture(scope="module")
def problem():
    truth = 0.5 + 2.0 * torch.rand(4, 8, 3, generator=torch.Generator().manual_seed(3))
    scene = lighting_scene(truth)
    views = cameras(3)
    targets = [ir.render(scene.with_camera(c), spp=1024, max_depth=3, seed=100 + i, progress=False) for i, c in enumerate(views)]
    return lighting_scene(torch.full((4, 8, 3), PRIOR)), targets, views, truth


@pytest.mark.slow
def test_lm_recovers_the_seen_texels_and_keeps_the_unseen_at_the_prior(problem):
    start, targets, views, truth = problem
    with pytest.warns(UserWarning, match=r"do not determine.*sky\.emission\[3,"):
        res = ir.fit(start, targets, ["sky.emission"], cameras=views, solver="lm", max_depth=3, spp=16, rounds=3, progress=False, truth={"sky.emission": truth})
    est, se = res.params["sky.emission"], res.std_error["sky.emission"]
    assert len(res.history) <= 3 and res.history[-1]["loss"] < res.history[0]["loss"]
    torch.testing.assert_close(est[3], torch.full_like(est[3], PRIOR), rtol=1e-6, atol=0)  # below the floor: the prior
    determined = se < 0.02 * est
    determined[3] = False  # held by the prior: standard error 0 (no Monte Carlo error), not seen
    assert int(determined.sum()) >= 30, int(determined.sum())  # of the 72 channels above the floor
    error = (est - truth).abs() / truth
    assert float(error[determined].max()) < 0.06 and float(error[determined].median()) < 0.02, error[determined]
    assert float(error[1:3].median()) < 0.05  # the rows the views see straight on (theta 60 and 120 degrees)


def test_identifiability_names_the_texels_no_view_sees(problem):
    start, targets, views, _ = problem
    ident = ir.identifiability(start, targets, ["sky.emission"], cameras=views, spp=16, max_depth=3)
    undetermined = {label for combo in ident.weak for label in combo}
    assert undetermined == {f"sky.emission[3,{j}][{c}]" for j in range(8) for c in "RGB"}, sorted(undetermined)
    assert "sky.emission[3,0][R]" in ident.describe()


def test_the_prior_is_a_relative_tikhonov_term():
    """Rows sqrt(lambda) (v - p) / p per channel, their Jacobian the diagonal sqrt(lambda) / p; the
    weight is checked as a fit setting."""
    scene = lighting_scene(torch.full((4, 8, 3), 2.0), resolution=(4, 4))
    rec = ir.record_paths(scene, ["sky.emission", "matte.reflectance"], spp=1, max_depth=2, progress=False)
    layout = _Layout.of(rec)
    p = torch.full((4, 8, 3), 2.0, dtype=torch.float64)
    prior = Prior({"sky.emission": p}, {"sky.emission": 4.0})
    values = {"sky.emission": p * 1.5, "matte.reflectance": torch.full((3,), 0.5, dtype=torch.float64)}
    torch.testing.assert_close(prior.residual(layout, values), torch.full((96,), 2.0 * 0.5, dtype=torch.float64))
    J = prior.jacobian(layout)
    assert J.shape == (96, 99) and float(J[:, 96:].abs().max()) == 0.0
    torch.testing.assert_close(J[:, :96], torch.eye(96, dtype=torch.float64) * 1.0)
    with pytest.raises(ParameterError, match="prior_weight must be >= 0"):
        ir.fit(scene, torch.zeros(4, 4, 3), ["sky.emission"], solver="lm", prior_weight=-1.0, progress=False)


def test_the_smoothness_prior_is_a_relative_difference_of_neighbours():
    """Rows sqrt(mu) (v_i - v_j) / sqrt(p_i p_j) per channel and pair of neighbouring texels (each
    row's next texel, wrapping in longitude; the texel below, not wrapping): 4 x 8 + 3 x 8 = 56
    pairs; zero on a constant map; their Jacobian the derivative of the residual, exactly."""
    pairs = neighbour_pairs(4, 8)
    assert pairs.shape == (56, 2)
    assert [7, 0] in pairs.tolist() and [0, 8] in pairs.tolist() and [24, 0] not in pairs.tolist()
    scene = lighting_scene(torch.full((4, 8, 3), 2.0), resolution=(4, 4))
    rec = ir.record_paths(scene, ["matte.reflectance", "sky.emission"], spp=1, max_depth=2, progress=False)
    layout = _Layout.of(rec)
    p = 1.0 + torch.rand(4, 8, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    prior = Prior({"sky.emission": p}, {"sky.emission": 0.0}, {"sky.emission": 9.0})
    rho = torch.full((3,), 0.5, dtype=torch.float64)
    flat = torch.full((4, 8, 3), 3.0, dtype=torch.float64)
    v = p * (1 + 0.1 * torch.randn(4, 8, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2)))
    r = prior.residual(layout, {"sky.emission": v, "matte.reflectance": rho})
    assert r.shape == (56 * 3,)
    i, j = int(pairs[5, 0]), int(pairs[5, 1])
    a, b = v.reshape(-1, 3), p.reshape(-1, 3)
    torch.testing.assert_close(r[15:18], 3.0 * (a[i] - a[j]) / (b[i] * b[j]).sqrt())
    assert float(Prior({"sky.emission": flat}, {"sky.emission": 0.0}, {"sky.emission": 9.0}).residual(layout, {"sky.emission": flat, "matte.reflectance": rho}).abs().max()) == 0.0
    J = prior.jacobian(layout)
    auto = torch.autograd.functional.jacobian(lambda x: prior.residual(layout, {"sky.emission": x[3:].reshape(4, 8, 3), "matte.reflectance": x[:3]}), torch.cat([rho, v.reshape(-1)]))
    assert J.shape == (168, 99)
    torch.testing.assert_close(J, auto)
    with pytest.raises(ParameterError, match="smoothness must be >= 0"):
        ir.fit(scene, torch.zeros(4, 4, 3), ["sky.emission"], solver="lm", smoothness=-1.0, progress=False)
