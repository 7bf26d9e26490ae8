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
from invrender.inverse.least_squares import Prior, _Layout
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
