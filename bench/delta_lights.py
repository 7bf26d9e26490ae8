"""invrender vs Mitsuba 3 with delta lights: the Cornell box lit by a point light, a spot light or a
directional light (through the open front) instead of its area light, channel means at high spp with standard errors from independent seeds.

    python bench/delta_lights.py [--resolution 64] [--spp 256] [--mitsuba-spp 1024] [--seeds 4]

Three comparisons per light: Mitsuba's ``path`` against invrender's ``path`` at max_depth 8 and 2,
and Mitsuba's ``direct`` against invrender's reading of it (``path`` at max_depth 2,
docs/rendering.md#mitsubas-direct-integrator). The scene goes to Mitsuba through
``mitsuba_ref.scene_dict`` (the emitter's ``to_mitsuba``). Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mitsuba_ref  # noqa: E402

import invrender as ir  # noqa: E402
from invrender.scene.builtin import CORNELL_CAMERA, CORNELL_GREEN, CORNELL_RED, CORNELL_WHITE, TALL_BOX, _shape, _walls  # noqa: E402
from invrender.scene.emitters import Emitter  # noqa: E402
from invrender.scene.scene import build_scene  # noqa: E402
from invrender.scene.shapes import rotate, scale, translate  # noqa: E402

LIGHTS = {
    "point": Emitter.of("point", emission=[3.0, 2.6, 2.0], position=[0.1, 0.8, 0.3]),
    "spot": Emitter.of("spot", emission=[8.0, 7.0, 5.0], position=[0.0, 0.9, 0.4], direction=[0.15, -1.0, -0.3], cutoff_angle=35.0, beam_width=20.0),
    "directional": Emitter.of("directional", emission=[2.0, 2.0, 1.8], direction=[0.2, -0.5, -1.0]),  # in through the open front
}


def scene(light: str, resolution: int) -> ir.Scene:
    shapes = [
        *_walls(),
        _shape("cube", translate([0.335, -0.7, 0.38]) @ rotate([0, 1, 0], -17) @ scale(0.3), "white"),
        _shape("cube", TALL_BOX, "white"),
    ]
    materials = {"white": CORNELL_WHITE, "red": CORNELL_RED, "green": CORNELL_GREEN}
    return build_scene(shapes, materials, {"lamp": LIGHTS[light]}, CORNELL_CAMERA, (resolution, resolution), name=f"cornell_{light}")


def stats(means: list[list[float]]) -> list[tuple[float, float]]:
    """Per channel: (mean over seeds, standard error)."""
    return [(statistics.fmean(c), statistics.stdev(c) / len(c) ** 0.5) for c in zip(*means)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--mitsuba-spp", type=int, default=1024)
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args()
    if not mitsuba_ref.available():
        sys.exit("Mitsuba 3 is not available (bench/README.md)")
    print(f"# {mitsuba_ref.label()}; {args.resolution}^2, invrender {args.spp} spp, Mitsuba {args.mitsuba_spp} spp, {args.seeds} seeds")
    print("| light | Mitsuba | invrender | R | G | B |")
    print("|---|---|---|---|---|---|")
    for light in LIGHTS:
        s = scene(light, args.resolution)
        for mitsuba_integrator, depth in (("path", 8), ("path", 2), ("direct", 2)):
            ours = [ir.render(s, spp=args.spp, max_depth=depth, seed=k, progress=False).mean((0, 1)).tolist() for k in range(args.seeds)]
            d = mitsuba_ref.scene_dict(s, args.mitsuba_spp, depth, integrator=mitsuba_integrator)
            if mitsuba_integrator == "direct":
                del d["integrator"]["max_depth"]
            mi, _ = mitsuba_ref._require()
            mi_scene = mi.load_dict(d)
            theirs = [mitsuba_ref.render(mi_scene, args.mitsuba_spp, seed=1000 + k).reshape(-1, 3).mean(0).tolist() for k in range(args.seeds)]
            cells = []
            for (a, sa), (b, sb) in zip(stats(ours), stats(theirs)):
                rel = a / b - 1.0
                err = (a / b) * ((sa / a) ** 2 + (sb / b) ** 2) ** 0.5
                cells.append(f"{100 * rel:+.2f} ± {100 * err:.2f}%")
            print(f"| {light} | {mitsuba_integrator} max_depth {depth if mitsuba_integrator == 'path' else '-'} | path max_depth {depth} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
