"""The fused primal bounce against the torch bounce it stands for (kept as the reference) and the
camera samples compiled against their eager torch evaluation: the same images within float
rounding, the camera's numbers bit for bit (and as the former torch expressions gave them), and
the torch bounce wherever the fused one does not apply."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

import invrender as ir
from invrender.core import driver, fused
from invrender.backends import arrays, kernels
from invrender.core.context import TransportContext
from invrender.core.driver import RenderSettings
from invrender.core.film import Film, PathFilm
from invrender.plugins.integrators import make_integrator

FORWARD = Path(__file__).resolve().parents[2] / "forward"
CPU = torch.device("cpu")


@pytest.fixture
def unfused(monkeypatch):
    """Call it to trace with the torch bounce (the kernels of single steps stay on)."""

    def off() -> None:
        monkeypatch.setenv(kernels.ENV, "steps")

    return off


def _fused_scene(scene, integrator="path", **options):
    integ = make_integrator(integrator, **options)
    ctx = integ.context(scene, RenderSettings(spp=1), CPU)
    return fused.tables(ctx, integ.fused_direct, integ.bsdf_sampling.hemisphere)


@pytest.mark.parametrize(
    "integrator, options",
    [("path", {}), ("path", {"strategy": "emitter"}), ("path", {"strategy": "bsdf"}), ("random_walk", {}), ("path", {"max_depth": 3, "rr_depth": -1})],
)
def test_the_fused_bounce_renders_the_torch_bounces_image(integrator, options, unfused):
    scene = ir.load_scene("cornell_box" if options.get("strategy") != "emitter" else str(FORWARD / "mesh_in_box.toml"), resolution=(24, 24))
    assert _fused_scene(scene, integrator, **options) is not None
    kw = dict(spp=16, seed=5, progress=False, integrator=integrator, **options)
    image = ir.render(scene, **kw)
    terms = ir.render(scene, terms=True, **kw)
    unfused()
    expected = ir.render(scene, **kw)
    expected_terms = ir.render(scene, terms=True, **kw)
    assert float(expected.mean()) > 0.05
    # float rounding (a roulette decision it flips changes one path: none did at this seed)
    assert (image - expected).abs().max() < 1e-5 * float(expected.max())
    assert terms.shape == expected_terms.shape and (terms - expected_terms).abs().max() < 1e-5 * float(expected.max())
    assert float(terms[2].mean()) > 0.01  # the indirect terms were traced


def test_hide_emitters_under_a_sky_takes_the_fused_bounce(unfused):
    """Without emitting shapes, hiding the emitters only drops the camera rays that leave the
    scene: the fused bounce does that, with the torch bounce's image."""
    from invrender.scene.builtin import sky_map, sky_spheres

    scene = sky_spheres((16, 16), (4, 8), subdivisions=2, sky=sky_map(4, 8))
    hidden = dict(integrator="path", hide_emitters=True)
    assert _fused_scene(scene, **hidden) is not None
    kw = dict(spp=8, seed=3, progress=False, max_depth=4, **hidden)
    image = ir.render(scene, **kw)
    seen = ir.render(scene, spp=8, seed=3, progress=False, max_depth=4)
    unfused()
    expected = ir.render(scene, **kw)
    assert float(expected.mean()) > 0.02 and float((seen - image).amax()) > 0.1  # the sky is hidden behind the spheres' edges
    assert (image - expected).abs().max() < 1e-5 * float(expected.max())


