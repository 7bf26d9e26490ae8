"""Non-finite values cannot kill the process: rays with a NaN, infinite or huge origin or direction
are misses (not occluded) on every intersection backend (Embree's packets, embreex, Warp on the
CPU, torch), a render whose camera casts some is an image, a NaN parameter or NaN radiance is a
one-line error, a scene file with ``inf`` in its camera is refused with the key's name.

Embree built with assertions (Debian's) aborts the whole interpreter on such a ray (SIGABRT, exit
134), so everything that could reach it runs in a child process and the test asserts its exit
status before anything else."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import invrender as ir
from invrender.errors import SceneError
from invrender.backends import accel, embree_native, packages

ROOT = Path(__file__).resolve().parents[2]


def run_child(code: str, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    """``code`` run by a fresh interpreter from the repository root (so it imports this checkout)."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code), *args], cwd=ROOT, capture_output=True, text=True, timeout=300, env={**os.environ, **(env or {})}
    )


def survived(proc: subprocess.CompletedProcess) -> dict:
    """The child's JSON answer (its last stdout line), after checking it exited normally."""
    assert proc.returncode == 0, f"exit {proc.returncode}: {proc.stderr[-2000:]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


#: the backends of this machine: name -> (backend, INVRENDER_EMBREE); Embree's packets where they build
BACKENDS = {"torch": ("torch", None)}
if embree_native.library()[0] is not None:
    BACKENDS["embree packets"] = ("embree", "packets")
if packages.find("embreex") is not None:
    BACKENDS["embreex"] = ("embree", "embreex")
if packages.find("warp") is not None:
    BACKENDS["warp"] = ("warp", None)

#: bad lanes: (name, origin, direction) of rays no backend may trace
BAD = [
    ("nan origin", ["nan", 0, 3], [0, 0, -1]),
    ("inf origin", [0, 0, "inf"], [0, 0, -1]),
    ("-inf origin", [0, "-inf", 0], [0, 0, 1]),
    ("nan direction", [0, 0, 3], [0, "nan", -1]),
    ("inf direction", [0, 0, 3], [0, 0, "-inf"]),  # Warp alone answered a hit at t = 0
    ("huge origin", [0, 0, 1e19], [0, 0, -1]),  # beyond Embree's FLT_LARGE: its assertion too
    ("huge direction", [0, 0, 3], [0, 0, -1e30]),
    ("all nan", ["nan", "nan", "nan"], ["nan", "nan", "nan"]),
]

RAYS_CHILD = """
    import json, math, os, sys
    import torch
    import invrender as ir
    from invrender.backends import accel, embree_native
    from tests.transport.test_backends import random_rays

    def answers(backend, n, threads, bad):
        o, d = random_rays(scene, n, seed=n)
        tmax = torch.rand(n, generator=torch.Generator().manual_seed(1)) * 4
        tmax[:4] = torch.tensor([math.nan, 0.0, -1.0, math.inf])  # not traced, not traced, not traced, traced
        lanes = torch.arange(len(bad)) * (n // len(bad)) + 5
        o2, d2 = o.clone(), d.clone()
        for k, (_, bo, bd) in zip(lanes.tolist(), bad):
            o2[k], d2[k] = torch.tensor([float(x) for x in bo]), torch.tensor([float(x) for x in bd])
        inter, ref = accel.make_intersector(scene.triangles, backend, threads), accel.make_intersector(scene.triangles, "torch")
        hits, want = inter.intersect(o2, d2), ref.intersect(o, d)
        occluded, want_occluded = inter.occluded(o2, d2, tmax), ref.occluded(o, d, tmax)
        good = torch.ones(n, dtype=torch.bool)
        good[lanes] = False
        return {
            "bad_prim": hits.prim[lanes].tolist(), "bad_t": hits.t[lanes].tolist(), "bad_uv": (hits.u[lanes].abs() + hits.v[lanes].abs()).tolist(),
            "bad_occluded": occluded[lanes].tolist(), "untraced_tmax": occluded[:3].tolist(), "good_hits": int(hits.valid[good].sum()),
            "good_same_prim": float((hits.prim[good] == want.prim[good]).float().mean()),
            "good_same_occluded": float((occluded[good] == want_occluded[good]).float().mean()),
        }

    backends, bad = json.loads(sys.argv[1]), json.loads(sys.argv[2])
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    out = {}
    for name, (backend, mode) in backends.items():
        os.environ[embree_native.ENV] = mode or "packets"
        for n, threads in ((37, 1), (5003, 2)):  # a partial packet; a batch split across threads
            out[f"{name}, {n} rays"] = answers(backend, n, threads, bad)
    print(json.dumps(out))
"""


