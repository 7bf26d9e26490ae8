"""Least squares on re-traced renders (retraced.py): the rule of which path a fit takes, the
forward-mode Jacobian columns against central finite differences, recovery of roughness and k_s by
solver 'lm' from an invrender-rendered target with sane standard errors, and the one-line errors."""

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.inverse import retraced
from invrender.inverse.fit import FitSettings
from invrender.scene.builtin import primitive, rotate, scale, translate
from invrender.scene.camera import Camera
from invrender.scene.materials import Material
from invrender.scene.scene import build_scene

KS = [0.8, 0.6, 0.4]


def plate(alpha=0.3, ks=KS, resolution=(16, 16), type="glossy"):
    """A glossy plate on a diffuse floor under a small tilted light: the highlight's spread is the roughness."""
    meshes = [
        primitive("rectangle", "plate").transformed(scale([1.5, 1.5, 1.0])),
        primitive("rectangle", "lamp", "light").transformed(translate([0, 0.8, 1.2]) @ rotate([1, 0, 0], 150) @ scale([0.12, 0.12, 1])),
    ]
    materials = {"plate": Material.of(type, specular_reflectance=ks, roughness=alpha), "lamp": 0.0}
    return build_scene(meshes, materials, {"light": [30.0, 30.0, 30.0]}, Camera(origin=(0, -2.0, 2.2), target=(0, 0.2, 0), fov=50), resolution)


def test_the_rule_non_polynomial_means_re_traced():
    scene = plate()
    assert "roughness" in retraced.record_obstacle(scene, ["plate.roughness", "plate.specular_reflectance"])
    assert retraced.record_obstacle(scene, ["plate.specular_reflectance"]) is None
    box = ir.load_scene("cornell_materials", resolution=(8, 8), subdivisions=0)
    assert retraced.record_obstacle(box, ["plastic.reflectance", "white.reflectance"]) is None  # a smooth plastic records
    rough = build_scene(
        [primitive("rectangle", "p")], {"p": Material.of("roughplastic", reflectance=[0.5] * 3)}, {}, Camera(origin=(0, 0, 2)), (4, 4)
    )  # fmt: skip
    assert "two lobes" in retraced.record_obstacle(rough, ["p.reflectance"])


def test_jacobian_columns_match_central_differences():
    """Each forward-mode column (roughness: one; k_s: three, one render) equals the central
    difference of the same renders (common seeds, sampling held at the start)."""
    scene = plate(resolution=(10, 10))
    start = {n: scene.params[n].detach().double() for n in ("plate.roughness", "plate.specular_reflectance")}
    U = retraced.Unknowns.of(start)
    assert U.offsets == [0, 1, 4] and U.labels() == ["plate.roughness", "plate.specular_reflectance[R]", "plate.specular_reflectance[G]", "plate.specular_reflectance[B]"]
    renders = retraced._Renders([scene], U, {n: v.float() for n, v in start.items()}, retraced.retrace_integrator(FitSettings(max_depth=3).model), 4, [(3, 4)], "stratified")
    w = torch.rand(100, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64) + 0.5
    J, image = renders.jacobian(0, start, 1, w)
    assert J.shape == (300, 4)
    # the same paths: the forward-mode render is the torch bounce's, the plain one the compiled bounce's (float rounding)
    torch.testing.assert_close(image, renders.image(0, start, 1), rtol=1e-4, atol=1e-6)
    u = U.vector(start)
    for k, h in enumerate([1e-3, 1e-3, 1e-3, 1e-3]):
        e = torch.zeros(4, dtype=torch.float64)
        e[k] = h
        fd = ((renders.image(0, U.values(u + e), 1) - renders.image(0, U.values(u - e), 1)) * w).reshape(-1) / (2 * h)
        assert float(fd.abs().sum()) > 1.0
        assert float((J[:, k] - fd).abs().sum()) < 2e-3 * float(fd.abs().sum()), k
    assert float(J[0::3, 2].abs().sum()) == 0.0 and float(J[1::3, 2].abs().sum()) > 0  # k_s[G] moves green only


