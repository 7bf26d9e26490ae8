"""ir.fit: recovery on a small scene, determinism and exact resume, decorrelation, bad input."""

import dataclasses
import shutil
from pathlib import Path

import pytest
import torch

import invrender as ir
import invrender.inverse.fit as fit_module
from invrender.errors import ImageError, ParameterError
from invrender.inverse.losses import loss_and_gradient
from tests.conftest import furnace


@pytest.fixture(scope="module")
def small_target():
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    return ir.render(scene, spp=1024, max_depth=2, seed=99, progress=False)  # direct light: low noise


def start_scene(emission=5.0):
    scene = ir.load_scene("cornell_box", resolution=(16, 16))
    with torch.no_grad():
        scene.params["light.emission"].fill_(emission)
    return scene


def test_fit_recovers_emission_and_white_albedo(small_target):
    """A smoke test of recovery (100 short steps on a 16x16 image, direct light only); the full 64x64
    problem is measured by bench/fit_cornell.py."""
    truth = ir.load_scene("cornell_box").params
    scene = start_scene()
    with torch.no_grad():
        scene.params["white.reflectance"].fill_(0.5)
    names = ["light.emission", "white.reflectance"]
    res = ir.fit(scene, small_target, names, solver="adam", steps=100, spp=16, spp_final=64, lr=0.15, lr_emission=0.15, max_depth=2, progress=False, truth={k: truth[k] for k in names})
    assert res.errors["light.emission"] < 0.05
    assert res.errors["white.reflectance"] < 0.05
    assert res.history[-1]["loss"] < 0.05 * res.history[0]["loss"]
    # stopped on the loss's plateau (94 steps), or ran all 100
    assert res.converged is not None and 80 <= len(res.history) <= 100 and set(res.history[0]) >= {"step", "loss", "spp", "seconds", "params", "errors", "grad_norm"}
    assert torch.equal(scene.params["light.emission"], torch.full((3,), 5.0))  # the input scene is untouched


@pytest.mark.parametrize("control_variate", [False, True])
def test_fit_is_deterministic_and_resume_gives_the_same_result(small_target, tmp_path, monkeypatch, control_variate):
    """Also with the recursive control variate: the checkpoint carries each view's state."""
    kw = dict(steps=8, spp=4, spp_final=4, max_depth=3, checkpoint_every=2, progress=False, control_variate=control_variate)
    a = ir.fit(start_scene(), small_target, ["light.emission"], **kw)
    b = ir.fit(start_scene(), small_target, ["light.emission"], checkpoint=tmp_path / "a.pt", **kw)
    assert torch.equal(a.params["light.emission"], b.params["light.emission"])

    calls = {"n": 0}
    original = fit_module._view_loss

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 6:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(fit_module, "_view_loss", interrupted)
    with pytest.raises(KeyboardInterrupt):
        ir.fit(start_scene(), small_target, ["light.emission"], checkpoint=tmp_path / "c.pt", **kw)
    monkeypatch.setattr(fit_module, "_view_loss", original)
    assert torch.load(tmp_path / "c.pt", weights_only=False)["step"] == 5  # saved on Ctrl-C
    c = ir.fit(start_scene(), small_target, ["light.emission"], checkpoint=tmp_path / "c.pt", resume=True, **kw)
    assert torch.equal(c.params["light.emission"], a.params["light.emission"])
    assert [h["loss"] for h in c.history] == [h["loss"] for h in a.history]


def test_checkpoint_from_another_scene_is_refused(small_target, tmp_path):
    kw = dict(steps=2, spp=2, spp_final=2, max_depth=2, progress=False)
    ir.fit(start_scene(), small_target, ["light.emission"], checkpoint=tmp_path / "k.pt", **kw)
    other = furnace(resolution=(16, 16))
    with pytest.raises(ParameterError, match="another scene"):
        ir.fit(other, small_target, ["glow.emission"], checkpoint=tmp_path / "k.pt", resume=True, **kw)
    shutil.copy(tmp_path / "k.pt", tmp_path / "k2.pt")
    with pytest.raises(ParameterError, match="another solver"):
        ir.fit(start_scene(), small_target, ["light.emission"], checkpoint=tmp_path / "k2.pt", resume=True, solver="lm")


def test_resume_reuses_the_stored_settings_unless_given_anew(small_target, tmp_path):
    kw = dict(steps=2, spp=2, spp_final=2, max_depth=2, progress=False)
    first = ir.fit(start_scene(), small_target, ["light.emission"], checkpoint=tmp_path / "k.pt", **kw)
    # no settings: the stored ones (2 steps, all done): the same result
    same = ir.fit(start_scene(), small_target, ["light.emission"], checkpoint=tmp_path / "k.pt", resume=True, progress=False)
    assert same.settings == first.settings and torch.equal(same.params["light.emission"], first.params["light.emission"])
    # a new setting wins (one more step), the rest stay stored
    more = ir.fit(start_scene(), small_target, ["light.emission"], checkpoint=tmp_path / "k.pt", resume=True, steps=3, progress=False)
    assert len(more.history) == 3 and more.settings.spp == 2 and more.settings.max_depth == 2


