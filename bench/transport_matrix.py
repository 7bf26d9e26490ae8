"""Inverse lighting by the transport matrix on ``sky_spheres``: time, peak memory, held-out relighting error.

    python bench/transport_matrix.py [--maps 16x32 32x64] [--views 3] [--resolution 64] [--spp 64]
                                     [--target-spp 1024] [--max-depth 3] [--sun] [--unknowns 3072]
                                     [--rounds auto] [--sweep] [--out DIR] [--json PATH]

For each map size: ``--views`` views of ``sky_spheres`` evenly spaced around the spheres (the
background hidden: ``{"type": "path", "hide_emitters": True}``) rendered with the true map
(``sky_map``; ``--sun``: its brightest texel raised to 1000x the map's median, a sun of one texel)
at ``--target-spp`` are the targets. ``ir.lighting.fit_map`` starts from a flat map (every texel 1:
the first round's sampling), streams the normal equations of the transport matrix view by view
(two halves of ``--spp`` samples per pixel) and solves for the map with the prior's weight by the
discrepancy principle (a second round sampled by the first round's map where ``--rounds`` asks or
``auto`` finds a sun). The fit's peak resident memory is measured alone (the peak is reset before
it). A held-out view, 60 degrees from the first, is relit through its own transport matrix of the
true map's sampling (``--target-spp`` samples per pixel), so that the true and the recovered map
are seen along the same paths and their difference is the map's: channel-mean differences and the
pooled relative RMSE ``||relit - true|| / ||true||``; with ``--sun`` also the angle between the
brightest recovered texel and the sun.

``--out DIR`` writes, per map, the relighting product (``fit.write``: map.exr, stderr.exr,
resolution.png, fit.json) into ``DIR/HxW`` and a figure ``DIR/HxW/figure.png``
(``ir.lighting.relighting_figure``, as ``invrender fit`` writes it): the true and the recovered map,
the standard errors, the identifiability, the held-out view under the true map and relit.

``--sweep`` solves the same normal equations at fixed weights 10^-1 .. 10^3 (quarter decades) and
with generalized cross-validation (``rule="gcv"``) and prints each one's held-out error against
the discrepancy principle's. The machine (CPU model, vector width, load average) is printed first.
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
from _measure import Results, add_json_option, machine, peak_rss_mib  # noqa: E402
from invrender.errors import ParameterError  # noqa: E402
from invrender.inverse.map_fit import fit_map, solve_map  # noqa: E402
from invrender.inverse.relighting import relighting_error, relighting_figure  # noqa: E402
from invrender.scene.builtin import map_directions, sky_map, sky_spheres  # noqa: E402
from invrender.scene.camera import Camera  # noqa: E402

HIDDEN = {"type": "path", "hide_emitters": True}


def view(azimuth: float) -> Camera:
    """The built-in camera (4.2 from the centre, a little above) turned ``azimuth`` degrees about +Y."""
    a = math.radians(azimuth)
    return Camera(origin=(4.2 * math.sin(a), 0.35, 4.2 * math.cos(a)), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")


def reset_peak() -> None:
    """Reset this process's peak resident set size (Linux: /proc/self/clear_refs)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def truth_map(h: int, w: int, sun: bool) -> torch.Tensor:
    """sky_map, or (``sun``) with its brightest texel raised to 1000x the map's median luminance."""
    m = sky_map(h, w)
    if sun:
        lum = m.mean(2)
        peak = lum.flatten().argmax()
        i, j = divmod(int(peak), w)
        m[i, j] *= 1000 * float(lum.median()) / float(lum[i, j])
    return m


