"""An ablation's table (text and CSV) and figure (RMSE against samples and against time)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from invrender.ablation.measure import AblationResult
from invrender.io.reports import save_figure, write_text


def format_table(result: AblationResult) -> str:
    """A Markdown table: per variant its RMSE at each spp, relative RMSE and seconds at the largest,
    RMSE at equal time (the defaults' time at the largest spp) and efficiency relative to the
    defaults (their MSE over the variant's at that time)."""
    spps = sorted({r.spp for r in result.rows})
    top = spps[-1]
    head = ["strategy", "choice", *[f"RMSE {n} spp" for n in spps], f"rel. RMSE {top} spp", f"CPU s at {top} spp", f"RMSE at {result.time_budget:.2f} CPU s", "efficiency"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for v in result.variants:
        rows = {r.spp: r for r in result.of(v.name)}
        if not rows:
            continue
        last = rows[max(rows)]
        cells = [v.name, v.choice, *[f"{rows[n].rmse:.4g}" if n in rows else "-" for n in spps]]
        cells += [f"{last.rel_rmse:.4g}", f"{last.cpu_seconds:.3g}", f"{result.rmse_at_time(v.name):.4g}", f"{result.efficiency(v.name):.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    w, h = result.resolution
    lines.append("")
    lines.append(
        f"{result.scene} {w}x{h}, max_depth {result.max_depth}, {result.rows[0].trials} seed(s) per cell; reference {result.reference_spp} spp "
        f"(its own RMSE about {result.reference_rmse:.2g}); efficiency = the defaults' MSE over the variant's at equal CPU time"
    )
    return "\n".join(lines)


def write_csv(result: AblationResult, path) -> None:
    """One row per variant and spp: variant, choice, spp, rmse, rel_rmse, seconds (wall clock),
    cpu_seconds, trials, and the variant's rmse_equal_time and efficiency (repeated on each of its
    rows)."""
    choices = {v.name: v.choice for v in result.variants}
    out = io.StringIO()
    writer = csv.writer(out)
    writer.writerow(["variant", "choice", "spp", "rmse", "rel_rmse", "seconds", "cpu_seconds", "trials", "rmse_equal_time", "efficiency"])
    for r in result.rows:
        writer.writerow([r.variant, choices[r.variant], r.spp, f"{r.rmse:.6g}", f"{r.rel_rmse:.6g}", f"{r.seconds:.6g}", f"{r.cpu_seconds:.6g}", r.trials, f"{result.rmse_at_time(r.variant):.6g}", f"{result.efficiency(r.variant):.4g}"])
    write_text(path, out.getvalue())


def plot(result: AblationResult, path) -> None:
    """Two log-log panels, RMSE against spp and against CPU seconds per render, one line per
    variant (the defaults in black)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    w, h = result.resolution
    fig.suptitle(f"sampling strategies: {result.scene} {w}x{h}, max_depth {result.max_depth}, reference {result.reference_spp} spp", fontsize=10)
    for i, v in enumerate(result.variants):
        rows = result.of(v.name)
        style = {"color": "black", "lw": 2.2} if v.name == "default" else {"color": plt.get_cmap("tab10")(i % 10), "lw": 1.4}
        axes[0].plot([r.spp for r in rows], [r.rmse for r in rows], marker="o", ms=3, label=v.name, **style)
        axes[1].plot([r.cpu_seconds for r in rows], [r.rmse for r in rows], marker="o", ms=3, label=v.name, **style)
    axes[0].set_xlabel("samples per pixel")
    axes[1].set_xlabel("CPU seconds per render (all threads)")
    axes[1].axvline(result.time_budget, color="grey", lw=0.8, ls=":")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylabel("RMSE against the reference")
        ax.grid(True, which="both", alpha=0.3)
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def write_ablation(result: AblationResult, out) -> list[Path]:
    """``out``/ablation.csv, ablation.md and ablation.png; returns the paths written."""
    out = Path(out)
    paths = [out / "ablation.csv", out / "ablation.md", out / "ablation.png"]
    write_csv(result, paths[0])
    write_text(paths[1], format_table(result) + "\n")
    plot(result, paths[2])
    return paths
