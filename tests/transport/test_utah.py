"""The Utah approximation ``g eps + g M g eps + rho eps0`` (integrator "utah")."""

import math

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError, SceneError
from invrender.scene.camera import Camera
from invrender.scene.scene import AMBIENT, build_scene
from invrender.scene.shapes import Mesh, rectangle, scale, translate

RHO = (0.8, 0.5, 0.3)
EPS = (40.0, 30.0, 20.0)
SIDE, HEIGHT = 0.2, 1.0  # the emitter: a square of this side, this high above the plane's centre


def plane_under_light(resolution=(33, 33)):
    """A 4 x 4 diffuse plane at z = 0 under a small square emitter facing down; nothing else.

    The camera looks at the plane's centre from the side, so the centre pixel sees the point right
    under the emitter (and not the emitter's dark back)."""
    v, f, uv = rectangle()
    plane = Mesh(v, f, uv, "plane").transformed(scale(2.0))
    light = Mesh(v, f, uv, "light_back", "light").flipped().transformed(translate((0, 0, HEIGHT)) @ scale(SIDE / 2))
    camera = Camera(origin=(0.0, -2.5, 2.5), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov=40.0)
    return build_scene([plane, light], {"plane": RHO, "light_back": (0.0, 0.0, 0.0)}, {"light": EPS}, camera, resolution)


def form_factor_point_to_square(side: float, height: float) -> float:
    """Form factor from a point to a parallel square centred above it (Howell's corner-rectangle
    formula, four times): F = sum over 4 corners of (1 / 2 pi)[X/sqrt(1+X^2) atan(Y/sqrt(1+X^2)) + ...]."""
    X = Y = side / 2 / height
    a, b = math.sqrt(1 + X * X), math.sqrt(1 + Y * Y)
    return 4 * (X / a * math.atan(Y / a) + Y / b * math.atan(X / b)) / (2 * math.pi)


def test_utah_is_the_path_tracer_truncated_at_two_terms(cbox32):
    """Without ambient, utah is path at max_depth 2 (same seed: the very same estimate), whatever
    max_depth is asked for; with max_depth 1 only the emitters seen directly. (To float rounding:
    path's bounce is compiled, utah's is torch.)"""
    two = ir.render(cbox32, "path", spp=4, max_depth=2, seed=3, progress=False)
    torch.testing.assert_close(ir.render(cbox32, "utah", spp=4, max_depth=8, seed=3, progress=False), two, rtol=1e-5, atol=1e-7)
    torch.testing.assert_close(ir.render(cbox32, "utah", spp=4, max_depth=-1, seed=3, progress=False), two, rtol=1e-5, atol=1e-7)
    one = ir.render(cbox32, "path", spp=4, max_depth=1, seed=3, progress=False)
    torch.testing.assert_close(ir.render(cbox32, "utah", spp=4, max_depth=1, seed=3, progress=False), one, rtol=1e-5, atol=1e-7)
    terms = ir.render(cbox32, "utah", spp=4, seed=3, terms=True, progress=False)
    assert terms.shape == (2, 32, 32, 3)


def test_utah_matches_path_depth_2_within_monte_carlo_error():
    """Independent seeds: the difference of the two images' means is within 4 standard errors."""
    scene = plane_under_light()
    runs = [ir.render(scene, "utah", spp=16, seed=s, progress=False).mean(dim=(0, 1)) for s in range(4)]
    runs += [ir.render(scene, "path", spp=16, max_depth=2, seed=100 + s, progress=False).mean(dim=(0, 1)) for s in range(4)]
    utah, path = torch.stack(runs[:4]), torch.stack(runs[4:])
    se = torch.sqrt(utah.var(0) / 4 + path.var(0) / 4)
    assert ((utah.mean(0) - path.mean(0)).abs() <= 4 * se + 1e-6).all()


def test_direct_light_under_a_square_emitter_is_rho_eps_F():
    """The centre pixel sees the point under the emitter: radiance rho eps F with F the point-to-
    square form factor (docs/closed_forms.md#form-factors, Howell), to 1% (pixel footprint and noise are ~0.2%)."""
    scene = plane_under_light()
    image = ir.render(scene, "utah", spp=256, seed=0, progress=False)
    F = form_factor_point_to_square(SIDE, HEIGHT)
    expected = torch.tensor(RHO) * torch.tensor(EPS) * F
    assert torch.allclose(image[16, 16], expected, rtol=0.01)


