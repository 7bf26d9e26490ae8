"""The radiosity integrator and ir.radiosity: settings, errors, Neumann terms, estimators, textures."""

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError


@pytest.fixture(scope="module")
def cbox():
    return ir.load_scene("cornell_box", resolution=(12, 12))


def test_solution_fields(cbox):
    sol = ir.radiosity(cbox, patches=128, rays=64)
    S = sol.sides.shape[0]
    assert sol.B.shape == sol.rho.shape == sol.E.shape == (S, 3) and sol.F.shape == sol.F_stderr.shape == (S, S)
    assert sol.report.method == "direct" and float(sol.report.residual.max()) < 1e-12
    # rows sum to the share of the hemisphere that sees the scene (the box is open at the front); the
    # columns of the light come from its own rays by reciprocity, so rows are not exactly below 1
    assert 0.99 < float(sol.row_sum.max()) < 1.2 and float(sol.row_sum.min()) >= 0
    assert S < 2 * sol.patches.count  # back sides of the walls and the boxes' insides never receive light
    radiance = sol.side_radiance()
    assert radiance.shape == (2 * sol.patches.count, 3) and torch.equal(radiance[sol.sides], sol.B)
    img = sol.render(spp=2, progress=False)
    assert img.shape == (12, 12, 3) and torch.isfinite(img).all()


def test_bad_input_is_a_one_line_error(cbox):
    cases = [
        (dict(subdivision=0), r"radiosity subdivision must be an integer in \[1, 64\], got 0"),
        (dict(subdivision=65), r"radiosity subdivision must be an integer in \[1, 64\], got 65"),
        (dict(patches=0), r"radiosity patches must be an integer in \[1, 16384\], got 0"),
        (dict(subdivision=2, patches=100), "either subdivision .* or patches"),
        (dict(method="lu"), "unknown radiosity solver method 'lu'"),
        (dict(rays=0), "form factor rays must be an integer >= 1"),
        (dict(rr_depth=3), "integrator 'radiosity' has no setting 'rr_depth'"),
    ]
    for options, message in cases:
        with pytest.raises(ParameterError, match=message) as err:
            ir.render(cbox, "radiosity", spp=1, progress=False, **options)
        assert "\n" not in str(err.value)
    spec = ir.load_scene("cornell_specular", resolution=(8, 8), subdivisions=1)
    with pytest.raises(ParameterError, match="radiosity models diffuse surfaces only: material 'mirror' is mirror"):
        ir.radiosity(spec)
    with pytest.raises(ParameterError, match="not split into Neumann terms"):
        ir.render(cbox, "radiosity", spp=1, terms=True, progress=False)
    white = ir.load_scene("cornell_box", resolution=(8, 8))
    with torch.no_grad():
        white.params["white.reflectance"][:] = 1.0
    with pytest.raises(ParameterError, match="exact solve needs every reflectance below 1"):
        ir.radiosity(white, subdivision=1)
    ir.radiosity(white, subdivision=1, max_depth=8)  # a truncated series is fine


def test_neumann_terms_counted_as_the_path_tracer_counts_them(cbox):
    """max_depth D keeps D terms; term 0 is the emission seen, identical to the path tracer's for the
    same camera samples; the terms sum to the image."""
    kw = dict(spp=4, seed=1, subdivision=1, rays=64, progress=False)
    terms = ir.render(cbox, "radiosity", max_depth=4, terms=True, **kw)
    assert terms.shape == (4, 12, 12, 3)
    assert torch.allclose(terms.sum(0), ir.render(cbox, "radiosity", max_depth=4, **kw), atol=1e-6)
    path_terms = ir.render(cbox, "path", spp=4, seed=1, max_depth=2, terms=True, progress=False)
    assert torch.equal(terms[0], path_terms[0])
    assert torch.equal(ir.render(cbox, "radiosity", max_depth=1, **kw), terms[0])
    exact = ir.render(cbox, "radiosity", **kw)
    deep = ir.render(cbox, "radiosity", max_depth=200, **kw)
    assert torch.allclose(deep, exact, rtol=1e-4, atol=1e-6)
    gather = ir.render(cbox, "radiosity", max_depth=4, terms=True, final_gather=True, **kw)
    assert gather.shape == (4, 12, 12, 3) and torch.equal(gather[0], terms[0])


@pytest.mark.parametrize("final_gather", [False, True])
def test_replay_and_autodiff_give_the_same_exact_gradient(cbox, final_gather):
    """Path replay re-solves the system in its backward pass (cached form factors) and
    differentiates through the adjoint solve: the same gradient as autodiff."""
    names = ["white.reflectance", "red.reflectance", "light.emission"]
    grads = {}
    for estimator in ("autodiff", "replay"):
        params = {n: cbox.params[n].detach().clone().requires_grad_(True) for n in names}
        scene = ir.load_scene("cornell_box", resolution=(12, 12))
        scene.params.update(params)
        ir.render(scene, "radiosity", spp=4, subdivision=2, rays=64, final_gather=final_gather, estimator=estimator, progress=False).square().mean().backward()
        grads[estimator] = torch.cat([params[n].grad for n in names])
    assert float(grads["autodiff"].abs().min()) > 0
    torch.testing.assert_close(grads["replay"], grads["autodiff"], rtol=1e-5, atol=1e-9)


def test_gradient_matches_finite_differences(cbox):
    scene = ir.load_scene("cornell_box", resolution=(12, 12))
    rho = scene.params["red.reflectance"].requires_grad_(True)
    kw = dict(spp=2, subdivision=2, rays=64, progress=False)
    ir.render(scene, "radiosity", **kw).mean().backward()
    h = 1e-3
    with torch.no_grad():
        rho[1] += h
        up = ir.render(scene, "radiosity", **kw).double().mean()
        rho[1] -= 2 * h
        down = ir.render(scene, "radiosity", **kw).double().mean()
        rho[1] += h
    assert abs(float(rho.grad[1]) - float(up - down) / (2 * h)) < 1e-3 * abs(float(rho.grad[1]))


def test_textures_are_averaged_per_patch():
    """A uniform texture gives the constant's image, and its texels share the constant's gradient."""
    plain = ir.load_scene("cornell_box", resolution=(12, 12))
    textured = ir.load_scene("cornell_box", resolution=(12, 12))
    value = plain.params["white.reflectance"]
    texture = value.expand(4, 5, 3).clone().requires_grad_(True)
    textured.params["white.reflectance"] = texture
    value.requires_grad_(True)
    kw = dict(spp=2, subdivision=2, rays=64, progress=False)
    a = ir.render(plain, "radiosity", **kw)
    b = ir.render(textured, "radiosity", **kw)
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    a.sum().backward()
    b.sum().backward()
    torch.testing.assert_close(texture.grad.sum((0, 1)), value.grad, rtol=1e-4, atol=1e-6)


def test_path_records_refuse_radiosity(cbox):
    with pytest.raises(ParameterError, match="integrator .radiosity. cannot be recorded as path records .solver .lm., identifiability.: its image is a rational function"):
        ir.record_paths(cbox, ["red.reflectance"], spp=1, max_depth=2, integrator="radiosity", progress=False)


def test_solution_renders_as_the_integrator_does(cbox):
    sol = ir.radiosity(cbox, patches=128, rays=64)
    kw = dict(spp=2, seed=3, progress=False)
    assert torch.equal(sol.render(**kw), ir.render(cbox, "radiosity", patches=128, rays=64, **kw))
    with pytest.raises(ParameterError, match=r"^unknown render setting 'max_depth' of a radiosity solution \(known: spp, seed, device, "):
        sol.render(spp=1, max_depth=3)