@pytest.mark.parametrize(
    "target, params, error, words",
    [
        (torch.zeros(8, 8, 3), ["light.emission"], ImageError, "8x8 but the scene renders 16x16"),
        (torch.zeros(16, 16, 4), ["light.emission"], ImageError, r"\(H, W, 3\)"),
        (torch.full((16, 16, 3), float("nan")), ["light.emission"], ImageError, "NaN"),
        (torch.full((16, 16, 3), -0.5), ["light.emission"], ImageError, "negative radiance"),
        (torch.zeros(16, 16, 3), ["lamp.emission"], ParameterError, r"unknown parameter 'lamp.emission' \(did you mean 'light.emission'\?\)"),
        (torch.full((16, 16, 3), 1e24), ["light.emission"], ImageError, r"target 0 has a value of 1e\+24, beyond 1.845e\+19"),
        ([], ["light.emission"], ParameterError, "no target was given"),
        (torch.zeros(16, 16, 3), None, ParameterError, "parameter names must be a list of names or a comma-separated string, got None"),
    ],
)
def test_bad_fit_input(target, params, error, words):
    with pytest.raises(error, match=words):
        ir.fit(start_scene(), target, params, steps=1, progress=False)
    with pytest.raises(ParameterError, match="unknown fit setting"):
        ir.fit(start_scene(), torch.zeros(16, 16, 3), ["light.emission"], stpes=3)


@pytest.mark.parametrize(
    "options, words",
    [
        (dict(truth={"light.emision": [1, 1, 1]}), r"^truth of unknown parameter 'light.emision' \(did you mean 'light.emission'\?\)"),
        (dict(truth={"light.emission": [1, 1]}), r"^truth of light.emission: a value of shape \(2,\) does not fit the parameter's shape \(3,\)$"),
        (dict(truth={"light.emission": float("inf")}), r"^truth of light.emission: values must be finite$"),
        (dict(sensor=5), r"^sensor options must be a mapping of exposure, white_balance, shared, got 5$"),
        (dict(sensor={"shared": 5}), r"^sensor option shared must be a list of 'exposure', 'white_balance', got 5$"),
        (dict(sensor={"exposur": 2}), r"^unknown sensor option 'exposur' \(did you mean 'exposure'\?\)"),
    ],
)
def test_bad_fit_options_are_refused_before_any_work(options, words, monkeypatch):
    """The ground truth and the sensor options: one-line ParameterErrors before tracing (a truth of
    the wrong shape used to fail with a RuntimeError after the fit, when its errors were taken)."""
    from invrender.inverse import fit as fit_module

    monkeypatch.setattr(fit_module, "_fit_least_squares", lambda *a, **k: pytest.fail("worked before checking"))
    monkeypatch.setattr(fit_module.Integrator, "context", lambda *a, **k: pytest.fail("worked before checking"), raising=False)
    with pytest.raises(ParameterError, match=words) as e:
        ir.fit(start_scene(), torch.zeros(16, 16, 3), ["light.emission"], steps=1, progress=False, **options)
    assert "\n" not in str(e.value)


def test_parameter_no_pixel_depends_on_warns(tmp_path):
    scene_file = tmp_path / "s.toml"
    scene_file.write_text(
        """
[materials.wall]
reflectance = 0.5
[materials.hidden]
reflectance = 0.5
[emitters.lamp]
emission = 3.0
[[shapes]]
type = "rectangle"
material = "wall"
emitter = "lamp"
[[shapes]]  # behind the emitting wall (which emits from its front side only): no light reaches it
type = "rectangle"
material = "hidden"
transform = [{ translate = [0, 0, -5] }]
"""
    )
    scene = ir.load_scene(scene_file, resolution=(8, 8))
    with pytest.warns(UserWarning, match="hidden.reflectance has a zero gradient"):
        ir.fit(scene, torch.ones(8, 8, 3), ["hidden.reflectance", "lamp.emission"], steps=1, spp=1, progress=False)