def test_ambient_adds_rho_eps0_where_a_surface_is_seen():
    scene = plane_under_light(resolution=(24, 24))
    eps0 = (0.2, 0.4, 0.6)
    dark = ir.render(scene, "utah", spp=4, seed=1, progress=False)
    lit = ir.render(scene.with_ambient(eps0), "utah", spp=4, seed=1, progress=False)
    # each pixel gains rho eps0 times the fraction of its samples that hit the plane
    fraction = (lit - dark) / (torch.tensor(RHO) * torch.tensor(eps0))
    assert torch.allclose(fraction, fraction[..., :1].expand_as(fraction), atol=1e-5)  # the same in every channel
    assert fraction.min() >= -1e-6 and fraction.max() <= 1 + 1e-5
    assert (fraction[..., 0] > 1 - 1e-5).float().mean() > 0.3  # pixels wholly on the plane: exactly rho eps0
    assert (fraction[..., 0] == 0).any()  # pixels that miss it gain nothing
    # the path tracer ignores eps0: interreflection is computed, not assumed
    assert torch.equal(ir.render(scene.with_ambient(eps0), "path", spp=4, max_depth=2, seed=1, progress=False), dark)


@pytest.mark.parametrize("estimator", ["autodiff", "replay"])
def test_utah_gradient_in_eps0_rho_and_eps(cbox32, estimator):
    """d(sum of image)/d eps0 is the summed reflectance of what each pixel sees; replay equals
    autodiff for every parameter."""
    scene = cbox32.with_params({k: v.detach().clone() for k, v in cbox32.params.items()}).with_ambient((0.1, 0.2, 0.3))  # own leaves: cbox32 is shared
    for p in scene.params.values():
        p.requires_grad_(True)
    image = ir.render(scene, "utah", spp=4, seed=5, estimator=estimator, progress=False)
    image.sum().backward()
    grads = {k: v.grad.clone() for k, v in scene.params.items()}
    for p in scene.params.values():
        p.grad = None
    with torch.no_grad():
        reflected = ir.render(scene.with_ambient(1.0), "utah", spp=4, seed=5, progress=False) - ir.render(scene.with_ambient(0.0), "utah", spp=4, seed=5, progress=False)
    assert torch.allclose(grads[AMBIENT], reflected.sum(dim=(0, 1)), rtol=1e-4)
    if estimator == "replay":
        reference = ir.render(scene, "utah", spp=4, seed=5, estimator="autodiff", progress=False)
        reference.sum().backward()
        for k, v in scene.params.items():
            assert torch.allclose(grads[k], v.grad, rtol=1e-4, atol=1e-6), k


def test_ambient_value_checks(tmp_path):
    scene = ir.load_scene("cornell_box", resolution=(8, 8), ambient=0.25)
    assert torch.equal(scene.params[AMBIENT], torch.full((3,), 0.25))
    assert AMBIENT not in ir.load_scene("cornell_box", resolution=(8, 8)).params
    with pytest.raises(ParameterError, match="ambient.emission"):
        scene.with_ambient((-1.0, 0.0, 0.0))
    with pytest.raises(ParameterError, match="ambient.emission"):
        scene.with_ambient(np.zeros((2, 2, 3)))
    with pytest.raises(SceneError, match="reserved"):
        v, f, uv = rectangle()
        build_scene([Mesh(v, f, uv, "ambient")], {"ambient": 0.5}, {}, Camera(), (4, 4))


def test_toml_ambient_key(tmp_path):
    text = """
ambient = [0.1, 0.2, 0.3]
[materials.grey]
reflectance = 0.5
[[shapes]]
type = "rectangle"
material = "grey"
"""
    (tmp_path / "a.toml").write_text(text)
    scene = ir.load_scene(tmp_path / "a.toml", resolution=(4, 4))
    assert torch.allclose(scene.params[AMBIENT], torch.tensor([0.1, 0.2, 0.3]))
    (tmp_path / "b.toml").write_text(text.replace("[0.1, 0.2, 0.3]", '"bright"'))
    with pytest.raises(SceneError, match="ambient"):
        ir.load_scene(tmp_path / "b.toml")
