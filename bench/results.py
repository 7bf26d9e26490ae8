"""Write docs/results.md from the benchmarks' own output (bench/results/*.json).

    python bench/results.py [--results bench/results] [--out docs/results.md]

Each benchmark script writes its figures with ``--json PATH`` (``_measure.Results``): its tables,
the machine (CPU model, vector width, cores, load average, niceness), the date, the git commit
and the exact command. This script turns every such file into one section of docs/results.md,
saying which machine and which command produced each table, and lists the benchmarks that have no
file as not regenerated, with the command that regenerates them. The page is generated: edit the
benchmarks or this script, never the page.

To refresh a benchmark: ``nice python bench/NAME.py ... --json bench/results/NAME.json``, then
``python bench/results.py``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

# Every benchmark, in the order of the page: (name, what it measures, the command that regenerates
# it at its documented settings, its duration there, the docs page that explains it).
BENCHMARKS = [
    ("forward", "forward-rendering throughput against Mitsuba 3", "python bench/forward.py", "~1 min", "scale.md#which-backend-where"),
    ("forward_avx2_standin", "forward-rendering throughput against Mitsuba 3 as AVX2 code on an AVX-512 CPU (both renderers' kernels and Embree; a stand-in for an AVX2 machine)", "ATEN_CPU_CAPABILITY=avx2 python bench/forward.py --llvm-target znver3:8 --scenes cornell_box,cornell_specular,forward/textured_floor.toml --backends embree --no-torch-steps --repeats 9", "~1 min", "scale.md#which-backend-where"),
    ("gradient", "time and memory of one gradient against Mitsuba 3 `prb`", "python bench/gradient.py", "~5 min", "scale.md#gradients"),
    ("scale", "one process against torchrun ranks", "python bench/scale.py", "~2 min", "scale.md#across-processes-and-machines-torchdistributed"),
    ("radiosity", "radiosity against closed forms and the path tracer", "python bench/radiosity.py", "~3-6 min", "radiosity.md#measured-in-brief"),
    ("ladder", "the ladder of approximations (figure and channel means)", "python bench/ladder.py --out /tmp/ladder.png", "~1 min", "integrators.md#the-ladder-of-approximations"),
    ("mitsuba_compare", "channel means against Mitsuba 3 (acceptance)", "python bench/mitsuba_compare.py --acceptance --closeups", "14-25 min", "rendering.md#against-mitsuba-3"),
    ("filter_compare", "reconstruction filters against Mitsuba 3, pixel for pixel", "python bench/filter_compare.py", "~3 min", "rendering.md#reconstruction-filters"),
    ("envmap_compare", "an environment map against Mitsuba 3 (diffuse and GGX spheres)", "python bench/envmap_compare.py --resolution 64 --spp 512 --seeds 8 --max-depth 8 2", "~2 min", "environment.md#against-mitsuba-3"),
    ("fit_cornell", "the acceptance fit (Adam, lm, Mitsuba `prb` + Adam)", "python bench/fit_cornell.py", "~13 min", "fitting.md#measured"),
    ("fit_recipes", "every shipped fit recipe with both solvers", "python bench/fit_recipes.py", "~40 min", "fitting.md#every-recipe-with-both-solvers"),
    ("normalmap_fit", "fitting a normal map: normal_plane's 16x16 map from four views (Adam)", "python bench/normalmap_fit.py", "~10 min", "fitting.md#normals"),
    ("inverse_lighting", "inverse lighting: the transport matrix against Mitsuba 3 `prb` + Adam", "python bench/inverse_lighting.py", "~15 min", "environment.md#against-mitsuba-3-prb--adam"),
    ("sampling_ablation", "the sampling-strategy ablation", "python bench/sampling_ablation.py", "~10 min", "sampling.md#measured"),
    ("pixel_samples", "error against samples per pixel, per pixel sampler", "python bench/pixel_samples.py", "~15 min", "sampling.md#pixel-samples"),
    ("census", "a census of public Mitsuba scene files: features, loads, channel means against Mitsuba 3", "python bench/census.py /tmp/md /tmp/tut", "~15-40 min", "../forward/README.md#mitsuba-xml-scenes"),
]


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:g}"
    return str(value).replace("|", "\\|").replace("\n", " ")


def machine_line(record: dict) -> str:
    m = record["machine"]
    load = m.get("load_average", [None])[0], m.get("load_average_end", [None])[0]
    loads = "-".join(f"{x:g}" for x in load if x is not None)
    nice = f", run under `nice` ({m['nice']})" if m.get("nice") else ""
    gpu = f", GPU {m['cuda']}" if m.get("cuda") else ""
    versions = ", ".join(f"{k} {m[k]}" for k in ("python", "torch") if m.get(k))
    return (
        f"{m['cpu']} ({m['vector']}), {m['cores']} cores, {m.get('memory_gib')} GiB{gpu}; {versions}. "
        f"Load average {loads} (a machine shared with other jobs: compare the ratios within a table, "
        f"not absolute times across tables){nice}."
    )


def section(record: dict, docs_page: str | None) -> list[str]:
    commit = record.get("commit") or "unknown commit"
    if record.get("dirty"):
        commit += " with uncommitted changes"
    lines = [
        f"## {record['title']}",
        "",
        f"Produced by `{record['command']}` on {record['date']} at commit {commit}, in {record['seconds']:g} s.",
        f"Machine: {machine_line(record)}",
    ]
    if docs_page:
        lines.append(f"What the figures mean: [{docs_page.split('#')[0]}]({docs_page}).")
    for table in record["tables"]:
        lines += ["", f"**{table['title']}**", ""]
        lines.append("| " + " | ".join(_cell(c) for c in table["columns"]) + " |")
        lines.append("|" + "---|" * len(table["columns"]))
        for row in table["rows"]:
            lines.append("| " + " | ".join(_cell(v) for v in row) + " |")
        if table.get("note"):
            lines += ["", table["note"]]
    if record.get("notes"):
        lines.append("")
        lines += [f"- {n}" for n in record["notes"]]
    return lines + [""]


def render_page(records: dict[str, dict]) -> str:
    lines = [
        "# Measured results",
        "",
        "<!-- Generated by bench/results.py from bench/results/*.json: do not edit by hand. -->",
        "",
        "Every figure on this page was written by a benchmark script (`bench/`, see",
        "[bench/README.md](../bench/README.md)) with `--json bench/results/NAME.json` and collected by",
        "`python bench/results.py`; each table says which machine and which command produced it.",
        "Benchmarks print figures and are never asserted; the tests check correctness, not speed.",
        "",
        "| benchmark | measures | regenerated |",
        "|---|---|---|",
    ]
    for name, what, command, duration, _page in BENCHMARKS:
        rec = records.get(name)
        done = f"{rec['date']}, commit {rec.get('commit') or '?'}" if rec else "not regenerated in this run"
        lines.append(f"| [`{name}`](#{name.replace('_', '-')}) | {what} | {done} |")
    lines.append("")
    for name, what, command, duration, page in BENCHMARKS:
        lines.append(f'<a id="{name.replace("_", "-")}"></a>')
        lines.append("")
        if name in records:
            lines += section(records[name], page)
        else:
            lines += [
                f"## {name}: not regenerated in this run",
                "",
                f"{what[0].upper() + what[1:]}. Regenerate with `{command} --json bench/results/{name}.json` ({duration} at the",
                "documented settings), then `python bench/results.py`. The last figures measured by hand, with their",
                f"dates and machines, are in [{page.split('#')[0]}]({page}) (labelled historical).",
                "",
            ]
    extra = sorted(set(records) - {b[0] for b in BENCHMARKS})
    for name in extra:
        lines.append(f'<a id="{name.replace("_", "-")}"></a>')
        lines.append("")
        lines += section(records[name], None)
    return "\n".join(lines).rstrip() + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", default=str(REPO / "bench" / "results"), help="folder of the benchmarks' JSON files")
    parser.add_argument("--out", default=str(REPO / "docs" / "results.md"))
    args = parser.parse_args()
    records = {}
    for path in sorted(Path(args.results).glob("*.json")):
        record = json.loads(path.read_text())
        records[record.get("benchmark", path.stem)] = record
    page = render_page(records)
    out = Path(args.out)
    tmp = out.with_suffix(".md.tmp")
    tmp.write_text(page)
    tmp.replace(out)
    print(f"wrote {out} ({len(records)} benchmark(s) with results, {sum(b[0] not in records for b in BENCHMARKS)} not regenerated)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
