"""Reconstruction filters and film options: Mitsuba 3's six filters (weights by hand), the splat
and its per-pixel normalization, sample_border, crop windows, and every estimator following the
filter (replay = autodiff, finite differences, path records' Jacobian)."""

import dataclasses
import math

import pytest
import torch
import torch.autograd.forward_ad as fwAD

import invrender as ir
from invrender.core.driver import RenderSettings, film_weights, total_paths
from invrender.errors import InvRenderError, ParameterError, SceneError
from invrender.plugins.filters import make_filter
from invrender.scene.film import FilmOptions

FILTERS = ("box", "tent", "gaussian", "mitchell", "catmullrom", "lanczos")
PARAMS = ["white.reflectance", "red.reflectance", "light.emission"]


def with_filter(scene, spec, sample_border=False):
    return dataclasses.replace(scene, film=FilmOptions(make_filter(spec), sample_border))


def test_filter_weights_by_hand():
    """Each 1-D weight against values worked out from the definitions (Mitsuba's src/rfilters)."""
    x = lambda *v: torch.tensor(v, dtype=torch.float64)  # noqa: E731
    ev = lambda name, *v: make_filter(name).eval(x(*v)).tolist()  # noqa: E731
    assert ev("box", -0.5, 0.0, 0.49, 0.5) == [1.0, 1.0, 1.0, 0.0]
    assert ev("tent", 0.0, 0.25, -0.5, 1.0, 1.5) == pytest.approx([1.0, 0.75, 0.5, 0.0, 0.0])
    # gaussian, stddev 1/2: exp(-2 x^2) - exp(-8), clamped at 0 beyond r = 2
    assert ev("gaussian", 0.0, 1.0, 2.0, 2.5) == pytest.approx([1 - math.exp(-8), math.exp(-2) - math.exp(-8), 0.0, 0.0], abs=1e-12)
    # mitchell B = C = 1/3: 16/18 at 0, 1/18 at 1, -5/144 at 1.5
    assert ev("mitchell", 0.0, 1.0, -1.5, 2.0) == pytest.approx([8 / 9, 1 / 18, -5 / 144, 0.0])
    # catmull-rom: 1 at 0, 9/16 at 1/2, 0 at 1, -1/16 at 1.5
    assert ev("catmullrom", 0.0, 0.5, 1.0, 1.5) == pytest.approx([1.0, 0.5625, 0.0, -0.0625], abs=1e-12)
    # lanczos, 3 lobes: sinc(x) sinc(x / 3): 6 / pi^2 at 1/2, 0 at the integers, 0 beyond 3
    assert ev("lanczos", 0.0, 0.5, 1.0, 3.5) == pytest.approx([1.0, 6 / math.pi**2, 0.0, 0.0], abs=1e-12)
    radii = {n: make_filter(n).radius for n in FILTERS}
    assert radii == {"box": 0.5, "tent": 1.0, "gaussian": 2.0, "mitchell": 2.0, "catmullrom": 2.0, "lanczos": 3.0}
    assert [make_filter(n).border_size for n in FILTERS] == [0, 1, 2, 2, 2, 3]  # Mitsuba's ceil(r - 1/2)
    assert make_filter({"type": "gaussian", "stddev": 0.3}).radius == pytest.approx(1.2)


def test_footprint_reaches_the_pixels_within_the_radius_and_gather_is_its_adjoint():
    f = make_filter("gaussian")
    xy = torch.tensor([[2.5, 2.5], [0.2, 3.9], [7.99, 0.01]])
    fp = f.footprint(xy, 8, 6)
    # the sample at a pixel centre (2.5, 2.5): centres within 2 pixels, columns and rows 0..4
    row = fp.weight[0].reshape(5, 5)
    assert row.sum() == pytest.approx(sum(f.eval(torch.tensor([float(i)], dtype=torch.float64)).item() for i in range(-2, 3)) ** 2)
    assert sorted(set(fp.index[0][fp.weight[0] > 0].tolist())) == sorted(r * 8 + c for r in range(1, 4) for c in range(1, 4))  # f(2) = 0
    assert (fp.index >= 0).all() and (fp.index < 48).all()
    # <splat(v), g> = <v, gather(g)>
    v, g = torch.rand(3, 3, dtype=torch.float64), torch.rand(48, 3, dtype=torch.float64)
    out = torch.zeros(48, 3, dtype=torch.float64)
    fp.splat(v, out)
    assert (out * g).sum().item() == pytest.approx((v * fp.gather(g)).sum().item(), rel=1e-12)