def test_lm_recovers_roughness_and_ks_with_sane_standard_errors():
    truth_scene = plate()
    target = ir.render(truth_scene, spp=1024, max_depth=3, seed=11, progress=False)
    start = plate(alpha=0.1, ks=[0.5, 0.5, 0.5])
    names = ["plate.roughness", "plate.specular_reflectance"]
    truth = {n: truth_scene.params[n].detach() for n in names}
    res = ir.fit(start, target, names, solver="lm", spp=16, rounds=3, max_depth=3, truth=truth, progress=False)
    assert all(h["on"] == "re-traced renders" for h in res.history)
    assert res.errors["plate.roughness"] < 0.05 and res.errors["plate.specular_reflectance"] < 0.03, res.errors
    for n in names:
        se = res.std_error[n]
        assert bool((se > 0).all()) and bool((se < 0.05 * truth[n]).all()), (n, se)
        assert bool(((res.params[n] - truth[n]).abs() < 5 * se + 1e-3).all()), (n, res.params[n], se)
    assert res.history[-1]["correlation"]["channels"][0] == "plate.roughness"


def test_lm_refuses_what_it_cannot_handle():
    scene = plate(resolution=(8, 8))
    target = torch.full((8, 8, 3), 0.1)
    with pytest.raises(ParameterError, match="re-traced renders.*cannot fit the sensor"):
        ir.fit(scene, target, ["plate.roughness", "sensor.exposure"], solver="lm", progress=False)
    textured = scene.with_params({"plate.roughness": torch.full((9, 9, 3), 0.3)})
    with pytest.raises(ParameterError, match="one forward-mode render per texel.*81 per Jacobian, at most 64") as e:
        ir.fit(textured, target, ["plate.roughness"], solver="gauss_newton", progress=False)
    assert "\n" not in str(e.value)


def test_identifiability_of_a_roughness_on_re_traced_renders():
    """Without fitting: the roughness and k_s are determined (small standard errors); with the
    light's emission too, k_s and eps trade off exactly (the light lies outside the view: every
    pixel is k_s times eps), and the report names each channel's combination as undetermined."""
    scene = plate()
    target = ir.render(scene, spp=256, max_depth=3, seed=5, progress=False)
    both = ir.identifiability(scene, target, ["plate.roughness", "plate.specular_reflectance"], spp=8, max_depth=3)
    assert both.channels[0] == "plate.roughness" and len(both.channels) == 4
    assert 0 < float(both.std_error["plate.roughness"][0]) < 0.02 * 0.3
    assert bool((both.std_error["plate.specular_reflectance"] < 0.03 * torch.tensor(KS, dtype=torch.float64)).all())
    scale = ir.identifiability(scene, target, ["plate.roughness", "plate.specular_reflectance", "light.emission"], spp=8, max_depth=3)
    assert not both.undetermined and scale.undetermined
    described = scale.describe()
    for c in "RGB":
        assert f"plate.specular_reflectance[{c}]" in described and f"light.emission[{c}]" in described
    assert abs(float(scale.correlation[1, 4])) > 0.9  # k_s[R] against eps[R]


def test_a_sky_beside_another_goes_to_re_traced_renders():
    """Two emitters infinitely far away add their radiance along every ray that leaves the scene:
    path records refuse to record either before tracing, naming the parameter and the other
    emitter, and the rule sends a least-squares fit of one to re-traced renders."""
    from invrender.scene.emitters import Emitter

    floor = primitive("rectangle", "floor").transformed(scale([2.0, 2.0, 1.0]))
    skies = {"sky": Emitter.of("envmap", emission=torch.full((2, 3, 3), 0.5)), "glow": Emitter.of("constant", emission=[0.2, 0.2, 0.2])}
    scene = build_scene([floor], {"floor": 0.5}, skies, Camera(origin=(0, -2.0, 2.0), target=(0, 0, 0), fov=50), (4, 4))
    why = retraced.record_obstacle(scene, ["sky.emission"])
    assert why.startswith("sky.emission: emitter 'sky' shares the rays that leave the scene with the other emitter(s) infinitely far away (glow)")
    assert retraced.record_obstacle(scene, ["floor.reflectance"]) is None  # a reflectance under two skies is still one factor
    with pytest.raises(ParameterError, match=r"^glow.emission: emitter 'glow' .* \(sky\), .*path records cannot represent it; ir.fit fits it with solver 'lm'") as info:
        ir.record_paths(scene, ["glow.emission"], spp=1, max_depth=1, progress=False)
    assert "\n" not in str(info.value)
    one = build_scene([floor], {"floor": 0.5}, {"sky": skies["sky"]}, Camera(origin=(0, -2.0, 2.0), target=(0, 0, 0), fov=50), (4, 4))
    assert retraced.record_obstacle(one, ["sky.emission"]) is None  # one map alone records per texel
