"""invrender vs Mitsuba 3 on plastics: the Cornell box of forward/cornell_box.xml with its tall box a
``roughplastic`` of Mitsuba's defaults (Beckmann, alpha 0.1) in orange, its short box a smooth
``plastic`` in blue (``int_ior`` 1.6, ``nonlinear``) and its floor a GGX ``roughplastic``
(alpha 0.3, ``specular_reflectance`` 0.8), one XML file read by both renderers (invrender's XML
subset, ``mi.load_file``), and the same scene as invrender loaded it, converted back for Mitsuba by
bench's converter (each type's ``to_mitsuba``): channel means with Monte Carlo standard errors over
seeds (box filter, max_depth 8), target within 1.5%.

    python bench/plastic_compare.py [--resolution 64] [--spp 256] [--mitsuba-spp 1024] [--seeds 4]
                                    [--write PATH] [--json PATH]

``--write`` also saves the scene file. Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from _measure import Results, add_json_option  # noqa: E402
from conductor_compare import mitsuba_file_means  # noqa: E402
from mitsuba_compare import Means, _cells, _rel_cells, invrender_means, relative  # noqa: E402

import invrender as ir  # noqa: E402

BOX = Path(__file__).parents[1] / "forward" / "cornell_box.xml"
TOLERANCE = 1.5  # percent, largest channel |difference|

ROUGH = """<bsdf type="roughplastic">
            <rgb name="diffuse_reflectance" value="0.8, 0.35, 0.1"/>
        </bsdf>"""
SMOOTH = """<bsdf type="twosided"><bsdf type="plastic">
            <rgb name="diffuse_reflectance" value="0.1, 0.25, 0.7"/>
            <float name="int_ior" value="1.6"/>
            <boolean name="nonlinear" value="true"/>
        </bsdf></bsdf>"""
FLOOR = """<bsdf type="twosided"><bsdf type="roughplastic">
            <string name="distribution" value="ggx"/>
            <float name="alpha" value="0.3"/>
            <rgb name="diffuse_reflectance" value="0.6, 0.6, 0.5"/>
            <rgb name="specular_reflectance" value="0.8, 0.8, 0.8"/>
        </bsdf></bsdf>"""


def scene_xml() -> str:
    """forward/cornell_box.xml with the tall box, the short box and the floor plastics."""
    text = BOX.read_text()
    for shape, bsdf in (("large_box", ROUGH), ("small_box", SMOOTH), ("floor", FLOOR)):
        head = f'<shape type="{"rectangle" if shape == "floor" else "cube"}" id="{shape}">'
        start = text.index(head)
        ref = text.index('<ref id="white"/>', start)
        text = text[:ref] + bsdf + text[ref + len('<ref id="white"/>') :]
    return text


def mitsuba_dict_means(scene, resolution: int, spp: int, seeds) -> Means:
    """Mitsuba's means on the scene invrender loaded, converted by ``mitsuba_ref.scene_dict``."""
    mi, _ = mitsuba_ref._require()
    mi_scene = mi.load_dict(mitsuba_ref.scene_dict(scene, spp=spp, max_depth=8))
    start = time.perf_counter()
    runs = [mitsuba_ref.render(mi_scene, spp, seed=s).mean(axis=(0, 1), dtype="float64").tolist() for s in seeds]
    return Means(runs, time.perf_counter() - start)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--spp", type=int, default=256, help="invrender's samples per pixel of each render")
    parser.add_argument("--mitsuba-spp", type=int, default=None, help="Mitsuba's (default 4 x spp)")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--write", type=Path, default=None, help="also save the scene file here")
    add_json_option(parser)
    args = parser.parse_args()
    if not mitsuba_ref.available():
        print("Mitsuba 3 is not available (bench/README.md)", file=sys.stderr)
        return 2
    record = Results("plastic_compare", "Plastics (plastic, roughplastic Beckmann and GGX) vs Mitsuba 3")  # made first: it times the run
    mi_spp = args.mitsuba_spp or 4 * args.spp
    text = scene_xml()
    if args.write:
        args.write.write_text(text)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cornell_plastics.xml"
        path.write_text(text)
        scene = ir.load_scene(path, resolution=(args.resolution, args.resolution))
        ours = invrender_means(scene, args.spp, 8, range(args.seeds))
        ref = mitsuba_file_means(path, args.resolution, mi_spp, range(args.seeds))
        converted = mitsuba_dict_means(scene, args.resolution, mi_spp, range(100, 100 + args.seeds))
    title = (f"Cornell box, Beckmann roughplastic (alpha 0.1), smooth plastic (ior 1.6, nonlinear), GGX roughplastic floor (alpha 0.3): "
             f"{args.resolution}^2, box filter, max_depth 8, {args.seeds} seeds; invrender {args.spp} spp, {mitsuba_ref.label()} path {mi_spp} spp")  # fmt: skip
    print(title)
    table = record.table(title, ["renderer", "R mean ± s.e.", "G mean ± s.e.", "B mean ± s.e.", "seconds"])
    cells = lambda m: [f"{v:.5f} ± {e:.5f}" for v, e in zip(m.mean, m.se)]  # noqa: E731
    print(f"  invrender              {_cells(ours)}  {ours.seconds:4.0f}s")
    table.append(["invrender", *cells(ours), round(ours.seconds)])
    worst = 0.0
    for label, m in (("Mitsuba (same XML)", ref), ("Mitsuba (to_mitsuba)", converted)):
        rel, se = relative(ours, m)
        worst = max(worst, *map(abs, rel))
        print(f"  {label:22s} {_cells(m)}  {m.seconds:4.0f}s")
        print(f"    invrender / it - 1 (%): {_rel_cells(rel, se)}")
        table.append([label, *cells(m), round(m.seconds)])
        table.append([f"invrender / {label} - 1 (%)", *(f"{r:+.3f} ± {e:.3f}" for r, e in zip(rel, se)), ""])
    print(f"  largest {worst:.3f}% ({'within' if worst < TOLERANCE else 'NOT within'} {TOLERANCE:g}%)")
    record.write(args.json)
    return 0 if worst < TOLERANCE else 1


if __name__ == "__main__":
    sys.exit(main())
