"""``invrender dataset``: render a synthetic dataset recipe (a front over :func:`invrender.recipes.make_dataset`)."""

from __future__ import annotations

import sys


def add_parser(sub) -> None:
    d = sub.add_parser("dataset", help="render a synthetic dataset recipe", description="Render a datasets_synthetic/*.toml recipe: view_NN.exr/png, truth.json, manifest.json.")
    d.add_argument("recipe", help="a dataset recipe (.toml)")
    d.add_argument("--out", required=True, help="output folder")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(run=run)


def run(args) -> int:
    from invrender.recipes import make_dataset

    manifest = make_dataset(args.recipe, args.out, progress=not args.quiet)
    if not args.quiet:
        print(f"wrote {len(manifest['views'])} view(s), truth.json and manifest.json to {args.out}", file=sys.stderr)
    return 0
