"""What a fit leaves behind for people: a JSON report and a PNG of loss and parameter error."""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from pathlib import Path

from invrender.inverse.fit import FitResult


def report_dict(result: FitResult, **extra) -> dict:
    """The fit as plain data: initial, recovered and (when known) true values with errors."""
    last = result.history[-1] if result.history else {}
    out = {
        "steps": len(result.history),
        "seconds": last.get("seconds", 0.0),
        "final_loss": last.get("loss"),
        "settings": dataclasses.asdict(result.settings),
        "initial": {k: v.tolist() for k, v in result.initial.items()},
        "recovered": {k: v.tolist() for k, v in result.params.items()},
    }
    if result.truth:
        out["truth"] = {k: v.tolist() for k, v in result.truth.items()}
        out["relative_error"] = result.errors
        out["max_relative_error"] = max(result.errors.values())
    out.update(extra)
    return out


def write_json(path, data: dict) -> None:
    """Atomically write ``data`` as indented JSON."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2)
            f.write("\n")
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".png", dir=path.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=110)
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        Path(tmp).unlink(missing_ok=True)
