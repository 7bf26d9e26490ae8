"""The sampling-strategy figures of docs/sampling.md: three ablations and the adaptive sample counts.

    python bench/sampling_ablation.py [--out runs/sampling] [--figures docs/images]

Runs (64 x 64, spp 16-128, 3 seeds, reference 8192 spp; about 10 minutes on 2 cores):
- cornell_box with every variant;
- forward/cornell_far.toml (the box in a black frame) with independent and adaptive sampling;
- forward/mis_plates.toml with BSDF-only, emitter-only and uniform hemisphere sampling;
writing OUT/<scene>/ablation.{csv,md,png} and FIGURES/sampling_<scene>.png, then
FIGURES/adaptive_counts.png: the far box at 128 x 128 and 32 spp, uniform and adaptive, with the
adaptive render's samples per pixel.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

import torch

import invrender as ir
from invrender.ablation import ablation, format_table, write_ablation
from invrender.inverse.report import save_figure
from invrender.io.images import to_srgb

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _measure import Results, add_json_option  # noqa: E402

RUNS = [
    ("cornell_box", "cornell_box", None),
    ("cornell_far", "forward/cornell_far.toml", "independent,adaptive"),
    ("mis_plates", "forward/mis_plates.toml", "bsdf_only,emitter_only,uniform_hemisphere"),
]


def adaptive_figure(path: Path, spp: int = 32) -> None:
    """The far box rendered with uniform and with adaptive allocation at equal samples, and the
    adaptive render's samples per pixel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scene = ir.load_scene("forward/cornell_far.toml", resolution=(128, 128))
    uniform = ir.render(scene, spp=spp, seed=1, progress=False)
    result = ir.render(scene, spp=spp, seed=1, adaptive=True, return_counts=True, progress=False)
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.9))
    axes[0].imshow(to_srgb(uniform).numpy())
    axes[0].set_title(f"uniform, {spp} spp everywhere", fontsize=9)
    axes[1].imshow(to_srgb(result.image).numpy())
    axes[1].set_title(f"adaptive, {spp} spp on average", fontsize=9)
    shown = axes[2].imshow(result.spp.numpy(), cmap="viridis")
    axes[2].set_title("adaptive: samples per pixel", fontsize=9)
    fig.colorbar(shown, ax=axes[2], fraction=0.046)
    for ax in axes:
        ax.axis("off")
    fig.tight_layout()
    save_figure(fig, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="runs/sampling")
    parser.add_argument("--figures", default="docs/images")
    add_json_option(parser)
    args = parser.parse_args()
    figures = Path(args.figures)
    figures.mkdir(parents=True, exist_ok=True)
    record = Results("sampling_ablation", "Sampling-strategy ablation: RMSE at equal samples and at equal time")
    for name, scene_path, strategies in RUNS:
        scene = ir.load_scene(scene_path, resolution=(64, 64))
        result = ablation(scene, strategies, spp=(16, 32, 64, 128), trials=3, reference_spp=8192)
        written = write_ablation(result, Path(args.out) / name)
        print(format_table(result), flush=True)
        record.markdown(f"{name} ({scene_path}), 64x64, spp 16-128, 3 seeds, reference 8192 spp", format_table(result))
        shutil.copyfile(written[2], figures / f"sampling_{name}.png")
    torch.manual_seed(0)
    adaptive_figure(figures / "adaptive_counts.png")
    record.write(args.json)


if __name__ == "__main__":
    main()
