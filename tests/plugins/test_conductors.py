"""Conductors and microfacet distributions against closed forms and Mitsuba 3's numbers: the
conductor Fresnel term, the named metals' RGB indices, Beckmann's D, G1 and visible-normal sampling
at several roughnesses and angles (the conformance suite checks every registered type at its
defaults only), and the TOML spellings of conductors and checkerboards."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.backends import arrays
from invrender.core import compiled, lanes
from invrender.errors import SceneError
from invrender.plugins.bsdfs import checks, metals
from invrender.plugins.bsdfs.glossy import Glossy, GlossyBeckmann
from invrender.plugins.bsdfs.metal_iors import METAL_IORS
from invrender.plugins.bsdfs.microfacet import BECKMANN, DISTRIBUTIONS, GGX
from invrender.plugins.bsdfs.mirror import Mirror

GOLD = METAL_IORS["Au"]
XP = arrays.drjit_arrays(torch.device("cpu"))


def exact_fresnel(cos_i: float, eta: float, k: float) -> float:
    """Unpolarized reflectance of a conductor n = eta + i k from complex amplitudes (not Mitsuba's form)."""
    n = complex(eta, k)
    s2 = 1.0 - cos_i * cos_i
    root = np.sqrt(n * n - s2)
    rs = (cos_i - root) / (cos_i + root)
    rp = (n * n * cos_i - root) / (n * n * cos_i + root)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


def test_conductor_fresnel_against_closed_forms():
    eta = torch.tensor([[0.2, 1.5, 3.0]])
    k = torch.tensor([[3.9, 0.0, 2.0]])
    normal = metals.fresnel_conductor(torch.tensor([1.0]), eta, k)
    closed = ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2)  # normal incidence
    assert torch.allclose(normal, closed, rtol=1e-6)
    assert float(closed[0, 1]) == pytest.approx(0.04)  # k = 0: a dielectric's ((n - 1) / (n + 1))^2
    for cos_i in (0.9, 0.5, 0.1):
        ours = metals.fresnel_conductor(torch.tensor([cos_i]), eta, k)[0]
        assert ours.tolist() == pytest.approx([exact_fresnel(cos_i, float(e), float(kk)) for e, kk in zip(eta[0], k[0])], rel=1e-5)
    grazing = metals.fresnel_conductor(torch.tensor([0.0]), eta, k)
    assert torch.allclose(grazing, torch.ones(1, 3))
    # Mitsuba's material "none": eta 0, k 1 reflects everything at every angle
    one = metals.fresnel_conductor(torch.linspace(0, 1, 11), torch.zeros(11, 3), torch.ones(11, 3))
    assert torch.allclose(one, torch.ones(11, 3), atol=1e-6)


def test_named_metals_are_mitsubas_rgb_values():
    """Against Mitsuba 3.9.1 scalar_rgb (``mi.traverse(mi.load_dict({"type": "conductor", "material": name}))``)."""
    mitsuba = {
        "Au": ((0.143036, 0.375307, 1.44205), (3.983, 2.38556, 1.60336)),
        "Cu": ((0.201005, 0.92375, 1.10222), (3.91326, 2.45305, 2.14209)),
        "Al": ((1.6575, 0.880405, 0.521244), (9.22381, 6.2695, 4.837)),
        "Ag": ((0.155276, 0.116728, 0.138388), (4.82835, 3.12222, 2.1469)),
        "Cr": ((4.36967, 2.91651, 1.6549), (5.20655, 4.23131, 3.7547)),
    }
    for name, (eta, k) in mitsuba.items():
        assert METAL_IORS[name][0] == pytest.approx(eta, rel=2e-5) and METAL_IORS[name][1] == pytest.approx(k, rel=2e-5), name
    assert len(METAL_IORS) == 71 and {"W", "TiN", "Cu_palik", "a-C"} <= set(metals.NAMES)
    assert metals.named("none", "x") == ((0.0,) * 3, (1.0,) * 3)
    with pytest.raises(SceneError, match=r"x: unknown conductor material 'Gold' \(known: none, a-C"):
        metals.named("Gold", "x")


