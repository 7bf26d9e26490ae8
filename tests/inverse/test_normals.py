"""Shading normals as parameters: a mesh's vertex normals (``NAME.normals``) and a normal map's
texels (``NAME.normalmap``), differentiated by both estimators (replay = autodiff), checked against
central finite differences, fitted by Adam (records and lm refuse them, naming Adam), renders
unchanged where they are not differentiated, and the bad values refused in one line."""

from __future__ import annotations

import dataclasses

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError
from invrender.inverse.convergence import ConvergenceWarning
from invrender.scene.builtin import plane_views
from invrender.scene.materials import Material, NormalPerturbation
from invrender.scene.scene import build_scene
from invrender.scene.shapes import Mesh, primitive, sphere

KW = dict(spp=16, max_depth=2, progress=False)


def plane(size=4, resolution=16):
    return ir.load_scene("normal_plane", resolution=(resolution, resolution), normalmap_size=(size, size))


def angles(texels, truth):
    """Degrees between the normals 2 c - 1 of two maps."""
    a, b = (torch.nn.functional.normalize(2 * t.double() - 1, dim=-1) for t in (texels, truth))
    return torch.rad2deg(torch.acos((a * b).sum(-1).clamp(-1, 1)))


def test_the_parameters_hold_the_meshes_normals_and_the_maps_texels():
    """``plane.normals`` (the plane's four +y vertex normals) and ``plane.normalmap`` (its texels)
    are parameters; a smooth mesh's normals are the floats its triangles shade with; a flat mesh
    has none."""
    scene = plane()
    assert scene.params["plane.normals"].shape == (4, 3) and torch.equal(scene.params["plane.normals"], torch.tensor([[0.0, 1.0, 0.0]] * 4))
    assert scene.params["plane.normalmap"].shape == (4, 4, 3)
    ball = build_scene([primitive("sphere", "ball", None, 1), primitive("rectangle", "floor")], {"ball": 0.5, "floor": 0.5}, {}, ir.Camera(), (4, 4))
    assert "floor.normals" not in ball.params and ball.params["ball.normals"].shape == (42, 3)
    rows, t = ball.triangles.normal_row, ball.triangles
    smooth = rows[:, 0] >= 0
    assert torch.equal(ball.params["ball.normals"][rows[smooth]], t.vertex_normal[smooth]) and bool((rows[~smooth] == -1).all())


def test_renders_unchanged_until_the_normals_change():
    """Setting the values a scene holds changes no bit; a differentiated render (the torch bounce)
    equals the compiled one within float rounding; a turned normal changes the image."""
    scene = plane(resolution=12)
    base = ir.render(scene, seed=3, **KW)
    same = scene.with_params({"plane.normals": scene.params["plane.normals"].clone(), "plane.normalmap": scene.params["plane.normalmap"].clone()})
    assert torch.equal(ir.render(same, seed=3, **KW), base)
    scene.params["plane.normalmap"].requires_grad_(True)
    diff = ir.render(scene, seed=3, estimator="autodiff", **KW)
    torch.testing.assert_close(diff.detach(), base, rtol=1e-4, atol=1e-5)
    scene.params["plane.normalmap"].requires_grad_(False)
    tilted = scene.with_params({"plane.normals": torch.tensor([[0.3, 1.0, 0.0]] * 4)})
    torch.testing.assert_close(tilted.params["plane.normals"].norm(dim=1), torch.ones(4))  # normalized when set
    assert float((ir.render(tilted, seed=3, **KW) - base).abs().mean()) > 1e-3


def test_replay_equals_autodiff():
    """Both estimators give the same gradient of a weighted image, for the map and the vertex
    normals (replay re-traces the same paths)."""
    scene = plane(resolution=12)
    w = torch.rand(12, 12, 3, generator=torch.Generator().manual_seed(0))
    names = ["plane.normalmap", "plane.normals"]
    grads = {}
    for estimator in ("autodiff", "replay"):
        for n in names:
            scene.params[n].requires_grad_(True)
            scene.params[n].grad = None
        (ir.render(scene, seed=2, estimator=estimator, **KW) * w).sum().backward()
        grads[estimator] = {n: scene.params[n].grad.clone() for n in names}
    for n in names:
        a, b = grads["autodiff"][n], grads["replay"][n]
        assert float(a.abs().max()) > 0
        torch.testing.assert_close(b, a, rtol=1e-5, atol=1e-5 * float(a.abs().max()))


def test_gradcheck_within_two_percent():
    """Each estimator's gradient within 2% of central differences with common random numbers
    (sampling held at the unperturbed normals): the map's texels and the vertex normals, every
    component (a unit normal's own direction does not move the image: its difference is 0 and its
    gradient float noise, measured against the parameter's largest difference)."""
    rows = ir.gradcheck(plane(resolution=16), ["plane.normalmap", "plane.normals"], spp=16, max_depth=2, seed=1, max_components=6)
    assert len([r for r in rows if abs(r.fd) > 1e-3]) >= 8 and {r.name for r in rows} == {"plane.normalmap", "plane.normals"}
    assert any(r.fd == 0.0 for r in rows)  # the normals' own directions
    for r in rows:
        assert max(r.rel_errors.values()) < 0.02, r


