"""Materials made of others (blendbsdf, mask: invrender/plugins/bsdfs/blend.py, mask.py, composite.py),
Mitsuba's pplastic as its RGB variants render it (pplastic.py) and textured roughness on
roughdielectric: eval and pdf against Mitsuba 3.9.1's values (360 direction pairs of six settings,
computed by bench/nested_compare.py with mitsuba's llvm_ad_rgb variant and stored beside this file:
no Mitsuba at test time), sampling (delta lobes inside a blend, a mask's pass-through), the
compiled bounce against the torch one on a scene of them, the Mitsuba loader and its one-line
errors. The registry-driven suites (test_conformance.py, test_lane_forms.py) check the registered
defaults and, for test_lane_forms.py, several nestings."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

import invrender as ir
from invrender.core.bsdf import Lobe, ShadingPoint
from invrender.errors import SceneError
from invrender.plugins.bsdfs import checks
from invrender.registry import MATERIALS
from invrender.scene.materials import Material

TABLE = json.loads((Path(__file__).parent / "mitsuba_nested_values.json").read_text())


def _bsdf(type_name: str, **entries):
    """A material as a scene builds it (constants resolved: a plastic's sampling weight)."""
    m = Material.of(type_name, "test", **entries)
    return checks.instance(m.spec, **m.values, **m.constants)


def _values(bsdf, wi, wo):
    """invrender's (eval, pdf) for Mitsuba's ``si.wi`` (camera side) ``wi`` and ``wo`` (light side),
    local, normal +z turned to the camera side."""
    wo_t = torch.tensor(wi, dtype=torch.float32)
    wo_t = wo_t / wo_t.norm(dim=1, keepdim=True)
    light = torch.tensor(wo, dtype=torch.float32)
    light = light / light.norm(dim=1, keepdim=True)
    n = wo_t.shape[0]
    front = wo_t[:, 2] > 0
    normal = torch.zeros(n, 3)
    normal[:, 2] = torch.where(front, 1.0, -1.0)
    zeros = torch.zeros(n, dtype=torch.int64)
    sp = ShadingPoint(wo_t, normal, normal, front, torch.zeros(n, 2), zeros, zeros)
    return bsdf.eval(sp, light), bsdf.pdf(sp, light)


@pytest.mark.parametrize("setting", sorted(TABLE["settings"]))
def test_eval_and_pdf_match_mitsuba(setting):
    """Within 1e-4 relative where Mitsuba's value exceeds 1e-3 (float32 cancellation below), 2e-5
    absolute elsewhere, on the stored pairs (front and back, reflection and transmission)."""
    spec = TABLE["settings"][setting]
    rows = [r for r in TABLE["pairs"] if r[0] == setting]
    assert len(rows) >= 50
    f, pdf = _values(_bsdf(spec["type"], **spec["entries"]), [r[1] for r in rows], [r[2] for r in rows])
    ref_f = torch.tensor([r[3] for r in rows])
    ref_pdf = torch.tensor([r[4] for r in rows])
    for ours, ref in ((f, ref_f), (pdf, ref_pdf)):
        tol = torch.where(ref.abs() > 1e-3, 1e-4 * ref.abs(), torch.full_like(ref, 2e-5))
        assert bool(((ours - ref).abs() <= tol).all()), (setting, float((ours - ref).abs().max()))
    assert float((ref_f.amax(1) > 0).float().mean()) > 0.3  # most pairs are lit: the table tests something


@pytest.mark.parametrize("name", ["blendbsdf(roughplastic,dielectric)", "blendbsdf(glossy,roughdielectric)", "mask(blendbsdf(diffuse,mirror))", "mask(pplastic)", "pplastic_ggx"])
def test_sampling_matches_pdf_and_delta_lobes(name):
    """Sampling against ``pdf`` (chi-square), weights ``eval / pdf`` on smooth samples, and the delta
    samples' mean weights the listed delta lobes' (a blended mirror or glass, a mask's pass-through)."""
    bsdf = checks.instance(MATERIALS[name])
    for theta in (0.3, 1.1):
        assert checks.chi_square_p(bsdf, theta, samples=100_000) > 1e-3, (name, theta)
        pdf_err, weight_err, _ = checks.weight_errors(bsdf, theta)
        assert pdf_err < 1e-3 and weight_err < 1e-3, (name, theta, pdf_err, weight_err)
        if bsdf.has(Lobe.DELTA):
            assert checks.delta_weight_gap(bsdf, theta, n=100_000) < 6e-3, (name, theta)


def test_a_blended_mirror_keeps_its_weight():
    """blend(mirror, diffuse rho) at w: every mirror sample has weight 1 (the blend's factor and its
    choice cancel) and the mean weight is the albedo ``(1 - w) + w rho`` (Mitsuba 3.9.1's sampler
    returns less there: bench/nested_compare.py, blend.py's docstring)."""
    bsdf = _bsdf("blendbsdf(mirror,diffuse)", weight=0.5, **{"bsdf_1.reflectance": 0.2})
    n = 200_000
    g = torch.Generator().manual_seed(3)
    bs = bsdf.sample(checks.shading_point(0.5, n), torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    assert abs(float(bs.delta.float().mean()) - 0.5) < 0.005
    assert torch.allclose(bs.weight[bs.delta], torch.ones(1)) and bool((bs.pdf[bs.delta] == 0).all())
    assert torch.allclose(bs.weight[~bs.delta], torch.full((1,), 0.2), atol=1e-6)
    assert abs(float(bs.weight[:, 0].mean()) - 0.6) < 0.003


def test_a_mask_passes_light_straight_through():
    """With probability 1 - opacity: ``wi = -wo``, weight 1, delta, pdf 0; eval and pdf are the
    nested material's times the opacity; the opacity is read detached (no gradient), the nested
    reflectance differentiably."""
    bsdf = _bsdf("mask(diffuse)", opacity=0.3, **{"bsdf.reflectance": 0.6})
    n = 100_000
    sp = checks.shading_point(0.7, n)
    g = torch.Generator().manual_seed(4)
    bs = bsdf.sample(sp, torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    through = bs.delta
    assert abs(float(through.float().mean()) - 0.7) < 0.005
    assert torch.allclose(bs.wi[through], -sp.wo[through]) and torch.allclose(bs.weight[through], torch.ones(1))
    assert torch.allclose(bs.weight[~through], torch.full((1,), 0.6), atol=1e-6)
    wi = torch.tensor([[0.0, 0.6, 0.8]]).expand(n, 3)
    plain = checks.instance(MATERIALS["diffuse"], reflectance=0.6)
    assert torch.allclose(bsdf.eval(sp, wi), 0.3 * plain.eval(sp, wi)) and torch.allclose(bsdf.pdf(sp, wi), 0.3 * plain.pdf(sp, wi))
    values = bsdf.values[0]
    for key in ("opacity", "bsdf.reflectance"):
        values[key].requires_grad_(True)
    bsdf.eval(checks.shading_point(0.7, 4), wi[:4]).sum().backward()
    assert values["opacity"].grad is None or float(values["opacity"].grad.abs().sum()) == 0.0
    assert float(values["bsdf.reflectance"].grad.abs().sum()) > 0


def test_a_one_sided_nested_material_is_black_from_behind():
    """blend(one-sided diffuse, glass) seen from behind: only the glass's share, w f_1; the blend's
    samples of the diffuse weigh nothing there."""
    bsdf = _bsdf("blendbsdf(diffuse,roughdielectric)", weight=0.6, one_sided_0=True)
    glass = checks.instance(MATERIALS["roughdielectric"])
    n = 20_000
    sp = checks.shading_point(0.5, n, front=False)
    wi = checks.local_directions(torch.rand(n, generator=torch.Generator().manual_seed(5)) * 2 - 1, torch.rand(n, generator=torch.Generator().manual_seed(6)) * 6.28)
    assert torch.allclose(bsdf.eval(sp, wi), 0.6 * glass.eval(sp, wi), atol=1e-6) and torch.allclose(bsdf.pdf(sp, wi), 0.6 * glass.pdf(sp, wi), atol=1e-6)
    g = torch.Generator().manual_seed(7)
    bs = bsdf.sample(sp, torch.rand(n, generator=g), torch.rand(n, 2, generator=g))
    assert float((bs.weight.amax(1) > 0).float().mean()) < 0.62  # the diffuse's 40% of samples weigh nothing
    front = checks.shading_point(0.5, 8)
    assert float(bsdf.eval(front, wi[:8]).amax()) > 0


def test_a_blends_weight_is_differentiable():
    """d eval / d w = f_1 - f_0 (autograd through the lane form)."""
    bsdf = _bsdf("blendbsdf(diffuse,glossy)", weight=0.4, **{"bsdf_0.reflectance": 0.3})
    w = bsdf.values[0]["weight"].requires_grad_(True)
    sp = checks.shading_point(0.4, 3)
    wi = torch.tensor([[0.3, 0.1, 0.9]]).expand(3, 3)
    wi = wi / wi.norm(dim=1, keepdim=True)
    bsdf.eval(sp, wi)[:, 0].sum().backward()
    f0 = checks.instance(MATERIALS["diffuse"], reflectance=0.3).eval(sp, wi)[:, 0].sum()
    f1 = checks.instance(MATERIALS["glossy"]).eval(sp, wi)[:, 0].sum()
    assert abs(float(w.grad.sum()) - float(f1 - f0)) < 1e-5 * max(1.0, abs(float(f1)))


def test_compiled_bounce_renders_them_as_the_torch_bounce(monkeypatch):
    """A blend with a delta lobe, a mask (paths through it), a pplastic and a rough glass with a
    roughness map, on the compiled bounce and on the torch one: the same image within rounding."""
    from invrender.backends import kernels
    from tests.transport.test_fused import _fused_scene, _smooth_spheres

    alpha = torch.rand(4, 6, generator=torch.Generator().manual_seed(2))[..., None].expand(4, 6, 3) * 0.4 + 0.05
    mats = {
        "near": Material.of("mask(blendbsdf(mirror,pplastic))", opacity=0.6, **{"bsdf.weight": 0.7, "bsdf.bsdf_1.reflectance": [0.7, 0.3, 0.2]}),
        "far": Material.of("roughdielectric_ggx", roughness=alpha.clone()),
    }
    scene = _smooth_spheres(mats)
    assert _fused_scene(scene, "path") is not None
    kw = dict(spp=16, seed=7, progress=False, integrator="path")
    image = ir.render(scene, **kw)
    monkeypatch.setenv(kernels.ENV, "steps")
    expected = ir.render(scene, **kw)
    assert float(expected.mean()) > 0.05
    close = (image - expected).abs() <= 1e-4 * float(expected.max())
    assert float(close.float().mean()) > 0.99
    assert abs(float(image.mean() / expected.mean()) - 1) < 3e-3


def test_a_constant_roughness_map_renders_as_the_constant():
    """roughdielectric's roughness as a map of one value: the same image as the number."""
    from tests.transport.test_fused import _smooth_spheres

    kw = dict(spp=4, seed=1, progress=False)
    flat = ir.render(_smooth_spheres({"near": Material.of("roughdielectric", roughness=0.2), "far": Material.of("diffuse")}), **kw)
    mapped = ir.render(_smooth_spheres({"near": Material.of("roughdielectric", roughness=torch.full((3, 5, 3), 0.2)), "far": Material.of("diffuse")}), **kw)
    assert torch.allclose(flat, mapped, atol=1e-5, rtol=1e-4)


XML = """<scene version="3.0.0">
    <integrator type="path"/>
    <sensor type="perspective"><transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>
    <shape type="rectangle">{bsdf}</shape>
    <shape type="rectangle"><transform name="to_world"><translate z="-1"/></transform><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
</scene>"""


def _load(tmp_path, bsdf: str):
    path = tmp_path / "scene.xml"
    path.write_text(XML.format(bsdf=bsdf))
    return ir.load_scene(path)


def test_the_mitsuba_loader_reads_blends_masks_pplastic_and_textured_roughness(tmp_path):
    scene = _load(tmp_path, """<bsdf type="mask"><texture type="checkerboard" name="opacity"><rgb name="color0" value="0.2, 0.4, 0.6"/></texture>
        <bsdf type="blendbsdf"><float name="weight" value="0.25"/>
            <bsdf type="twosided"><bsdf type="pplastic"><float name="alpha" value="0.2"/><float name="eta" value="1.4"/></bsdf></bsdf>
            <bsdf type="twosided"><bsdf type="roughconductor"><string name="distribution" value="ggx"/></bsdf></bsdf>
        </bsdf></bsdf>""")
    spec = scene.material_specs[0]
    assert spec.type == "mask(blendbsdf(pplastic,glossy))" and not spec.one_sided
    name = scene.materials[0]
    opacity = scene.params[f"{name}.opacity"]
    assert opacity.ndim == 3 and abs(float(opacity.max()) - (0.212671 * 0.2 + 0.715160 * 0.4 + 0.072169 * 0.6)) < 1e-5  # luminance, as eval_1
    assert float(scene.params[f"{name}.bsdf.weight"][0]) == 0.25
    assert spec.constants["bsdf.bsdf_0.int_ior"] == 1.4 and spec.constants["bsdf.bsdf_0.ext_ior"] == 1.0
    assert spec.constants["nested_one_sided"] == 0.0  # the blend's materials are twosided
    glass = _load(tmp_path, """<bsdf type="roughdielectric"><texture type="checkerboard" name="alpha"><float name="color0" value="0.05"/><float name="color1" value="0.3"/></texture></bsdf>""")
    alpha = glass.params[f"{glass.materials[0]}.roughness"]
    assert glass.material_specs[0].type == "roughdielectric" and alpha.ndim == 3 and {round(float(v), 4) for v in alpha.unique()} >= {0.05, 0.3}
    board = _load(tmp_path, """<bsdf type="diffuse"><texture type="checkerboard" name="reflectance"><float name="color0" value="0.05"/><float name="color1" value="0.3"/></texture></bsdf>""")
    rho = board.params[f"{board.materials[0]}.reflectance"]
    assert torch.allclose(alpha, 0.35 - rho, atol=1e-6)  # Mitsuba's checkerboard eval_1 swaps the colours of its eval
    smooth = _load(tmp_path, """<bsdf type="roughdielectric"><texture type="checkerboard" name="alpha"><float name="color0" value="0"/></texture></bsdf>""")
    assert float(smooth.params[f"{smooth.materials[0]}.roughness"].min()) == pytest.approx(1e-4)  # Mitsuba's microfacet clamps alpha to 1e-4
    one_sided = _load(tmp_path, """<bsdf type="blendbsdf"><bsdf type="diffuse"/><bsdf type="twosided"><bsdf type="plastic"/></bsdf></bsdf>""").material_specs[0]
    assert one_sided.type == "blendbsdf(diffuse,plastic)" and not one_sided.one_sided
    assert one_sided.constants["one_sided_0"] == 1.0 and one_sided.constants["one_sided_1"] == 0.0  # each nested material's side, as in Mitsuba
    wrapped = _load(tmp_path, """<bsdf type="twosided"><bsdf type="blendbsdf"><bsdf type="diffuse"/><bsdf type="plastic"/></bsdf></bsdf>""").material_specs[0]
    assert wrapped.constants["one_sided_0"] == 0.0 and wrapped.constants["one_sided_1"] == 0.0
    masked = _load(tmp_path, """<bsdf type="mask"><bsdf type="diffuse"/></bsdf>""")
    assert masked.material_specs[0].constants["nested_one_sided"] == 1.0


@pytest.mark.parametrize(
    "bsdf, message",
    [
        ("""<bsdf type="blendbsdf"><bsdf type="diffuse"/></bsdf>""", "needs two nested BSDFs, got 1"),
        ("""<bsdf type="blendbsdf"><float name="weight" value="1.5"/><bsdf type="diffuse"/><bsdf type="diffuse"/></bsdf>""", "'weight'"),
        ("""<bsdf type="blendbsdf"><float name="weight" value="nan"/><bsdf type="diffuse"/><bsdf type="diffuse"/></bsdf>""", "weight"),
        ("""<bsdf type="blendbsdf"><bsdf type="diffuse"/><bsdf type="hair"/></bsdf>""", "unsupported bsdf type 'hair'"),
        ("""<bsdf type="twosided"><bsdf type="blendbsdf"><bsdf type="diffuse"/><bsdf type="dielectric"/></bsdf></bsdf>""", "twosided cannot wrap a blendbsdf(diffuse,dielectric)"),
        ("""<bsdf type="mask"><bsdf type="diffuse"/><bsdf type="diffuse"/></bsdf>""", "needs one nested BSDF, got 2"),
        ("""<bsdf type="mask"><float name="opacity" value="-0.1"/><bsdf type="diffuse"/></bsdf>""", "'opacity'"),
        ("""<bsdf type="pplastic"><float name="eta" value="1.4"/><float name="int_ior" value="1.5"/></bsdf>""", "not both"),
        ("""<bsdf type="roughdielectric"><texture type="checkerboard" name="alpha"><float name="color0" value="-0.1"/></texture></bsdf>""", "'alpha'"),
        ("""<bsdf type="roughdielectric"><float name="alpha" value="nan"/></bsdf>""", "finite"),
    ],
)
def test_bad_nested_materials_are_one_line_errors(tmp_path, bsdf, message):
    with pytest.raises(ir.InvRenderError) as e:
        _load(tmp_path, bsdf)
    text = str(e.value)
    assert message in text and "\n" not in text, text


@pytest.mark.parametrize("name, message", [("blendbsdf(diffuse,velvet)", "unknown material type 'velvet'"), ("blendbsdf(diffuse)", "nests 2 material type(s), got 1"), ("mask(diffuse", "must read")])
def test_bad_type_names_are_one_line_errors(name, message):
    with pytest.raises(SceneError) as e:
        Material.of(name, "materials.m")
    assert message in str(e.value) and "materials.m" in str(e.value)


def test_variants_are_built_once_and_not_listed():
    assert MATERIALS["blendbsdf(diffuse, mirror)"] is MATERIALS["blendbsdf(diffuse,mirror)"]
    assert "blendbsdf(diffuse,mirror)" not in MATERIALS.names()
    assert math.isclose(MATERIALS["mask(glossy)"].params["opacity"].default, 0.5)


def test_path_records_refuse_a_blends_parameters():
    """A blend's value sums its two materials: no parameter of it is one monomial of a path's weight."""
    from invrender.estimators.records import record_obstacle
    from tests.transport.test_fused import _smooth_spheres

    scene = _smooth_spheres({"near": Material.of("blendbsdf(diffuse,diffuse)"), "far": Material.of("mask(diffuse)")})
    assert "sums its two materials" in record_obstacle(scene, ["near.bsdf_0.reflectance"])
    assert record_obstacle(scene, ["far.bsdf.reflectance"]) is None  # a mask's opacity is a constant factor
    assert "not a polynomial" in record_obstacle(scene, ["far.opacity"])
    # and a mask's nested reflectance is recorded: the record re-evaluated elsewhere is the render there
    from invrender.estimators.records import record_paths

    records = record_paths(scene, ["far.bsdf.reflectance"], spp=2, max_depth=4, seed=3, progress=False)
    value = torch.tensor([0.2, 0.7, 0.3])
    expected = ir.render(scene.with_params({"far.bsdf.reflectance": value}), spp=2, max_depth=4, seed=3, progress=False)
    assert torch.allclose(records.image({"far.bsdf.reflectance": value}).float(), expected, atol=1e-5)


def test_gradients_of_a_blend_and_a_masked_material_match_finite_differences():
    """A blend's weight and nested reflectance, a mask's nested reflectance: autodiff and path replay
    against central differences (common random numbers); the opacity is refused (read detached)."""
    from invrender.errors import ParameterError
    from invrender.inverse.gradcheck import gradcheck
    from tests.transport.test_fused import _smooth_spheres

    scene = _smooth_spheres({"near": Material.of("blendbsdf(diffuse,glossy)", weight=0.4), "far": Material.of("mask(pplastic)", opacity=0.6)})
    rows = gradcheck(scene, ["near.weight", "near.bsdf_0.reflectance", "far.bsdf.reflectance"], spp=8, max_depth=3)
    assert len(rows) == 7
    for row in rows:
        assert max(row.rel_errors.values()) < 0.02, row
    with pytest.raises(ParameterError, match="far.opacity: the opacity is read detached"):
        gradcheck(scene, ["far.opacity"])
    assert float(scene.with_params({"far.opacity": 0.2}).params["far.opacity"][0]) == pytest.approx(0.2)  # set, not fitted


def test_two_instances_of_a_composite_share_one_compiled_kernel():
    """The lane forms of two instances of one combination are equal as the compiled kernels' keys
    compare them (the nested forms' functions by what they compute), another combination's not."""
    from invrender.core import lanes

    def key(name):
        form = checks.instance(MATERIALS[name]).lane_form()
        return lanes.Material(form, (), True, False).key()

    assert key("mask(blendbsdf(glossy,mirror))") == key("mask(blendbsdf(glossy,mirror))")
    assert hash(key("blendbsdf(roughplastic,mirror)")) == hash(key("blendbsdf(roughplastic,mirror)"))
    assert key("mask(blendbsdf(glossy,mirror))") != key("mask(blendbsdf(glossy_beckmann,mirror))")