def test_beckmann_D_is_normalized_and_G1_is_walters_approximation():
    assert DISTRIBUTIONS == {"ggx": GGX, "beckmann": BECKMANN}
    t = (torch.arange(20000, dtype=torch.float64) + 0.5) * (math.pi / 2 / 20000)
    for alpha in (0.05, 0.3, 1.0):
        a = torch.tensor(alpha, dtype=torch.float64)
        integral = float((BECKMANN.D(torch.cos(t), a) * torch.cos(t) * torch.sin(t)).sum() * 2 * math.pi * (math.pi / 2 / 20000))
        assert integral == pytest.approx(1.0, abs=2e-4), alpha
    cos_v = torch.linspace(0.02, 0.999, 400, dtype=torch.float64)
    for alpha in (0.1, 0.5, 1.0):
        a = 1.0 / (alpha * torch.sqrt(1 - cos_v**2) / cos_v)
        exact = 2.0 / (1.0 + torch.erf(a) + torch.exp(-a * a) / (a * math.sqrt(math.pi)))
        g = BECKMANN.G1(cos_v, torch.tensor(alpha, dtype=torch.float64))
        assert float(((g - exact) / exact).abs().max()) < 0.0035
        assert torch.equal(g[a >= 1.6], torch.ones_like(g[a >= 1.6]))  # Mitsuba's cut-off: exactly 1
        # and it differs from the exact form where the approximation is coarse (not the erf form itself)
        assert float(((g - exact) / exact).abs().max()) > 1e-4
    assert BECKMANN.G1(torch.tensor([1.0, -0.5]), torch.tensor(0.3)).tolist() == [1.0, 0.0]


@pytest.mark.parametrize("alpha,theta_o", [(0.05, 0.3), (0.3, 0.0), (0.3, 1.35), (0.8, 0.8), (1.0, 1.2)])
def test_beckmann_sampling_matches_pdf_and_weights(alpha, theta_o):
    gold = {"eta": GOLD[0], "k": GOLD[1]}
    bsdf = checks.instance(GlossyBeckmann, roughness=alpha, **gold)
    assert checks.chi_square_p(bsdf, theta_o, samples=100_000, seed=int(alpha * 100 + theta_o * 10)) > 1e-3
    pdf_err, weight_err, smooth = checks.weight_errors(bsdf, theta_o)
    assert pdf_err < 2e-3 and weight_err < 2e-3 and smooth > 0.3


def albedo_quadrature(bsdf, theta_o: float, n: int = 400) -> torch.Tensor:
    """int eval dw over the hemisphere (N, 3) by the midpoint rule in (cos theta, phi)."""
    c = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    p = (torch.arange(2 * n, dtype=torch.float64) + 0.5) * (math.pi / n)
    C, P = torch.meshgrid(c, p, indexing="ij")
    d = checks.local_directions(C, P).reshape(-1, 3).float()
    return bsdf.eval(checks.shading_point(theta_o, d.shape[0]), d).double().sum(0) * (1.0 / n) * (math.pi / n)