@pytest.mark.parametrize("name", FILTERS)
@pytest.mark.parametrize("border", [False, True])
def test_a_constant_image_stays_constant(name, border):
    """Every sample of the furnace at max_depth 1 sees eps exactly: the normalized splat keeps
    every pixel at eps, at the edges too (with or without sample_border), for filters with
    negative lobes as well."""
    scene = with_filter(ir.load_scene("furnace", resolution=(9, 7), rho=0.5, eps=1.5), name, border)
    image = ir.render(scene, spp=3, max_depth=1, progress=False)
    assert image.shape == (7, 9, 3)
    assert torch.allclose(image, torch.full_like(image, 1.5), rtol=1e-5)


def test_box_is_todays_render_bit_for_bit(cbox32):
    plain = ir.render(cbox32, spp=4, max_depth=3, seed=2, progress=False)
    assert torch.equal(ir.render(cbox32, spp=4, max_depth=3, seed=2, progress=False, filter="box"), plain)
    assert torch.equal(ir.render(with_filter(cbox32, "box", sample_border=True), spp=4, max_depth=3, seed=2, progress=False), plain)


def test_filtered_render_is_the_box_render_smoothed(cbox32):
    """Same mean radiance as the box (the filters preserve a constant), but less noise and softer
    edges; the gaussian from ir.render(filter=...) equals the scene's own."""
    box = ir.render(cbox32, spp=16, max_depth=3, progress=False)
    gauss = ir.render(cbox32, spp=16, max_depth=3, progress=False, filter={"type": "gaussian", "stddev": 0.5})
    assert torch.equal(gauss, ir.render(with_filter(cbox32, "gaussian"), spp=16, max_depth=3, progress=False))
    assert gauss.mean().item() == pytest.approx(box.mean().item(), rel=0.02)
    tv = lambda im: (im[1:] - im[:-1]).abs().mean() + (im[:, 1:] - im[:, :-1]).abs().mean()  # noqa: E731
    assert tv(gauss) < 0.8 * tv(box)


def test_sample_border_traces_the_border_and_evens_the_weights(cbox32):
    scene = with_filter(cbox32, "gaussian", sample_border=True)
    settings = RenderSettings(spp=64, progress=False)
    assert total_paths(scene, settings) == 36 * 36 * 64 and total_paths(with_filter(cbox32, "gaussian"), settings) == 32 * 32 * 64
    W = film_weights(scene, settings, torch.device("cpu")).reshape(32, 32)
    W0 = film_weights(with_filter(cbox32, "gaussian"), settings, torch.device("cpu")).reshape(32, 32)
    interior = W[8:24, 8:24].mean()
    assert W[0, 0] == pytest.approx(interior.item(), rel=0.02)  # every pixel gets the samples around it
    # without the border a corner gets the samples of one quadrant: P(Z > -1)^2 = 0.71 of the weight (stddev 1/2)
    assert W0[0, 0] / interior == pytest.approx(0.8413**2, abs=0.02) and W0[8:24, 8:24].mean() == pytest.approx(interior.item(), rel=1e-3)


@pytest.mark.parametrize("name", ["gaussian", "mitchell"])
def test_replay_equals_autodiff(cbox32, name):
    scene = with_filter(cbox32.with_resolution((12, 12)), name, sample_border=True)
    target = torch.rand(12, 12, 3, generator=torch.Generator().manual_seed(1))
    grads = {}
    for estimator in ("autodiff", "replay"):
        params = {k: v.detach().clone().requires_grad_(k in PARAMS) for k, v in scene.params.items()}
        image = ir.render(dataclasses.replace(scene, params=params), spp=4, max_depth=4, estimator=estimator, progress=False)
        ((image - target) ** 2).sum().backward()
        grads[estimator] = torch.cat([params[k].grad for k in PARAMS])
    a, b = grads["autodiff"], grads["replay"]
    assert torch.allclose(a, b, rtol=1e-5, atol=1e-5 * a.abs().max().item())


