"""PNG figures of a run (matplotlib, Agg backend), drawn in the true frame."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .output import to_true_frame

__all__ = ["plot_snapshots", "plot_profile", "plot_field"]


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_field(ax, X: np.ndarray, values: np.ndarray, size: float, vmin=None, vmax=None,
               cmap="viridis"):
    """Scatter points coloured by ``values`` (square markers of about the point spacing)."""
    fig = ax.figure
    w_in = fig.get_size_inches()[0] * ax.get_position().width
    span = max(np.ptp(X[:, 0]), 1e-9)
    s = max((size / span * w_in * 72) ** 2, 0.5)
    return ax.scatter(X[:, 0], X[:, 1], c=values, s=s, marker="s", linewidths=0,
                      vmin=vmin, vmax=vmax, cmap=cmap)


def plot_snapshots(path: str | Path, snapshots: list[tuple[float, np.ndarray, np.ndarray]],
                   frame_angle_deg: float, spacing: float, label: str = "plastic shear strain (-)",
                   vmax: float | None = None, title: str = "") -> None:
    """One panel per snapshot (t, x (n, 2) grid frame, value (n,)), shared colour scale."""
    plt = _plt()
    n = len(snapshots)
    allX = np.vstack([to_true_frame(x, frame_angle_deg) for _, x, _ in snapshots])
    if vmax is None:   # the literature's contour range: localised bands stand out at ~1
        vmax = min(1.0, max(float(np.max([v.max() for *_, v in snapshots])), 1e-9))
    fig, axes = plt.subplots(n, 1, figsize=(11, 1.0 + 2.1 * n), squeeze=False, sharex=True)
    for ax, (t, x, v) in zip(axes[:, 0], snapshots):
        X = to_true_frame(x, frame_angle_deg)
        sc = plot_field(ax, X, v, spacing, 0.0, vmax, cmap="turbo")
        ax.set_aspect("equal")
        ax.set_xlim(allX[:, 0].min() - 1, allX[:, 0].max() + 1)
        ax.set_ylim(allX[:, 1].min() - 1, allX[:, 1].max() + 1)
        ax.set_ylabel("Y (m)")
        ax.set_title(f"t = {t:.2f} s", fontsize=9, loc="left")
    axes[-1, 0].set_xlabel("X, true horizontal (m)")
    fig.colorbar(sc, ax=axes[:, 0].tolist(), label=label, shrink=0.8, extend="max")
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_profile(path: str | Path, initial: list, final: list, title: str = "") -> None:
    """Initial and final surface profiles (true frame)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(11, 3.2))
    for prof, lab, st in ((initial, "initial surface", "k--"), (final, "final surface", "r-")):
        if prof:
            a = np.array(prof)
            ax.plot(a[:, 0], a[:, 1], st, label=lab)
    ax.set_xlabel("X, true horizontal (m)")
    ax.set_ylabel("Y (m)")
    ax.set_aspect("equal")
    ax.legend()
    if title:
        ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
