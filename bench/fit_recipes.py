"""Every shipped fit recipe with each solver, side by side: is ``lm`` better than Adam everywhere?

    python bench/fit_recipes.py [--solvers adam,lm] [--recipes cornell_random,two_lights,...]
                                [--set KEY=VALUE ...] [--out runs/fit_recipes]

For each recipe of ``optimize/`` (a model study's variants each count as a recipe of their own:
``utah_bias/utah``), its dataset is rendered once into ``OUT/<recipe>/dataset`` and fitted with each
solver at the recipe's own settings (only ``solver`` changes), exactly as ``invrender fit RECIPE
--solver S`` would. Prints, per fit: the wall time until every channel of every parameter is first
within 2% and within 1% of the truth (from the fit's history: "never" if it does not get there),
the final largest error over all channels, the median error, and the total time; then which solver
is better on each recipe (smaller final largest error, ties within 10% of it going to the faster
one). Each fit's report is written to ``OUT/<recipe>/<solver>/report.json``. ``--set KEY=VALUE``
overrides a fit setting in every fit (``--set sampler=antithetic``).

Model-study variants whose model cannot match the target (``utah`` without eps0) have a large final
error under every solver: there the comparison is between two estimates of the same biased optimum.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

from _measure import Results, add_json_option  # bench/ is the script's directory
from fit_cornell import setting

import invrender as ir
from invrender.inverse.report import report_dict
from invrender.io.reports import write_json
from invrender.recipes import apply_init, load_dataset, load_fit_recipe, make_dataset

ROOT = Path(__file__).resolve().parent.parent
TOLERANCES = (0.02, 0.01)


def fits_of(recipe_path: Path):
    """(label, names, init, settings) of every fit a recipe asks for (one per study variant)."""
    recipe = load_fit_recipe(recipe_path)
    stem = recipe_path.stem
    if not recipe.variants:
        return recipe, [(stem, recipe.params, recipe.init, recipe.settings)]
    fits = []
    for v in recipe.variants:
        names = recipe.params + [p for p in v.params if p not in recipe.params]
        fits.append((f"{stem}/{v.slug}", names, {**recipe.init, **v.init}, {**recipe.settings, **v.settings}))
    return recipe, fits


def first_within(history: list[dict], tol: float) -> float | None:
    """Seconds until the largest error over the truth's parameters first drops below ``tol``."""
    for h in history:
        if h.get("errors") and max(h["errors"].values()) < tol:
            return h["seconds"]
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--solvers", default="adam,lm")
    parser.add_argument("--recipes", default=None, help="comma-separated recipe stems (default: every recipe in optimize/)")
    parser.add_argument("--out", default="runs/fit_recipes")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a fit setting for every fit")
    add_json_option(parser)
    args = parser.parse_args()
    record = Results("fit_recipes", "Every shipped fit recipe with each solver")
    overrides = dict(setting(t) for t in args.set)
    solvers = [s.strip() for s in args.solvers.split(",") if s.strip()]
    paths = sorted((ROOT / "optimize").glob("*.toml"))
    if args.recipes:
        wanted = {s.strip() for s in args.recipes.split(",")}
        paths = [p for p in paths if p.stem in wanted]
    out = Path(args.out)
    rows = []
    for path in paths:
        recipe, fits = fits_of(path)
        data = out / path.stem / "dataset"
        if not (data / "manifest.json").is_file():
            make_dataset(recipe.dataset, data, progress=False)
        scene0, targets, cameras, truth = load_dataset(data)
        for label, names, init, settings in fits:
            for solver in solvers:
                scene = scene0.with_params(detach=True)
                apply_init(scene, names, init)
                start = time.perf_counter()
                result = ir.fit(scene, targets, names, cameras=cameras, truth=truth, progress=False, **{**settings, **overrides, "solver": solver})
                seconds = time.perf_counter() - start
                errors = [e for n in result.truth for e in (result.params[n] / result.truth[n] - 1).abs().reshape(-1).tolist()]
                row = {
                    "recipe": label, "solver": solver, "seconds": seconds, "max_error": max(errors), "median_error": statistics.median(errors),
                    **{f"to_{tol:g}": first_within(result.history, tol) for tol in TOLERANCES},
                }  # fmt: skip
                rows.append(row)
                write_json(out / label / solver / "report.json", report_dict(result, recipe=str(path)))
                print(json.dumps(row), flush=True)

    def when(s):
        return "never" if s is None else f"{s:.1f} s"

    print("\n| recipe | solver | to 2% | to 1% | final largest error | median error | total |")
    print("|---|---|---|---|---|---|---|")
    table = record.table("each recipe at its own settings, only the solver changed (final largest and median error over all channels)",
                         ["recipe", "solver", "to 2%", "to 1%", "final largest error", "median error", "total"])
    for r in rows:
        print(f"| {r['recipe']} | {r['solver']} | {when(r['to_0.02'])} | {when(r['to_0.01'])} | {100 * r['max_error']:.2f}% | {100 * r['median_error']:.2f}% | {r['seconds']:.1f} s |")
        table.append([r["recipe"], r["solver"], when(r["to_0.02"]), when(r["to_0.01"]), f"{100 * r['max_error']:.2f}%", f"{100 * r['median_error']:.2f}%", f"{r['seconds']:.1f} s"])
    print()
    for label in dict.fromkeys(r["recipe"] for r in rows):
        group = [r for r in rows if r["recipe"] == label]
        best = min(r["max_error"] for r in group)
        contenders = [r for r in group if r["max_error"] <= 1.1 * best]
        winner = min(contenders, key=lambda r: r["seconds"])
        print(f"{label}: {winner['solver']} (largest error {100 * winner['max_error']:.2f}% in {winner['seconds']:.1f} s)")
        record.note(f"{label}: {winner['solver']} does better (largest error {100 * winner['max_error']:.2f}% in {winner['seconds']:.1f} s)")
    record.write(args.json)


if __name__ == "__main__":
    main()