def test_beckmann_gold_energy_against_a_quadrature():
    """The mean sample weight (directional albedo) of rough gold at normal incidence against the
    integral of eval, near the Fresnel term at normal incidence (Beckmann and GGX)."""
    g = torch.Generator().manual_seed(5)
    for cls in (GlossyBeckmann, Glossy):
        bsdf = checks.instance(cls, roughness=0.3, eta=GOLD[0], k=GOLD[1])
        n = 200_000
        bs = bsdf.sample(checks.shading_point(0.0, n), torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
        sampled = bs.weight.double().mean(0)
        quad = albedo_quadrature(bsdf, 0.0)
        assert torch.allclose(sampled, quad, rtol=5e-3), (cls.type_name, sampled, quad)
        f0 = metals.fresnel_conductor(torch.tensor([1.0]), torch.tensor([GOLD[0]]), torch.tensor([GOLD[1]]))[0].double()
        assert bool((quad > 0.8 * f0).all()) and bool((quad < 1.02 * f0).all())  # single scattering at alpha 0.3 loses some (GGX more)


def test_mirror_weight_is_the_conductor_fresnel_term():
    mirror = checks.instance(Mirror, specular_reflectance=0.5, eta=GOLD[0], k=GOLD[1])
    for theta in (0.0, 1.0):
        ((wi, weight),) = mirror.specular_lobes(checks.shading_point(theta, 2))
        expected = [0.5 * exact_fresnel(math.cos(theta), e, k) for e, k in zip(*GOLD)]
        assert weight[0].tolist() == pytest.approx(expected, rel=1e-5)
    assert weight[0].tolist()[0] > weight[0].tolist()[2]  # gold: red reflected more than blue


def test_fresnel_one_computes_no_fresnel_term():
    """Material none (the default, and constants without eta/k) multiplies by nothing: the weights are
    k_s G1 exactly as before conductors had an index."""
    sp = checks.shading_point(0.7, 64)
    default = checks.instance(Glossy, roughness=0.3)
    bare = Glossy([{"specular_reflectance": torch.ones(3), "roughness": torch.full((3,), 0.3)}], [{}])
    assert default.fresnel(sp, torch.ones(64)) is None and bare.fresnel(sp, torch.ones(64)) is None
    u = torch.rand(64, 2, generator=torch.Generator().manual_seed(2))
    a, b = default.sample(sp, torch.zeros(64), u), bare.sample(sp, torch.zeros(64), u)
    assert torch.equal(a.weight, b.weight) and torch.equal(a.wi, b.wi)
    cos_i = sp.frame.to_local(a.wi)[:, 2]
    assert torch.equal(a.weight[:, 0], torch.where(cos_i > 0, GGX.G1(cos_i, torch.tensor(0.3)), 0.0))  # k_s G1, no factor more
    # mixed: a none material beside a gold one keeps F = 1 exactly where it is none
    mixed = Glossy([{"specular_reflectance": torch.ones(3), "roughness": torch.full((3,), 0.3)}] * 2, [{"eta": (0.0,) * 3, "k": (1.0,) * 3}, {"eta": GOLD[0], "k": GOLD[1]}])
    sp2 = checks.shading_point(0.7, 2)
    sp2.material[1] = 1
    f = mixed.fresnel(sp2, torch.tensor([0.6, 0.6]))
    assert f[0].tolist() == [1.0, 1.0, 1.0] and f[1].tolist() == pytest.approx([exact_fresnel(0.6, e, k) for e, k in zip(*GOLD)], rel=1e-5)


@pytest.mark.skipif(XP is None, reason="Dr.Jit's LLVM backend is not available")
@pytest.mark.parametrize("cls", [Glossy, GlossyBeckmann, Mirror])
def test_gold_lane_forms_compiled_equal_eager(cls):
    """With a Fresnel term (the registry's lane-form test covers the defaults, F = 1): Dr.Jit's
    compiled lanes give the eager torch ones, lane by lane, finite everywhere, and the eager ones
    are the material's methods."""
    extra = {"roughness": 0.2} if "roughness" in cls.params else {}
    bsdf = checks.instance(cls, eta=GOLD[0], k=GOLD[1], specular_reflectance=0.7, **extra)
    form = bsdf.lane_form()
    assert dict(form.keys)["eta"] == 3
    table = lanes.material_rows(bsdf, form.keys)
    n = 4096
    g = torch.Generator().manual_seed(3)
    wo, wi = (torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=1) for _ in range(2))
    wo[: n // 4, 2] *= 0.02  # grazing
    wo[n // 2 :, 2] = wo[n // 2 :, 2].abs()
    u = torch.rand(3, n, generator=g)
    front = torch.rand(n, generator=g) < 0.5

    def run(xp, table, m, wo, wi, front, u_lobe, u0, u1):
        p = lanes.material_values(xp, table, m, form.keys)
        return form.eval(xp, p, p, wo, wi, front) + form.sample(xp, p, p, wo, front, u_lobe, u0, u1)

    args = (table, torch.zeros(n, dtype=torch.int32), wo, wi, front, u[0], u[1], u[2])
    eager, jit = compiled.evaluate(arrays.TORCH, run, *args), compiled.evaluate(XP, run, *args)
    for a, b in zip(eager, jit):
        if a.dtype == torch.bool:
            assert torch.equal(a, b)
            continue
        assert bool(torch.isfinite(b).all())
        assert float(((a - b).abs() <= 1e-4 * a.abs().amax().clamp_min(1.0) + 1e-4 * a.abs()).float().mean()) > 0.999
    # the eager lanes are the methods (the shading frame at normal +z is the identity)
    sp = checks.shading_point(0.0, n)
    sp = type(sp)(wo, sp.n, sp.ng, front, sp.uv, sp.material, sp.slot)
    bs = bsdf.sample(sp, u[0], u[1:].T.contiguous())
    assert torch.allclose(bs.weight, eager[3], atol=1e-6) and torch.allclose(bs.pdf, eager[4], atol=1e-6)
    assert torch.allclose(bsdf.eval(sp, wi), eager[0], atol=1e-6) and torch.allclose(bs.wi, eager[2], atol=1e-6)


# ---------------------------------------------------------------- TOML


def write_toml(tmp_path, materials: str):
    path = tmp_path / "s.toml"
    path.write_text(materials + '\n[[shapes]]\ntype = "rectangle"\nmaterial = "m"\n')
    return path


def test_toml_conductors(tmp_path):
    scene = ir.load_scene(write_toml(tmp_path, '[materials.m]\ntype = "glossy_beckmann"\nmaterial = "Au"\nroughness = 0.2\n'))
    spec = scene.material_specs[0]
    assert spec.type == "glossy_beckmann" and spec.constants["eta"] == GOLD[0] and spec.constants["k"] == GOLD[1]
    scene = ir.load_scene(write_toml(tmp_path, '[materials.m]\ntype = "mirror"\neta = [0.2, 0.9, 1.1]\nk = [3.9, 2.4, 2.1]\n'))
    assert scene.material_specs[0].constants["eta"] == pytest.approx((0.2, 0.9, 1.1)) and scene.material_specs[0].constants["k"] == pytest.approx((3.9, 2.4, 2.1))
    scene = ir.load_scene(write_toml(tmp_path, '[materials.m]\ntype = "glossy"\nmaterial = "none"\n'))
    assert scene.material_specs[0].constants["eta"] == (0.0,) * 3 and scene.material_specs[0].constants["k"] == (1.0,) * 3
    bad = {
        'type = "glossy"\nmaterial = "Au"\neta = [1, 1, 1]': "give either material = 'Au' or 'eta', not both",
        'type = "mirror"\nmaterial = "gold"': "unknown conductor material 'gold' (known: none, a-C",
        'type = "mirror"\nmaterial = 3': "'material' must be a string naming a conductor",
        'type = "mirror"\nk = [1, -1, 1]': "'k' must lie in [0, inf)",
        'type = "diffuse"\nmaterial = "Au"': "unknown key 'material'",
    }
    for body, words in bad.items():
        with pytest.raises(SceneError) as info:
            ir.load_scene(write_toml(tmp_path, "[materials.m]\n" + body + "\n"))
        assert words in str(info.value) and "[materials.m]" in str(info.value), str(info.value)


def test_toml_checkerboard(tmp_path):
    scene = ir.load_scene(write_toml(tmp_path, '[materials.m]\nreflectance = { checkerboard = { color0 = [0.9, 0.1, 0.1], color1 = 0.3, scale = 2, resolution = 64 } }\n'))
    board = scene.params["m.reflectance"]
    assert board.shape == (64, 64, 3)
    assert board[0, 0].tolist() == pytest.approx([0.9, 0.1, 0.1]) and board[0, 16].tolist() == pytest.approx([0.3] * 3)
    assert board[16, 16].tolist() == pytest.approx([0.9, 0.1, 0.1]) and board[63, 0].tolist() == pytest.approx([0.3] * 3)
    default = ir.load_scene(write_toml(tmp_path, '[materials.m]\nreflectance = { checkerboard = { translate = [0.5, 0] } }\n')).params["m.reflectance"]
    assert default.shape == (512, 512, 3) and float(default[0, 0, 0]) == pytest.approx(0.2) and float(default[0, 300, 0]) == pytest.approx(0.4)
    bad = {
        '[materials.m]\nreflectance = { stripes = {} }': "a texture table holds one key naming its type (checkerboard)",
        '[materials.m]\nreflectance = { checkerboard = { colour0 = 1 } }': "unknown key 'colour0'",
        '[materials.m]\nreflectance = { checkerboard = { scale = 0 } }': "'scale' must be non-zero",
        '[materials.m]\ntype = "mirror"\nspecular_reflectance = { checkerboard = {} }': "'specular_reflectance' must be an RGB list or one number: it cannot be a texture",
    }
    for body, words in bad.items():
        with pytest.raises(SceneError) as info:
            ir.load_scene(write_toml(tmp_path, body + "\n"))
        assert words in str(info.value), str(info.value)
