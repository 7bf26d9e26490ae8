"""Inverse lighting by the transport matrix on ``sky_spheres``: time, peak memory, held-out relighting error.

    python bench/transport_matrix.py [--maps 16x32 32x64] [--views 3] [--resolution 64] [--spp 64]
                                     [--target-spp 1024] [--max-depth 3] [--sweep] [--sun]

For each map size: three (``--views``) views of ``sky_spheres`` 120 degrees apart around the
spheres (the background hidden: ``{"type": "path", "hide_emitters": True}``) rendered with the
true map (``sky_map``; ``--sun``: its sun made 1000x brighter than the sky) at ``--target-spp`` are
the targets. ``ir.lighting.fit_map`` starts from a flat map (every texel 1: the sampling and the
matrix's shape), renders the transport matrix in two halves of ``--spp`` samples per pixel and
solves for the map with the prior's weight by the discrepancy principle. A held-out view, 60
degrees from the first, is rendered with the true and with the recovered map (same seed and the
true map's sampling in both, so their difference is the map's); the script prints the time of the
matrix and of the solve, the process's peak resident memory, the chosen weight, and the held-out
view's channel-mean differences and pooled relative RMSE (``||relit - true|| / ||true||`` over
pixels and channels). ``--sweep`` also solves at fixed weights 10^-7 .. 10^1 on the same matrix
and prints each one's held-out error (the rule's against the best). The machine: ``lscpu``.
"""

from __future__ import annotations

import argparse
import math
import resource
import sys
import time

import torch

import invrender as ir
from invrender.inverse.map_fit import fit_map, solve_map
from invrender.scene.builtin import sky_map, sky_spheres
from invrender.scene.camera import Camera

HIDDEN = {"type": "path", "hide_emitters": True}


def view(azimuth: float) -> Camera:
    """The built-in camera (4.2 from the centre, a little above) turned ``azimuth`` degrees about +Y."""
    a = math.radians(azimuth)
    return Camera(origin=(4.2 * math.sin(a), 0.35, 4.2 * math.cos(a)), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def truth_map(h: int, w: int, sun: bool) -> torch.Tensor:
    """sky_map, or (``sun``) with its brightest texel's neighbourhood raised so that the sun's peak is 1000x the sky's median."""
    m = sky_map(h, w)
    if sun:
        lum = m.mean(2)
        peak = lum.flatten().argmax()
        i, j = divmod(int(peak), w)
        m[i, j] *= 1000 * float(lum.median()) / float(lum[i, j])
    return m


def held_out_error(truth: torch.Tensor, recovered: torch.Tensor, res: int, spp: int, max_depth: int) -> tuple[torch.Tensor, float]:
    """(channel-mean differences (3,), pooled relative RMSE) of the held-out view relit."""
    h, w, _ = truth.shape
    scene = sky_spheres((res, res), (h, w), sky=truth).with_camera(view(60.0))
    true_img = ir.render(scene, HIDDEN, spp=spp, max_depth=max_depth, seed=7, progress=False)
    relit = ir.render(scene.with_params({"sky.emission": recovered.clamp_min(0)}), HIDDEN, spp=spp, max_depth=max_depth, seed=7, progress=False, sampling_params={"sky.emission": truth})
    means = (relit.mean((0, 1)) - true_img.mean((0, 1))) / true_img.mean((0, 1))
    return means, float((relit - true_img).norm() / true_img.norm())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--maps", nargs="+", default=["16x32", "32x64"], help="map sizes HxW")
    parser.add_argument("--views", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel of each half of the matrix")
    parser.add_argument("--target-spp", type=int, default=1024)
    parser.add_argument("--max-depth", type=int, default=3)
    parser.add_argument("--sweep", action="store_true", help="also solve at fixed weights and print their held-out errors")
    parser.add_argument("--sun", action="store_true", help="a sun 1000x the sky's median")
    args = parser.parse_args()
    res = (args.resolution, args.resolution)
    cams = [view(360.0 * i / args.views) for i in range(args.views)]
    print(f"sky_spheres, {args.views} views {args.resolution}x{args.resolution} (background hidden), max_depth {args.max_depth}, matrix 2 x {args.spp} spp, targets {args.target_spp} spp")
    for size in args.maps:
        h, w = (int(x) for x in size.split("x"))
        truth = truth_map(h, w, args.sun)
        true_scene = sky_spheres(res, (h, w), sky=truth)
        targets = [ir.render(true_scene.with_camera(c), HIDDEN, spp=args.target_spp, max_depth=args.max_depth, seed=100 + i, progress=False) for i, c in enumerate(cams)]
        start = sky_spheres(res, (h, w), sky=torch.ones(h, w, 3))
        clock = time.perf_counter()
        fit = fit_map(start, targets, "sky", cameras=cams, integrator=HIDDEN, spp=args.spp, max_depth=args.max_depth)
        seconds = time.perf_counter() - clock
        means, rmse = held_out_error(truth, fit.texels, args.resolution, args.target_spp, args.max_depth)
        print(f"{h}x{w} map: {seconds:.1f} s (matrix {fit.seconds['render']:.1f} s, solve {fit.seconds['solve']:.1f} s), peak RSS {peak_mb():.0f} MB")
        print(f"  {fit.describe()}")
        print(f"  held-out view: channel means {' '.join(f'{100 * float(x):+.2f}%' for x in means)}, pooled relative RMSE {100 * rmse:.2f}%")
        if args.sweep:
            rows = []
            for e in range(-7, 2):
                fixed = solve_map(fit.matrix, targets, weight=10.0**e, stderr=False)
                m, r = held_out_error(truth, fixed.texels, args.resolution, args.target_spp, args.max_depth)
                rows.append((e, float(m.abs().max()), r))
                print(f"    weight 1e{e:+d}: channel means worst {100 * rows[-1][1]:.2f}%, RMSE {100 * r:.2f}%")
            best = min(rows, key=lambda t: t[2])
            print(f"  best swept weight 1e{best[0]:+d}: RMSE {100 * best[2]:.2f}%; the rule's {100 * rmse:.2f}% ({rmse / best[2]:.2f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
