"""Shared by the XML comparisons (conductor_compare.py, plastic_compare.py): the Cornell box of
forward/cornell_box.xml with some shapes' BSDFs replaced, one XML file read by both renderers
(invrender's XML subset, ``mi.load_file``) and, optionally, the scene as invrender loaded it
converted back for Mitsuba by bench's converter (each type's ``to_mitsuba``): channel means with
Monte Carlo standard errors over seeds (box filter, max_depth 8), target within 1.5%.
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
from mitsuba_compare import Means, _cells, _rel_cells, invrender_means, relative  # noqa: E402

import invrender as ir  # noqa: E402

BOX = Path(__file__).parents[1] / "forward" / "cornell_box.xml"
TOLERANCE = 1.5  # percent, largest channel |difference|


def box_with(bsdfs: dict[str, str]) -> str:
    """forward/cornell_box.xml with the BSDF of each shape id in ``bsdfs`` (``large_box``,
    ``small_box``, ``floor``) replaced by the given XML."""
    text = BOX.read_text()
    for shape, bsdf in bsdfs.items():
        head = f'<shape type="{"rectangle" if shape == "floor" else "cube"}" id="{shape}">'
        start = text.index(head)
        ref = text.index('<ref id="white"/>', start)
        text = text[:ref] + bsdf + text[ref + len('<ref id="white"/>') :]
    return text


def parser(doc: str, spp: int, seeds: int) -> argparse.ArgumentParser:
    """The comparisons' command line, with their defaults for invrender's spp and the seeds."""
    p = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--spp", type=int, default=spp, help="invrender's samples per pixel of each render")
    p.add_argument("--mitsuba-spp", type=int, default=None, help="Mitsuba's (default 4 x spp)")
    p.add_argument("--seeds", type=int, default=seeds)
    p.add_argument("--write", type=Path, default=None, help="also save the scene file here")
    add_json_option(p)
    return p


def mitsuba_file_means(path: Path, resolution: int, spp: int, seeds) -> Means:
    """Mitsuba's means on the scene file ``path``."""
    mi, _ = mitsuba_ref._require()
    scene = mi.load_file(str(path), spp=str(spp), res=str(resolution))
    start = time.perf_counter()
    runs = [mitsuba_ref.render(scene, spp, seed=s).mean(axis=(0, 1), dtype="float64").tolist() for s in seeds]
    return Means(runs, time.perf_counter() - start)


def mitsuba_dict_means(scene, resolution: int, spp: int, seeds) -> Means:
    """Mitsuba's means on the scene invrender loaded, converted by ``mitsuba_ref.scene_dict``."""
    mi, _ = mitsuba_ref._require()
    mi_scene = mi.load_dict(mitsuba_ref.scene_dict(scene, spp=spp, max_depth=8))
    start = time.perf_counter()
    runs = [mitsuba_ref.render(mi_scene, spp, seed=s).mean(axis=(0, 1), dtype="float64").tolist() for s in seeds]
    return Means(runs, time.perf_counter() - start)


def compare(args, name: str, heading: str, scene: str, text: str, converted: bool = False) -> int:
    """Render ``text`` (the scene's XML) in both, print and record the channel means and their
    relative differences (``--json``), and return 0 when every one is within :data:`TOLERANCE`.
    ``scene`` describes the scene for the title; ``converted``: also Mitsuba on bench's converter."""
    if not mitsuba_ref.available():
        print("Mitsuba 3 is not available (bench/README.md)", file=sys.stderr)
        return 2
    record = Results(name, heading)  # made first: it times the run
    mi_spp = args.mitsuba_spp or 4 * args.spp
    if args.write:
        args.write.write_text(text)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{name}.xml"
        path.write_text(text)
        loaded = ir.load_scene(path, resolution=(args.resolution, args.resolution))
        ours = invrender_means(loaded, args.spp, 8, range(args.seeds))
        refs = [("Mitsuba (same XML)", mitsuba_file_means(path, args.resolution, mi_spp, range(args.seeds)))]
        if converted:
            refs.append(("Mitsuba (to_mitsuba)", mitsuba_dict_means(loaded, args.resolution, mi_spp, range(100, 100 + args.seeds))))
    title = (f"{scene}: {args.resolution}^2, box filter, max_depth 8, {args.seeds} seeds; "
             f"invrender {args.spp} spp, {mitsuba_ref.label()} path {mi_spp} spp")  # fmt: skip
    print(title)
    table = record.table(title, ["renderer", "R mean ± s.e.", "G mean ± s.e.", "B mean ± s.e.", "seconds"])
    cells = lambda m: [f"{v:.5f} ± {e:.5f}" for v, e in zip(m.mean, m.se)]  # noqa: E731
    print(f"  invrender              {_cells(ours)}  {ours.seconds:4.0f}s")
    table.append(["invrender", *cells(ours), round(ours.seconds)])
    worst = 0.0
    for label, m in refs:
        rel, se = relative(ours, m)
        worst = max(worst, *map(abs, rel))
        print(f"  {label:22s} {_cells(m)}  {m.seconds:4.0f}s")
        print(f"    invrender / it - 1 (%): {_rel_cells(rel, se)}")
        table.append([label, *cells(m), round(m.seconds)])
        table.append([f"invrender / {label} - 1 (%)", *(f"{r:+.3f} ± {e:.3f}" for r, e in zip(rel, se)), ""])
    print(f"  largest {worst:.3f}% ({'within' if worst < TOLERANCE else 'NOT within'} {TOLERANCE:g}%)")
    record.write(args.json)
    return 0 if worst < TOLERANCE else 1
