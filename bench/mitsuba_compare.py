"""invrender vs Mitsuba 3: channel means at high spp (box filter, same max_depth), with Monte Carlo
standard errors from independent seeds.

    python bench/mitsuba_compare.py [--scene cornell_box] [--resolution 64] [--spp 1024] [--seeds 8]
                                    [--mitsuba-spp 4096] [--max-depth 8 2 1]
                                    [--aperture-radius R --focus-distance F]
                                    [--look-at X Y Z] [--fov DEG]
    python bench/mitsuba_compare.py --acceptance [--closeups] [--spp 1024 --seeds 8]

``--scene`` is any built-in scene (``cornell_box``, ``cornell_specular``, ``furnace``) or a scene
file; Mitsuba renders it through ``mitsuba_ref.scene_dict`` (the generic converter). For the Cornell
box, Mitsuba's own ``cornell_box()`` is rendered too (the original 1% check, and a check of the
converter). ``--aperture-radius``/``--focus-distance`` turn the camera into a thin lens,
``--look-at``/``--fov`` aim it elsewhere.

Each renderer renders the scene ``--seeds`` times (seeds 0, 1, ...; Mitsuba's independent of
invrender's), invrender at ``--spp`` and Mitsuba at ``--mitsuba-spp`` (default 4 x spp: Mitsuba is
~5x faster here, and its image means are noisier per sample, since its ``independent`` sampler does
not stratify pixel positions as invrender does); the tables print the mean over seeds of each
channel mean, its standard error (standard deviation of the per-seed means / sqrt(seeds)), and the
relative difference invrender / Mitsuba - 1 with its standard error (both renderers' errors
combined, to first order). Use 8 seeds or more: the standard error is itself estimated from them.

``--acceptance`` runs the acceptance set: the Cornell box (max_depth 8, 2, 1; within 1%),
``cornell_specular`` (max_depth 8; within 1.5%) and the thin-lens Cornell box (aperture radius
0.1, focus distance 2.0, in front of the boxes; max_depth 8; within 1%). ``--closeups`` adds
close-ups of cornell_specular's glass sphere, mirror sphere and glossy block (``CLOSEUPS``), where
each material's own transport weighs more than in the wall-dominated whole image. Needs Mitsuba 3
(see bench/README.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from _measure import Results, add_json_option  # noqa: E402

import invrender as ir  # noqa: E402

#: the thin-lens case of --acceptance: the Cornell box through a lens of radius 0.1 focused at 2.0,
#: in front of everything (the nearest wall edges are 2.9 away): a point at distance d blurs over
#: an angle of 2 r (1/f - 1/d), 0.043 rad on the short box (d 3.5) and 0.059 on the back wall
#: (d 4.9), 4-6 pixels at 64x64 (a pixel is 0.0107 rad)
THIN_LENS = {"aperture_radius": 0.1, "focus_distance": 2.0}
#: close-ups of cornell_specular's three objects from the Cornell-box eye (0, 0, 3.9): target and
#: fov (degrees) so that the object fills most of the image (``--closeups``): the whole-image means
#: are dominated by the diffuse walls, these weigh each material's own light transport
CLOSEUPS = {
    "glass": ((0.1, -0.72, 0.45), 11.0),  # the glass sphere (ior 1.5) and its caustic on the floor
    "mirror": ((0.45, -0.7, -0.3), 9.5),  # the mirror sphere (the glass sphere in the lower left)
    "glossy": ((-0.33, -0.4, -0.28), 12.0),  # the glossy block's front faces
}
#: acceptance thresholds on the largest channel |relative difference|, percent
TOLERANCE = {"cornell_box": 1.0, "cornell_specular": 1.5, "thin_lens": 1.0}


@dataclasses.dataclass
class Means:
    """Per-seed channel means of one renderer: ``runs[k] = [R, G, B]`` of seed k."""

    runs: list[list[float]]
    seconds: float

    @property
    def mean(self) -> list[float]:
        return [statistics.fmean(r[c] for r in self.runs) for c in range(3)]

    @property
    def se(self) -> list[float]:
        k = len(self.runs)
        if k < 2:
            return [math.nan] * 3
        return [statistics.stdev(r[c] for r in self.runs) / math.sqrt(k) for c in range(3)]


def invrender_means(scene, spp: int, depth: int, seeds) -> Means:
    start = time.perf_counter()
    runs = [ir.render(scene, spp=spp, max_depth=depth, seed=s, progress=False).double().mean(dim=(0, 1)).tolist() for s in seeds]
    return Means(runs, time.perf_counter() - start)


def mitsuba_means(mi_scene, spp: int, seeds) -> Means:
    start = time.perf_counter()
    runs = [mitsuba_ref.render(mi_scene, spp, seed=s).mean(axis=(0, 1), dtype="float64").tolist() for s in seeds]
    return Means(runs, time.perf_counter() - start)


def relative(a: Means, b: Means) -> tuple[list[float], list[float]]:
    """Percent ``a / b - 1`` per channel and its standard error (first order, independent errors)."""
    rel, se = [], []
    for ma, sa, mb, sb in zip(a.mean, a.se, b.mean, b.se):
        r = ma / mb
        rel.append(100 * (r - 1))
        se.append(100 * math.sqrt((sa / mb) ** 2 + (r * sb / mb) ** 2))
    return rel, se


def _cells(means: Means) -> str:
    return "  ".join(f"{v:.5f} ± {e:.5f}" for v, e in zip(means.mean, means.se))


def _rel_cells(rel, se) -> str:
    return "  ".join(f"{r:+6.3f} ± {e:.3f}" for r, e in zip(rel, se))


def compare(scene, label: str, spp: int, mi_spp: int, seeds: int, depths, tolerance: float, own_cornell: bool = False, record: Results | None = None) -> float:
    """Print the table for one scene; returns the largest channel |relative difference| (percent)
    of invrender vs Mitsuba (converted scene) over ``depths``."""
    w, h = scene.width, scene.height
    print(f"\n{label}: {w}x{h}, box filter, {seeds} seeds; invrender {spp} spp per seed ({seeds * spp} in all), "
          f"{mitsuba_ref.label()} path {mi_spp} spp per seed ({seeds * mi_spp} in all)")  # fmt: skip
    cam = scene.camera
    if cam.aperture_radius > 0:
        print(f"  thin lens: aperture_radius {cam.aperture_radius:g}, focus_distance {cam.focus_distance:g}")
    header = f"  {'depth':>5}  {'renderer':<22} {'R mean ± s.e.':^19}  {'G mean ± s.e.':^19}  {'B mean ± s.e.':^19}"
    print(f"{header}  {'invrender / this - 1 (%) ± s.e.: R, G, B':<46}  {'time':>5}")
    worst = 0.0
    rows = [] if record is None else record.table(
        f"{label}: {w}x{h}, box filter, {seeds} seeds; invrender {spp} spp per seed, {mitsuba_ref.label()} path {mi_spp} spp per seed",
        ["max_depth", "renderer", "R mean ± s.e.", "G mean ± s.e.", "B mean ± s.e.", "invrender / this - 1 (%) ± s.e.: R, G, B", "seconds"])  # fmt: skip
    for depth in depths:
        ours = invrender_means(scene, spp, depth, range(seeds))
        refs = [("Mitsuba (converted)", mitsuba_means(mitsuba_ref.load_scene(scene, mi_spp, depth), mi_spp, range(seeds)))]
        if own_cornell:  # other seeds than the converted scene's: independent errors
            own = mitsuba_ref.cornell_scene(w, h, mi_spp, depth)
            refs.append(("Mitsuba cornell_box()", mitsuba_means(own, mi_spp, range(seeds, 2 * seeds))))
        print(f"  {depth:>5}  {'invrender':<22} {_cells(ours)}  {'':<46}  {ours.seconds:4.0f}s")
        cells = lambda m: [f"{v:.5f} ± {e:.5f}" for v, e in zip(m.mean, m.se)]  # noqa: E731
        rows.append([depth, "invrender", *cells(ours), "", round(ours.seconds)])
        for i, (name, ref) in enumerate(refs):
            rel, se = relative(ours, ref)
            if i == 0:
                worst = max(worst, *map(abs, rel))
            print(f"  {'':>5}  {name:<22} {_cells(ref)}  {_rel_cells(rel, se):<46}  {ref.seconds:4.0f}s")
            rows.append([depth, name, *cells(ref), " ".join(_rel_cells(rel, se).split()), round(ref.seconds)])
        if own_cornell:
            rel, se = relative(refs[0][1], refs[1][1])
            print(f"  {'':>5}  {'(converted / own - 1)':<22} {'':<61}  {_rel_cells(rel, se):<46}")
            rows.append([depth, "(converted / own - 1)", "", "", "", " ".join(_rel_cells(rel, se).split()), ""])
    verdict = "within" if worst < tolerance else "NOT within"
    print(f"  largest channel |difference| vs Mitsuba (converted): {worst:.3f}% ({verdict} {tolerance:g}%)")
    return worst


def thin_lens(scene, aperture_radius: float, focus_distance: float):
    return scene.with_camera(dataclasses.replace(scene.camera, aperture_radius=aperture_radius, focus_distance=focus_distance))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="cornell_box", help="built-in scene name or scene file (default cornell_box)")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--spp", type=int, default=1024, help="invrender's samples per pixel of each render")
    parser.add_argument("--mitsuba-spp", type=int, default=None, help="Mitsuba's samples per pixel of each render (default 4 x spp)")
    parser.add_argument("--seeds", type=int, default=8, help="independent renders per renderer (for standard errors)")
    parser.add_argument("--max-depth", type=int, nargs="+", default=None, help="default: 8 2 1 (8 for --acceptance's other scenes)")
    parser.add_argument("--aperture-radius", type=float, default=None, help="turn the camera into a thin lens of this radius")
    parser.add_argument("--focus-distance", type=float, default=None, help="the thin lens's focus distance (default: the camera's)")
    parser.add_argument("--look-at", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"), help="aim the camera at this point")
    parser.add_argument("--fov", type=float, default=None, help="the camera's field of view, degrees")
    parser.add_argument("--tolerance", type=float, default=None, help="percent (default 1, 1.5 for cornell_specular)")
    parser.add_argument("--closeups", action="store_true", help="cornell_specular's glass sphere, mirror sphere, glossy block")
    parser.add_argument("--acceptance", action="store_true", help="the Cornell box, cornell_specular and the thin-lens box")
    add_json_option(parser)
    args = parser.parse_args()
    record = Results("mitsuba_compare", "Channel means against Mitsuba 3")
    if not mitsuba_ref.available():
        print("Mitsuba 3 is not installed (see bench/README.md); nothing to compare.")
        return 0
    mi_spp = args.mitsuba_spp or 4 * args.spp
    if args.seeds < 4:
        print(f"note: standard errors from {args.seeds} seed(s) are unreliable (use --seeds 8 or more)")
    if args.seeds < 1 or args.spp < 1 or mi_spp < 1:
        parser.error("--seeds, --spp and --mitsuba-spp must be positive")
    n = args.resolution
    box = ir.load_scene("cornell_box", resolution=(n, n))
    specular = ir.load_scene("cornell_specular", resolution=(n, n)) if args.acceptance or args.closeups else None
    cases = []  # (summary name, scene, label, depths, tolerance %, also Mitsuba's own cornell_box())
    if args.acceptance:
        thin = thin_lens(box, **THIN_LENS)
        cases += [
            ("cornell_box", box, "cornell_box", args.max_depth or [8, 2, 1], TOLERANCE["cornell_box"], True),
            ("cornell_specular", specular, "cornell_specular", args.max_depth or [8], TOLERANCE["cornell_specular"], False),
            ("thin_lens", thin, "cornell_box, thin lens", args.max_depth or [8], TOLERANCE["thin_lens"], False),
        ]
    if args.closeups:
        for name, (target, fov) in CLOSEUPS.items():
            view = specular.with_camera(dataclasses.replace(specular.camera, target=target, fov=fov))
            label = f"cornell_specular, close-up of the {name} object (target {target}, fov {fov:g})"
            cases.append((f"{name} close-up", view, label, args.max_depth or [8], args.tolerance or TOLERANCE["cornell_specular"], False))
    if not cases:
        scene = ir.load_scene(args.scene, resolution=(n, n))
        label = scene.name
        cam = scene.camera
        if args.look_at is not None or args.fov is not None:
            scene = scene.with_camera(dataclasses.replace(cam, target=tuple(args.look_at or cam.target), fov=args.fov or cam.fov))
            label += f", camera aimed at {scene.camera.target}, fov {scene.camera.fov:g}"
        if args.aperture_radius is not None or args.focus_distance is not None:
            radius = cam.aperture_radius if args.aperture_radius is None else args.aperture_radius
            scene = thin_lens(scene, radius, args.focus_distance or cam.focus_distance)
            label += ", thin lens"
        tolerance = args.tolerance if args.tolerance is not None else TOLERANCE.get(scene.name, 1.0)
        own = args.scene == "cornell_box" and scene.camera == box.camera
        cases.append((label, scene, label, args.max_depth or [8, 2, 1], tolerance, own))

    results = []
    for name, scene, label, depths, tol, own in cases:
        results.append((name, compare(scene, label, args.spp, mi_spp, args.seeds, depths, tol, own, record), tol))
    if len(results) > 1:
        print("\nsummary (largest channel |relative difference| vs Mitsuba):")
    summary = record.table("summary: largest channel |relative difference| against Mitsuba (converted scene)", ["case", "largest difference", "tolerance"])
    for name, worst, tol in results:
        if len(results) > 1:
            print(f"  {name:<17} {worst:6.3f}%  ({'within' if worst < tol else 'NOT within'} {tol:g}%)")
        summary.append([name, f"{worst:.3f}%", f"{'within' if worst < tol else 'NOT within'} {tol:g}%"])
    record.write(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