class HeldOut:
    """A held-out view's transport matrix (sampled by the true map): relights any map along the
    same paths as the true one."""

    def __init__(self, truth: torch.Tensor, res: int, spp: int, max_depth: int):
        h, w, _ = truth.shape
        self.truth = truth
        scene = sky_spheres((res, res), (h, w), sky=truth)
        half = max(spp // 2, 1)
        self.tm = ir.lighting.transport_matrix(scene, "sky", cameras=[view(60.0)], integrator=HIDDEN, spp=half, max_depth=max_depth, seed=7, sampling_map=truth)
        self.true_img = self.tm.images(truth)[0]

    def relit(self, recovered: torch.Tensor) -> torch.Tensor:
        """(H, W, 3) the held-out view under the map ``recovered``."""
        return self.tm.images(recovered.clamp_min(0))[0]

    def error(self, recovered: torch.Tensor) -> tuple[torch.Tensor, float]:
        """(channel-mean differences (3,), pooled relative RMSE) of the held-out view relit."""
        return relighting_error(self.true_img, self.relit(recovered))


def sun_angle(truth: torch.Tensor, recovered: torch.Tensor) -> float:
    """Degrees between the brightest texel of the recovered map and of the true one."""
    h, w, _ = truth.shape
    d = map_directions(h, w).reshape(-1, 3)
    a, b = d[int(truth.mean(2).flatten().argmax())], d[int(recovered.mean(2).flatten().argmax())]
    return math.degrees(math.acos(max(-1.0, min(1.0, float(a @ b)))))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--maps", nargs="+", default=["16x32", "32x64"], help="map sizes HxW")
    parser.add_argument("--views", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel of each half of the matrix")
    parser.add_argument("--target-spp", type=int, default=1024)
    parser.add_argument("--max-depth", type=int, default=3)
    parser.add_argument("--sun", action="store_true", help="a one-texel sun 1000x the map's median")
    parser.add_argument("--unknowns", type=int, default=3072, help="fit_map's budget of unknowns")
    parser.add_argument("--rounds", default="auto", help="fit_map's rounds: 1, 2 or auto")
    parser.add_argument("--out", default=None, metavar="DIR", help="write each map's relighting product and figure under DIR/HxW")
    parser.add_argument("--sweep", action="store_true", help="also solve at fixed weights and by GCV, and print their held-out errors")
    add_json_option(parser)
    args = parser.parse_args()
    rounds = args.rounds if args.rounds == "auto" else int(args.rounds)
    res = (args.resolution, args.resolution)
    cams = [view(360.0 * i / args.views) for i in range(args.views)]
    info = machine()
    print(f"{info['cpu']} ({info['vector']}), {info['cores']} cores, load average {info['load_average']}; torch {info.get('torch')}")
    print(f"sky_spheres, {args.views} views {args.resolution}x{args.resolution} (background hidden), max_depth {args.max_depth}, matrix 2 x {args.spp} spp, targets {args.target_spp} spp{', sun 1000x' if args.sun else ''}")
    results = Results("transport_matrix", "Inverse lighting by the transport matrix (sky_spheres, background hidden)")
    rows, sweep_rows = [], []
    for size in args.maps:
        h, w = (int(x) for x in size.split("x"))
        truth = truth_map(h, w, args.sun)
        true_scene = sky_spheres(res, (h, w), sky=truth)
        targets = [ir.render(true_scene.with_camera(c), HIDDEN, spp=args.target_spp, max_depth=args.max_depth, seed=100 + i, progress=False) for i, c in enumerate(cams)]
        start = sky_spheres(res, (h, w), sky=torch.ones(h, w, 3))
        reset_peak()
        clock = time.perf_counter()
        fit = fit_map(start, targets, "sky", cameras=cams, integrator=HIDDEN, spp=args.spp, max_depth=args.max_depth, unknowns=args.unknowns, rounds=rounds)
        seconds = time.perf_counter() - clock
        peak = peak_rss_mib()
        held = HeldOut(truth, args.resolution, args.target_spp, args.max_depth)
        means, rmse = held.error(fit.texels)
        angle = sun_angle(truth, fit.texels) if args.sun else None
        s = fit.seconds
        print(f"{h}x{w} map: {seconds:.1f} s (render {s['render']:.1f} s, normal equations {s['gram']:.1f} s, solve {s['solve']:.1f} s), peak RSS {peak:.0f} MiB")
        print(f"  {fit.describe()}; Cholesky factorizations in the weight's search {fit.evaluations.tolist()}")
        print(f"  held-out view: channel means {' '.join(f'{100 * float(x):+.2f}%' for x in means)}, pooled relative RMSE {100 * rmse:.2f}%" + (f"; brightest texel {angle:.1f} deg from the sun" if angle is not None else ""))
        if args.out:
            folder = Path(args.out) / size
            fit.write(folder)
            title = f"{size} map from {args.views} views: held-out pooled RMSE {100 * rmse:.2f}%; {fit.describe()}"
            relighting_figure(folder / "figure.png", fit.texels, stderr=fit.stderr, resolution=fit.resolution, truth=truth, views=[("held-out view", held.true_img, held.relit(fit.texels))], title=title)
            print(f"  wrote {folder}")
        rows.append({"map": size, "views": args.views, "spp": args.spp, "unknowns": fit.basis.n, "rounds": fit.rounds, "seconds": round(seconds, 2), "render_s": round(s["render"], 2), "normal_s": round(s["gram"], 2), "solve_s": round(s["solve"], 2),
                     "peak_mib": round(peak), "weight": [round(float(x), 3) for x in fit.weight], "means_pct": [round(100 * float(x), 3) for x in means], "rmse_pct": round(100 * rmse, 3), "sun_deg": None if angle is None else round(angle, 2)})  # fmt: skip
        if args.sweep:
            errors = []
            for e in [k / 4 for k in range(-4, 13)]:
                try:
                    fixed = solve_map(fit.normal, weight=10.0**e, stderr=False)
                except ParameterError:  # below the weight at which the regularized matrix is definite
                    continue
                errors.append((e, held.error(fixed.texels)[1]))
                print(f"    weight 1e{e:+.2f}: pooled RMSE {100 * errors[-1][1]:.2f}%")
            gcv = solve_map(fit.normal, rule="gcv", stderr=False)
            gcv_rmse = held.error(gcv.texels)[1]
            best = min(errors, key=lambda t: t[1])
            print(f"  best swept weight 1e{best[0]:+.2f}: RMSE {100 * best[1]:.2f}%; discrepancy (weight {float(fit.weight.mean()):.3g}) {100 * rmse:.2f}% ({rmse / best[1]:.2f}x); GCV (weight {float(gcv.weight.mean()):.3g}) {100 * gcv_rmse:.2f}% ({gcv_rmse / best[1]:.2f}x)")
            sweep_rows.append({"map": size, "views": args.views, "spp": args.spp, "best_weight": round(10.0 ** best[0], 3), "best_rmse_pct": round(100 * best[1], 3), "discrepancy_weight": round(float(fit.weight.mean()), 3), "discrepancy_rmse_pct": round(100 * rmse, 3),
                               "discrepancy_ratio": round(rmse / best[1], 3), "gcv_weight": round(float(gcv.weight.mean()), 3), "gcv_rmse_pct": round(100 * gcv_rmse, 3), "gcv_ratio": round(gcv_rmse / best[1], 3)})  # fmt: skip
    for title, table in (("fits", rows), ("weight rules against a sweep", sweep_rows)):
        if table:
            results.table(title, list(table[0])).extend([[str(v) for v in r.values()] for r in table])
    if args.json:
        results.write(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
