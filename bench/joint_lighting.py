"""Joint lighting and materials on ``sky_spheres``: an environment map and two objects' albedos
from a few views, the floor's albedo known (``ir.lighting.fit_joint``).

    PYTHONPATH=. python bench/joint_lighting.py [--map 16x32] [--views 4] [--resolution 64] [--spp 128]
                                   [--target-spp 1024] [--max-depth 3] [--rounds 10]

``--views`` views around the spheres (background hidden: ``{"type": "path", "hide_emitters":
True}``) rendered with the true map and albedos at ``--target-spp`` are the targets. The fit starts
from a flat map (every texel 1) and ``diffuse.reflectance`` = ``glossy.specular_reflectance`` =
0.5; ``floor.reflectance`` stays known (it fixes the scale between map and albedos). Printed: the
machine (CPU model, vector width), wall time (map solves, records, lm), rounds, each albedo's
largest relative channel error, and a held-out view (60 degrees from the first) rendered with the
recovered map and albedos against the truth's render at the same seed: channel-mean differences
and the pooled relative RMSE.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import invrender as ir  # noqa: E402
from _measure import machine  # noqa: E402
from invrender.scene.camera import Camera  # noqa: E402

HIDDEN = {"type": "path", "hide_emitters": True}
FITTED = ["diffuse.reflectance", "glossy.specular_reflectance"]


def view(azimuth: float) -> Camera:
    """The built-in camera (4.2 from the centre, a little above) turned ``azimuth`` degrees about +Y."""
    a = math.radians(azimuth)
    return Camera(origin=(4.2 * math.sin(a), 0.35, 4.2 * math.cos(a)), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--map", default="16x32")
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--target-spp", type=int, default=1024)
    ap.add_argument("--max-depth", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=10)
    args = ap.parse_args()
    m = machine()
    print(f"machine: {m.get('cpu')} ({m.get('vector')}), {m.get('cores')} cores, load {m.get('load')}")
    h, w = (int(x) for x in args.map.split("x"))
    R = args.resolution
    truth = ir.load_scene("sky_spheres", resolution=(R, R), map_size=(h, w))
    cams = [view(360.0 * i / args.views) for i in range(args.views)]
    held = view(60.0)
    targets = [ir.render(truth.with_camera(c), HIDDEN, spp=args.target_spp, max_depth=args.max_depth, seed=100 + i, progress=False) for i, c in enumerate(cams)]
    start = truth.with_params({"sky.emission": torch.ones(h, w, 3), **{n: torch.full((3,), 0.5) for n in FITTED}})
    clock = time.perf_counter()
    fit = ir.lighting.fit_joint(start, targets, "sky", FITTED, cameras=cams, integrator=HIDDEN, spp=args.spp, max_depth=args.max_depth, rounds=args.rounds, progress=True)
    seconds = time.perf_counter() - clock
    print(f"{args.map} map, {args.views} views {R}x{R}, spp {args.spp}: {seconds:.1f} s (" + ", ".join(f"{k} {v:.1f} s" for k, v in fit.seconds.items()) + ")")
    print(fit.describe())
    for n in FITTED:
        err = float(((fit.values[n] - truth.params[n]).abs() / truth.params[n]).max())
        print(f"  {n}: {[round(float(x), 4) for x in fit.values[n]]} (truth {[round(float(x), 4) for x in truth.params[n]]}) error {100 * err:.2f}% (stderr {[round(float(x), 4) for x in fit.std_error[n]]})")
    recovered = truth.with_params({"sky.emission": fit.texels, **fit.values})
    true_img = ir.render(truth.with_camera(held), HIDDEN, spp=args.target_spp, max_depth=args.max_depth, seed=7, progress=False)
    relit = ir.render(recovered.with_camera(held), HIDDEN, spp=args.target_spp, max_depth=args.max_depth, seed=7, progress=False)
    means = (relit.mean((0, 1)) / true_img.mean((0, 1)) - 1).tolist()
    rmse = float((relit - true_img).norm() / true_img.norm())
    print(f"held-out view (60 deg): channel means {', '.join(f'{100 * x:+.2f}%' for x in means)}; pooled relative RMSE {100 * rmse:.2f}% (same seed for both)")


if __name__ == "__main__":
    main()