def test_adam_recovers_a_small_normal_map():
    """From a flat start, Adam (its default step) brings a 4 x 4 map's normals from 17 degrees off
    on average to a few (a broken gradient would leave them flat or send them away)."""
    scene = plane(size=4, resolution=24)
    truth = scene.params["plane.normalmap"].clone()
    views = plane_views()
    targets = [ir.render(scene.with_camera(c), spp=128, max_depth=2, seed=100 + k, progress=False) for k, c in enumerate(views)]
    flat = scene.with_params({"plane.normalmap": torch.tensor([0.5, 0.5, 1.0]).expand(4, 4, 3).clone()}, detach=True)
    start = float(angles(flat.params["plane.normalmap"], truth).mean())
    res = ir.fit(flat, targets, ["plane.normalmap"], cameras=views, steps=40, spp=4, spp_final=8, max_depth=2, progress=False, plateau_window=0)
    assert res.solver == "adam"
    end = angles(res.params["plane.normalmap"], truth)
    assert start > 15 and float(end.mean()) < 0.3 * start and float(end.median()) < 0.25 * start, (start, end)
    assert bool(((2 * res.params["plane.normalmap"] - 1).norm(dim=-1) - 1).abs().max() < 1e-5)  # unit normals after every step


def test_records_and_lm_refuse_normals_naming_adam_and_auto_chooses_adam():
    scene = plane()
    for name in ("plane.normalmap", "plane.normals"):
        with pytest.raises(ParameterError, match=rf"^{name} is a shading normal .*path records cannot represent it; fit it with Adam"):
            ir.record_paths(scene, [name], spp=1, max_depth=2, progress=False)
        with pytest.raises(ParameterError, match=rf"solver 'lm' on re-traced renders cannot follow {name}.*solver 'adam'"):
            ir.fit(scene, torch.zeros(16, 16, 3), [name], solver="lm", progress=False)
    from invrender.inverse.fit import FitSettings
    from invrender.inverse.solver_choice import choose_solver

    choice = choose_solver(scene, ["plane.normals"], FitSettings())
    assert choice.solver == "adam" and "shading normal" in choice.reason


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("plane.normalmap", "nan", r"^plane.normalmap: values must be finite$"),
        ("plane.normalmap", "grey", r"^plane.normalmap: the normal at texel \(row 1, column 2\) has length 0 \(below 0.01: no direction\)"),
        ("plane.normalmap", "range", r"^plane.normalmap: a normal map's texels c must lie in \[0, 1\]"),
        ("plane.normalmap", "rgb", r"^plane.normalmap: a normal map is an \(h, w, 3\) texture"),
        ("plane.normals", "nan", r"^plane.normals: values must be finite$"),
        ("plane.normals", "zero", r"^plane.normals: the normal at row 2 has length 0 \(below 0.01: no direction\)"),
        ("plane.normals", "shape", r"^plane.normals: a per-vertex parameter keeps its shape \(4, 3\)"),
    ],
)
def test_bad_normals_are_one_line_errors(name, value, message):
    scene = plane()
    v = scene.params[name].clone()
    if value == "nan":
        v[1, 2] = float("nan")
    elif value == "grey":
        v[1, 2] = 0.5
    elif value == "range":
        v[0, 0, 0] = 1.5
    elif value == "rgb":
        v = [0.5, 0.5, 1.0]
    elif value == "zero":
        v[2] = 0.0
    elif value == "shape":
        v = v[:3]
    with pytest.raises(ParameterError, match=message) as e:
        scene.with_params({name: v})
    assert "\n" not in str(e.value)


def test_a_normal_map_built_with_a_zero_normal_is_refused():
    texels = torch.full((2, 2, 3), 0.5)
    material = dataclasses.replace(Material.of("diffuse", reflectance=0.5), perturbation=NormalPerturbation("normalmap", texels))
    with pytest.raises(ParameterError, match=r"^base.normalmap: the normal at texel \(row 0, column 0\) has length 0"):
        build_scene([Mesh(*sphere(0), material="base")], {"base": material}, {}, ir.Camera(), (4, 4))


def test_an_unconverged_normal_fit_advises_more_steps_not_lm():
    """Adam's warning that it did not converge names what can help: more steps (lm cannot fit a
    normal map, so the advice leaves it out there and keeps it for an albedo)."""
    scene = plane()
    target = ir.render(scene, seed=1, **KW)
    for name, advice in (("plane.normalmap", "; give more steps$"), ("plane.reflectance", "; give more steps, or solver 'auto' / 'lm'$")):
        with pytest.warns(ConvergenceWarning, match=advice):
            ir.fit(scene, target, [name], solver="adam", steps=3, spp=2, progress=False)


def test_a_fit_writes_the_recovered_normal_map(tmp_path):
    """``fit_into`` (what ``invrender fit`` writes) saves a recovered map as ``NAME.exr`` (its values)
    and ``NAME.png`` (a normal map's codes as stored, within 8-bit rounding: not sRGB-encoded)."""
    import numpy as np
    from PIL import Image

    from invrender.inverse.fit_output import fit_into

    scene = plane()
    target = ir.render(scene, seed=1, **KW)
    out = fit_into(tmp_path / "run", scene, target, ["plane.normalmap"], solver="adam", steps=2, spp=2, progress=False)
    recovered = out.result.params["plane.normalmap"]
    torch.testing.assert_close(ir.read_image(tmp_path / "run" / "plane.normalmap.exr"), recovered)
    codes = torch.from_numpy(np.asarray(Image.open(tmp_path / "run" / "plane.normalmap.png"), dtype=np.float32) / 255.0)
    assert float((codes - recovered).abs().max()) <= 0.5 / 255 + 1e-4
    assert {p.name for p in out.written} >= {"plane.normalmap.exr", "plane.normalmap.png"}
