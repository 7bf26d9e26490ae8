"""Veach's MIS scene (four small emitting spheres over rough plastic plates): per-sample variance and
channel means of invrender against Mitsuba 3 at the same spp and resolution.

    python bench/veach_mis.py [--scene /tmp/md/docs/scenes/integrator_direct_both.xml]
                              [--resolution 96 64] [--spp 32] [--seeds 8] [--max-depth 8]

The scene is mitsuba-data's ``docs/scenes/integrator_direct_both.xml`` (it includes
``include/veach_mis.xml``). Both renderers read one copy of it, written to a temporary folder with a
box pixel filter (invrender's only filter: a wider one would average neighbouring samples and hide
variance), the requested film size and absolute search paths; a second copy swaps its ``direct``
integrator (one emitter and one BSDF sample, MIS) for ``path`` at ``--max-depth``. invrender reads
``direct`` as ``path`` at max_depth 2 (docs/rendering.md).

Per-sample variance: the per-pixel variance over ``--seeds`` renders of ``--spp`` samples, times
spp, averaged over pixels and channels (one number per renderer; Mitsuba renders 4x the seeds, its
figure being the reference); its standard error comes from the spread of that figure over four
groups of the seeds. The ratio invrender / Mitsuba is the figure of issue 22 (target at most 1.2),
over three sets of pixels: the light transport (every pixel but those where a camera ray may see
an emitter), the same without the ``--trim`` pixels of highest Mitsuba variance (the highlight of
the smallest sphere in the sharpest plate: one pixel there carries a third of the figure, and
its variance estimate is heavy-tailed), and every pixel (there invrender's stratified pixel
samples make the emitters' edges far quieter than Mitsuba's independent ones). Channel means are
over every render. Needs Mitsuba 3 (bench/README.md); prints what it measured.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import mitsuba_ref  # noqa: E402

import invrender as ir  # noqa: E402

SCENE = Path("/tmp/md/docs/scenes/integrator_direct_both.xml")
TARGET = 1.2  # invrender's per-sample variance at most this times Mitsuba's


def write_copies(scene: Path, folder: Path, width: int, height: int, max_depth: int) -> dict[str, Path]:
    """The scene and its include rewritten into ``folder``: box filter, ``width`` x ``height``,
    search paths made absolute; ``{"direct": file, "path": file}``."""
    text = scene.read_text()
    text = re.sub(r'<path value="([^"]+)"/>', lambda m: f'<path value="{(scene.parent / m.group(1)).resolve()}"/>', text)
    text = re.sub(r"(<scene [^>]*>)", rf'\1<path value="{scene.parent.resolve()}"/>', text, count=1)  # its meshes
    includes = re.findall(r'<include filename="([^"]+)"/>', text)
    for name in includes:
        inc = (scene.parent / name).read_text()
        inc = re.sub(r'<rfilter type="\w+"\s*/>', '<rfilter type="box"/>', inc)
        inc = re.sub(r'(<integer name="width" value=")\d+', rf"\g<1>{width}", inc)
        inc = re.sub(r'(<integer name="height" value=")\d+', rf"\g<1>{height}", inc)
        out = folder / name
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(inc)
    direct = folder / scene.name
    direct.write_text(text)
    path = folder / f"path_{scene.name}"
    path.write_text(re.sub(r"<integrator .*?</integrator>", f'<integrator type="path"><integer name="max_depth" value="{max_depth}"/></integrator>', text, flags=re.S))
    return {"direct": direct, "path": path}


def per_sample(images: np.ndarray, spp: int, keep: np.ndarray | None = None) -> tuple[float, float]:
    """(per-sample variance, its standard error) of ``images`` (S, H, W, 3) of ``spp`` samples each:
    the mean over pixels (those where ``keep`` (H, W) is True) and channels of the per-pixel
    variance over seeds, times spp; the error from the spread of the figure over four groups of
    the seeds."""
    keep = np.ones(images.shape[1:3], dtype=bool) if keep is None else keep

    def var(part):
        return float(part.var(axis=0, ddof=1, dtype=np.float64).mean(axis=2)[keep].mean()) * spp

    groups = [var(g) for g in np.array_split(images, 4)]
    return var(images), float(np.std(groups, ddof=1)) / 2


def emitters_seen(path: Path, spp: int = 64) -> np.ndarray:
    """(H, W) bool: the pixels where a camera ray may see an emitter (invrender at max_depth 1,
    nonzero anywhere, dilated by a pixel): their variance is the pixel filter's sampling of a
    radiance edge of up to 900, the same in both renderers and no part of light sampling."""
    scene = load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # max_depth 1 overrides the file's, as meant
        seen = ir.render(scene, "path", spp=spp, max_depth=1, seed=99, progress=False).numpy().max(axis=2) > 0
    grown = seen.copy()
    for axis in (0, 1):
        for step in (-1, 1):
            grown |= np.roll(seen, step, axis=axis)
    return grown


def load(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ir.load_scene(str(path))


def invrender_images(path: Path, spp: int, seeds: int) -> tuple[np.ndarray, float]:
    scene = load(path)
    d = scene.defaults
    start = time.perf_counter()
    images = [ir.render(scene, d.get("integrator", "path"), spp=spp, max_depth=d["max_depth"], seed=s, progress=False).numpy() for s in range(seeds)]
    return np.stack(images), time.perf_counter() - start


def mitsuba_images(path: Path, spp: int, seeds: int) -> tuple[np.ndarray, float]:
    mi, _ = mitsuba_ref._require()
    scene = mi.load_file(str(path), spp=str(spp))
    start = time.perf_counter()
    images = [mitsuba_ref.render(scene, spp, seed=1000 + s) for s in range(seeds)]
    return np.stack(images), time.perf_counter() - start


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", type=Path, default=SCENE)
    p.add_argument("--resolution", type=int, nargs=2, default=(96, 64), metavar=("W", "H"))
    p.add_argument("--spp", type=int, default=32)
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--mitsuba-seeds", type=int, default=None, help="Mitsuba's renders (default 4 x seeds: its figure is the reference)")
    p.add_argument("--trim", type=int, default=8, help="pixels of highest variance (Mitsuba's) left out of the trimmed figure")
    p.add_argument("--max-depth", type=int, default=8, help="of the path comparison")
    p.add_argument("--only", choices=("direct", "path"), default=None)
    args = p.parse_args(argv)
    if not args.scene.is_file():
        print(f"scene not found: {args.scene} (a checkout of mitsuba-data)", file=sys.stderr)
        return 2
    if not mitsuba_ref.available():
        print("Mitsuba 3 is not available (bench/README.md)", file=sys.stderr)
        return 2
    w, h = args.resolution
    mi_seeds = args.mitsuba_seeds or 4 * args.seeds
    print(f"Veach MIS scene {args.scene.name}, {w}x{h}, box filter, {args.spp} spp x {args.seeds} seeds (invrender), x {mi_seeds} seeds ({mitsuba_ref.label()})")
    worst = {"light": 0.0, "trimmed": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        files = write_copies(args.scene, Path(tmp), w, h, args.max_depth)
        seen = emitters_seen(files["direct"])
        print(f"{int(seen.sum())} of {seen.size} pixels may see an emitter directly: the figures without them (the light transport) and with them")
        for name, path in files.items():
            if args.only and name != args.only:
                continue
            ours, t_ours = invrender_images(path, args.spp, args.seeds)
            theirs, t_theirs = mitsuba_images(path, args.spp, mi_seeds)
            hot_map = np.where(seen, -1.0, theirs.var(axis=0, dtype=np.float64).mean(axis=2))
            hot = np.zeros_like(seen)
            hot.flat[np.argsort(hot_map.ravel())[::-1][: args.trim]] = True
            rows = [("light transport", ~seen), (f"without the {args.trim} hottest", ~seen & ~hot), ("every pixel", None)]
            m_ours, m_theirs = ours.mean(axis=(0, 1, 2), dtype=np.float64), theirs.mean(axis=(0, 1, 2), dtype=np.float64)
            se = lambda im: im.mean(axis=(1, 2), dtype=np.float64).std(axis=0, ddof=1) / len(im) ** 0.5  # noqa: E731
            s_ours, s_theirs = se(ours), se(theirs)
            label = "direct (invrender: path, max_depth 2)" if name == "direct" else f"path, max_depth {args.max_depth}"
            print(f"\n{label}")
            print(f"  per-sample variance (mean over pixels; +- from four groups of seeds), target ratio <= {TARGET}")
            for (title, keep), key in zip(rows, ("light", "trimmed", None)):
                (v_ours, e_ours), (v_theirs, e_theirs) = per_sample(ours, args.spp, keep), per_sample(theirs, args.spp, keep)
                ratio = v_ours / v_theirs
                if key:
                    worst[key] = max(worst[key], ratio)
                print(f"    {title:22s} invrender {v_ours:.4g} +- {e_ours:.2g}   Mitsuba {v_theirs:.4g} +- {e_theirs:.2g}   ratio {ratio:.3f} +- {ratio * math.hypot(e_ours / v_ours, e_theirs / v_theirs):.2f}")
            print("  channel means        invrender " + " ".join(f"{m:.5f}+-{s:.5f}" for m, s in zip(m_ours, s_ours)))
            print("                       Mitsuba   " + " ".join(f"{m:.5f}+-{s:.5f}" for m, s in zip(m_theirs, s_theirs)))
            print("  difference           " + " ".join(f"{100 * (a / b - 1):+.2f}%" for a, b in zip(m_ours, m_theirs)))
            print(f"  seconds              invrender {t_ours:.1f}   Mitsuba {t_theirs:.1f}")
    for key, value in worst.items():
        print(f"worst variance ratio ({key}) {value:.3f}: {'within' if value <= TARGET else 'over'} {TARGET}x")
    return 0 if max(worst.values()) <= TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