def test_decorrelation_removes_the_same_sample_bias():
    """Furnace with the analog random walk (Russian roulette with q = rho, weight 1): the image of a
    path is eps n, n ~ geometric, dI/deps = n. With the target at the true radiance, the gradient of
    the per-pixel L2 loss from the same sample has mean 2 eps rho/(1-rho)^2 = 4 (docs/closed_forms.md#correlated-gradient-bias; the 2
    from mse's derivative), from independent samples 0. 64x64 pixels at 1 spp: standard error 0.25."""
    scene = furnace(rho=0.5, eps=1.0, resolution=(64, 64))
    eps = scene.params["glow.emission"].requires_grad_(True)
    target = torch.full((64, 64, 3), 2.0)
    kw = dict(integrator="random_walk", spp=1, max_depth=-1, rr_depth=1, progress=False)
    image = ir.render(scene, seed=0, **kw)
    loss_and_gradient("l2", target, image, image)
    correlated = eps.grad.sum().item()
    eps.grad = None
    image = ir.render(scene, seed=0, **kw)
    with torch.no_grad():
        residual = ir.render(scene, seed=1, **kw)
    loss_and_gradient("l2", target, residual, image)
    decorrelated = eps.grad.sum().item()
    assert 3.0 < correlated < 5.0
    assert -1.0 < decorrelated < 1.0


@pytest.mark.parametrize("loss", ["l1", "relative_l2", "ssim"])
def test_other_losses_descend(small_target, loss):
    res = ir.fit(start_scene(), small_target, ["light.emission"], steps=15, spp=4, spp_final=4, max_depth=2, loss=loss, progress=False)
    truth = ir.load_scene("cornell_box").params["light.emission"]
    assert (res.params["light.emission"] - truth).abs().sum() < (torch.full((3,), 5.0) - truth).abs().sum() * 0.8


def test_auto_estimator_records_small_renders_and_replays_large_ones(small_target, monkeypatch):
    """``estimator="auto"`` (the fit default): replay where the fused bounce carries the derivatives
    forward (one trace), else autodiff where the recorded render fits in the memory budget, replay
    where it does not or the depth is unbounded; a fit takes the same steps either way (they give
    the same gradient to float rounding)."""
    from invrender.estimators import resolve_estimator
    from invrender.core.driver import RenderSettings
    from invrender.plugins.integrators import make_integrator

    scene = ir.load_scene("cornell_box", resolution=(64, 64))
    path = make_integrator("path", max_depth=8)
    assert resolve_estimator("auto", scene, path, RenderSettings(spp=64)) == "autodiff"  # 262k paths x 8 terms x 128 B = 256 MiB
    assert resolve_estimator("auto", scene, path, RenderSettings(spp=256)) == "replay"  # 1 GiB
    assert resolve_estimator("auto", scene, path, RenderSettings(spp=256, memory_mb=2048)) == "autodiff"
    assert resolve_estimator("auto", scene, make_integrator("path", max_depth=-1), RenderSettings(spp=1)) == "replay"
    assert resolve_estimator("replay", scene, path, RenderSettings(spp=1)) == "replay"
    cpu = torch.device("cpu")
    assert resolve_estimator("auto", scene, path, RenderSettings(spp=64), cpu, ["red.reflectance"]) == "replay"  # carried forward
    glossy = ir.load_scene(str(Path(__file__).resolve().parents[2] / "forward" / "glossy_plate.toml"), resolution=(16, 16))
    assert resolve_estimator("auto", glossy, path, RenderSettings(spp=4), cpu, [next(iter(glossy.params))]) == "autodiff"
    with pytest.raises(ParameterError, match="unknown estimator 'fast'"):
        ir.render(scene, spp=1, estimator="fast", progress=False)
    small = ir.load_scene("cornell_box", resolution=(8, 8))
    rho = small.params["red.reflectance"].clone().requires_grad_(True)
    ir.render(dataclasses.replace(small, params={**small.params, "red.reflectance": rho}), spp=2, estimator="auto", progress=False).sum().backward()
    assert rho.grad is not None and rho.grad.abs().sum() > 0
    with pytest.raises(ParameterError, match="unknown estimator 'fast'"):
        fit_module.FitSettings(estimator="fast")

    import invrender.estimators as diff
    import invrender.estimators.replay as replay

    used = []  # the estimator each gradient of the fits ran
    autodiff_render, replay_gradient = diff.autodiff_render, replay.replay_gradient
    monkeypatch.setattr(diff, "autodiff_render", lambda *a: (used.append("autodiff"), autodiff_render(*a))[1])
    monkeypatch.setattr(replay, "replay_gradient", lambda *a, **k: (used.append("replay"), replay_gradient(*a, **k))[1])
    runs = {e: ir.fit(start_scene(), small_target, ["white.reflectance"], steps=3, spp=4, spp_final=4, max_depth=3, progress=False, estimator=e) for e in ("auto", "replay")}
    assert used == ["replay"] * 6  # the Cornell box's derivatives are carried forward: replay's path
    a, b = (runs[e].params["white.reflectance"] for e in ("auto", "replay"))
    assert torch.allclose(a, b, rtol=1e-4)
