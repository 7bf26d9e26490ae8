"""Scale-out on torch.distributed: the same render and the same fit in one process and split across
N ranks by ``torchrun`` (docs/scale.md), their times, and whether the results agree.

    python bench/scale.py [--nproc 2] [--resolution 128] [--spp 64] [--fit-steps 20]

The render is the Cornell box at ``--resolution``, ``--spp``, written to EXR by each run and
compared pixel for pixel; the fit recovers the box's four parameters from half their values at
64x64 (``--fit-steps`` Adam steps), and the two runs' last steps are compared. Times are the
commands' own (the render's as ``invrender render`` reports it, the fit's from its report), so
process start-up and imports are left out. On one machine the ranks share its cores: with
``--nproc`` equal to the core count and one thread per rank the split costs little and gains
nothing; across machines (``torchrun --nnodes``) the ranks add cores. Figures are printed, never
asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

import invrender as ir

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _measure import Results, add_json_option  # noqa: E402


def run(cmd: list[str], cwd: Path, nproc: int) -> str:
    env = {**os.environ, "OMP_NUM_THREADS": "1"} if nproc > 1 else dict(os.environ)
    if nproc > 1:
        cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", str(nproc), "-m", "invrender", *cmd]
    else:
        cmd = [sys.executable, "-m", "invrender", *cmd]
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=3600)
    if done.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}\n{done.stderr[-2000:]}")
    return done.stderr


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--nproc", type=int, default=2)
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--fit-steps", type=int, default=20)
    add_json_option(parser)
    args = parser.parse_args()
    n = args.resolution
    record = Results("scale", "Scale-out on torch.distributed: 1 process against torchrun ranks")
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)
        print(f"render: Cornell box {n}x{n}, {args.spp} spp; 1 process vs {args.nproc} ranks (gloo, one thread each)")
        images = {}
        rows = record.table(f"render: Cornell box {n}x{n}, {args.spp} spp; 1 process vs {args.nproc} ranks (gloo, one thread each)", ["processes", "seconds", "M paths/s"])
        for p in (1, args.nproc):
            out = run(["render", "cornell_box", "--resolution", f"{n}x{n}", "--spp", str(args.spp), "--out", f"r{p}.exr"], cwd, p)
            seconds = float(re.search(r"spp, ([\d.]+) s", out).group(1))
            images[p] = ir.read_image(cwd / f"r{p}.exr")
            print(f"  {p} process(es): {seconds:.2f} s ({n * n * args.spp / seconds / 1e6:.3f} M paths/s)")
            rows.append([p, round(seconds, 2), round(n * n * args.spp / seconds / 1e6, 3)])
        diff = (images[1] - images[args.nproc]).abs().max().item()
        print(f"  largest pixel difference: {diff:.3g} (relative to the mean {diff / images[1].mean().item():.3g})")
        record.note(f"render: largest pixel difference between 1 and {args.nproc} processes {diff:.3g} (relative to the mean {diff / images[1].mean().item():.3g})")

        scene = ir.load_scene("cornell_box", resolution=(64, 64))
        ir.write_image(cwd / "target.exr", ir.render(scene, spp=1024, seed=99, progress=False))
        print(f"fit: Cornell box 64x64, 4 parameters from half their values, {args.fit_steps} Adam steps (16 then 64 spp)")
        last = {}
        rows = record.table(f"fit: Cornell box 64x64, 4 parameters from half their values, {args.fit_steps} Adam steps (16 then 64 spp)", ["processes", "ms per step"])
        for p in (1, args.nproc):
            run(["fit", "--scene", "cornell_box", "--target", "target.exr", "--params", "red.reflectance,green.reflectance,white.reflectance,light.emission",
                 "--init", "reflectance=0.5", "--init", "emission=9", "--steps", str(args.fit_steps), "--out", f"f{p}", "--quiet"], cwd, p)  # fmt: skip
            report = json.loads((cwd / f"f{p}" / "report.json").read_text())
            last[p] = torch.load(cwd / f"f{p}" / "checkpoint.pt", weights_only=False)["history"][-1]
            print(f"  {p} process(es): {report['seconds'] / report['steps'] * 1000:.0f} ms per step")
            rows.append([p, round(report["seconds"] / report["steps"] * 1000)])
        a, b = last[1]["params"], last[args.nproc]["params"]
        worst = max(abs(x - y) / abs(x) for k in a for x, y in zip(a[k], b[k]))
        print(f"  last step's parameters differ by at most {worst:.3g} relative")
        record.note(f"fit: the last step's parameters differ by at most {worst:.3g} relative between 1 and {args.nproc} processes")
    record.write(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