def test_the_fused_bounce_applies_only_where_nothing_needs_the_torch_bounce(tmp_path, monkeypatch):
    box = ir.load_scene("cornell_box", resolution=(8, 8))
    assert _fused_scene(box) is not None
    for choice in ("steps", "torch"):  # switched off (both names say the same now)
        monkeypatch.setenv(kernels.ENV, choice)
        assert _fused_scene(box) is None and not kernels.fused_bounce(CPU)
    monkeypatch.delenv(kernels.ENV)
    assert _fused_scene(box, "path", hemisphere="uniform") is not None  # the lane form samples as the BSDF does
    assert _fused_scene(box, "utah") is None  # a vertex step of its own
    assert _fused_scene(box, "path", hide_emitters=True) is None
    assert _fused_scene(ir.load_scene(str(FORWARD / "mesh_in_box.toml"), resolution=(8, 8))) is not None  # flat meshes: yes
    assert _fused_scene(ir.load_scene(str(FORWARD / "textured_floor.toml"), resolution=(8, 8))) is not None  # textures: yes
    assert _fused_scene(ir.load_scene("cornell_specular", resolution=(8, 8))) is not None  # mirror, glass, GGX: in lane form
    # a plugin built on the diffuse BSDF that changes what it does: its own methods, the torch bounce
    from invrender.plugins.bsdfs.diffuse import Diffuse

    class Brighter(Diffuse):
        def eval(self, sp, wi):
            return 2 * super().eval(sp, wi)

    bright = TransportContext.build(box, CPU)
    bright.materials.bsdfs[0] = Brighter(bright.materials.bsdfs[0].values, bright.materials.bsdfs[0].constants, flat=True)
    assert fused.tables(bright, "mis", "cosine") is None
    # a parameter that carries a gradient: its factors must go through autograd
    leaf = box.params["red.reflectance"].clone().requires_grad_(True)
    ctx = TransportContext.build(box, CPU, params={"red.reflectance": leaf})
    assert fused.tables(ctx, "mis", "cosine") is None
    with torch.no_grad():
        assert fused.tables(ctx, "mis", "cosine") is not None
    # a plugin built on the area light that changes what it does: its own methods
    from invrender.plugins.emitters.area import Area

    class Dimmer(Area):
        def emitted(self, s):
            return 0.5 * super().emitted(s)

    rho = {"reflectance": torch.tensor([0.5, 0.5, 0.5])}
    assert Diffuse([rho], [{}], flat=True).fused_albedo() is not None and Brighter([rho], [{}], flat=True).fused_albedo() is None
    eps = [{"emission": box.params["light.emission"]}]
    assert Area([0], eps, [{}], box.triangles).lanes() is not None and Dimmer([0], eps, [{}], box.triangles).lanes() is None
    # films with hooks (path records', replay's adjoint) take the torch bounce
    from invrender.estimators.records import _RecordFilm
    from invrender.estimators.replay import AdjointFilm

    lambertian = _fused_scene(box)
    assert fused.takes(Film(2, 2, False, CPU), lambertian) and fused.takes(PathFilm(4, CPU), lambertian)
    assert not fused.takes(AdjointFilm.__new__(AdjointFilm), lambertian) and not fused.takes(_RecordFilm.__new__(_RecordFilm), lambertian)


@pytest.mark.parametrize("strategy", ["mis", "emitter", "bsdf"])
def test_the_fused_bounces_derivatives_are_autodiffs(strategy, unfused, monkeypatch):
    """Replay of a fusable render carries each pixel's derivatives forward in the fused kernels (one
    trace, no adjoint pass): the gradient is autodiff's and the torch replay's to float rounding, in
    a render (loss.backward) and a decorrelated gradient (backpropagate) alike, with the kernels
    compiled (whose calls of under 4096 lanes, all of these, are padded: padded lanes add
    nothing) and as eager torch."""
    from invrender.estimators import backpropagate
    from invrender.estimators.replay import tangent_slots

    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    names = ["white.reflectance", "red.reflectance", "light.emission"]
    integrator = make_integrator("path", strategy=strategy)
    settings = RenderSettings(spp=8, seed=2, progress=False)
    assert tangent_slots(scene, integrator, settings, CPU, names) == {"white.reflectance": 0, "red.reflectance": 1, "light.emission": 3}
    assert tangent_slots(scene, integrator, settings, CPU, ["white.reflectance", "sensor.gain"]) is None

    def gradient(estimator):
        params = {n: scene.params[n].clone().requires_grad_(True) for n in names}
        work = dataclasses.replace(scene, params={**scene.params, **params})
        image = ir.render(work, spp=8, seed=2, progress=False, estimator=estimator, strategy=strategy)
        (image**2).sum().backward()
        decorrelated = {n: v.detach().clone().requires_grad_(True) for n, v in params.items()}
        backpropagate(dataclasses.replace(scene, params={**scene.params, **decorrelated}), 2 * image.detach(), integrator, settings, estimator)
        return image.detach(), [params[n].grad for n in names], [decorrelated[n].grad for n in names]

    image, replayed, decorrelated = gradient("replay")
    _, autodiff, autodiff_decorrelated = gradient("autodiff")
    monkeypatch.setenv(arrays.ENV, "torch")
    _, replayed_eager, _ = gradient("replay")
    monkeypatch.delenv(arrays.ENV)
    unfused()
    image_torch, replayed_torch, _ = gradient("replay")
    assert (image - image_torch).abs().max() < 1e-5 * float(image.max())
    for got, expected in ((replayed, autodiff), (replayed, replayed_torch), (replayed_eager, replayed), (decorrelated, autodiff_decorrelated), (decorrelated, replayed)):
        for a, b in zip(got, expected):
            assert float(b.abs().max()) > 0 and (a - b).abs().max() < 1e-4 * float(b.abs().max())


