"""A glossy material's roughness as a differentiable parameter (the conductors' and the rough
plastics'): both estimators against central finite differences (sampling held at the unperturbed
roughness), replay = autodiff, recovery by Adam (and lm for a plastic), renders unchanged where
nothing is differentiated, and the one-line refusals (path records, values outside (0, 1], a
plastic's roughness map)."""

import pytest
import torch

import invrender as ir
from invrender.errors import InvRenderError, ParameterError
from invrender.scene.builtin import primitive, rotate, scale, translate
from invrender.scene.camera import Camera
from invrender.scene.materials import Material
from invrender.scene.scene import build_scene


def plate(alpha=0.3, resolution=(24, 24), type="glossy"):
    """A 3 x 3 glossy plate under a small tilted light: the highlight's spread is the roughness."""
    meshes = [
        primitive("rectangle", "plate").transformed(scale([1.5, 1.5, 1.0])),
        primitive("rectangle", "lamp", "light").transformed(translate([0, 0.8, 1.2]) @ rotate([1, 0, 0], 150) @ scale([0.12, 0.12, 1])),
    ]
    materials = {"plate": Material.of(type, specular_reflectance=[0.8, 0.7, 0.6], roughness=alpha), "lamp": 0.0}
    return build_scene(meshes, materials, {"light": [30.0, 30.0, 30.0]}, Camera(origin=(0, -2.0, 2.2), target=(0, 0.2, 0), fov=50), resolution)


def check_rows(rows, tol=0.02):
    for r in rows:
        for estimator, err in r.rel_errors.items():
            assert err < tol, (r.name, r.index, estimator, r.fd, r.gradients)
        a, b = r.gradients["autodiff"], r.gradients["replay"]
        assert abs(a - b) <= 1e-5 * max(abs(a), 1e-3), (r.name, r.index, a, b)


@pytest.mark.parametrize("type", ["glossy", "glossy_beckmann"])
def test_roughness_gradient_matches_finite_differences_direct(type):
    """Direct light (next-event estimation and BSDF sampling, MIS with detached pdfs): the
    roughness and k_s gradients of both estimators within 2% of central differences."""
    rows = ir.gradcheck(plate(0.3, type=type), ["plate.roughness", "plate.specular_reflectance"], spp=32, max_depth=2, seed=4)
    alpha = [r for r in rows if r.name == "plate.roughness"]
    assert len(alpha) == 1 and abs(alpha[0].fd) > 0.1  # one component: its three channels move together
    check_rows(rows)


def test_roughness_gradient_through_indirect_paths():
    """The Cornell box's glossy block seen directly and through the mirror and the walls (depth 4)."""
    scene = ir.load_scene("cornell_specular", resolution=(24, 24), subdivisions=2)
    rows = ir.gradcheck(scene, ["glossy.roughness", "white.reflectance"], spp=32, max_depth=4, seed=3)
    check_rows(rows)


def test_sampling_params_hold_bsdf_sampling_fixed():
    """With sampling held at alpha_0, a render at alpha_0 is bit-identical to the plain one, and
    renders at alpha_0 +- h reuse every direction: each pixel moves smoothly (its differences on the
    two sides cancel to second order), as f(alpha) / pdf(alpha_0) does."""
    scene = plate(0.3)
    kw = dict(spp=4, max_depth=2, seed=2, progress=False)
    base = ir.render(scene, **kw)
    frozen = dict(scene.params)
    assert torch.equal(ir.render(scene, sampling_params=frozen, **kw), base)
    plus, minus = (ir.render(scene.with_params({"plate.roughness": 0.3 + h}), sampling_params=frozen, **kw) for h in (1e-3, -1e-3))
    assert float((plus - minus).abs().sum()) > 0
    assert float((plus + minus - 2 * base).abs().sum()) < 0.02 * float((plus - minus).abs().sum())


@pytest.mark.parametrize("type", ["glossy", "roughplastic", "roughplastic_ggx"])
def test_constant_roughness_renders_as_before(type):
    """A roughness given as before renders the same image whether or not it is differentiated (a
    glossy metal, and the plastics whose tables it moves)."""
    scene = plate(0.2, type=type)
    kw = dict(spp=4, max_depth=3, seed=1, progress=False)
    plain = ir.render(scene, **kw)
    scene.params["plate.roughness"].requires_grad_(True)
    attached = ir.render(scene, **kw)
    assert torch.equal(plain, attached.detach())
    attached.sum().backward()
    g = scene.params["plate.roughness"].grad
    assert g is not None and bool(torch.isfinite(g).all()) and float(g[0]) == float(g[1]) == float(g[2]) != 0.0


