"""invrender's reconstruction filters side by side with Mitsuba 3's, pixel for pixel.

For each of Mitsuba's six filters (box, tent, gaussian, mitchell, catmullrom, lanczos, at their
default settings), two scenes at 64 x 64 are rendered by invrender and by Mitsuba 3 (llvm_ad_rgb,
the scene converted by bench/mitsuba_ref.py with the same ``rfilter``): the Cornell box
(forward/cornell_box.toml) and the same box whose white surfaces carry a sharp checkerboard
(baked 512 x 512, scale 6: edges inside every pixel's footprint); and, with the gaussian and
mitchell filters, forward/cornell_box.xml on a film twice the size cropped to its centre window
with ``sample_border`` on, the same file loaded by both. Each side renders ``--seeds``
independent images; their per-pixel means and standard errors give

- channel-mean differences (invrender / Mitsuba - 1, %), acceptance 0.5%;
- the pooled relative RMSE ``||pool(a) - pool(b)|| / ||pool(b)||`` over 4 x 4 blocks, acceptance 1%,
  beside its Monte Carlo floor (the same norm of the two means' standard errors);
- per-pixel z = (a - b) / sqrt(se_a^2 + se_b^2) on edge pixels (the 15% of pixels with the largest
  gradient of Mitsuba's mean image): the share within 3 and the largest |z|. A filter applied
  differently (box for gaussian, a wrong radius, no normalization) shows there first; with
  hundreds of edge pixels a few beyond 3 are chance: each z is Student-t distributed with about
  2 (seeds - 1) degrees of freedom (the standard errors are estimated from the seeds), so about 1%
  of them lie beyond 3 with 8 seeds (0.27% for known standard errors).

Run from the repository root: ``python bench/filter_compare.py [--spp 64 --seeds 8 --json PATH]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

import mitsuba_ref  # noqa: E402
from _measure import Results, add_json_option  # noqa: E402

import invrender as ir  # noqa: E402
from invrender.plugins.filters import make_filter  # noqa: E402
from invrender.scene.film import FilmOptions  # noqa: E402

FILTERS = ("box", "tent", "gaussian", "mitchell", "catmullrom", "lanczos")
BOX = Path(__file__).parents[1] / "forward" / "cornell_box.toml"
CHECKER = '{ checkerboard = { color0 = [0.85, 0.85, 0.85], color1 = 0.08, scale = 6, resolution = 512 } }'
MAX_DEPTH = 8
MEAN_TOLERANCE, RMSE_TOLERANCE, Z_LIMIT = 0.5, 1.0, 3.0


def scenes(resolution: int, tmp: Path) -> dict:
    """{name: invrender Scene} of the two scenes at ``resolution``^2 (box filter: each filter is set per render)."""
    text = BOX.read_text()
    white = text[text.index("[materials.white]") :].split("\n")[1]
    checker = tmp / "cornell_checker.toml"
    checker.write_text(text.replace(white, f"reflectance = {CHECKER}", 1))
    return {"cornell": ir.load_scene(BOX, resolution=(resolution, resolution)), "checkerboard": ir.load_scene(checker, resolution=(resolution, resolution))}


XML = Path(__file__).parents[1] / "forward" / "cornell_box.xml"


def cropped_xml(tmp: Path, resolution: int, rfilter: str) -> Path:
    """forward/cornell_box.xml on a ``2 resolution``^2 film cropped to its centre ``resolution``^2
    window, ``sample_border`` on and the ``rfilter`` given: one file both renderers load."""
    text = XML.read_text()
    start, end = text.index("<film"), text.index("</film>") + len("</film>")
    film = (f'<film type="hdrfilm"><integer name="width" value="{2 * resolution}"/><integer name="height" value="{2 * resolution}"/>'
            f'<integer name="crop_offset_x" value="{resolution // 2}"/><integer name="crop_offset_y" value="{resolution // 2}"/>'
            f'<integer name="crop_width" value="{resolution}"/><integer name="crop_height" value="{resolution}"/>'
            f'<boolean name="sample_border" value="true"/><rfilter type="{rfilter}"/></film>')
    path = tmp / f"cornell_crop_{rfilter}.xml"
    path.write_text(text[:start] + film + text[end:])
    return path


def stats(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(per-pixel mean, its standard error, the standard error of the channel means) of
    independent renders (H, W, 3)."""
    stack = np.stack(images).astype(np.float64)
    return stack.mean(0), stack.std(0, ddof=1) / np.sqrt(len(images)), stack.mean(axis=(1, 2)).std(0, ddof=1) / np.sqrt(len(images))


