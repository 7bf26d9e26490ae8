"""The integrator ladder side by side: one scene rendered by every integrator, tiled into one PNG
with each image's time and channel means (the figure in the README).

    python bench/ladder.py [--scene cornell_specular] [--resolution 128] [--spp 256] [--ambient 0.03]
                           [--out docs/images/ladder.png]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import invrender as ir  # noqa: E402
from invrender.io.images import to_srgb  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _measure import Results, add_json_option  # noqa: E402

LADDER = [
    ("utah", "Utah: emitters + direct light\n+ ambient rho*eps0"),
    ("whitted", "Whitted: direct + ambient,\nmirrors and glass followed (split)"),
    ("distributed", "Cook: glossy lobes followed,\nsoft shadows, ambient"),
    ("path", "Kajiya: path tracing\n(the whole series)"),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="cornell_specular")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--ambient", type=float, default=0.03, help="eps0 of the Utah, Whitted and Cook models")
    parser.add_argument("--out", default="docs/images/ladder.png")
    add_json_option(parser)
    args = parser.parse_args()
    record = Results("ladder", "The ladder of approximations: one scene by every integrator")
    rows = record.table(f"{args.scene}, {args.resolution}x{args.resolution}, {args.spp} spp, max_depth {args.max_depth} (utah: 2), eps0 = {args.ambient} (path: none)",
                        ["integrator", "seconds", "mean R", "mean G", "mean B"])

    scene = ir.load_scene(args.scene, resolution=(args.resolution, args.resolution), ambient=args.ambient)
    fig, axes = plt.subplots(1, len(LADDER), figsize=(3.2 * len(LADDER), 3.9))
    for ax, (name, title) in zip(axes, LADDER):
        start = time.perf_counter()
        image = ir.render(scene, name, spp=args.spp, max_depth=args.max_depth if name != "utah" else 2, progress=False)
        seconds = time.perf_counter() - start
        mean = image.mean((0, 1)).tolist()
        print(f"{name:12s} {seconds:7.2f} s  mean RGB {mean[0]:.4f} {mean[1]:.4f} {mean[2]:.4f}")
        rows.append([name, round(seconds, 2), *(round(m, 4) for m in mean)])
        ax.imshow(to_srgb(image.clamp(0, 1)).numpy())
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.suptitle(f"{scene.name}, {args.resolution}x{args.resolution}, {args.spp} spp, max_depth {args.max_depth}, eps0 = {args.ambient} (path: none)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.92))
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}")
    record.write(args.json)


if __name__ == "__main__":
    main()