def test_adam_recovers_roughness_from_a_target():
    """alpha 0.3 from a start of 0.1 (k_s known), on a 20 x 20 image of the highlight."""
    target = ir.render(plate(0.3, resolution=(20, 20)), spp=512, max_depth=2, seed=9, progress=False)
    scene = plate(0.1, resolution=(20, 20))
    res = ir.fit(scene, target, ["plate.roughness"], steps=100, spp=8, spp_final=32, lr=0.05, max_depth=2, progress=False, truth={"plate.roughness": torch.full((3,), 0.3)})
    alpha = res.params["plate.roughness"]
    assert float(alpha[0]) == float(alpha[1]) == float(alpha[2])  # the channels stay one number
    assert res.errors["plate.roughness"] < 0.03, alpha


@pytest.mark.parametrize("call", ["record"])  # solver 'lm' and identifiability take it on re-traced renders (test_retraced_lm.py)
def test_path_records_refuse_roughness(call):
    scene = plate(0.3, resolution=(8, 8))
    run = {
        "record": lambda: ir.record_paths(scene, ["plate.roughness"], spp=2, max_depth=2, progress=False),
    }[call]
    with pytest.raises(ParameterError, match=r"plate.roughness is a roughness, not a polynomial factor of a path's weight: path records cannot represent it; ir.fit fits it with solver 'lm' or 'gauss_newton' on re-traced renders") as info:
        run()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "value, message",
    [
        (0.0, r"plate.roughness: roughness alpha must lie in \(0, 1\], got values in \[0, 0\]"),
        (1.5, r"must lie in \(0, 1\], got values in \[1.5, 1.5\]"),
        (-0.2, r"must lie in \(0, 1\]"),
        (float("nan"), r"plate.roughness: values must be finite"),
        ([0.1, 0.2, 0.3], r"plate.roughness: roughness alpha is one number \(three equal channels\)"),
    ],
)
def test_roughness_out_of_range_is_a_one_line_error(value, message):
    with pytest.raises(InvRenderError, match=message) as info:
        plate(value)
    assert "\n" not in str(info.value)
    with pytest.raises(ParameterError, match=message.replace("plate.roughness: ", "")):
        plate(0.3).with_params({"plate.roughness": value})


