"""Rough glass (invrender/plugins/bsdfs/roughdielectric.py): sampling against pdf and weights against
eval / pdf from both sides of the interface at several roughnesses and angles, Walter's BTDF by an
independent formula, reciprocity, energy (the smooth dielectric's split as alpha -> 0), next-event
estimation through the transmission lobe, roughness gradients, and the scene formats.

The registry-driven conformance suite (test_conformance.py) also checks both types at their
defaults (and their sampling from inside)."""

from __future__ import annotations

import math

import pytest
import torch

import invrender as ir
from invrender.errors import SceneError
from invrender.plugins.bsdfs import checks
from invrender.plugins.bsdfs.dielectric import fresnel_dielectric
from invrender.plugins.bsdfs.microfacet import BECKMANN, GGX
from invrender.plugins.bsdfs.roughdielectric import RoughDielectric, RoughDielectricGGX
from invrender.scene.builtin import primitive, scale, translate
from invrender.scene.camera import Camera
from invrender.scene.emitters import Emitter
from invrender.scene.materials import Material
from invrender.scene.scene import build_scene

ETA = 1.5046 / 1.000277  # bk7 over air, Mitsuba's defaults
TYPES = [RoughDielectric, RoughDielectricGGX]


@pytest.mark.parametrize("front", [True, False])
@pytest.mark.parametrize("alpha", [0.05, 0.5])
@pytest.mark.parametrize("cls", TYPES)
def test_sampling_matches_pdf_and_weight_is_eval_over_pdf(cls, alpha, front):
    bsdf = checks.instance(cls, roughness=alpha)
    for theta in (0.0, 0.8, 1.35):
        assert checks.chi_square_p(bsdf, theta, samples=100_000, seed=int(10 * theta), front=front) > 1e-3, theta
    for theta in (0.2, 1.0):
        pdf_err, weight_err, smooth = checks.weight_errors(bsdf, theta, front=front)
        assert pdf_err < 2e-3 and weight_err < 2e-3 and smooth > 0.8, theta


def walter_btdf(wo, wi, alpha, eta, d):
    """Walter et al. 2007, eq. 21, in float64 with its own notation: incident i = wo in a medium of
    index 1, transmitted o = wi in a medium of index eta; f_t times |cos_o| / eta^2 (radiance)."""
    i, o = wo, wi
    ht = -(i + eta * o)
    ht = ht / ht.norm()
    ht = ht if ht[2] > 0 else -ht
    c = float(i @ ht)
    F = float(fresnel_dielectric(torch.tensor([c], dtype=torch.float64), torch.tensor([eta], dtype=torch.float64))[0][0])
    t = lambda x: torch.tensor([x], dtype=torch.float64)  # noqa: E731
    D = float(d.D(t(float(ht[2])), t(alpha)))
    G = float(d.G1(t(abs(float(i[2]))), t(alpha)) * d.G1(t(abs(float(o[2]))), t(alpha)))
    f = abs(float(i @ ht)) * abs(float(o @ ht)) / (abs(float(i[2])) * abs(float(o[2]))) * eta**2 * (1 - F) * G * D / (float(i @ ht) + eta * float(o @ ht)) ** 2
    return f * abs(float(o[2])) / eta**2


@pytest.mark.parametrize("cls", TYPES)
def test_transmission_is_walters_btdf_scaled_by_one_over_eta_squared(cls):
    theta_o, alpha = 0.7, 0.25
    bsdf = checks.instance(cls, roughness=alpha, specular_transmittance=[0.9, 0.6, 0.3])
    sp = checks.shading_point(theta_o, 1)
    wo = sp.wo[0].double()
    for theta_i, phi in ((2.62, 0.1), (2.75, -0.1), (2.8, 0.05)):  # wo lies at phi = pi
        wi = torch.tensor([math.sin(theta_i) * math.cos(phi), math.sin(theta_i) * math.sin(phi), math.cos(theta_i)], dtype=torch.float64)
        want = walter_btdf(wo, wi, alpha, ETA, cls.distribution)
        got = bsdf.eval(sp, wi[None].float())[0].double()
        assert want > 1e-3
        assert got.tolist() == pytest.approx([0.9 * want, 0.6 * want, 0.3 * want], rel=2e-4)