@pytest.mark.parametrize("scene_name, fixed", [("forward/textured_floor.toml", "floor.reflectance"), ("cornell_specular", "glossy.specular_reflectance")])
def test_beside_other_materials_the_colours_derivatives_are_carried_forward(scene_name, fixed):
    """A textured Lambertian's albedo, a mirror's, a glass's or a glossy lobe's factors are
    constants of the paths that meet them (and shading normals only scale a Lambertian's weight):
    replay of the Lambertian colours and the emission still carries each pixel's derivatives
    forward (one trace), equal to autodiff's; the other materials' parameters are replayed by the
    adjoint pass."""
    from invrender.estimators.replay import tangent_slots

    path = Path(__file__).resolve().parents[2] / scene_name
    scene = ir.load_scene(str(path) if path.exists() else scene_name, resolution=(16, 16))
    names = ["white.reflectance", "green.reflectance", "light.emission"]
    settings = RenderSettings(spp=8, seed=2, progress=False)
    integrator = make_integrator("path")
    assert tangent_slots(scene, integrator, settings, CPU, names) is not None
    assert tangent_slots(scene, integrator, settings, CPU, [fixed]) is None

    def gradient(estimator):
        params = {n: scene.params[n].clone().requires_grad_(True) for n in names}
        work = dataclasses.replace(scene, params={**scene.params, **params})
        (ir.render(work, spp=8, seed=2, progress=False, estimator=estimator) ** 2).sum().backward()
        return [params[n].grad for n in names]

    for a, b in zip(gradient("replay"), gradient("autodiff")):
        assert float(b.abs().max()) > 0 and (a - b).abs().max() < 1e-4 * float(b.abs().max())


def _camera_samples_both_ways(monkeypatch, scene, settings, ids):
    """The camera samples compiled (Dr.Jit) and as eager torch."""
    got = driver._camera_samples(scene, settings, ids)
    monkeypatch.setenv(arrays.ENV, "torch")
    expected = driver._camera_samples(scene, settings, ids)
    monkeypatch.delenv(arrays.ENV)
    return got, expected


#: keys and film positions of path ids 3, 5, 7 (sampler, spp, seed 123, cornell_box 24x20): the
#: values the former torch expressions (and Warp's kernel) gave, bit for bit
FORMER = {
    ("stratified", 5): ([779660490, -348255248, 1043623692], [[0.9599143862724304, 0.13033129274845123], [1.336341381072998, 0.1691148281097412], [1.6254956722259521, 0.5860918164253235]]),
    ("antithetic", 7): ([-242894807, 1191612429, -348255248], [[0.3525664806365967, 0.6730439066886902], [0.7886312007904053, 0.910433828830719], [1.170426607131958, 0.4613935351371765]]),
    ("independent", 33): ([779660490, 136106338, 530251282], [[0.7995719313621521, 0.651656448841095], [0.7004150152206421, 0.038420140743255615], [0.6433205604553223, 0.10037928819656372]]),
}


@pytest.mark.parametrize("sampler", ["stratified", "independent", "antithetic"])
def test_camera_samples_compiled_equal_eager_torch_bit_for_bit(sampler, monkeypatch):
    for name, res in (("cornell_box", (24, 20)), (str(FORWARD / "cornell_far.toml"), (9, 7))):
        scene = ir.load_scene(name, resolution=res)
        for spp in (1, 5, 7, 16, 33):
            settings = RenderSettings(spp=spp, sampler=sampler, seed=123)
            ids = torch.arange(3, res[0] * res[1] * spp, 2, dtype=torch.int64)  # not consecutive, not from 0
            got, expected = _camera_samples_both_ways(monkeypatch, scene, settings, ids)
            for a, b in zip(got, expected):
                assert (a is None and b is None) or (a.dtype == b.dtype and torch.equal(a, b)), (name, spp)
            if name == "cornell_box" and (sampler, spp) in FORMER:
                keys, film = FORMER[sampler, spp]
                assert got[1][:3].tolist() == keys and got[2][:3].tolist() == film


