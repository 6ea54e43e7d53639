"""The figure of a subset-simulation campaign: each level's samples as an exceedance curve."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fem_rmpm.campaign.methods import MethodResult
from fem_rmpm.io.plots import _plt

__all__ = ["plot_levels"]


def _level_curve(lv, p_start: float, below: bool) -> tuple[np.ndarray, np.ndarray]:
    """(response values, P(exceedance)) of a level's samples: the k-th largest Y has
    P(Y >= y) = p_start k / N (the conditional samples scaled by the levels before)."""
    y = np.sort(lv.responses[np.isfinite(lv.responses)])[::-1]
    p = p_start * np.arange(1, len(y) + 1) / len(lv.responses)
    return (-y if below else y), p


def plot_levels(path: Path, result: MethodResult, response, title: str, unit: str = "") -> Path:
    """``subset_levels.png``: P(response > x) (P(FS < x)) from the samples of every level,
    the intermediate thresholds (dashed) and the failure threshold with the estimate."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8.0, 5.0), dpi=110)
    colors = plt.cm.viridis(np.linspace(0.0, 0.85, max(len(result.levels), 2)))
    p_start = 1.0
    for lv, color in zip(result.levels, colors):
        x, p = _level_curve(lv, p_start, response.below)
        ax.step(x, p, where="post", color=color, lw=1.6,
                label=f"level {lv.level}: {len(lv.responses)} samples"
                      + (f", acceptance {lv.acceptance:.2f}" if lv.acceptance is not None else ""))
        b = -lv.threshold if response.below else lv.threshold
        if lv is not result.levels[-1]:
            ax.axvline(b, color=color, ls="--", lw=0.9)
        p_start *= lv.conditional_probability
    ax.axvline(response.threshold, color="crimson", lw=1.4)
    ax.plot([response.threshold], [result.probability], "o", color="crimson", ms=7,
            label=f"P = {result.probability:.3g} (COV {result.cov:.2f}), {result.total_runs} runs")
    ax.set_yscale("log")
    ax.set_xlabel(response.name.replace("_", " ") + (f" ({unit})" if unit else ""))
    ax.set_ylabel(f"P({'FS < x' if response.below else 'response > x'})")
    ax.set_title(f"{title}: subset simulation of P({response.describe()})\n"
                 "dashed: intermediate thresholds; red: failure threshold", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="lower left" if response.below else "upper right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
