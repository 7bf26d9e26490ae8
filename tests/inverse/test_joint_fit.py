"""Joint lighting and materials (``ir.lighting.fit_joint``, ir.fit's ``solver="joint"``): an
environment map and two objects' reflectances from a few views, the floor's albedo known; the
global scale ambiguity refused in one line when nothing known fixes it."""

from __future__ import annotations

import math

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.inverse.joint_fit import _Anderson, scale_anchor
from invrender.inverse.targets import load_targets
from invrender.scene.camera import Camera

HIDDEN = {"type": "path", "hide_emitters": True}
FITTED = ["diffuse.reflectance", "glossy.specular_reflectance"]


def view(azimuth: float) -> Camera:
    a = math.radians(azimuth)
    return Camera(origin=(4.2 * math.sin(a), 0.35, 4.2 * math.cos(a)), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")


CAMERAS = [view(a) for a in (0.0, 120.0, 240.0)]


@pytest.mark.slow
def test_joint_fit_recovers_albedos_and_map_through_auto():
    """ir.fit's default routes a map plus two reflectances to the joint solve; with the floor's
    albedo known (the scale's anchor, named in the result) the albedos come within 6% and the
    relit image within 3% of the truth's (the acceptance case, 16x32 from four 64x64 views: bench/joint_lighting.py)."""
    truth = ir.load_scene("sky_spheres", resolution=(24, 24), map_size=(4, 8))
    targets = [ir.render(truth.with_camera(c), HIDDEN, spp=512, max_depth=3, seed=10 + i, progress=False) for i, c in enumerate(CAMERAS)]
    start = truth.with_params({"sky.emission": torch.ones(4, 8, 3), **{n: torch.full((3,), 0.5) for n in FITTED}})
    names = ["sky.emission", *FITTED]
    res = ir.fit(start, targets, names, cameras=CAMERAS, integrator=HIDDEN, max_depth=3, spp_final=96, progress=False, truth={n: truth.params[n] for n in FITTED})
    assert res.solver == "joint" and "bilinear" in res.solver_reason
    assert res.converged is True and 2 <= len(res.history) <= 8
    assert res.history[-1]["scale"] == "the known reflectance floor.reflectance"
    errors = {n: res.errors[n] for n in FITTED}
    assert max(errors.values()) < 0.06, errors  # measured 4.5% (diffuse red) at 24x24 pixels, 96 spp
    assert res.params["sky.emission"].shape == (4, 8, 3) and res.std_error["diffuse.reflectance"].shape == (3,)
    relit = ir.render(res.scene.with_camera(CAMERAS[0]), HIDDEN, spp=512, max_depth=3, seed=10, progress=False)
    assert abs(float(relit.mean() / targets[0].mean()) - 1) < 0.03


def test_scale_ambiguity_refused_in_one_line():
    """Every reflectance fitted, the map hidden: only the product is determined."""
    sky = ir.load_scene("sky_spheres", resolution=(8, 8), map_size=(3, 4))
    target = torch.full((8, 8, 3), 0.2)
    everything = ["floor.reflectance", *FITTED]
    with pytest.raises(ParameterError, match=r"^fit_joint: nothing fixes the scale between sky.emission and floor.reflectance, diffuse.reflectance, glossy.specular_reflectance \(the images determine their product, not the split\): keep one reflectance known") as e:
        ir.lighting.fit_joint(sky, target, "sky", everything, integrator=HIDDEN)
    assert "\n" not in str(e.value)
    # the same fit with the background counted: the map seen directly fixes it
    views = load_targets(sky, target, None)
    assert scale_anchor(sky, "sky", everything, views, {"type": "path"}).startswith("the map seen directly in ")
    assert scale_anchor(sky, "sky", everything, views, HIDDEN) is None
    assert scale_anchor(sky, "sky", FITTED, views, HIDDEN) == "the known reflectance floor.reflectance"
    with pytest.raises(ParameterError, match="solver 'joint' fits one environment map's texels with material reflectances"):
        ir.fit(sky, target, ["sky.emission"], solver="joint", progress=False)


def test_anderson_solves_a_linear_fixed_point():
    """The acceleration on a contraction G(x) = A x + b (factor 0.9): the fixed point in n + 2 steps."""
    g = torch.Generator().manual_seed(0)
    A = 0.9 * torch.linalg.qr(torch.randn(4, 4, generator=g, dtype=torch.float64))[0]
    b = torch.randn(4, generator=g, dtype=torch.float64)
    fixed = torch.linalg.solve(torch.eye(4, dtype=torch.float64) - A, b)
    x, steps = torch.zeros(4, dtype=torch.float64), _Anderson()
    for _ in range(6):
        x = steps.next(x, A @ x + b)
    torch.testing.assert_close(x, fixed)