def test_a_thin_lens_camera_draws_its_lens_point_in_the_kernel(monkeypatch):
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    lens = dataclasses.replace(scene, camera=dataclasses.replace(scene.camera, aperture_radius=0.05, focus_distance=3.0))
    if lens.camera.is_pinhole:
        pytest.skip("the camera has no thin-lens fields")
    ids = torch.arange(0, 64 * 4, dtype=torch.int64)
    settings = RenderSettings(spp=4, seed=1)
    got, expected = _camera_samples_both_ways(monkeypatch, lens, settings, ids)
    assert got[3] is not None and all(torch.equal(a, b) for a, b in zip(got, expected))
    assert 0.0 <= float(got[3].min()) and float(got[3].max()) < 1.0


def test_a_pinhole_cameras_rays_come_from_the_samples_kernel_as_generate_rays_gives_them(monkeypatch):
    """The pinhole's directions, computed in the camera samples' kernel, are generate_rays' within
    an ulp (offset principal point, non-square pixels and a sampled border included); a
    replacement of generate_rays is followed (the kernel only stands for the original)."""
    from invrender.scene.camera import Camera

    from invrender.plugins.filters import make_filter
    from invrender.scene.film import FilmOptions

    scene = ir.load_scene("cornell_box", resolution=(20, 12))
    odd = dataclasses.replace(scene.camera, principal_point_offset=(0.11, -0.07), pixel_aspect=1.3)
    bordered = dataclasses.replace(scene, film=FilmOptions(make_filter("gaussian"), True))
    assert bordered.film.border > 0
    for view in (scene, scene.with_camera(odd), bordered):
        camera = view.camera
        settings = RenderSettings(spp=3, seed=4)
        ids = torch.arange(0, driver.total_paths(view, settings), dtype=torch.int64)
        state, xy = driver.camera_paths(view, settings, ids, positions=True)
        o, d = camera.generate_rays(xy, view.width, view.height)
        assert (state.d - d).abs().max() <= 2.4e-7 and torch.equal(state.o, o.contiguous())
    calls = []
    original = Camera.generate_rays
    monkeypatch.setattr(Camera, "generate_rays", lambda self, *a, **k: calls.append(1) or original(self, *a, **k))
    driver.camera_paths(scene, RenderSettings(spp=1), torch.arange(8, dtype=torch.int64))
    assert calls  # the replacement ran


def test_where_true_is_nonzero():
    from invrender.vec import where_true

    for p in (0.0, 0.3, 1.0):
        mask = torch.rand(10_000, generator=torch.Generator().manual_seed(1)) < p
        got = where_true(mask)
        assert got.dtype == torch.int64 and torch.equal(got, mask.nonzero()[:, 0])


def _renders_as_torch(scene, unfused, kw: dict, agree: float, mean: float) -> torch.Tensor:
    """Render ``scene`` with the fused bounce, then (``unfused``) with the torch bounce on the same
    random bits: more than ``agree`` of the pixels equal to float rounding (a roulette decision
    that rounding flips changes a path) and the means within ``mean``. Returns the torch image."""
    image = ir.render(scene, progress=False, **kw)
    unfused()
    expected = ir.render(scene, progress=False, **kw)
    close = (image - expected).abs() <= 1e-4 * float(expected.max())
    assert float(close.float().mean()) > agree
    assert abs(float(image.mean() / expected.mean()) - 1) < mean
    return expected