@pytest.mark.parametrize("name", ["gaussian", "mitchell"])
def test_gradients_match_finite_differences(cbox32, name):
    scene = with_filter(cbox32.with_resolution((16, 16)), name)
    rows = ir.gradcheck(scene, ["red.reflectance", "light.emission"], spp=16, max_depth=3, seed=4, max_components=3)
    assert sum(abs(r.fd) >= 1e-3 for r in rows) >= 5
    for r in rows:
        if abs(r.fd) < 1e-3:
            continue
        assert r.rel_errors["autodiff"] < 0.02 and r.rel_errors["replay"] < 0.02, (r.name, r.index, r.fd, r.gradients)


@pytest.mark.parametrize("name", ["gaussian", "mitchell"])
def test_records_jacobian_is_autodiffs_per_pixel_derivative(cbox32, name):
    scene = with_filter(cbox32.with_resolution((12, 12)), name, sample_border=True)
    records = ir.record_paths(scene, PARAMS, spp=4, max_depth=3, progress=False)
    image = ir.render(scene, spp=4, max_depth=3, progress=False, rr_depth=100)
    assert torch.allclose(records.image().float(), image, rtol=1e-5, atol=1e-6)
    J = records.jacobian()
    for name_ in ("red.reflectance", "light.emission"):
        params = {k: v.detach().clone() for k, v in scene.params.items()}
        with torch.no_grad(), fwAD.dual_level():
            params[name_] = fwAD.make_dual(params[name_], torch.ones(3))
            tangent = fwAD.unpack_dual(ir.render(dataclasses.replace(scene, params=params), spp=4, max_depth=3, progress=False, rr_depth=100)).tangent
        assert torch.allclose(J[name_].float(), tangent, rtol=1e-5, atol=1e-6 * tangent.abs().max().item())


def test_crop_window_keeps_the_full_films_projection(tmp_path):
    full = tmp_path / "full.toml"
    body = '[materials.white]\nreflectance = 0.5\n[emitters.light]\nemission = 1\n[[shapes]]\ntype = "rectangle"\nmaterial = "white"\nemitter = "light"\n'
    full.write_text("resolution = [32, 24]\n" + body)
    crop = tmp_path / "crop.toml"
    crop.write_text('resolution = [32, 24]\n[film]\ncrop_offset = [5, 7]\ncrop_size = [12, 10]\n' + body)
    a, b = ir.load_scene(full), ir.load_scene(crop)
    assert b.resolution == (12, 10)
    xy = torch.rand(64, 2) * torch.tensor([12.0, 10.0])
    da = a.camera.generate_rays(xy + torch.tensor([5.0, 7.0]), 32, 24)[1]
    db = b.camera.generate_rays(xy, 12, 10)[1]
    assert torch.allclose(da, db, atol=1e-6)
    with pytest.warns(UserWarning, match="crop window is dropped"):
        assert ir.load_scene(crop, resolution=(16, 12)).resolution == (16, 12)


def test_bad_filters_and_film_options_are_one_line_errors(cbox32, tmp_path):
    cases = [
        ("gauss", "unknown reconstruction filter 'gauss' (did you mean 'gaussian'?)"),
        ({"type": "gaussian", "stddev": -0.5}, "stddev must be a number in (0, 4]"),
        ({"type": "tent", "radius": 1e9}, "radius must be a number in (0, 16]"),
        ({"type": "tent", "radius": float("nan")}, "radius must be a number"),
        ({"type": "lanczos", "lobes": 0}, "lobes must be an integer in [1, 16]"),
        ({"type": "mitchell", "b": 0.3}, "has no setting 'b'"),
        (7, "expected a filter name"),
    ]
    for spec, message in cases:
        with pytest.raises(ParameterError) as e:
            ir.render(cbox32, spp=1, filter=spec, progress=False)
        assert message in str(e.value) and "\n" not in str(e.value)
    body = '[materials.white]\nreflectance = 0.5\n[[shapes]]\ntype = "rectangle"\nmaterial = "white"\n'
    for film, message in (('crop_offset = [30, 0]\ncrop_size = [8, 8]', "must be whole pixels inside the 32x24 film"), ('filter = "sinc"', "unknown reconstruction filter 'sinc'"), ('sample_border = 1', "'sample_border' must be true or false")):
        path = tmp_path / "bad.toml"
        path.write_text(f"resolution = [32, 24]\n[film]\n{film}\n" + body)
        with pytest.raises(SceneError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
            ir.load_scene(path)
    gauss = with_filter(cbox32, "gaussian")
    with pytest.raises(InvRenderError, match="adaptive sampling supports the box filter only"):
        ir.render(gauss, spp=4, adaptive=True, progress=False)