def test_untraceable_rays_are_misses_on_every_backend():
    """Every backend of this machine, in one child (which would die at the first that aborts)."""
    out = survived(run_child(RAYS_CHILD, json.dumps(BACKENDS), json.dumps(BAD)))
    assert len(out) == 2 * len(BACKENDS)
    for case, got in out.items():
        n = int(case.split(", ")[1].split()[0])
        assert got["bad_prim"] == [-1] * len(BAD), (case, list(zip([b[0] for b in BAD], got["bad_prim"])))
        assert got["bad_t"] == [float("inf")] * len(BAD) and got["bad_uv"] == [0.0] * len(BAD), case
        assert got["bad_occluded"] == [False] * len(BAD), case
        assert got["untraced_tmax"] == [False, False, False], case  # tmax NaN, 0, -1: not traced
        # the other rays of the same batch are answered as ever (coplanar ties of the box aside)
        assert got["good_same_prim"] > 0.995 and got["good_same_occluded"] > 0.995 and got["good_hits"] > n // 2, case


def test_traceable_is_embree_s_limit():
    """The exact rule, and the CPU's one-dot-product shortcut agreeing with it at the limit."""
    import torch

    o = torch.tensor([[0.0, 0, 1.8e18], [0, 0, 1.9e18], [0, 0, 0], [0, 0, 0]])
    d = torch.tensor([[0.0, 0, 1], [0, 0, 1], [0, float("nan"), 1], [0, 0, float("inf")]])
    assert accel.traceable(o, d).tolist() == [True, False, False, False]
    assert accel._untraceable_lanes(o[:1], d[:1]) is None  # all traceable: no mask
    assert accel._untraceable_lanes(o, d).tolist() == [True, False, False, False]
    assert accel.RAY_LIMIT == 1.844e18  # Embree's FLT_LARGE, as in embree_packets.cpp
    assert "kRayLimit = 1.844e18f" in Path(accel.__file__).with_name("embree_packets.cpp").read_text()


RENDER_CHILD = """
    import json, math, sys
    import torch
    import invrender as ir
    from invrender.scene.camera import Camera
    from invrender.plugins.integrators import Integrator

    out = {}
    scene = ir.load_scene("cornell_box", resolution=(8, 8))
    clean = ir.render(scene, spp=2, seed=3, progress=False)
    # a camera (a plugin) that casts NaN and infinite rays for two rows of pixels
    generate = Camera.generate_rays
    def broken(self, film_xy, width, height, u_lens=None):
        o, d = generate(self, film_xy, width, height, u_lens)
        row = film_xy[:, 1].floor()
        o = torch.where((row == 2)[:, None], torch.tensor([0.0, math.inf, 3.0]), o)
        d = torch.where((row == 5)[:, None], torch.full((3,), math.nan), d)
        return o, d
    Camera.generate_rays = broken
    for backend in sys.argv[1:]:
        image = ir.render(scene, spp=2, seed=3, backend=backend, progress=False)
        out[backend] = {"dark_rows": image[[2, 5]].abs().sum().item(), "finite": bool(torch.isfinite(image).all()),
                        "other_rows": (image[[0, 1, 3, 4, 6, 7]] - clean[[0, 1, 3, 4, 6, 7]]).abs().max().item()}
    Camera.generate_rays = generate
    # a NaN parameter set in place: refused before rendering, named
    with torch.no_grad():
        scene.params["red.reflectance"][1] = math.nan
    try:
        ir.render(scene, spp=1, progress=False)
    except ir.InvRenderError as e:
        out["param"] = [type(e).__name__, str(e)]
    with torch.no_grad():
        scene.params["red.reflectance"][1] = 0.5
    # NaN radiance from an integrator: refused with the pixel count
    render = Integrator.render
    def nan_pixels(self, *args, **kwargs):
        image = render(self, *args, **kwargs).clone()
        image[0, :3, 1] = math.nan
        image[7, 7] = math.inf
        return image
    Integrator.render = nan_pixels
    try:
        ir.render(scene, spp=1, progress=False)
    except ir.InvRenderError as e:
        out["radiance"] = [type(e).__name__, str(e)]
    print(json.dumps(out))
"""