def _smooth_spheres(materials: dict, texture_sampling=None, sky=None) -> ir.Scene:
    """The Cornell box with its boxes replaced by two smooth-shaded spheres of the given materials
    (names ``near``, ``far``), the walls one-sided from behind (``white``)."""
    from invrender.scene.builtin import CORNELL_CAMERA, CORNELL_GREEN, CORNELL_LIGHT, CORNELL_RED, CORNELL_WHITE, _light, _walls
    from invrender.scene.materials import Material
    from invrender.scene.scene import build_scene
    from invrender.scene.shapes import primitive, scale, translate

    shapes = [
        *_walls(),
        primitive("sphere", "near", None, 2).transformed(translate([0.35, -0.7, 0.3]) @ scale(0.3)),
        primitive("sphere", "far", None, 2).transformed(translate([-0.35, -0.6, -0.3]) @ scale(0.35)),
        _light(),
    ]
    specs = {"white": dataclasses.replace(Material.of("diffuse", reflectance=CORNELL_WHITE), one_sided=True), "red": CORNELL_RED, "green": CORNELL_GREEN, **materials}
    emitters = {"light": CORNELL_LIGHT, **({"sky": sky} if sky is not None else {})}
    return build_scene(shapes, specs, emitters, CORNELL_CAMERA, (24, 24), name="spheres", texture_sampling=texture_sampling)


@pytest.mark.parametrize("options", [{}, {"strategy": "emitter"}, {"hemisphere": "uniform"}, {"max_depth": 4, "rr_depth": -1}])
def test_the_fused_bounce_renders_smooth_one_sided_and_mixed_materials_as_the_torch_bounce(options, unfused):
    """Every material in lane form is on the fused bounce: shading normals, one-sided materials,
    textures (bilinear and repeating, nearest and mirrored), several material types dispatched by
    masks, delta lobes, paths that end with a zero weight."""
    from invrender.scene.materials import Material
    from invrender.scene.textures import TextureSampling

    texture = torch.rand(5, 7, 3, generator=torch.Generator().manual_seed(1)) * 0.8 + 0.1
    mats = {"near": Material.of("diffuse", reflectance=texture), "far": Material.of("diffuse", reflectance=texture.flip(0)[:3])}
    scene = _smooth_spheres(mats, {"far.reflectance": TextureSampling("nearest", "mirror", (2.0, 0.5, 0.1, -0.3, 3.0, 0.2))})
    assert _fused_scene(scene, "path", **options) is not None
    expected = _renders_as_torch(scene, unfused, dict(spp=16, seed=7, integrator="path", **options), agree=0.995, mean=2e-3)
    assert float(expected.mean()) > 0.05


SKIES = {
    "constant": lambda: {"type": "constant", "emission": (0.4, 0.5, 0.9)},
    "envmap": lambda: {"type": "envmap", "emission": torch.rand(5, 8, 3, generator=torch.Generator().manual_seed(2)) * 2 + 0.1},
    "point": lambda: {"type": "point", "emission": (0.6, 0.5, 0.4), "position": (0.3, 0.5, 0.2)},
    "spot": lambda: {"type": "spot", "emission": (3.0, 2.5, 2.0), "position": (-0.4, 0.6, 0.8), "direction": (0.5, -1.0, -0.5), "cutoff_angle": 30.0, "beam_width": 20.0},
    "spot_texture": lambda: {"type": "spot", "emission": torch.rand(6, 5, 3, generator=torch.Generator().manual_seed(4)) * 4, "position": (-0.4, 0.6, 0.8), "direction": (0.5, -1.0, -0.5), "cutoff_angle": 30.0, "beam_width": 20.0},
    "projector": lambda: {"type": "projector", "emission": torch.rand(4, 6, 3, generator=torch.Generator().manual_seed(5)) + 0.2, "position": (-0.4, 0.6, 0.8), "direction": (0.5, -1.0, -0.5), "fov": 50.0},
}


@pytest.mark.parametrize("sky", sorted(SKIES))
@pytest.mark.parametrize("options", [{}, {"strategy": "emitter"}])
def test_the_fused_bounce_renders_emitters_of_several_types_as_the_torch_bounce(options, sky, unfused):
    """Emitter samples choose among the area light and a second type (a sky, a map, a point, a
    spot) by their power, rays that leave the box through its open front see the sky or map
    (MIS-weighted), delta samples weigh 1, on the fused bounce."""
    from invrender.scene.emitters import Emitter
    from invrender.scene.materials import Material

    spec = SKIES[sky]()
    kind = spec.pop("type")
    mats = {"near": Material.of("diffuse", reflectance=(0.7, 0.6, 0.2)), "far": Material.of("diffuse", reflectance=(0.2, 0.5, 0.7))}
    scene = _smooth_spheres(mats, sky=Emitter.of(kind, **spec))
    fused_scene = _fused_scene(scene, "path", **options)
    assert fused_scene is not None and fused_scene.infinite == (kind in ("constant", "envmap")) and len(fused_scene.emitters) == 2
    _renders_as_torch(scene, unfused, dict(spp=16, seed=3, integrator="path", **options), agree=0.995, mean=2e-3)