@pytest.mark.parametrize("cls", TYPES)
def test_transmission_is_reciprocal_up_to_eta_squared(cls):
    """f(wo, wi) / eta_wo^2 = f(wi, wo) / eta_wi^2 (Veach's thesis, 5.2): the radiance BTDF seen
    from inside is eta^2 times the one seen from outside, for the same pair of directions."""
    bsdf = checks.instance(cls, roughness=0.3)
    out = checks.shading_point(0.6, 1)  # wo outside, at 0.6 rad
    wi = torch.tensor([[math.sin(2.7) * math.cos(0.2), math.sin(2.7) * math.sin(0.2), math.cos(2.7)]])
    f_out = float(bsdf.eval(out, wi)[0, 0]) / abs(float(wi[0, 2]))
    # the same pair the other way round: wo' = wi, inside (normal turned to it), wi' = the old wo
    sp_in = checks.shading_point(math.pi - 2.7, 1, normal=(0.0, 0.0, -1.0), front=False)
    sp_in = type(sp_in)(wi.clone(), sp_in.n, sp_in.ng, sp_in.front, sp_in.uv, sp_in.material, sp_in.slot)
    f_in = float(bsdf.eval(sp_in, out.wo)[0, 0]) / abs(float(out.wo[0, 2]))
    assert f_out > 1e-3
    assert f_in == pytest.approx(ETA**2 * f_out, rel=1e-4)


