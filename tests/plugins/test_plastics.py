"""Plastics (invrender/plugins/bsdfs/plastic.py): closed forms and quadratures a broken model misses,
Mitsuba's sampling weights, the scene formats and their one-line errors, and path records.

The registry-driven conformance suite (test_conformance.py) already checks their sampling against
their pdfs, weights against eval / pdf, delta samples against specular_lobes and albedo <= 1."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError, SceneError
from invrender.plugins.bsdfs import checks
from invrender.plugins.bsdfs.dielectric import fresnel_dielectric
from invrender.plugins.bsdfs.plastic import Plastic, RoughPlastic, RoughPlasticGGX, fresnel_diffuse_reflectance, rough_tables

ETA = 1.49 / 1.000277  # Mitsuba's default polypropylene over air
F0 = ((ETA - 1) / (ETA + 1)) ** 2
BOX = Path(__file__).parents[2] / "forward" / "cornell_box.xml"


def fresnel(c, eta):
    return float(fresnel_dielectric(torch.tensor([c], dtype=torch.float64), torch.tensor([eta], dtype=torch.float64))[0][0])


def diffuse_fresnel_integral(eta, n=20000):
    """2 int_0^1 F(mu, eta) mu dmu by the midpoint rule (float64)."""
    mu = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    F, _ = fresnel_dielectric(mu, torch.full_like(mu, eta))
    return float(2 * (F * mu).mean())


def mean_weight(bsdf, theta, n=200_000, seed=0):
    g = torch.Generator().manual_seed(seed)
    bs = bsdf.sample(checks.shading_point(theta, n), torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    return bs, bs.weight.double().mean(0)


# ---------------------------------------------------------------- the smooth plastic


def test_specular_lobe_at_normal_incidence_is_the_fresnel_term():
    bsdf = checks.instance(Plastic, specular_reflectance=0.8)
    ((wi, weight),) = bsdf.specular_lobes(checks.shading_point(0.0, 2))
    assert weight[0].tolist() == pytest.approx([0.8 * F0] * 3, rel=1e-5)
    assert wi[0].tolist() == pytest.approx([0.0, 0.0, 1.0], abs=1e-6)
    assert F0 == pytest.approx(0.03867, abs=1e-5)


def test_diffuse_fresnel_fits_against_the_integral():
    """Mitsuba's fits of the diffuse Fresnel reflectance (inside: Egan-Hilgeman; outside: d'Eon-Irving)
    against the integral, and reciprocity 1 - F_dr(1/eta) = (1 - F_dr(eta)) / eta^2."""
    for eta in (1.33, ETA, 1.7):
        inside, outside = diffuse_fresnel_integral(1 / eta), diffuse_fresnel_integral(eta)
        assert fresnel_diffuse_reflectance(1 / eta) == pytest.approx(inside, rel=3e-3)
        assert fresnel_diffuse_reflectance(eta) == pytest.approx(outside, rel=3e-3)
        assert 1 - inside == pytest.approx((1 - outside) / eta**2, rel=1e-4)
    assert fresnel_diffuse_reflectance(1 / ETA) == pytest.approx(0.5905, abs=5e-4)


@pytest.mark.parametrize("nonlinear", [False, True])
def test_diffuse_lobe_closed_form(nonlinear):
    rho = torch.tensor([0.2, 0.5, 0.9])
    bsdf = checks.instance(Plastic, reflectance=rho, nonlinear=nonlinear)
    sp = checks.shading_point(0.6, 1)
    wi = torch.tensor([[math.sin(1.1) * math.cos(2.0), math.sin(1.1) * math.sin(2.0), math.cos(1.1)]])
    fdr = fresnel_diffuse_reflectance(1 / ETA)
    base = rho / (1 - rho * fdr) if nonlinear else rho / (1 - fdr)
    expected = base * math.cos(1.1) / math.pi * (1 - fresnel(math.cos(0.6), ETA)) * (1 - fresnel(math.cos(1.1), ETA)) / ETA**2
    assert bsdf.eval(sp, wi)[0].tolist() == pytest.approx(expected.tolist(), rel=1e-5)
    # nonlinear darkens and saturates: the ratio to the linear model is (1 - F_dr) / (1 - rho F_dr)
    other = checks.instance(Plastic, reflectance=rho, nonlinear=not nonlinear).eval(sp, wi)[0]
    ratio = (bsdf.eval(sp, wi)[0] / other).tolist()
    want = ((1 - fdr) / (1 - rho * fdr)) ** (1 if nonlinear else -1)
    assert ratio == pytest.approx(want.tolist(), rel=1e-5)


@pytest.mark.parametrize("theta", [0.0, 0.7, 1.3])
def test_white_furnace_smooth_plastic_conserves_energy(theta):
    """rho = k_s = 1: the Fresnel reflection plus the diffuse part refracted out, summed over internal
    reflections, is F + (1 - F) (1 - F_dr,out) / (eta^2 (1 - F_dr,in)) = 1 (up to Mitsuba's fits);
    the Monte Carlo albedo agrees with that quadrature."""
    bsdf = checks.instance(Plastic, reflectance=1.0)
    _, albedo = mean_weight(bsdf, theta)
    F = fresnel(math.cos(theta), ETA)
    exact = F + (1 - F) * (1 - diffuse_fresnel_integral(ETA)) / (ETA**2 * (1 - fresnel_diffuse_reflectance(1 / ETA)))
    assert exact == pytest.approx(1.0, abs=2e-3)
    assert albedo.tolist() == pytest.approx([exact] * 3, abs=5e-3)


def test_lobe_choice_follows_mitsubas_specular_sampling_weight():
    """w = mean(k_s) / (mean(rho) + mean(k_s)) from the values the scene is built with (a constant);
    P_s = F w / (F w + (1 - F)(1 - w))."""
    from invrender.scene.materials import Material

    spec = Material.of("plastic", reflectance=[0.1, 0.3, 0.5], specular_reflectance=0.6)
    w = 0.6 / (0.3 + 0.6)
    assert spec.constants["specular_sampling_weight"] == pytest.approx(w)
    assert Material.of("plastic", specular_sampling_weight=0.25).constants["specular_sampling_weight"] == 0.25
    rho = torch.tensor([0.1, 0.3, 0.5], requires_grad=True)
    bsdf = Plastic([{"reflectance": rho, "specular_reflectance": torch.full((3,), 0.6)}], [dict(spec.constants)])
    bs, _ = mean_weight(bsdf, 0.0, n=100_000)
    p_s = F0 * w / (F0 * w + (1 - F0) * (1 - w))
    assert float(bs.delta.double().mean()) == pytest.approx(p_s, abs=4 * math.sqrt(p_s / 1e5))
    assert not bs.pdf.requires_grad and bs.weight.requires_grad  # sampling detached, weights differentiable


# ---------------------------------------------------------------- the rough plastics


def test_rough_tables_at_low_roughness_approach_the_smooth_interface():
    T, R = rough_tables("ggx", 0.01, ETA)
    mu = np.maximum(1e-6, np.linspace(0, 1, 64))
    smooth_T = [1 - fresnel(m, ETA) for m in mu]
    assert np.abs(np.asarray(T[16:]) - smooth_T[16:]).max() < 1e-3  # away from grazing
    assert T[-1] == pytest.approx(1 - F0, abs=1e-4)
    smooth_R = 2 * np.mean([fresnel(m, 1 / ETA) * m for m in mu])  # Mitsuba's 64-point mean rule
    assert R == pytest.approx(smooth_R, rel=5e-3)


@pytest.mark.parametrize("name, alpha", [("beckmann", 0.3), ("ggx", 0.5)])
def test_rough_tables_converge(name, alpha):
    """The default rules (32 and 64 nodes per axis) against 128 x 128 ones."""
    T, R = rough_tables(name, alpha, ETA)
    T2, R2 = rough_tables(name, alpha, ETA, (128, 128))
    assert np.abs(np.asarray(T) - T2).max() < 1e-3 and R == pytest.approx(R2, rel=1e-3)


@pytest.mark.parametrize("cls", [RoughPlastic, RoughPlasticGGX])
def test_rough_coating_reflects_what_it_does_not_transmit(cls):
    """rho = 0 (specular sampling weight 1): the albedo is the coating's reflection alone, and with its
    transmittance T it sums to a little under 1 (single scattering loses a little), 1 at low roughness."""
    for alpha, loss in ((0.05, 2e-3), (0.4, 0.1)):
        bsdf = checks.instance(cls, reflectance=0.0, roughness=alpha)
        T, _ = rough_tables(cls.distribution.name, alpha, ETA)
        for theta in (0.0, 1.0):
            _, albedo = mean_weight(bsdf, theta, n=100_000)
            t = float(np.interp(math.cos(theta), np.linspace(0, 1, 64), T))
            total = float(albedo[0]) + t
            assert 1 - loss - 3e-3 < total < 1 + 3e-3, (cls.type_name, alpha, theta, total)


@pytest.mark.parametrize("cls", [RoughPlastic, RoughPlasticGGX])
def test_rough_plastic_white_furnace_against_a_quadrature(cls):
    """rho = 1: the albedo is the coating's (sampled alone, rho = 0) plus the base's,
    T(c_o) / (eta^2 (1 - R_int)) 2 int T(mu) mu dmu (a quadrature of the table), and at most 1."""
    T, R = rough_tables(cls.distribution.name, 0.3, ETA)
    mu = (np.arange(4000) + 0.5) / 4000
    hemisphere = 2 * np.mean(np.interp(mu, np.linspace(0, 1, 64), T) * mu)
    for theta in (0.0, 0.8, 1.3):
        _, albedo = mean_weight(checks.instance(cls, reflectance=1.0, roughness=0.3), theta, n=100_000)
        _, coating = mean_weight(checks.instance(cls, reflectance=0.0, roughness=0.3), theta, n=100_000, seed=1)
        t_o = float(np.interp(math.cos(theta), np.linspace(0, 1, 64), T))
        expected = float(coating[0]) + t_o * hemisphere / (ETA**2 * (1 - R))
        assert float(albedo[0]) == pytest.approx(expected, abs=6e-3) and float(albedo.max()) < 1.0 + 5e-3


def test_rough_diffuse_lobe_closed_form():
    rho = torch.tensor([0.3, 0.6, 0.9])
    bsdf = checks.instance(RoughPlasticGGX, reflectance=rho, specular_reflectance=0.0, roughness=0.2, nonlinear=True)
    T, R = rough_tables("ggx", 0.2, ETA)
    sp = checks.shading_point(0.5, 1)
    wi = torch.tensor([[-math.sin(0.9), 0.0, math.cos(0.9)]])
    lerp = lambda c: float(np.interp(c, np.linspace(0, 1, 64), T))  # noqa: E731
    expected = rho / (1 - rho * R) * math.cos(0.9) / math.pi * lerp(math.cos(0.5)) * lerp(math.cos(0.9)) / ETA**2
    assert bsdf.eval(sp, wi)[0].tolist() == pytest.approx(expected.tolist(), rel=1e-5)


# ---------------------------------------------------------------- scene formats


def write_toml(tmp_path, body):
    path = tmp_path / "s.toml"
    path.write_text("[materials.m]\n" + body + '\n[[shapes]]\ntype = "rectangle"\nmaterial = "m"\n')
    return path


def test_toml_plastics(tmp_path):
    scene = ir.load_scene(write_toml(tmp_path, 'type = "plastic"\nreflectance = [0.2, 0.5, 0.8]\nint_ior = "bk7"\nnonlinear = true'))
    spec = scene.material_specs[0]
    assert spec.type == "plastic" and spec.constants == {"int_ior": 1.5046, "ext_ior": 1.000277, "nonlinear": 1.0, "specular_sampling_weight": pytest.approx(1 / 1.5)}
    assert scene.params["m.reflectance"].tolist() == pytest.approx([0.2, 0.5, 0.8]) and "m.specular_reflectance" in scene.params
    scene = ir.load_scene(write_toml(tmp_path, 'type = "roughplastic_ggx"\nroughness = 0.3\next_ior = "water"\nint_ior = 1.7'))
    assert scene.material_specs[0].constants == {"int_ior": 1.7, "ext_ior": 1.333, "nonlinear": 0.0, "specular_sampling_weight": 1 / 1.5}
    assert scene.params["m.roughness"].tolist() == pytest.approx([0.3] * 3)  # a parameter (kind roughness), as glossy's
    bad = {
        'type = "plastic"\nint_ior = -1': "'int_ior' must lie in (0, inf)",
        'type = "plastic"\nint_ior = "unobtainium"': "unknown int_ior 'unobtainium' (a number or one of vacuum",
        'type = "plastic"\nnonlinear = 2': "'nonlinear' must be true or false",
        'type = "roughplastic"\nint_ior = 1.2\next_ior = 1.2': "'int_ior' and 'ext_ior' must differ",
        # absurd indices: beyond float32, or a ratio no media have (whose eta^2 would make the render NaN)
        'type = "plastic"\nint_ior = 1e39': "'int_ior' is 1e+39, beyond float32's range (|x| <= 3.403e+38)",
        'type = "plastic"\nint_ior = 1e-30': "'int_ior' / 'ext_ior' = 1e-30 / 1.00028 = 9.99723e-31; expected a relative index of refraction in [0.01, 100]",
        'type = "roughplastic_ggx"\next_ior = 1e30': "'int_ior' / 'ext_ior' = 1.49 / 1e+30 = 1.49e-30; expected a relative index of refraction in [0.01, 100]",
        'type = "plastic"\nint_ior = 1e6': "= 999723; expected a relative index of refraction in [0.01, 100] (real media lie between 1 and about 4)",
        'type = "plastic"\nroughness = 0.2': "unknown key 'roughness'",
        'type = "plastic"\nspecular_reflectance = { checkerboard = {} }': "'specular_reflectance' must be an RGB list or one number",
        'type = "roughplastic_ggx"\nroughness = { checkerboard = {} }': "'roughness' must be an RGB list or one number",
    }
    for body, words in bad.items():
        with pytest.raises(SceneError) as info:
            ir.load_scene(write_toml(tmp_path, body))
        message = str(info.value)
        assert words in message and "[materials.m]" in message and "\n" not in message, message
    # the roughness is a parameter: its range is the roughness kind's, named as the parameter
    for value, words in (("0", "[0, 0]"), ("1.5", "[1.5, 1.5]")):
        with pytest.raises(ParameterError) as info:
            ir.load_scene(write_toml(tmp_path, f'type = "roughplastic"\nroughness = {value}'))
        message = str(info.value)
        assert f"m.roughness: roughness alpha must lie in (0, 1], got values in {words}" in message and "\n" not in message, message


def box_xml(tmp_path, large: str, small: str) -> Path:
    """forward/cornell_box.xml with its boxes' BSDFs replaced."""
    text = BOX.read_text()
    for shape, bsdf in (("large_box", large), ("small_box", small)):
        start = text.index(f'<shape type="cube" id="{shape}">')
        ref = text.index('<ref id="white"/>', start)
        text = text[:ref] + bsdf + text[ref + len('<ref id="white"/>') :]
    path = tmp_path / "box.xml"
    path.write_text(text)
    return path


def test_mitsuba_xml_plastics(tmp_path):
    path = box_xml(
        tmp_path,
        '<bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="0.1, 0.3, 0.6"/></bsdf>',
        '<bsdf type="twosided"><bsdf type="plastic"><float name="int_ior" value="1.9"/><string name="ext_ior" value="water"/>'
        '<boolean name="nonlinear" value="true"/><rgb name="specular_reflectance" value="0.5"/></bsdf></bsdf>',
    )
    scene = ir.load_scene(path, resolution=(8, 8))
    by_type = {s.type: (m, s) for m, s in zip(scene.materials, scene.material_specs)}
    large, small = by_type["roughplastic"], by_type["plastic"]
    assert large[1].constants == {"int_ior": 1.49, "ext_ior": 1.000277, "nonlinear": 0.0, "specular_sampling_weight": pytest.approx(1 / 1.3333333)}  # Mitsuba's defaults: Beckmann
    assert scene.params[f"{large[0]}.roughness"].tolist() == pytest.approx([0.1] * 3)  # alpha's default, the parameter
    assert scene.params[f"{large[0]}.reflectance"].tolist() == pytest.approx([0.1, 0.3, 0.6])
    assert small[1].constants == {"int_ior": 1.9, "ext_ior": 1.333, "nonlinear": 1.0, "specular_sampling_weight": pytest.approx(0.5)}
    assert scene.params[f"{small[0]}.specular_reflectance"].tolist() == pytest.approx([0.5] * 3)
    ggx = box_xml(tmp_path, '<bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.25"/></bsdf>', '<ref id="white"/>')
    scene = ir.load_scene(ggx, resolution=(8, 8))
    name, spec = next((m, s) for m, s in zip(scene.materials, scene.material_specs) if s.type.startswith("rough"))
    assert spec.type == "roughplastic_ggx" and scene.params[f"{name}.roughness"].tolist() == pytest.approx([0.25] * 3)
    bad = {
        '<bsdf type="roughplastic"><string name="distribution" value="phong"/></bsdf>': "distribution 'phong' is not supported (supported: beckmann, ggx)",
        '<bsdf type="roughplastic"><float name="alpha_u" value="0.2"/></bsdf>': "anisotropic roughness",
        '<bsdf type="roughplastic"><float name="alpha" value="0"/></bsdf>': "'alpha' (Beckmann roughness) must lie in (0, 1]",
        '<bsdf type="plastic"><float name="int_ior" value="-1.5"/></bsdf>': "'int_ior' must be positive",
        '<bsdf type="plastic"><string name="int_ior" value="cheese"/></bsdf>': "unknown int_ior 'cheese'",
        '<bsdf type="plastic"><float name="alpha" value="0.1"/></bsdf>': "alpha",
        '<bsdf type="roughplastic"><float name="int_ior" value="1.000277"/></bsdf>': "'int_ior' and 'ext_ior' must differ",
    }
    for bsdf, words in bad.items():
        with pytest.raises(SceneError) as info:
            ir.load_scene(box_xml(tmp_path, bsdf, '<ref id="white"/>'), resolution=(8, 8))
        message = str(info.value)
        assert words in message and "box.xml:" in message and "\n" not in message, message


def test_to_mitsuba_writes_mitsubas_plugins():
    values = {"reflectance": np.array([0.1, 0.2, 0.3]), "specular_reflectance": np.ones(3)}
    d = RoughPlasticGGX.to_mitsuba({**values, "roughness": np.full(3, 0.2)}, {"int_ior": 1.5, "ext_ior": 1.0, "nonlinear": 1.0})
    assert d["type"] == "twosided"
    inner = d["bsdf"]
    assert inner["type"] == "roughplastic" and inner["distribution"] == "ggx" and inner["alpha"] == 0.2 and inner["nonlinear"] is True
    assert inner["int_ior"] == 1.5 and inner["diffuse_reflectance"] is values["reflectance"]
    assert Plastic.to_mitsuba(values, {"int_ior": 1.49, "ext_ior": 1.0, "nonlinear": 0.0})["bsdf"]["type"] == "plastic"


# ---------------------------------------------------------------- path records and renders


def test_path_records_take_the_smooth_plastic_and_refuse_the_others(tmp_path):
    plastic = '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.3, 0.5, 0.7"/><rgb name="specular_reflectance" value="0.9"/></bsdf>'
    scene = ir.load_scene(box_xml(tmp_path, plastic, '<ref id="white"/>'), resolution=(8, 8))
    name = next(m for m, s in zip(scene.materials, scene.material_specs) if s.type == "plastic")
    params = [f"{name}.reflectance", f"{name}.specular_reflectance", "white.reflectance"] if "white" in scene.materials else [f"{name}.reflectance"]
    rec = ir.record_paths(scene, params, spp=4, max_depth=4, seed=1, progress=False)
    img = ir.render(scene, spp=4, max_depth=4, seed=1, progress=False)
    torch.testing.assert_close(rec.image().float(), img, rtol=1e-4, atol=1e-6)
    rough = ir.load_scene(box_xml(tmp_path, plastic.replace('"plastic"', '"roughplastic"'), '<ref id="white"/>'), resolution=(8, 8))
    name = next(m for m, s in zip(rough.materials, rough.material_specs) if s.type == "roughplastic")
    with pytest.raises(ParameterError, match="sums two lobes"):
        ir.record_paths(rough, [f"{name}.reflectance"], spp=1, max_depth=2, progress=False)
    nonlinear = ir.load_scene(box_xml(tmp_path, plastic.replace("</bsdf>", '<boolean name="nonlinear" value="true"/></bsdf>'), '<ref id="white"/>'), resolution=(8, 8))
    name = next(m for m, s in zip(nonlinear.materials, nonlinear.material_specs) if s.type == "plastic")
    with pytest.raises(ParameterError, match="nonlinear = true"):
        ir.record_paths(nonlinear, [f"{name}.reflectance"], spp=1, max_depth=2, progress=False)


def test_gradients_through_both_lobes_match_finite_differences(tmp_path):
    """A box of each plastic: gradients of their reflectances and the rough one's alpha (seen
    directly and through the box's walls, depth 4) within 2% of central differences for both
    estimators, and replay = autodiff."""
    path = box_xml(
        tmp_path,
        '<bsdf type="roughplastic" id="rough"><rgb name="diffuse_reflectance" value="0.2, 0.4, 0.6"/><rgb name="specular_reflectance" value="0.7"/>'
        '<float name="alpha" value="0.2"/></bsdf>',
        '<bsdf type="plastic" id="smooth"><rgb name="diffuse_reflectance" value="0.6, 0.4, 0.2"/><rgb name="specular_reflectance" value="0.8"/></bsdf>',
    )
    scene = ir.load_scene(path, resolution=(12, 12))
    params = ["rough.reflectance", "rough.specular_reflectance", "rough.roughness", "smooth.reflectance", "smooth.specular_reflectance"]
    rows = ir.gradcheck(scene, params, spp=16, max_depth=4, seed=3)
    assert {r.name for r in rows} == set(params)
    for r in rows:
        for estimator, err in r.rel_errors.items():
            assert err < 0.02, (r.name, r.index, estimator, r.fd, r.gradients)
        a, b = r.gradients["autodiff"], r.gradients["replay"]
        assert abs(a - b) <= 1e-5 * max(abs(a), 1e-3), (r.name, r.index, a, b)
