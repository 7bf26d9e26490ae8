"""What a fit leaves behind for people: a JSON report, a study table and PNGs of loss, parameter
error and correlations (written by :mod:`invrender.io.reports`)."""

from __future__ import annotations

import dataclasses

from invrender.inverse.fit import FitResult
from invrender.io.reports import save_figure


def report_dict(result: FitResult, **extra) -> dict:
    """The fit as plain data: initial, recovered and (when known) true values with errors."""
    last = result.history[-1] if result.history else {}
    out = {
        "steps": len(result.history),
        "seconds": last.get("seconds", 0.0),
        "final_loss": last.get("loss"),
        "solver": result.solver,
        "solver_reason": result.solver_reason,
        "converged": result.converged,
        "settings": dataclasses.asdict(result.settings),
        "initial": {k: v.tolist() for k, v in result.initial.items()},
        "recovered": {k: v.tolist() for k, v in result.params.items()},
    }
    if result.std_error:
        out["std_error"] = {k: v.tolist() for k, v in result.std_error.items()}
        for key in ("correlation", "undetermined"):  # least-squares fits: from the last round
            if key in last:
                out[key] = last[key]
    if result.targets and any(t["response"] != "linear" or t["counting"] != t["pixels"] for t in result.targets):
        out["pixels"] = result.targets  # photographs and masks: per view what counted
    if result.truth:
        out["truth"] = {k: v.tolist() for k, v in result.truth.items()}
        out["relative_error"] = result.errors
        out["max_relative_error"] = max(result.errors.values())
    out.update(extra)
    return out


def study_table(results: dict[str, FitResult], truth: dict) -> tuple[str, dict]:
    """A model study: every variant's signed relative error per parameter channel.

    Args:
        results: variant label -> its fit.
        truth: parameter name -> ground truth.
    Returns:
        (a Markdown table, the same as plain data). Parameters without a ground truth (such as the
        ambient eps0 of ``utah``) are listed with their recovered values.
    """
    labels = list(results)
    names = list(dict.fromkeys(n for r in results.values() for n in r.params))
    rows, data = [], {"variants": {}, "errors": {}, "recovered": {}}
    for label, r in results.items():
        data["variants"][label] = {"integrator": r.settings.integrator, "steps": len(r.history), "seconds": r.history[-1]["seconds"] if r.history else 0.0,
                                   "max_relative_error": max(r.errors.values()) if r.errors else None}  # fmt: skip
    for name in names:
        size = next(r.params[name] for r in results.values() if name in r.params).numel()
        channels = "RGB" if size == 3 else [str(i) for i in range(size)]
        for c, channel in enumerate(channels):
            key = f"{name} {channel}"
            if name in truth:
                t = float(truth[name].reshape(-1)[c])
                errs = {lab: float(r.params[name].reshape(-1)[c]) / t - 1 if name in r.params else None for lab, r in results.items()}
                data["errors"][key] = errs
                cells = ["" if e is None else f"{100 * e:+.2f}%" for e in errs.values()]
                rows.append(f"| {key} | {t:.4f} | " + " | ".join(cells) + " |")
            else:
                vals = {lab: float(r.params[name].reshape(-1)[c]) if name in r.params else None for lab, r in results.items()}
                data["recovered"][key] = vals
                cells = ["" if v is None else f"= {v:.4f}" for v in vals.values()]
                rows.append(f"| {key} | - | " + " | ".join(cells) + " |")
    worst = [data["variants"][lab]["max_relative_error"] for lab in labels]
    rows.append("| largest error | | " + " | ".join("" if w is None else f"{100 * w:.2f}%" for w in worst) + " |")
    head = "| parameter | truth | " + " | ".join(labels) + " |\n|---|---|" + "---|" * len(labels)
    return head + "\n" + "\n".join(rows) + "\n", data


def plot_history(result: FitResult, path) -> None:
    """A PNG with the loss per step and, when the truth is known, each parameter's relative error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [h["step"] for h in result.history]
    panels = 2 if result.truth else 1
    fig, axes = plt.subplots(1, panels, figsize=(5.5 * panels, 4), squeeze=False)
    ax = axes[0][0]
    ax.semilogy(steps, [h["loss"] for h in result.history], color="black", lw=1)
    _mark_spp(axes[0], result.history)
    ax.set_xlabel("step")
    ax.set_ylabel(f"{result.settings.loss} loss")
    ax.set_title("loss")
    ax.grid(alpha=0.3)
    if result.truth:
        ax = axes[0][1]
        for name in result.truth:
            ax.semilogy(steps, [max(h["errors"][name], 1e-6) for h in result.history], lw=1, label=name)
        ax.axhline(0.02, color="grey", ls="--", lw=0.8, label="2%")
        ax.set_xlabel("step")
        ax.set_ylabel("max relative error over channels")
        ax.set_title("parameter error")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def plot_correlation(result: FitResult, path) -> bool:
    """A PNG of the last round's correlation matrix of the parameter channels (least-squares
    fits; a channel per parameter and colour, per texel for textures). Returns whether there was
    one to plot (Adam fits have none)."""
    last = result.history[-1] if result.history else {}
    if "correlation" not in last:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels, matrix = last["correlation"]["channels"], last["correlation"]["matrix"]
    size = min(4 + 0.22 * len(labels), 16)
    fig, ax = plt.subplots(figsize=(size + 1.2, size))
    image = ax.imshow(matrix, cmap="RdBu_r", vmin=-1, vmax=1, interpolation="nearest")
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04, label="correlation")
    font = 7 if len(labels) <= 36 else 4
    ax.set_xticks(range(len(labels)), labels, rotation=90, fontsize=font)
    ax.set_yticks(range(len(labels)), labels, fontsize=font)
    ax.set_title(f"parameter correlations at {last['spp']} spp (round {last['step']})")
    fig.tight_layout()
    save_figure(fig, path)
    return True


def _mark_spp(axes, history: list[dict]) -> None:
    """A dotted vertical line and a label at every step where the samples per pixel change."""
    previous = None
    for h in history:
        if h["spp"] != previous:
            for ax in axes:
                ax.axvline(h["step"], color="grey", ls=":", lw=0.8)
            axes[0].annotate(f"{h['spp']} spp", (h["step"], 1), xycoords=("data", "axes fraction"), xytext=(2, -10), textcoords="offset points", fontsize=7, color="grey")
            previous = h["spp"]