def split(bsdf, theta, front, n=200_000):
    """(reflected, transmitted) mean sample weights (channel 0), float64."""
    g = torch.Generator().manual_seed(1)
    bs = bsdf.sample(checks.shading_point(theta, n, front=front), torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    up = bs.wi[:, 2] > 0
    w = bs.weight[:, 0].double()
    return float((w * up).mean()), float((w * ~up).mean())


@pytest.mark.parametrize("front", [True, False])
@pytest.mark.parametrize("cls", TYPES)
def test_energy_tends_to_the_smooth_dielectrics_split(cls, front):
    """At alpha 0.005 reflection carries F and transmission (1 - F) / eta^2 (the smooth
    dielectric's weights; from inside at 1.0 rad: total internal reflection); rougher, R + eta^2 T
    (the energy, radiance scaling undone) stays <= 1 and falls with alpha (single scattering)."""
    eta = ETA if front else 1 / ETA
    for theta in (0.3, 1.0):
        F = float(fresnel_dielectric(torch.tensor([math.cos(theta)]), torch.tensor([eta]))[0][0])
        R, T = split(checks.instance(cls, roughness=0.005), theta, front)
        assert R == pytest.approx(F, abs=2e-3) and T == pytest.approx((1 - F) / eta**2, abs=3e-3), (theta, R, T, F)
        energies = [sum(x * s for x, s in zip(split(checks.instance(cls, roughness=a), theta, front), (1.0, eta**2))) for a in (0.005, 0.3, 0.7)]
        assert energies[0] == pytest.approx(1.0, abs=2e-3)
        assert 1.0 + 1e-3 >= energies[0] >= energies[1] - 1e-3 > energies[2] > 0.5, (theta, energies)


def test_the_distributions_differ():
    """GGX's longer tails transmit less at high roughness than Beckmann's (the same alpha)."""
    assert RoughDielectric.distribution is BECKMANN and RoughDielectricGGX.distribution is GGX
    _, t_b = split(checks.instance(RoughDielectric, roughness=0.5), 1.0, True)
    _, t_g = split(checks.instance(RoughDielectricGGX, roughness=0.5), 1.0, True)
    assert t_g < t_b - 0.01


# ---------------------------------------------------------------- in renders: a rough window onto a lamp


def window(alpha=0.3, type="roughdielectric_ggx", emitter=None, resolution=(12, 12)):
    """A 3 x 3 rough glass plate (front +z, towards the camera) over a lamp below it facing up:
    the camera sees the lamp only through the glass (transmitted light, blurred by alpha)."""
    meshes = [
        primitive("rectangle", "glass").transformed(scale([1.5, 1.5, 1.0])),
        primitive("rectangle", "lamp", None if emitter else "light").transformed(translate([0.2, 0.0, -0.8]) @ scale([0.4, 0.4, 1.0])),
    ]
    materials = {"glass": Material.of(type, roughness=alpha, specular_transmittance=[0.9, 0.8, 0.7]), "lamp": 0.0}
    emitters = emitter or {"light": [20.0, 20.0, 20.0]}
    return build_scene(meshes, materials, emitters, Camera(origin=(0, -1.0, 3.0), target=(0, 0, 0), fov=50), resolution)


def test_next_event_estimation_gathers_through_the_transmission_lobe():
    """Emitter sampling alone, BSDF sampling alone and MIS estimate the same image through the
    glass (before emitter samples behind a surface were taken as unlit, the first was 0 and MIS
    18% low); a point light, which only emitter sampling can find, lights the glass from below."""
    scene = window()
    kw = dict(spp=256, max_depth=3, progress=False)
    bsdf = ir.render(scene, "random_walk", seed=1, **kw).double().mean((0, 1))
    mis = ir.render(scene, "path", seed=2, **kw).double().mean((0, 1))
    nee = ir.render(scene, {"type": "path", "strategy": "emitter"}, seed=3, **kw).double().mean((0, 1))
    assert float(bsdf.min()) > 0.05
    torch.testing.assert_close(mis, bsdf, rtol=3e-2, atol=0)
    torch.testing.assert_close(nee, bsdf, rtol=0.1, atol=0)  # the noisiest: emitter samples through a peaked lobe
    point = window(emitter={"bulb": Emitter.of("point", emission=[2.0, 2.0, 2.0], position=[0.2, 0.0, -0.8])})
    lit = ir.render(point, "path", spp=16, max_depth=2, progress=False, seed=4)
    assert float(lit.mean()) > 1e-3


@pytest.mark.parametrize("type", ["roughdielectric", "roughdielectric_ggx"])
def test_roughness_gradient_matches_finite_differences(type):
    """Both estimators within 2% of central differences, replay = autodiff, through the glass
    (next-event estimation through the transmission lobe, MIS with detached pdfs)."""
    rows = ir.gradcheck(window(0.3, type), ["glass.roughness"], spp=32, max_depth=2, seed=4)
    alpha = [r for r in rows if r.name == "glass.roughness"]
    assert len(alpha) == 1 and abs(alpha[0].fd) > 0.01
    for r in rows:
        for estimator, err in r.rel_errors.items():
            assert err < 0.02, (r.name, r.index, estimator, r.fd, r.gradients)
        a, b = r.gradients["autodiff"], r.gradients["replay"]
        assert abs(a - b) <= 1e-5 * max(abs(a), 1e-3), (r.name, r.index, a, b)


# ---------------------------------------------------------------- the scene formats


def test_toml_and_mitsuba_xml(tmp_path):
    toml = tmp_path / "s.toml"
    toml.write_text(
        '[camera]\norigin = [0, 0, 3]\n[materials.glass]\ntype = "roughdielectric"\nroughness = 0.2\nint_ior = "water"\n'
        '[emitters.light]\nemission = 1\n[[shapes]]\ntype = "rectangle"\nmaterial = "glass"\n[[shapes]]\ntype = "sphere"\nmaterial = "glass"\nemitter = "light"\n'
    )
    scene = ir.load_scene(toml)
    assert scene.params["glass.roughness"].tolist() == pytest.approx([0.2] * 3)
    spec = scene.material_spec(scene.materials.index("glass"))
    assert spec.type == "roughdielectric" and spec.constants["int_ior"] == pytest.approx(1.3330)
    head = '<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/><transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>'
    xml = tmp_path / "s.xml"
    for dist, want in (("", "roughdielectric"), ('<string name="distribution" value="ggx"/>', "roughdielectric_ggx")):
        xml.write_text(head + f'<shape type="rectangle"><bsdf type="roughdielectric">{dist}<float name="alpha" value="0.35"/><float name="int_ior" value="1.7"/>'
                       '<rgb name="specular_transmittance" value="0.5, 0.6, 0.7"/></bsdf></shape></scene>')  # fmt: skip
        scene = ir.load_scene(xml)
        (m,) = [n[: -len(".roughness")] for n in scene.params if n.endswith(".roughness")]
        spec = scene.material_spec(scene.materials.index(m))
        assert spec.type == want and spec.constants["int_ior"] == pytest.approx(1.7) and spec.constants["ext_ior"] == pytest.approx(1.000277)
        assert scene.params[f"{m}.roughness"].tolist() == pytest.approx([0.35] * 3)
        assert spec.constants["specular_transmittance"] == pytest.approx((0.5, 0.6, 0.7))


@pytest.mark.parametrize(
    "bsdf, message",
    [
        ('<float name="alpha_u" value="0.1"/>', "'alpha_u' needs 'alpha_v' too"),
        ('<float name="alpha" value="0.1"/><float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.2"/>', "give either 'alpha' or 'alpha_u' and 'alpha_v'"),
        ('<string name="distribution" value="phong"/>', "distribution"),
        ('<float name="alpha" value="1.5"/>', "alpha"),
        ('<float name="int_ior" value="-1"/>', "int_ior"),
        ('<float name="int_ior" value="1.2"/><float name="ext_ior" value="1.2"/>', "'int_ior' and 'ext_ior' must differ"),
        ('<float name="int_ior" value="500"/>', "expected a relative index of refraction in \\[0.01, 100\\]"),
    ],
)
def test_bad_input_is_a_one_line_error(tmp_path, bsdf, message):
    xml = tmp_path / "bad.xml"
    xml.write_text(
        '<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="40"/></sensor>'
        f'<shape type="rectangle"><bsdf type="roughdielectric">{bsdf}</bsdf></shape></scene>'
    )
    with pytest.raises(SceneError, match=message) as err:
        ir.load_scene(xml)
    assert "\n" not in str(err.value)


def test_to_mitsuba_writes_the_plugin_back():
    values = {"roughness": torch.full((3,), 0.25), "specular_reflectance": torch.ones(3)}
    out = RoughDielectricGGX.to_mitsuba(values, {"int_ior": 1.6, "ext_ior": 1.0, "specular_transmittance": (0.5, 0.5, 0.5)})
    assert out["type"] == "roughdielectric" and out["distribution"] == "ggx" and out["alpha"] == pytest.approx(0.25)
    assert out["int_ior"] == pytest.approx(1.6) and out["ext_ior"] == 1.0 and out["specular_transmittance"].tolist() == [0.5] * 3


def test_path_records_hold_specular_reflectance():
    """k_r is one factor of the reflected lobe's weights and values, none of the transmitted ones':
    records reweighted to another k_r give the render at it (the glass lit from both sides)."""
    from invrender.scene.builtin import rotate

    def scene(k):
        lamp_above = primitive("rectangle", "lamp", "light").transformed(translate([0, 0.8, 1.2]) @ rotate([1, 0, 0], 150) @ scale([0.3, 0.3, 1]))
        meshes = [primitive("rectangle", "glass").transformed(scale([1.5, 1.5, 1.0])), primitive("rectangle", "lamp", "light").transformed(translate([0.2, 0.0, -0.8]) @ scale([0.4, 0.4, 1.0])), lamp_above]
        materials = {"glass": Material.of("roughdielectric_ggx", roughness=0.3, specular_reflectance=k), "lamp": 0.0}
        return build_scene(meshes, materials, {"light": [20.0, 20.0, 20.0]}, Camera(origin=(0, -2.0, 2.2), target=(0, 0.2, 0), fov=50), (12, 12))

    kw = dict(spp=8, max_depth=3, progress=False, seed=1)
    records = ir.record_paths(scene([0.8, 0.8, 0.8]), ["glass.specular_reflectance"], **kw)
    assert float(records.jacobian()["glass.specular_reflectance"].abs().sum()) > 1.0
    other = records.image({"glass.specular_reflectance": torch.tensor([0.4, 0.5, 0.6])}).float()
    torch.testing.assert_close(other, ir.render(scene([0.4, 0.5, 0.6]), **kw), rtol=1e-4, atol=1e-6)