@pytest.mark.parametrize("options", [{}, {"strategy": "emitter"}, {"strategy": "bsdf"}])
def test_the_fused_bounce_renders_the_specular_box_as_the_torch_bounce(options, unfused):
    """A mirror sphere, a glass sphere (delta lobes: no emitter samples, MIS weight 1 after them,
    refraction from inside), a GGX block and diffuse walls, several types by masks."""
    scene = ir.load_scene("cornell_specular", resolution=(24, 24), subdivisions=2)
    assert len(_fused_scene(scene, "path", **options).materials) == 4
    _renders_as_torch(scene, unfused, dict(spp=16, seed=5, integrator="path", **options), agree=0.99, mean=3e-3)


@pytest.mark.parametrize("options", [{}, {"strategy": "emitter"}])
def test_the_fused_bounce_renders_anisotropic_materials_in_the_uv_frame_as_the_torch_bounce(options, unfused):
    """Anisotropic roughness (the UV tangent frame, :mod:`invrender.core.shading`) on a smooth
    sphere: the compiled bounce and the torch bounce build the same frames."""
    from invrender.scene.materials import Material

    mats = {"near": Material.of("glossy", roughness=0.05, alpha_v=0.4), "far": Material.of("roughdielectric_ggx", roughness=0.4, alpha_v=0.08)}
    scene = _smooth_spheres(mats)
    fs = _fused_scene(scene, "path", **options)
    assert fs is not None and fs.lanes[5][1] is not None  # the UV frames' tables
    kw = dict(spp=16, seed=7, integrator="path", **options)
    expected = _renders_as_torch(scene, unfused, kw, agree=0.995, mean=2e-3)
    assert float(expected.mean()) > 0.05


@pytest.mark.parametrize("options", [{}, {"strategy": "emitter"}, {"max_depth": 4, "rr_depth": -1}])
def test_the_fused_bounce_renders_normal_and_bump_maps_as_the_torch_bounce(options, unfused):
    """Perturbed shading normals (:mod:`invrender.core.shading`): a normal map (the frame turned to
    the ray's side, as ``twosided`` around it) on a glossy sphere, a bump map (bilinear, mirrored,
    with ``to_uv``) on a diffuse one: the compiled and the torch bounce perturb alike."""
    from invrender.scene.materials import Material, NormalPerturbation
    from invrender.scene.textures import TextureSampling

    g = torch.Generator().manual_seed(3)
    n = torch.nn.functional.normalize(torch.randn(6, 9, 3, generator=g) * torch.tensor([0.4, 0.4, 0.0]) + torch.tensor([0.0, 0.0, 1.0]), dim=-1)
    normal_map = NormalPerturbation("normalmap", (n + 1) / 2, on_turned=True)
    bump = NormalPerturbation("bumpmap", torch.rand(7, 5, 3, generator=g), TextureSampling("bilinear", "mirror", (2.0, 0.5, 0.1, -0.3, 3.0, 0.2)), scale=0.05)
    mats = {
        "near": dataclasses.replace(Material.of("glossy", roughness=0.2), perturbation=normal_map),
        "far": dataclasses.replace(Material.of("diffuse", reflectance=(0.7, 0.6, 0.5)), perturbation=bump),
    }
    scene = _smooth_spheres(mats)
    fs = _fused_scene(scene, "path", **options)
    assert fs is not None and fs.lanes[5][2] is not None  # the perturbations' textures
    kw = dict(spp=16, seed=7, integrator="path", **options)
    expected = _renders_as_torch(scene, unfused, kw, agree=0.995, mean=2e-3)
    assert float(expected.mean()) > 0.05
    plain = ir.render(_smooth_spheres({k: dataclasses.replace(m, perturbation=None) for k, m in mats.items()}), progress=False, **kw)
    assert float((plain - expected).abs().mean()) > 0.01 * float(expected.mean())  # the maps change the image
