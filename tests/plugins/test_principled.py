"""The principled materials (invrender/plugins/bsdfs/principled.py, principledthin.py): eval and pdf
against Mitsuba 3.9.1's values (computed with mitsuba's llvm_ad_rgb variant by
bench/principled_compare.py's settings and hard-coded here: no Mitsuba at test time), sampling
against pdf, energy bounds, the gradient of a render against finite differences, the Mitsuba
loader (twosided, specular -> eta) and its one-line errors.

The registry-driven conformance suite (test_conformance.py) also checks them at their defaults."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

import invrender as ir
from invrender.core.bsdf import ShadingPoint
from invrender.errors import SceneError
from invrender.plugins.bsdfs import checks
from invrender.plugins.bsdfs.principled import Principled
from invrender.plugins.bsdfs.principledthin import PrincipledThin

BOX = Path(__file__).parents[2] / "forward" / "cornell_box.xml"

#: bench/principled_compare.py's settings (Mitsuba properties; specular read as eta as the loader does)
SETTINGS = {
    "default": ("principled", {}, False),
    "metal": ("principled", {"base_color": [0.9, 0.6, 0.2], "metallic": 0.8, "roughness": 0.3, "spec_tint": 0.5, "specular": 0.7}, False),
    "aniso": ("principled", {"base_color": [0.2, 0.5, 0.8], "roughness": 0.6, "anisotropic": 0.7, "metallic": 0.3}, False),
    "sheen_coat": ("principled", {"base_color": [0.7, 0.3, 0.3], "sheen": 0.8, "sheen_tint": 0.6, "clearcoat": 0.9, "clearcoat_gloss": 0.7, "roughness": 0.4}, False),
    "glass": ("principled", {"base_color": [0.9, 0.95, 1.0], "spec_trans": 1.0, "eta": 1.45, "roughness": 0.2}, False),
    "mixed": ("principled", {"base_color": [0.5, 0.8, 0.3], "spec_trans": 0.4, "metallic": 0.2, "clearcoat": 0.5, "sheen": 0.3, "roughness": 0.5, "anisotropic": 0.3, "flatness": 0.4}, False),
    "twosided": ("principled", {"base_color": [0.3, 0.6, 0.9], "roughness": 0.35, "spec_tint": 0.3, "sheen": 0.4, "specular": 0.4}, True),
    "everything": ("principled", {"base_color": [0.8, 0.4, 0.6], "metallic": 0.5, "specular": 0.6, "roughness": 0.25, "spec_tint": 0.4, "anisotropic": 0.5,
                                  "sheen": 0.3, "sheen_tint": 0.2, "clearcoat": 0.6, "clearcoat_gloss": 0.3, "spec_trans": 0.4}, False),
    "thin_default": ("principledthin", {}, False),
    "thin_leaf": ("principledthin", {"base_color": [0.3, 0.7, 0.2], "roughness": 0.45, "spec_trans": 0.3, "diff_trans": 0.8, "sheen": 0.5, "sheen_tint": 0.4, "spec_tint": 0.3}, False),
    "thin_aniso": ("principledthin", {"base_color": [0.8, 0.8, 0.9], "roughness": 0.3, "anisotropic": 0.6, "spec_trans": 0.7, "eta": 1.33, "flatness": 0.5, "diff_trans": 1.5}, False),
}

#: (setting, Mitsuba's si.wi (towards the camera), wo (towards the light), both local and rounded
#: (normalized before use), Mitsuba's eval (RGB) and pdf there)
MITSUBA = [
    ('default', [-0.81172, 0.20319, 0.54757], [-0.59432, -0.69731, 0.40069], [0.06612773, 0.06612773, 0.06612773], 0.07200736),
    ('default', [0.35356, -0.62485, 0.6961], [0.71476, -0.68629, 0.13462], [0.02575511, 0.02575511, 0.02575511], 0.02668137),
    ('default', [0.56449, 0.56732, 0.59958], [0.66788, 0.13427, 0.73206], [0.1181332, 0.1181332, 0.1181332], 0.1293555),
    ('metal', [0.84016, -0.34958, 0.41463], [-0.97144, 0.20948, 0.11147], [0.07287215, 0.05433789, 0.02962552], 0.08845979),
    ('metal', [-0.72394, -0.04621, 0.68831], [-0.54959, -0.82398, 0.13787], [0.008776782, 0.005853896, 0.001956712], 0.008597773),
    ('metal', [-0.89615, 0.3186, 0.30888], [0.1376, -0.22938, 0.96356], [0.07424141, 0.04956357, 0.01665977], 0.07439038),
    ('aniso', [-0.71839, -0.39482, 0.57274], [0.50852, 0.22901, 0.83004], [0.08830693, 0.1922525, 0.2961981], 0.4359187),
    ('aniso', [0.33871, 0.73781, 0.58388], [-0.5262, -0.8336, 0.16799], [0.05988371, 0.09452745, 0.1291712], 0.3211361),
    ('aniso', [0.70154, 0.69966, 0.1353], [0.74805, -0.6528, 0.11946], [0.0158245, 0.03433379, 0.05284308], 0.1677924),
    ('sheen_coat', [0.60966, -0.70715, 0.35814], [0.28253, 0.41396, 0.86534], [0.1954858, 0.08532752, 0.08532752], 0.1433903),
    ('sheen_coat', [-0.15041, -0.01568, 0.9885], [-0.90648, 0.34292, 0.24637], [0.05617444, 0.02440788, 0.02440788], 0.04195773),
    ('sheen_coat', [-0.44732, 0.38247, 0.80847], [-0.82647, -0.51362, 0.23054], [0.0524088, 0.02268896, 0.02268896], 0.03744458),
    ('glass', [-0.39881, 0.74777, -0.53084], [0.92498, -0.19617, -0.32546], [0.001216743, 0.001216743, 0.001216743], 0.001220837),
    ('glass', [0.53739, 0.05064, -0.84181], [-0.81651, 0.0328, -0.5764], [0.08556749, 0.08556749, 0.08556749], 0.08563623),
    ('glass', [-0.50796, -0.71347, -0.48264], [0.23232, 0.93666, 0.2621], [0.004752704, 0.004882939, 0.00500979], 0.00239563),
    ('mixed', [-0.04897, -0.21942, 0.9744], [0.81027, 0.20461, 0.54918], [0.05685171, 0.08787574, 0.03616903], 0.116408),
    ('mixed', [-0.76164, 0.26878, 0.58963], [-0.01432, -0.86129, 0.50791], [0.04642194, 0.0730969, 0.02863865], 0.06793296),
    ('mixed', [0.03253, 0.45262, 0.89111], [0.23948, 0.12471, -0.96286], [0.0009466655, 0.001197448, 0.000733284], 0.001879644),
    ('twosided', [-0.09331, 0.5295, -0.84316], [0.25976, -0.49468, -0.82935], [0.1443581, 0.2351364, 0.3259146], 1.255668),
    ('twosided', [-0.67938, 0.58666, -0.44076], [-0.25193, 0.9514, -0.17708], [0.01796808, 0.03586842, 0.05376876], 0.02984531),
    ('twosided', [-0.91577, -0.08828, -0.39189], [-0.87113, 0.15639, -0.46549], [0.04563947, 0.09117976, 0.13672], 0.07632815),
    ('everything', [0.73972, -0.62509, 0.24916], [-0.37617, -0.82203, 0.42751], [0.03147051, 0.01581731, 0.02364391], 0.02941858),
    ('everything', [-0.33803, 0.9064, -0.25332], [0.22109, -0.93461, -0.2786], [0.210326, 0.210326, 0.210326], 1.059109),
    ('everything', [0.17096, -0.35634, -0.91858], [0.02426, 0.83842, 0.54448], [0.002071482, 0.001464759, 0.001793956], 0.004757645),
    ('thin_default', [0.92955, -0.12723, 0.34606], [0.91893, 0.17686, 0.35254], [0.06252597, 0.06252597, 0.06252597], 0.1122172),
    ('thin_default', [0.62028, -0.61944, -0.48119], [0.52528, 0.18053, -0.83156], [0.1338798, 0.1338798, 0.1338798], 0.2646935),
    ('thin_default', [-0.71249, -0.22066, -0.66608], [-0.89479, -0.3822, -0.23081], [0.04113953, 0.04113953, 0.04113953], 0.07346913),
    ('thin_leaf', [0.31628, 0.24604, -0.91621], [0.55628, 0.35822, -0.74983], [0.03044287, 0.0706423, 0.02039301], 0.1055219),
    ('thin_leaf', [0.04689, -0.46768, -0.88265], [-0.59382, 0.70746, -0.38325], [0.01640746, 0.0370344, 0.01125073], 0.06313521),
    ('thin_leaf', [-0.83134, 0.49326, 0.25608], [0.8161, 0.50008, -0.28966], [0.007744929, 0.0180715, 0.005163286], 0.02581643),
    ('thin_aniso', [0.19813, 0.10705, 0.97431], [-0.11799, -0.77318, 0.62311], [0.01068869, 0.01068869, 0.01201352], 0.01701178),
    ('thin_aniso', [0.81579, -0.1652, -0.55426], [-0.64197, -0.16306, -0.74919], [0.01512644, 0.01512644, 0.01686982], 0.03771949),
    ('thin_aniso', [0.22701, 0.52717, 0.81888], [-0.20268, -0.79572, -0.57074], [0.03752194, 0.03752194, 0.04221218], 0.04397503),
]


def material(setting: str):
    plugin, props, twosided = SETTINGS[setting]
    entries = {k: v for k, v in props.items() if k != "specular"}
    if plugin == "principled" and "eta" not in props:
        entries["eta"] = 2.0 / (1.0 - math.sqrt(0.08 * props.get("specular", 0.5))) - 1.0
    if plugin == "principled":
        entries["two_sided"] = twosided  # Mitsuba's principled is one-sided unless wrapped
    return checks.instance(Principled if plugin == "principled" else PrincipledThin, **entries)


def point(wi_mitsuba) -> ShadingPoint:
    """invrender's view of Mitsuba's si.wi (local, normal +z): wo = si.wi, the normal turned to it."""
    wo = torch.tensor(wi_mitsuba, dtype=torch.float32)
    front = wo[:, 2] > 0
    n = torch.zeros_like(wo)
    n[:, 2] = torch.where(front, 1.0, -1.0)
    zeros = torch.zeros(wo.shape[0], dtype=torch.int64)
    return ShadingPoint(wo, n, n, front, torch.zeros(wo.shape[0], 2), zeros, zeros)


def unit(rows) -> np.ndarray:
    v = np.asarray(rows, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_eval_and_pdf_match_mitsuba(setting):
    rows = [r for r in MITSUBA if r[0] == setting]
    assert rows
    bsdf = material(setting)
    sp = point(unit([r[1] for r in rows]))
    wi = torch.tensor(unit([r[2] for r in rows]), dtype=torch.float32)
    f, pdf = bsdf.eval(sp, wi).double(), bsdf.pdf(sp, wi).double()
    want_f = torch.tensor([r[3] for r in rows], dtype=torch.float64)
    want_pdf = torch.tensor([r[4] for r in rows], dtype=torch.float64)
    torch.testing.assert_close(f, want_f, rtol=1e-4, atol=1e-7)
    torch.testing.assert_close(pdf, want_pdf, rtol=1e-4, atol=1e-7)


# ---------------------------------------------------------------- sampling, energy


@pytest.mark.parametrize("setting, front", [("metal", True), ("aniso", True), ("sheen_coat", True), ("glass", True), ("glass", False),
                                            ("twosided", False), ("thin_leaf", True), ("thin_aniso", False)])  # fmt: skip
def test_sampling_matches_pdf(setting, front):
    """Chi-square of the samples against pdf (settings where Mitsuba's lobe choice follows its pdf:
    opaque, or spec_trans = 1, or the thin sheet; see the module docstring of principled.py)."""
    bsdf = material(setting)
    assert checks.chi_square_p(bsdf, 0.7, samples=100_000, seed=3, front=front) > 1e-3


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_sample_weight_is_eval_over_pdf(setting):
    for front in (True, False):
        pdf_err, weight_err, _ = checks.weight_errors(material(setting), 0.9, front=front)
        assert pdf_err < 2e-3 and weight_err < 2e-3, (front, pdf_err, weight_err)


def albedo(bsdf, theta: float, front: bool = True, n: int = 200_000) -> torch.Tensor:
    g = torch.Generator().manual_seed(2)
    bs = bsdf.sample(checks.shading_point(theta, n, front=front), torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    return bs.weight.double().mean(0)


def test_white_furnace_burley_diffuse_closed_form():
    """eta = 1 turns the specular lobe off (F = 0), leaving Burley's diffuse with retro-reflection:
    at normal incidence its albedo is ``2 int_0^1 [1 - (1 - mu)^5 / 2 + r (1 + mu)(1 - mu)^5] mu dmu
    = 1 - 1/42 + 10 r / 168`` (above 1 for r > 0.4: Burley's model is not energy-conserving), the same
    for the thin sheet."""
    for r in (0.25, 0.8):
        want = 1.0 - 1.0 / 42.0 + 10.0 * r / 168.0
        for bsdf in (checks.instance(Principled, base_color=1.0, roughness=r, eta=1.0), checks.instance(PrincipledThin, base_color=1.0, roughness=r)):
            assert albedo(bsdf, 0.0).tolist() == pytest.approx([want] * 3, rel=3e-3), (bsdf.type_name, r)


def test_white_furnace_metal_and_glass():
    """A white metal reflects all but what single scattering loses (about 0.2% at alpha 0.04); a
    white glass at normal incidence splits into ``F0 + (1 - F0) / eta^2`` from outside and ``F0 +
    (1 - F0) eta^2`` from inside (radiance scaled across the interface)."""
    metal = albedo(checks.instance(Principled, base_color=1.0, metallic=1.0, roughness=0.2), 0.0)
    assert 0.99 < float(metal.min()) and float(metal.max()) < 1.0 + 3e-3
    glass = checks.instance(Principled, base_color=1.0, spec_trans=1.0, roughness=0.2, eta=1.5)
    F0 = 0.04
    assert albedo(glass, 0.0).tolist() == pytest.approx([F0 + (1 - F0) / 2.25] * 3, rel=1e-2)
    assert albedo(glass, 0.0, front=False).tolist() == pytest.approx([F0 + (1 - F0) * 2.25] * 3, rel=1.5e-2)


def test_opaque_back_side_is_black_unless_two_sided():
    # a fresh ShadingPoint per BSDF: its lookups are cached by the BSDF's id, which a freed BSDF's successor may reuse
    wi = torch.nn.functional.normalize(torch.randn(64, 3, generator=torch.Generator().manual_seed(0)), dim=1)
    assert float(material("default").eval(checks.shading_point(0.4, 64, front=False), wi).abs().max()) == 0.0
    two = material("twosided")
    torch.testing.assert_close(two.eval(checks.shading_point(0.4, 64, front=False), wi), two.eval(checks.shading_point(0.4, 64), wi))


@pytest.mark.parametrize("cls, key", [(Principled, "clearcoat"), (Principled, "sheen"), (Principled, "spec_trans"), (Principled, "metallic"),
                                      (PrincipledThin, "spec_trans"), (PrincipledThin, "sheen")])  # fmt: skip
def test_derivative_at_a_zero_weight_is_its_lobes(cls, key):
    """eval is linear in each of these weights, so its derivative at 0 equals the difference quotient
    (Mitsuba masks a lobe of weight 0, which would make it 0: a fit could never start there)."""
    g = torch.Generator().manual_seed(4)
    wi = torch.nn.functional.normalize(torch.randn(256, 3, generator=g), dim=1)
    entries = {"base_color": 0.6, "roughness": 0.4, **({"two_sided": False, "metallic": 0.3} if cls is Principled else {}), key: 0.0}
    bsdf = checks.instance(cls, **entries)
    weight = bsdf.values[0][key].requires_grad_(True)
    f0 = bsdf.eval(checks.shading_point(0.5, 256), wi)
    (grad,) = torch.autograd.grad(f0.sum(), weight)
    step = checks.instance(cls, **{**entries, key: 1e-2})
    quotient = float((step.eval(checks.shading_point(0.5, 256), wi) - f0.detach()).sum()) / 1e-2
    assert abs(quotient) > 1e-2 and float(grad.sum()) == pytest.approx(quotient, rel=2e-3)


# ---------------------------------------------------------------- the Mitsuba loader, renders, gradients


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


LARGE = ('<bsdf type="principled" id="large"><rgb name="base_color" value="0.8, 0.4, 0.2"/><float name="metallic" value="0.3"/>'
         '<float name="roughness" value="0.4"/><float name="clearcoat" value="0.5"/><rgb name="spec_tint" value="0.2, 0.4, 0.6"/></bsdf>')  # fmt: skip
SMALL = ('<bsdf type="twosided" id="small"><bsdf type="principled"><rgb name="base_color" value="0.2, 0.5, 0.7"/><float name="specular" value="0.3"/>'
         '<float name="spec_trans" value="0.0"/><float name="sheen" value="0.4"/></bsdf></bsdf>')  # fmt: skip


def test_mitsuba_xml_principled(tmp_path):
    scene = ir.load_scene(box_xml(tmp_path, LARGE, SMALL), resolution=(8, 8))
    large = scene.material_spec(scene.materials.index("large"))
    small = scene.material_spec(scene.materials.index("small"))
    assert large.type == small.type == "principled"
    assert scene.params["large.base_color"].tolist() == pytest.approx([0.8, 0.4, 0.2])
    assert scene.params["large.spec_tint"].tolist() == pytest.approx([0.4] * 3)  # a colour weight: its channel mean, Mitsuba's eval_1
    assert scene.params["large.metallic"].tolist() == pytest.approx([0.3] * 3) and scene.params["large.clearcoat"].tolist() == pytest.approx([0.5] * 3)
    assert large.constants["eta"] == pytest.approx(1.5) and large.constants["two_sided"] == 0.0
    assert small.constants["eta"] == pytest.approx(2.0 / (1.0 - math.sqrt(0.08 * 0.3)) - 1.0) and small.constants["two_sided"] == 1.0
    img = ir.render(scene, spp=2, max_depth=3, seed=1, progress=False)
    assert bool(torch.isfinite(img).all()) and float(img.mean()) > 0.01


@pytest.mark.parametrize(
    "bsdf, words",
    [
        ('<bsdf type="principled"><float name="eta" value="1.4"/><float name="specular" value="0.5"/></bsdf>', "give either 'eta' or 'specular', not both"),
        ('<bsdf type="principled"><float name="subsurface" value="0.5"/></bsdf>', "subsurface"),
        ('<bsdf type="principled"><float name="metallic" value="1.5"/></bsdf>', "'metallic'"),
        ('<bsdf type="principled"><float name="specular" value="-0.1"/></bsdf>', "'specular'"),
        ('<bsdf type="twosided"><bsdf type="principled"><float name="spec_trans" value="0.5"/></bsdf></bsdf>', "twosided cannot wrap a principled BSDF with spec_trans > 0"),
        ('<bsdf type="twosided"><bsdf type="principledthin"/></bsdf>', "twosided cannot wrap a principledthin BSDF"),
        ('<bsdf type="principledthin"><float name="diff_trans" value="2.5"/></bsdf>', "'diff_trans'"),
        ('<bsdf type="principledthin"><float name="metallic" value="0.5"/></bsdf>', "metallic"),
    ],
)
def test_bad_input_is_a_one_line_error(tmp_path, bsdf, words):
    with pytest.raises(SceneError) as info:
        ir.load_scene(box_xml(tmp_path, bsdf, '<ref id="white"/>'), resolution=(8, 8))
    message = str(info.value)
    assert words in message and "box.xml:" in message and "\n" not in message, message


def test_gradients_match_finite_differences(tmp_path):
    """The boxes' base colours and the large one's metallic: both estimators within 2% of central
    differences, replay = autodiff."""
    scene = ir.load_scene(box_xml(tmp_path, LARGE, SMALL), resolution=(10, 10))
    params = ["large.base_color", "large.metallic", "small.base_color"]
    rows = ir.gradcheck(scene, params, spp=8, max_depth=3, seed=3)
    assert {r.name for r in rows} == set(params)
    for r in rows:
        for estimator, err in r.rel_errors.items():
            assert err < 0.02, (r.name, r.index, estimator, r.fd, r.gradients)
        a, b = r.gradients["autodiff"], r.gradients["replay"]
        assert abs(a - b) <= 1e-5 * max(abs(a), 1e-3), (r.name, r.index, a, b)


THIN = ('<bsdf type="principledthin" id="thin"><rgb name="base_color" value="0.3, 0.7, 0.4"/><float name="spec_trans" value="0.4"/>'
        '<float name="diff_trans" value="0.8"/><float name="roughness" value="0.5"/><float name="sheen" value="0.3"/></bsdf>')  # fmt: skip


def test_gradients_of_the_weights_and_roughness_match_finite_differences(tmp_path):
    """The principled roughness and clearcoat, and a thin sheet's base colour, spec_trans and roughness
    (read detached by sampling, attached by eval): within 2% of central differences, replay = autodiff."""
    scene = ir.load_scene(box_xml(tmp_path, LARGE, THIN), resolution=(10, 10))
    params = ["large.roughness", "large.clearcoat", "thin.base_color", "thin.spec_trans", "thin.roughness"]
    rows = ir.gradcheck(scene, params, spp=8, max_depth=3, seed=3)
    assert {r.name for r in rows} == set(params)
    for r in rows:
        for estimator, err in r.rel_errors.items():
            assert err < 0.02, (r.name, r.index, estimator, r.fd, r.gradients)
        a, b = r.gradients["autodiff"], r.gradients["replay"]
        assert abs(a - b) <= 1e-5 * max(abs(a), 1e-3), (r.name, r.index, a, b)


def test_path_records_refuse_principled(tmp_path):
    from invrender.errors import ParameterError

    scene = ir.load_scene(box_xml(tmp_path, LARGE, SMALL), resolution=(8, 8))
    with pytest.raises(ParameterError, match="not a polynomial factor"):
        ir.record_paths(scene, ["large.base_color"], spp=1, max_depth=2, progress=False)


def test_to_mitsuba_round_trip():
    values = {k: torch.full((3,), 0.25) for k in Principled.params}
    out = Principled.to_mitsuba(values, {"eta": 1.4, "main_specular_sampling_rate": 1.0, "clearcoat_sampling_rate": 1.0, "diffuse_reflectance_sampling_rate": 1.0, "two_sided": 1.0})
    assert out["type"] == "twosided" and out["bsdf"]["type"] == "principled" and out["bsdf"]["metallic"] == 0.25 and out["bsdf"]["eta"] == 1.4


def test_toml_principled_with_textures(tmp_path):
    """TOML: two-sided by default; base_color and a weight may be textures (a weight's map is grey);
    the back of a two-sided material shades as its front."""
    path = tmp_path / "s.toml"
    path.write_text(
        '[camera]\norigin = [0, 0, 3]\n[materials.m]\ntype = "principled"\nmetallic = { checkerboard = { color0 = 0.9, color1 = 0.1, resolution = 8 } }\n'
        'base_color = { checkerboard = { color0 = [0.9, 0.2, 0.1], color1 = 0.3, resolution = 8 } }\nclearcoat = 0.4\n'
        '[emitters.light]\nemission = 1\n[[shapes]]\ntype = "rectangle"\nmaterial = "m"\n[[shapes]]\ntype = "sphere"\nmaterial = "m"\nemitter = "light"\n'
    )
    scene = ir.load_scene(path, resolution=(8, 8))
    spec = scene.material_spec(scene.materials.index("m"))
    assert spec.type == "principled" and spec.constants["two_sided"] == 1.0 and spec.constants["eta"] == 1.5
    metallic, base = scene.params["m.metallic"], scene.params["m.base_color"]
    assert metallic.ndim == 3 and bool((metallic == metallic[..., :1]).all()) and {round(float(x), 4) for x in metallic.unique()} == {0.1, 0.9}
    assert base.ndim == 3 and scene.params["m.clearcoat"].tolist() == pytest.approx([0.4] * 3)
    img = ir.render(scene, spp=2, max_depth=3, seed=1, progress=False)
    assert bool(torch.isfinite(img).all()) and float(img.mean()) > 0


#: a scene in the form mitsuba-blender writes (named top-level objects, a twosided principled with
#: every weight given, `specular` for an opaque material and `eta` for a transmissive one, a
#: constant environment), written here by hand in that form
BLENDER_XML = """<scene version="2.1.0">
	<integrator type="path">
		<integer name="max_depth" value="12"/>
	</integrator>
	<bsdf type="twosided" id="mat-Material" name="mat-Material">
		<bsdf type="principled" name="bsdf">
			<rgb value="0.800000 0.300000 0.200000" name="base_color"/>
			<float name="spec_tint" value="0.000000"/>
			<float name="spec_trans" value="0.000000"/>
			<float name="metallic" value="0.000000"/>
			<float name="anisotropic" value="0.000000"/>
			<float name="roughness" value="0.500000"/>
			<float name="sheen" value="0.000000"/>
			<float name="sheen_tint" value="0.500000"/>
			<float name="clearcoat" value="0.000000"/>
			<float name="clearcoat_gloss" value="0.030000"/>
			<float name="specular" value="0.500000"/>
		</bsdf>
	</bsdf>
	<bsdf type="principled" id="mat-Glass" name="mat-Glass">
		<rgb value="1.000000 1.000000 1.000000" name="base_color"/>
		<float name="spec_tint" value="0.000000"/>
		<float name="spec_trans" value="1.000000"/>
		<float name="metallic" value="0.000000"/>
		<float name="anisotropic" value="0.000000"/>
		<float name="roughness" value="0.100000"/>
		<float name="sheen" value="0.000000"/>
		<float name="sheen_tint" value="0.500000"/>
		<float name="clearcoat" value="0.000000"/>
		<float name="clearcoat_gloss" value="0.030000"/>
		<float name="eta" value="1.450000"/>
	</bsdf>
	<emitter type="constant" id="World" name="World">
		<rgb value="0.500000 0.500000 0.500000" name="radiance"/>
	</emitter>
	<shape type="rectangle" id="mesh-Plane" name="mesh-Plane">
		<transform name="to_world"><matrix value="4 0 0 0 0 0 -4 -1 0 4 0 0 0 0 0 1"/></transform>
		<ref id="mat-Material" name="bsdf"/>
	</shape>
	<shape type="sphere" id="mesh-Sphere" name="mesh-Sphere">
		<float name="radius" value="0.8"/>
		<ref id="mat-Glass" name="bsdf"/>
	</shape>
	<sensor type="perspective" id="Camera" name="Camera">
		<string name="fov_axis" value="x"/>
		<float name="fov" value="39.597755"/>
		<float name="near_clip" value="0.100000"/>
		<float name="far_clip" value="100.000000"/>
		<transform name="to_world"><lookat origin="0, 1, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
		<sampler type="independent" name="sampler"><integer name="sample_count" value="64"/></sampler>
		<film type="hdrfilm" name="film">
			<integer name="width" value="32"/>
			<integer name="height" value="32"/>
		</film>
	</sensor>
</scene>
"""
#: Mitsuba 3.9.1 llvm_ad_rgb's channel means of BLENDER_XML (4 seeds of 1024 spp; s.e. 5e-5)
BLENDER_MITSUBA = [0.4747636, 0.355883, 0.33224875]


def test_a_blender_export_loads_and_renders_as_mitsuba(tmp_path):
    path = tmp_path / "blender.xml"
    path.write_text(BLENDER_XML)
    scene = ir.load_scene(path)
    specs = {m: s for m, s in zip(scene.materials, scene.material_specs)}
    assert specs["mat-Material"].type == specs["mat-Glass"].type == "principled"
    assert specs["mat-Material"].constants["two_sided"] == 1.0 and specs["mat-Glass"].constants["eta"] == pytest.approx(1.45)
    img = ir.render(scene, spp=64, seed=1, progress=False)
    assert img.double().mean((0, 1)).tolist() == pytest.approx(BLENDER_MITSUBA, rel=1e-2)