def pooled(x: np.ndarray, k: int = 4) -> np.ndarray:
    h, w, c = x.shape
    return x.reshape(h // k, k, w // k, k, c).mean(axis=(1, 3))


def compare(a, sa, ma, b, sb, mb) -> dict:
    """The figures of invrender's (mean a, s.e. sa, s.e. of the channel means ma) against
    Mitsuba's (b, sb, mb)."""
    means = 100 * (a.mean(axis=(0, 1)) / b.mean(axis=(0, 1)) - 1)
    means_se = 100 * np.hypot(ma / a.mean(axis=(0, 1)), mb / b.mean(axis=(0, 1)))
    pa, pb = pooled(a), pooled(b)
    rmse = 100 * np.linalg.norm(pa - pb) / np.linalg.norm(pb)
    # the floor: the pooled means' noise (a block of 16 pixels: its s.e. is at most the pixels' mean s.e. / 4 for independent pixels, correlated by the filter)
    floor = 100 * np.sqrt((pooled(sa**2) / 16 + pooled(sb**2) / 16).sum()) / np.linalg.norm(pb)
    lum = b.mean(axis=2)
    grad = np.hypot(*np.gradient(lum))
    edges = grad >= np.quantile(grad, 0.85)
    z = (a - b) / np.sqrt(sa**2 + sb**2 + 1e-20)
    ze = np.abs(z[edges])
    return {"means": means, "means_se": means_se, "rmse": rmse, "floor": floor, "within": 100 * (ze <= Z_LIMIT).mean(), "zmax": ze.max(), "edges": int(edges.sum()), "zall": 100 * (np.abs(z) <= Z_LIMIT).mean()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--spp", type=int, default=64, help="samples per pixel of each render (both sides)")
    p.add_argument("--seeds", type=int, default=8, help="independent renders per side")
    p.add_argument("--filters", default=",".join(FILTERS))
    add_json_option(p)
    args = p.parse_args()
    if not mitsuba_ref.available():
        print("Mitsuba 3 is not available (bench/README.md)", file=sys.stderr)
        return 2
    import tempfile

    record = Results("filter_compare", f"Reconstruction filters: invrender vs {mitsuba_ref.label()}, {args.resolution}x{args.resolution}, {args.spp} spp x {args.seeds} seeds each, path max_depth {MAX_DEPTH}")
    table = record.table(
        "filters side by side",
        ["scene", "filter", "channel means (R, G, B) % ± s.e.", "pooled RMSE %", "MC floor %", "edge pixels within 3 s.e.", "max |z| on edges", "all pixels within 3 s.e.", "invrender s", "Mitsuba s"],
        note=f"acceptance: channel means within {MEAN_TOLERANCE}%, pooled relative RMSE (4x4 blocks) within {RMSE_TOLERANCE}%; z = (a - b) / sqrt(se_a^2 + se_b^2) per pixel and channel, edge pixels = the 15% largest gradients of Mitsuba's mean",
    )
    print(record.title)
    print(f"{'scene':13s} {'filter':10s} {'channel means % ± s.e.':>36s} {'RMSE %':>7s} {'floor %':>7s} {'edges<=3':>9s} {'max|z|':>7s} {'all<=3':>7s} {'ir s':>6s} {'mi s':>6s}")
    failed = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene_name, scene in scenes(args.resolution, Path(tmp)).items():
            for name in args.filters.split(","):
                filtered = dataclasses.replace(scene, film=FilmOptions(make_filter(name)))
                start = time.perf_counter()
                ours = [ir.render(filtered, spp=args.spp, max_depth=MAX_DEPTH, seed=s, progress=False).numpy() for s in range(args.seeds)]
                ours_s = (time.perf_counter() - start) / args.seeds
                mi_scene = mitsuba_ref.load_scene(scene, args.spp, MAX_DEPTH, filter=name)
                start = time.perf_counter()
                theirs = [mitsuba_ref.render(mi_scene, args.spp, seed=1000 + s) for s in range(args.seeds)]
                theirs_s = (time.perf_counter() - start) / args.seeds
                r = compare(*stats(ours), *stats(theirs))
                cells = ", ".join(f"{x:+.2f}±{e:.2f}" for x, e in zip(r["means"], r["means_se"]))
                print(f"{scene_name:13s} {name:10s} {cells:>36s} {r['rmse']:7.2f} {r['floor']:7.2f} {r['within']:8.1f}% {r['zmax']:7.2f} {r['zall']:6.1f}% {ours_s:6.2f} {theirs_s:6.2f}", flush=True)
                table.append([scene_name, name, cells, round(r["rmse"], 2), round(r["floor"], 2), f"{r['within']:.1f}% of {r['edges']}", round(float(r["zmax"]), 2), f"{r['zall']:.1f}%", round(ours_s, 2), round(theirs_s, 2)])
                if np.abs(r["means"]).max() > MEAN_TOLERANCE or r["rmse"] > RMSE_TOLERANCE:
                    failed.append(f"{scene_name}/{name}")
        # a file's crop window (the centre of a film twice the size) with sample_border, loaded by both
        for name in ("gaussian", "mitchell"):
            path = cropped_xml(Path(tmp), args.resolution, name)
            scene = ir.load_scene(path)
            start = time.perf_counter()
            ours = [ir.render(scene, spp=args.spp, max_depth=MAX_DEPTH, seed=s, progress=False).numpy() for s in range(args.seeds)]
            ours_s = (time.perf_counter() - start) / args.seeds
            mi, _ = mitsuba_ref._require()
            mi_scene = mi.load_file(str(path), spp=str(args.spp))
            start = time.perf_counter()
            theirs = [mitsuba_ref.render(mi_scene, args.spp, seed=1000 + s) for s in range(args.seeds)]
            theirs_s = (time.perf_counter() - start) / args.seeds
            r = compare(*stats(ours), *stats(theirs))
            cells = ", ".join(f"{x:+.2f}±{e:.2f}" for x, e in zip(r["means"], r["means_se"]))
            label = "crop+border"
            print(f"{label:13s} {name:10s} {cells:>36s} {r['rmse']:7.2f} {r['floor']:7.2f} {r['within']:8.1f}% {r['zmax']:7.2f} {r['zall']:6.1f}% {ours_s:6.2f} {theirs_s:6.2f}", flush=True)
            table.append([f"cornell_box.xml, crop {args.resolution}^2 of {2 * args.resolution}^2, sample_border", name, cells, round(r["rmse"], 2), round(r["floor"], 2), f"{r['within']:.1f}% of {r['edges']}", round(float(r["zmax"]), 2), f"{r['zall']:.1f}%", round(ours_s, 2), round(theirs_s, 2)])
            if np.abs(r["means"]).max() > MEAN_TOLERANCE or r["rmse"] > RMSE_TOLERANCE:
                failed.append(f"crop/{name}")
    verdict = "all within the acceptance" if not failed else f"outside the acceptance: {', '.join(failed)}"
    print(verdict)
    record.note(verdict)
    record.write(args.json)
    return 0 if not failed else 1


if __name__ == "__main__":
    sys.exit(main())