def test_render_survives_nan_rays_and_names_nan_values():
    backends = ["embree", "torch"] + (["warp"] if "warp" in BACKENDS else [])
    out = survived(run_child(RENDER_CHILD, *backends))
    for backend in backends:
        # the camera's NaN and infinite rays are misses: black pixels (no emitter at infinity), the rest as before
        assert out[backend] == {"dark_rows": 0.0, "finite": True, "other_rows": 0.0} or (
            out[backend]["dark_rows"] == 0.0 and out[backend]["finite"] and out[backend]["other_rows"] < 1e-4
        ), (backend, out[backend])
    kind, message = out["param"]
    assert kind == "ParameterError" and message == "parameter 'red.reflectance' (1 of 3 values) is not finite (NaN or inf): give finite values before rendering"
    kind, message = out["radiance"]
    assert kind == "NonFiniteError" and "4 of 64 pixels not finite (3 with NaN, 1 with inf)" in message and "\n" not in message


def test_cli_refuses_an_infinite_camera_target(tmp_path):
    """The issue's crash: ``target = [0, 0, inf]`` aborted the process inside Embree (exit 134)."""
    text = (ROOT / "forward" / "cornell_box.toml").read_text().replace("target = [0, 0, 0]", "target = [0, 0, inf]")
    scene = tmp_path / "inf.toml"
    scene.write_text(text)
    proc = subprocess.run(
        [sys.executable, "-m", "invrender", "render", str(scene), "--resolution", "8x8", "--spp", "1", "--out", str(tmp_path / "x.exr")],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines() == [f"invrender: error: {scene} [camera]: 'target' must be 3 finite numbers, got [0, 0, inf]"]
    assert not (tmp_path / "x.exr").exists()


@pytest.mark.parametrize(
    "old, new, message",
    [
        ("origin = [0, 0, 3.9]", "origin = [nan, 0, 3.9]", "[camera]: 'origin' must be 3 finite numbers, got [nan, 0, 3.9]"),
        ("fov = 39.3077", "fov = inf", "[camera]: 'fov' must be a finite number, got inf"),
        ("translate = [0, -1, 0]", "translate = [0, -inf, 0]", "shapes[0] transform[1]: 'translate' must be 3 finite numbers, got [0, -inf, 0]"),
        ("{ scale = 0.3 }", "{ scale = nan }", "shapes[5] transform[0]: 'scale' must be finite, got nan"),
        ("angle = -90", "angle = inf", "shapes[0] transform[0] rotate: 'angle' must be a finite number, got inf"),
        ("axis = [1, 0, 0], angle = -90", "axis = [1, nan, 0], angle = -90", "shapes[0] transform[0] rotate: 'axis' must be 3 finite numbers, got [1, nan, 0]"),
    ],
)
def test_scene_files_refuse_non_finite_values_by_key(tmp_path, old, new, message):
    text = (ROOT / "forward" / "cornell_box.toml").read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(SceneError) as info:
        ir.load_scene(path)
    assert str(info.value) == f"{path} {message}"


def test_cameras_refuse_non_finite_positions():
    from invrender.scene.camera import Camera

    for key in ("origin", "target", "up"):
        with pytest.raises(SceneError, match=f"^camera {key} must be 3 finite numbers \\(\\|x\\| <= 3.403e\\+38\\), got \\[0.0, nan, 1.0\\]$"):
            Camera(**{key: (0.0, float("nan"), 1.0)})


def test_scene_files_refuse_coordinates_beyond_float32_geometry(tmp_path):
    text = (ROOT / "forward" / "cornell_box.toml").read_text().replace("{ scale = 0.3 }", "{ scale = 1e300 }", 1)
    path = tmp_path / "huge.toml"
    path.write_text(text)
    with pytest.raises(SceneError, match=r"huge.toml: mesh of material 'white' has vertex coordinates up to 1.\d+e\+300, beyond \+-1e\+18 \(float32 geometry\)$"):
        ir.load_scene(path)