def test_toml_and_mitsuba_alpha_load_as_the_parameter(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text(
        '[camera]\norigin = [0, 0, 3]\n[materials.metal]\ntype = "glossy"\nroughness = 0.2\n[emitters.light]\nemission = 1\n'
        '[[shapes]]\ntype = "rectangle"\nmaterial = "metal"\n[[shapes]]\ntype = "sphere"\nmaterial = "metal"\nemitter = "light"\n'
    )
    assert ir.load_scene(toml).params["metal.roughness"].tolist() == pytest.approx([0.2] * 3)
    from invrender.io.images import write_image

    write_image(tmp_path / "alpha.exr", torch.tensor([[0.2, 0.4], [0.3, 0.1]])[:, :, None].expand(-1, -1, 3).contiguous())
    toml.write_text(toml.read_text().replace("roughness = 0.2", 'roughness_texture = "alpha.exr"\nspecular_reflectance_texture = "alpha.exr"'))
    scene = ir.load_scene(toml)
    torch.testing.assert_close(scene.params["metal.roughness"][..., 0], torch.tensor([[0.2, 0.4], [0.3, 0.1]]))
    assert scene.params["metal.specular_reflectance"].shape == (2, 2, 3)
    xml = tmp_path / "s.xml"
    xml.write_text(
        '<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/>'
        '<transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>'
        '<film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="6"/></film></sensor><shape type="rectangle"><bsdf type="roughconductor"><string name="distribution" value="ggx"/>'
        '<float name="alpha" value="0.35"/></bsdf></shape></scene>'
    )
    scene = ir.load_scene(xml)
    (name,) = [n for n in scene.params if n.endswith(".roughness")]
    assert scene.params[name].tolist() == pytest.approx([0.35] * 3)


# ---------------------------------------------------------------- the rough plastics' alpha

PLASTICS = ["roughplastic", "roughplastic_ggx"]


@pytest.mark.parametrize("type", PLASTICS)
def test_plastic_roughness_gradient_matches_finite_differences(type):
    """A rough plastic's alpha moves its coating's lobe and, through the transmittance tables, its
    diffuse base: with rho and k_s, both estimators within 2% of central differences."""
    rows = ir.gradcheck(plate(0.3, type=type), ["plate.roughness", "plate.specular_reflectance", "plate.reflectance"], spp=32, max_depth=2, seed=4)
    alpha = [r for r in rows if r.name == "plate.roughness"]
    assert len(alpha) == 1 and abs(alpha[0].fd) > 10
    check_rows(rows)


@pytest.mark.parametrize("type", PLASTICS)
def test_plastic_tables_follow_alpha(type):
    """The base alone (k_s = 0) at normal incidence: its albedo is a function of the tables only
    (T(c_o), R_int and the hemispherical mean of T), and its autodiff derivative in alpha is the
    slope of that function (central differences of fresh tables at +-0.02, not the attached step)."""
    import math

    import numpy as np

    from invrender.plugins.bsdfs import checks
    from invrender.plugins.bsdfs.plastic import rough_tables

    eta = 1.49 / 1.000277

    def albedo(alpha):
        T, R = rough_tables("beckmann" if type == "roughplastic" else "ggx", alpha, eta)
        mu = (np.arange(4000) + 0.5) / 4000
        return T[-1] * 2 * np.mean(np.interp(mu, np.linspace(0, 1, 64), T) * mu) / (eta**2 * (1 - R))

    cls = ir.registry.MATERIALS.get(type)
    alpha = torch.full((3,), 0.3, requires_grad=True)
    bsdf = cls([{"reflectance": torch.ones(3), "specular_reflectance": torch.zeros(3), "roughness": alpha}], [checks.instance(cls).constants[0]])
    n = 200_000
    g = torch.Generator().manual_seed(0)
    bs = bsdf.sample(checks.shading_point(0.0, n), torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    mean = bs.weight[:, 0].double().mean()
    assert float(mean) == pytest.approx(albedo(0.3), abs=4e-3)
    (grad,) = torch.autograd.grad(mean, alpha)
    slope = (albedo(0.32) - albedo(0.28)) / 0.04
    assert abs(slope) > 0.05 and float(grad.sum()) == pytest.approx(slope, rel=0.03), (float(grad.sum()), slope)
    assert math.isfinite(float(grad.sum())) and not bs.pdf.requires_grad


@pytest.mark.slow
def test_adam_and_lm_recover_a_plastic_roughness():
    """roughplastic_ggx with a blue base (forward/plastic_plate.toml's): alpha 0.3 from 0.1 (rho and
    k_s known) on a 16 x 16 image, with Adam (32 spp a step: a step's cost is mostly the tables')
    and with the re-traced lm."""

    def scene(alpha):
        return plate(alpha, (16, 16), "roughplastic_ggx").with_params({"plate.reflectance": [0.1, 0.25, 0.7]})

    target = ir.render(scene(0.3), spp=512, max_depth=2, seed=9, progress=False)
    truth = {"plate.roughness": torch.full((3,), 0.3)}
    adam = ir.fit(scene(0.1), target, ["plate.roughness"], steps=40, spp=32, spp_final=64, lr=0.08, max_depth=2, progress=False, truth=truth)
    assert adam.errors["plate.roughness"] < 0.05, adam.params["plate.roughness"]
    lm = ir.fit(scene(0.1), target, ["plate.roughness"], solver="lm", spp=8, rounds=2, max_depth=2, progress=False, truth=truth)
    assert all(h["on"] == "re-traced renders" for h in lm.history)
    assert lm.errors["plate.roughness"] < 0.03 and 0 < float(lm.std_error["plate.roughness"][0]) < 0.01, (lm.params, lm.std_error)


def test_plastic_roughness_bad_input_and_records():
    with pytest.raises(ParameterError, match=r"plate.roughness: roughness alpha must lie in \(0, 1\], got values in \[0, 0\]") as info:
        plate(0.0, type="roughplastic")
    assert "\n" not in str(info.value)
    with pytest.raises(ParameterError, match=r"plate.roughness: a roughplastic_ggx material's roughness must be an RGB triple, not a texture"):
        plate([[0.2, 0.3]], type="roughplastic_ggx")
    with pytest.raises(ParameterError, match=r"plate.roughness is a roughness, not a polynomial factor of a path.s weight: path records cannot represent it"):
        ir.record_paths(plate(0.3, (8, 8), "roughplastic"), ["plate.roughness"], spp=2, max_depth=2, progress=False)


# ---------------------------------------------------------------- maps over the mesh UVs (SVBRDF)

ROUGHNESS_MAP = [[0.15, 0.3], [0.45, 0.25]]  # (h, w): one number per texel
KS_MAP = [[[0.8, 0.7, 0.6], [0.5, 0.6, 0.7]], [[0.9, 0.9, 0.9], [0.4, 0.5, 0.3]]]


def textured_plate():
    return plate(0.3).with_params({"plate.roughness": ROUGHNESS_MAP, "plate.specular_reflectance": KS_MAP}, detach=True)


@pytest.mark.slow
def test_textured_roughness_and_specular_reflectance_gradients():
    """Per texel (a roughness texel's three channels together): within 2% of central differences,
    replay = autodiff."""
    scene = textured_plate()
    assert scene.params["plate.roughness"].shape == (2, 2, 3)  # an (h, w) map kept as grey texels
    rows = ir.gradcheck(scene, ["plate.roughness", "plate.specular_reflectance"], spp=32, max_depth=2, seed=4, max_components=6)
    assert sum(r.name == "plate.roughness" for r in rows) == 4 and all(abs(r.fd) > 0.5 for r in rows)
    check_rows(rows)


def test_records_take_a_specular_map_and_refuse_a_roughness_map():
    scene = textured_plate()
    records = ir.record_paths(scene, ["plate.specular_reflectance"], spp=4, max_depth=2, progress=False)
    image = ir.render(scene, spp=4, max_depth=2, progress=False)
    assert float((records.image() - image).abs().max()) <= 1e-5 * float(image.max())
    with pytest.raises(ParameterError, match=r"plate.roughness is a roughness, not a polynomial factor of a path.s weight: path records cannot represent it"):
        ir.record_paths(scene, ["plate.roughness"], spp=4, max_depth=2, progress=False)


def test_a_mirror_refuses_a_specular_map_a_glossy_takes_one():
    from invrender.scene.builtin import primitive

    maps = torch.full((2, 2, 3), 0.5)
    with pytest.raises(ParameterError, match=r"m.specular_reflectance: a mirror material's specular_reflectance must be an RGB triple, not a texture"):
        build_scene([primitive("rectangle", "m")], {"m": Material.of("mirror", specular_reflectance=maps)}, {}, Camera(), (4, 4))
    scene = build_scene([primitive("rectangle", "m")], {"m": Material.of("glossy", specular_reflectance=maps, roughness=torch.full((2, 2), 0.2))}, {}, Camera(), (4, 4))
    assert scene.params["m.roughness"].shape == (2, 2, 3)


def test_adam_recovers_a_roughness_map():
    """A 1 x 2 map (0.2 left, 0.4 right) from 0.1 everywhere, under two lamps whose highlights fall
    mostly on one texel each."""
    meshes = [primitive("rectangle", "plate").transformed(scale([1.5, 1.5, 1.0]))]
    for x in (-0.75, 0.75):
        meshes.append(primitive("rectangle", "lamp", "light").transformed(translate([x, 0.8, 1.2]) @ rotate([1, 0, 0], 150) @ scale([0.12, 0.12, 1])))
    camera = Camera(origin=(0, -2.0, 2.2), target=(0, 0.2, 0), fov=50, fov_axis="x")

    def scene(alpha):
        materials = {"plate": Material.of("glossy", specular_reflectance=[0.8, 0.7, 0.6], roughness=alpha), "lamp": 0.0}
        return build_scene(meshes, materials, {"light": [30.0, 30.0, 30.0]}, camera, (16, 8))

    truth = scene([[0.2, 0.4]])
    target = ir.render(truth, spp=512, max_depth=2, seed=9, progress=False)
    # all 120 steps (plateau_window=0): the plateau rule may stop at ~2.1% where the last steps reach < 2%
    res = ir.fit(scene([[0.1, 0.1]]), target, ["plate.roughness"], steps=120, spp=4, spp_final=16, lr=0.1, max_depth=2, progress=False,
                 plateau_window=0, truth={"plate.roughness": truth.params["plate.roughness"]})  # fmt: skip
    assert res.errors["plate.roughness"] < 0.02, res.params["plate.roughness"][..., 0]
