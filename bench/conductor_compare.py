"""invrender vs Mitsuba 3 on conductors as scene files write them: the Cornell box of
forward/cornell_box.xml with its tall box a ``roughconductor`` of Mitsuba's defaults (Beckmann,
``sample_visible``) in gold (``material = "Au"``, alpha 0.2), its short box a smooth ``conductor``
in copper (``material = "Cu"``) and its floor a ``checkerboard`` (``to_uv`` scale 4), one XML file
read by both renderers (invrender's XML subset, ``mi.load_file``): channel means with Monte Carlo
standard errors over seeds (box filter, max_depth 8), target within 1.5%.

    python bench/conductor_compare.py [--resolution 64] [--spp 1024] [--mitsuba-spp 4096] [--seeds 8]
                                      [--write PATH] [--json PATH]

``--write`` also saves the scene file. Needs Mitsuba 3 (bench/README.md).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from _measure import Results, add_json_option  # noqa: E402
from mitsuba_compare import Means, _cells, _rel_cells, invrender_means, relative  # noqa: E402

import invrender as ir  # noqa: E402

BOX = Path(__file__).parents[1] / "forward" / "cornell_box.xml"
TOLERANCE = 1.5  # percent, largest channel |difference|

GOLD = """<bsdf type="roughconductor">
            <string name="material" value="Au"/>
            <float name="alpha" value="0.2"/>
        </bsdf>"""
COPPER = """<bsdf type="conductor">
            <string name="material" value="Cu"/>
        </bsdf>"""
CHECKER = """<bsdf type="twosided"><bsdf type="diffuse">
            <texture type="checkerboard" name="reflectance">
                <rgb name="color0" value="0.8, 0.8, 0.8"/>
                <rgb name="color1" value="0.2, 0.3, 0.6"/>
                <transform name="to_uv"><scale x="4" y="4"/></transform>
            </texture>
        </bsdf></bsdf>"""


def scene_xml() -> str:
    """forward/cornell_box.xml with the tall box gold (Beckmann), the short box copper, the floor a checkerboard."""
    text = BOX.read_text()
    for shape, bsdf in (("large_box", GOLD), ("small_box", COPPER), ("floor", CHECKER)):
        head = f'<shape type="{"rectangle" if shape == "floor" else "cube"}" id="{shape}">'
        start = text.index(head)
        ref = text.index('<ref id="white"/>', start)
        text = text[:ref] + bsdf + text[ref + len('<ref id="white"/>'):]
    return text


def mitsuba_file_means(path: Path, resolution: int, spp: int, seeds) -> Means:
    import time

    mi, _ = mitsuba_ref._require()
    scene = mi.load_file(str(path), spp=str(spp), res=str(resolution))
    start = time.perf_counter()
    runs = [mitsuba_ref.render(scene, spp, seed=s).mean(axis=(0, 1), dtype="float64").tolist() for s in seeds]
    return Means(runs, time.perf_counter() - start)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--spp", type=int, default=1024, help="invrender's samples per pixel of each render")
    parser.add_argument("--mitsuba-spp", type=int, default=None, help="Mitsuba's (default 4 x spp)")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--write", type=Path, default=None, help="also save the scene file here")
    add_json_option(parser)
    args = parser.parse_args()
    if not mitsuba_ref.available():
        print("Mitsuba 3 is not available (bench/README.md)", file=sys.stderr)
        return 2
    record = Results("conductor_compare", "Conductors (named metals, Beckmann) and checkerboards vs Mitsuba 3")  # made first: it times the run
    mi_spp = args.mitsuba_spp or 4 * args.spp
    text = scene_xml()
    if args.write:
        args.write.write_text(text)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cornell_metals.xml"
        path.write_text(text)
        scene = ir.load_scene(path, resolution=(args.resolution, args.resolution))
        ours = invrender_means(scene, args.spp, 8, range(args.seeds))
        ref = mitsuba_file_means(path, args.resolution, mi_spp, range(args.seeds))
    rel, se = relative(ours, ref)
    worst = max(map(abs, rel))
    title = (f"Cornell box, gold Beckmann roughconductor (alpha 0.2), copper conductor, checkerboard floor: {args.resolution}^2, "
             f"box filter, max_depth 8, {args.seeds} seeds; invrender {args.spp} spp, {mitsuba_ref.label()} path {mi_spp} spp (same XML file)")  # fmt: skip
    print(title)
    print(f"  invrender  {_cells(ours)}  {ours.seconds:4.0f}s")
    print(f"  Mitsuba    {_cells(ref)}  {ref.seconds:4.0f}s")
    print(f"  invrender / Mitsuba - 1 (%): {_rel_cells(rel, se)}; largest {worst:.3f}% ({'within' if worst < TOLERANCE else 'NOT within'} {TOLERANCE:g}%)")
    table = record.table(title, ["renderer", "R mean ± s.e.", "G mean ± s.e.", "B mean ± s.e.", "seconds"])
    cells = lambda m: [f"{v:.5f} ± {e:.5f}" for v, e in zip(m.mean, m.se)]  # noqa: E731
    table.append(["invrender", *cells(ours), round(ours.seconds)])
    table.append(["Mitsuba", *cells(ref), round(ref.seconds)])
    table.append(["invrender / Mitsuba - 1 (%)", *(f"{r:+.3f} ± {e:.3f}" for r, e in zip(rel, se)), ""])
    record.write(args.json)
    return 0 if worst < TOLERANCE else 1


if __name__ == "__main__":
    sys.exit(main())
