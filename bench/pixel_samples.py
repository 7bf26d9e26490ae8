"""Error against samples per pixel: the RMSE of renders against a high-spp reference at every spp
of a list, for each pixel sampler, on the Cornell box and the specular box.

    python bench/pixel_samples.py [--spp 4 8 12 16 24 32 48 64 96 128] [--seeds 4]
        [--reference-spp 8192] [--resolution 64] [--samplers stratified independent antithetic stratified_direct]

The RMSE is the mean over ``--seeds`` seeds; the reference is an ``independent`` render at
``--reference-spp`` of another seed (its own RMSE, estimated from two halves, is printed). A row says
whether the error falls at every step of the list (docs/sampling.md#pixel-samples).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import warnings
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _measure import Results, add_json_option  # noqa: E402

import invrender as ir  # noqa: E402


def rmse(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a - b) ** 2).mean().sqrt())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, nargs="+", default=[4, 8, 12, 16, 24, 32, 48, 64, 96, 128])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--reference-spp", type=int, default=8192)
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--scenes", nargs="+", default=["cornell_box", "cornell_specular"])
    ap.add_argument("--samplers", nargs="+", default=["stratified", "independent", "antithetic", "stratified_direct"])
    add_json_option(ap)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    record = Results("pixel_samples", "Error against samples per pixel, per pixel sampler")
    for name in args.scenes:
        scene = ir.load_scene(name, resolution=(args.resolution, args.resolution))
        half = max(1, args.reference_spp // 2)
        parts = [ir.render(scene, spp=half, seed=10_000 + k, sampler="independent", progress=False) for k in range(2)]
        reference = (parts[0] + parts[1]) / 2
        ref_noise = rmse(parts[0], parts[1]) / 2  # RMSE of the mean of two halves against the truth
        rows = record.table(
            f"{name}: RMSE against a {args.reference_spp}-spp reference (its own RMSE {ref_noise:.4f}), {args.resolution}^2, mean of {args.seeds} seeds",
            ["sampler", *[str(s) for s in args.spp], "falls at every step"],
        )
        print(f"# {name} ({args.resolution}^2; reference {args.reference_spp} spp, its RMSE {ref_noise:.4f}; {args.seeds} seeds)", flush=True)
        for sampler in args.samplers:
            errors = [statistics.fmean(rmse(ir.render(scene, spp=spp, seed=s, sampler=sampler, progress=False), reference) for s in range(args.seeds)) for spp in args.spp]
            falls = all(a > b for a, b in zip(errors, errors[1:]))
            rows.append([sampler, *[f"{e:.4f}" for e in errors], "yes" if falls else "no"])
            print(sampler, " ".join(f"{s}:{e:.4f}" for s, e in zip(args.spp, errors)), "falls at every step" if falls else "NOT monotone", flush=True)
    record.write(args.json)


if __name__ == "__main__":
    main()
