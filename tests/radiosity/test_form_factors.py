"""Ray-cast form factors against Howell's closed forms (docs/closed_forms.md#form-factors), their
stated standard errors, reciprocity, and the tessellated sphere converging to ``F_ij = a_j``."""

import math

import pytest
import torch

import invrender as ir
from invrender.scene.scene import build_scene
from invrender.scene.shapes import primitive, rotate, scale, translate
from invrender.backends.accel import make_intersector
from invrender.radiosity_solver import FormFactorSettings, form_factors, mesh_patches
from invrender.radiosity_solver.patches import grid_triangles
from tests.radiosity.conftest import area_fractions, hemispheres


def parallel_squares(X: float, Y: float) -> float:
    """Howell: directly opposed parallel rectangles, sides X, Y in units of their distance."""
    x2, y2 = 1 + X * X, 1 + Y * Y
    return (2 / (math.pi * X * Y)) * (
        math.log(math.sqrt(x2 * y2 / (x2 + Y * Y)))
        + X * math.sqrt(y2) * math.atan(X / math.sqrt(y2))
        + Y * math.sqrt(x2) * math.atan(Y / math.sqrt(x2))
        - X * math.atan(X)
        - Y * math.atan(Y)
    )


def perpendicular_squares(W: float, H: float) -> float:
    """Howell: perpendicular rectangles with a common edge, W and H in units of the edge."""
    w2, h2 = W * W, H * H
    log = math.log(
        (1 + w2) * (1 + h2) / (1 + w2 + h2)
        * (w2 * (1 + w2 + h2) / ((1 + w2) * (w2 + h2))) ** w2
        * (h2 * (1 + h2 + w2) / ((1 + h2) * (h2 + w2))) ** h2
    )  # fmt: skip
    return (W * math.atan(1 / W) + H * math.atan(1 / H) - math.sqrt(h2 + w2) * math.atan(1 / math.sqrt(h2 + w2)) + log / 4) / (math.pi * W)


def square_pair(second) -> tuple:
    """Unit square "a" = [0, 1]^2 at z = 0 facing +z and unit square "b" placed by ``second`` (a
    transform of Mitsuba's rectangle [-1, 1]^2), one patch per triangle; their form factors."""
    a = primitive("rectangle", "a").transformed(translate([0.5, 0.5, 0]) @ scale(0.5))
    b = primitive("rectangle", "b").transformed(second @ scale(0.5))
    scene = build_scene([a, b], {"a": 0.5, "b": 0.5}, {}, ir.Camera(), (4, 4))
    patches = mesh_patches(scene.triangles, subdivision=1)
    factors = form_factors(patches, make_intersector(scene.triangles, "embree"), FormFactorSettings(rays=65536, batches=8), 1e-5)
    side = torch.arange(2 * patches.count)
    material = scene.triangles.material[patches.tri[side // 2]]
    front = side % 2 == 0
    return factors, front & (material == 0), front & (material == 1)


@pytest.mark.parametrize(
    "case, second, expected",
    [
        ("parallel, distance 1", translate([0.5, 0.5, 1]) @ rotate([1, 0, 0], 180), 0.19982),
        ("perpendicular, common edge", translate([0, 0.5, 0.5]) @ rotate([0, 1, 0], 90), 0.20004),
    ],
)
def test_unit_square_form_factors(case, second, expected):
    """Within 0.5% of Howell's values, and the stated standard error is honest (the error is within
    4 of them) and small (below 0.25%)."""
    closed = parallel_squares(1, 1) if case.startswith("parallel") else perpendicular_squares(1, 1)
    assert abs(closed - expected) < 1e-5  # the catalogue's figures follow from its formulas
    factors, a, b = square_pair(second)
    F_ab, se = factors.group(a, b)
    assert abs(F_ab / expected - 1) < 0.005, (case, F_ab, se)
    assert abs(F_ab - expected) < 4 * se and se / expected < 0.0025
    # reciprocity A_a F_ab = A_b F_ba (equal areas), within the errors
    F_ba, se_ba = factors.group(b, a)
    assert abs(F_ab - F_ba) < 4 * math.hypot(se, se_ba)
    # the dense matrix and its errors agree with the group estimate
    F = factors.matrix()
    area = factors.area.double()
    assert abs(float((area[a, None] * F[a][:, b]).sum() / area[a].sum()) - F_ab) < 1e-12
    assert factors.stderr().shape == F.shape and float(factors.stderr()[a][:, b].max()) > 0


def test_tessellated_sphere_converges_to_area_fractions():
    """Inside a closed sphere ``F_(i->k) = a_k`` from anywhere; a flat icosphere differs by O(h^2)
    (4x less per subdivision level), and every ray hits something (row sums 1)."""
    deviations = []
    for level in (0, 1, 2):
        scene = hemispheres(level)
        patches = mesh_patches(scene.triangles, subdivision=1)
        factors = form_factors(patches, make_intersector(scene.triangles, "embree"), FormFactorSettings(rays=2048, batches=8), 1e-5)
        side = torch.arange(2 * patches.count)
        material = scene.triangles.material[patches.tri[side // 2]]
        front = side % 2 == 0
        F, se = factors.group(front & (material == 1), front & (material == 0))  # south -> north
        deviations.append(F - float(area_fractions(scene)[0]))
        assert se < 0.2 * abs(deviations[-1])
        assert torch.allclose(factors.row_sum()[front], torch.ones(patches.count, dtype=torch.float64))
    assert abs(deviations[0]) > 2.5 * abs(deviations[1]) > 2.5**2 * abs(deviations[2])
    assert abs(deviations[2]) < 0.003


def test_patches_tile_their_triangles():
    """Subdivision n gives n^2 congruent patches per triangle, and every point finds its own patch."""
    corners = grid_triangles(5)
    assert corners.shape == (25, 3, 2)
    scene = ir.load_scene("cornell_box", resolution=(4, 4))
    patches = mesh_patches(scene.triangles, subdivision=3)
    assert patches.count == 9 * scene.triangles.count
    assert torch.allclose(patches.area.double().reshape(-1, 9).sum(1), scene.triangles.area.double(), rtol=1e-6)
    centroid = patches.corners.mean(1)
    assert torch.equal(patches.locate(scene.triangles, patches.tri, centroid), torch.arange(patches.count))
    target = mesh_patches(scene.triangles, patches=500)
    assert 400 < target.count < 600
