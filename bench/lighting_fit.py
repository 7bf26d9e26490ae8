"""Inverse lighting on the built-in ``sky_spheres``: its sky recovered from three views, a held-out view relit.

    python bench/lighting_fit.py [--map 4 8] [--resolution 24] [--spp 256] [--fit-spp 16]
                                [--rounds 3] [--prior-weight W] [--smoothness MU]
                                [--solver lm|gauss_newton|adam] [--steps 200]
                                [--out bench/out/inverse_lighting.png] [--docs]

Three views of ``sky_spheres`` (a diffuse and a glossy GGX sphere on a floor) 120 degrees apart
around the spheres, rendered with the true map (``sky_map``, h x w) and the background hidden
(``{"type": "path", "hide_emitters": True}``), are the targets. The fit starts from a flat map
(every texel 1) and solves for ``sky.emission`` with ``ir.fit(..., solver="lm")`` (path records,
Levenberg-Marquardt, the Tikhonov prior toward the start; ``--smoothness``: the smoothness prior
too; ``--solver adam``: Adam on re-traced renders instead, for comparison). A fourth view, 60 degrees from the
first and not fitted, is rendered with the true and with the recovered map: the script prints both
renders' channel means and their relative differences (the issue's target: within 3%), the fit's
time and rounds, and writes one PNG: the true map and the recovered map (top), the held-out view
with the true and with the recovered map (bottom). ``--docs`` writes it to
docs/images/inverse_lighting.png as well.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import torch

import invrender as ir
from invrender.io import write_image
from invrender.scene.builtin import sky_map, sky_spheres
from invrender.scene.camera import Camera

HIDDEN = {"type": "path", "hide_emitters": True}
#: the issue's acceptance on the held-out view's channel means, percent
TOLERANCE = 3.0
DOCS_IMAGE = Path(__file__).resolve().parent.parent / "docs" / "images" / "inverse_lighting.png"


def view(azimuth: float) -> Camera:
    """The built-in camera (4.2 from the centre, a little above) turned ``azimuth`` degrees about +Y."""
    a = math.radians(azimuth)
    return Camera(origin=(4.2 * math.sin(a), 0.35, 4.2 * math.cos(a)), target=(0, -0.35, 0), up=(0, 1, 0), fov=40.0, fov_axis="smaller")


def say(step: str) -> None:
    """What the script does next, on stderr at once (the fit's and renders' bars follow)."""
    print(step, file=sys.stderr, flush=True)


def upsample(img: torch.Tensor, k: int) -> torch.Tensor:
    return img.repeat_interleave(k, 0).repeat_interleave(k, 1)


def figure(true_map, recovered, true_view, relit, width: int = 384) -> torch.Tensor:
    """Maps side by side on top (tone-mapped, x / (1 + x) after scaling the sky's median to 1), views below."""
    h, w, _ = true_map.shape
    k = max(1, width // (2 * w))
    maps = torch.cat([upsample(true_map, k), upsample(recovered, k)], dim=1) / float(true_map.median())
    maps = maps / (1 + maps)
    kv = max(1, maps.shape[1] // (2 * true_view.shape[1]))
    views = torch.cat([upsample(true_view, kv), upsample(relit, kv)], dim=1)
    pad = maps.shape[1] - views.shape[1]
    views = torch.nn.functional.pad(views.permute(2, 0, 1), (0, pad)).permute(1, 2, 0)
    gap = torch.ones(4, maps.shape[1], 3)
    return torch.cat([maps, gap, views], dim=0).clamp(0, 1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--map", type=int, nargs=2, default=(4, 8), metavar=("H", "W"), help="the map's size (true and fitted)")
    parser.add_argument("--resolution", type=int, default=24, help="each view's width and height")
    parser.add_argument("--spp", type=int, default=256, help="samples per pixel of the targets and the held-out renders")
    parser.add_argument("--fit-spp", type=int, default=16, help="lm's first round's spp (x4 each round)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--solver", default="lm", choices=("lm", "gauss_newton", "adam"), help="adam: --steps steps at --fit-spp, then 4x")
    parser.add_argument("--steps", type=int, default=200, help="adam's steps")
    parser.add_argument("--max-depth", type=int, default=3)
    parser.add_argument("--prior-weight", type=float, default=None, help="FitSettings.prior_weight (default: its rule)")
    parser.add_argument("--smoothness", type=float, default=0.0, help="FitSettings.smoothness (-1: its rule; default 0, none)")
    parser.add_argument("--out", default="bench/out/inverse_lighting.png", help="the PNG (bench/out/ is git-ignored)")
    parser.add_argument("--docs", action="store_true", help="also write docs/images/inverse_lighting.png")
    args = parser.parse_args()
    say(f"inverse lighting on sky_spheres: {args.map[0]} x {args.map[1]} map, {args.solver} (about 30-80 s on 2 cores at the defaults)")

    h, w = args.map
    res = (args.resolution, args.resolution)
    truth = sky_map(h, w)
    scene = sky_spheres(resolution=res, map_size=(h, w))
    views = [view(a) for a in (0.0, 120.0, 240.0)]
    held_out = view(60.0)
    say(f"rendering the three targets ({args.resolution} x {args.resolution}, {args.spp} spp) ...")
    targets = [ir.render(scene.with_camera(c), HIDDEN, spp=args.spp, max_depth=args.max_depth, seed=100 + i) for i, c in enumerate(views)]
    say(f"fitting the {h} x {w} map from a flat start ({args.solver}) ...")

    start = sky_spheres(resolution=res, map_size=(h, w), sky=torch.ones(h, w, 3))
    clock = time.perf_counter()
    fit = ir.fit(start, targets, ["sky.emission"], cameras=views, solver=args.solver, integrator=HIDDEN, max_depth=args.max_depth,
                 spp=args.fit_spp, spp_final=4 * args.fit_spp, steps=args.steps, rounds=args.rounds, prior_weight=args.prior_weight,
                 smoothness=None if args.smoothness < 0 else args.smoothness, truth={"sky.emission": truth})
    seconds = time.perf_counter() - clock
    recovered = fit.params["sky.emission"]

    big = (2 * args.resolution, 2 * args.resolution)
    say("relighting the held-out view ...")
    true_view = ir.render(sky_spheres(big, (h, w)).with_camera(held_out), HIDDEN, spp=args.spp, max_depth=args.max_depth, seed=7, progress=False)
    relit_scene = sky_spheres(big, (h, w), sky=recovered).with_camera(held_out)
    relit = ir.render(relit_scene, HIDDEN, spp=args.spp, max_depth=args.max_depth, seed=7, progress=False)
    m_true, m_relit = true_view.mean((0, 1)), relit.mean((0, 1))
    diff = 100 * (m_relit - m_true) / m_true
    error = ((recovered - truth).abs() / truth).flatten()
    print(f"sky_spheres, {h} x {w} map ({3 * h * w} channels), three {args.resolution} x {args.resolution} views, background hidden, max_depth {args.max_depth}")
    if args.solver == "adam":
        print(f"adam: {len(fit.history)} steps at {args.fit_spp} then {4 * args.fit_spp} spp, {seconds:.1f} s")
    else:
        print(f"{args.solver}: {len(fit.history)} rounds (spp {', '.join(str(r['spp']) for r in fit.history)}), {seconds:.1f} s")
    print(f"texels: median relative error {100 * float(error.median()):.1f}%, largest {100 * float(error.max()):.0f}%")
    print(f"held-out view (60 degrees, {big[0]} x {big[1]}, {args.spp} spp) channel means:")
    print(f"  true map      {' '.join(f'{float(x):.4f}' for x in m_true)}")
    print(f"  recovered map {' '.join(f'{float(x):.4f}' for x in m_relit)}")
    worst = float(diff.abs().max())
    print(f"  difference    {' '.join(f'{float(x):+.2f}%' for x in diff)}   ({'within' if worst < TOLERANCE else 'NOT within'} {TOLERANCE:g}%)")
    image = figure(truth, recovered, true_view, relit)
    for path in [Path(args.out)] + ([DOCS_IMAGE] if args.docs else []):
        write_image(path, image)
        print(f"wrote {path} ({path.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
