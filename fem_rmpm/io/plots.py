"""PNG figures of a run (matplotlib, Agg backend), drawn in the true frame."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fem_rmpm.io.output import to_true_frame

__all__ = ["plot_snapshots", "plot_profile", "plot_energy", "plot_field", "draw_ground",
           "draw_water", "strain_norm", "strain_panel", "STRAIN_FLOOR"]

#: Lower end of the logarithmic plastic-strain colour scale: points below it (elastic or
#: barely yielded) take the lowest colour.
STRAIN_FLOOR = 1e-3


def strain_norm(vmax: float):
    """Logarithmic colour scale of plastic shear strain from :data:`STRAIN_FLOOR` to
    ``vmax`` (at least 10x the floor): shows the whole range, from first yield to the
    large strains of run-out, instead of saturating at 1."""
    from matplotlib.colors import LogNorm  # lazy, as _plt: matplotlib only for figures
    return LogNorm(vmin=STRAIN_FLOOR, vmax=max(float(vmax), 10 * STRAIN_FLOOR))


def draw_ground(ax, scene) -> None:
    """Bedrock (grey, hatched) and the initial soil surface (dashed) in the true frame."""
    a = scene.scene.frame_angle_deg
    for k, rock in enumerate(scene.bedrock):
        P = to_true_frame(np.asarray(rock.polygon, float), a)
        ax.fill(P[:, 0], P[:, 1], facecolor="0.85", edgecolor="0.4", hatch="//", lw=0.8,
                zorder=0, label="bedrock" if k == 0 else None)
    for k, soil in enumerate(scene.soils):
        P = to_true_frame(np.vstack([soil.polygon, soil.polygon[:1]]), a)
        ax.plot(P[:, 0], P[:, 1], "k--", lw=0.7, zorder=3,
                label="initial soil" if k == 0 else None)
    draw_water(ax, scene)


def draw_water(ax, scene) -> None:
    """The phreatic surface (blue, true frame) over the soils' horizontal extent; no-op
    without ``[water]``."""
    w = getattr(scene, "water", None)
    if w is None:
        return
    a = scene.scene.frame_angle_deg
    soil = to_true_frame(np.vstack([so.polygon for so in scene.soils]).astype(float), a)
    line = to_true_frame(np.asarray(w.phreatic_surface, float), a)
    X = np.linspace(soil[:, 0].min(), soil[:, 0].max(), 400)
    X = np.union1d(X, line[(line[:, 0] > X[0]) & (line[:, 0] < X[-1]), 0])
    Y = np.interp(X, line[:, 0], line[:, 1])
    ends = (X < line[0, 0]) | (X > line[-1, 0])       # the end segments continued
    if ends.any():
        k = np.clip(np.searchsorted(line[:, 0], X, side="right") - 1, 0, len(line) - 2)
        slope = (line[k + 1, 1] - line[k, 1]) / (line[k + 1, 0] - line[k, 0])
        Y = np.where(ends, line[k, 1] + slope * (X - line[k, 0]), Y)
    ax.plot(X, Y, color="tab:blue", lw=1.2, zorder=4,
            label=f"phreatic surface ({w.pore_pressure})")


def strain_panel(ax, X: np.ndarray, strain: np.ndarray, spacing: float, norm,
                 allX: np.ndarray, title: str, scene=None):
    """One panel of plastic shear strain: points X (n, 2, true frame, m) coloured on the
    shared logarithmic ``norm``, equal aspect, limits 1 m beyond ``allX`` (every panel's
    points), the ground if ``scene`` is given; returns the scatter (for a colour bar)."""
    if scene is not None:
        draw_ground(ax, scene)
    sc = plot_field(ax, X, np.maximum(strain, STRAIN_FLOOR), spacing, cmap="turbo")
    sc.set_norm(norm)
    ax.set_aspect("equal")
    ax.set_xlim(allX[:, 0].min() - 1, allX[:, 0].max() + 1)
    ax.set_ylim(allX[:, 1].min() - 1, allX[:, 1].max() + 1)
    ax.set_ylabel("Y (m)")
    ax.set_title(title, fontsize=9, loc="left")
    return sc


def _plt():
    # lazy: matplotlib (~0.5 s to import) only when a figure is drawn; Agg before pyplot
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: as matplotlib, after choosing the backend
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
                   vmax: float | None = None, title: str = "", scene=None,
                   mechanism_time: float | None = None) -> None:
    """One panel per snapshot (t, x (n, 2) grid frame, value (n,)), one logarithmic colour
    scale (:func:`strain_norm`); with ``scene`` the bedrock and the initial soil are drawn;
    the snapshot nearest ``mechanism_time`` (s) is marked as such."""
    plt = _plt()
    n = len(snapshots)
    allX = np.vstack([to_true_frame(x, frame_angle_deg) for _, x, _ in snapshots])
    if vmax is None:
        vmax = float(np.max([v.max() for *_, v in snapshots]))
    norm = strain_norm(vmax)
    times = np.array([t for t, *_ in snapshots])
    mech = int(np.argmin(np.abs(times - mechanism_time))) if mechanism_time is not None else -1
    fig, axes = plt.subplots(n, 1, figsize=(11, 1.0 + 2.1 * n), squeeze=False, sharex=True)
    for k, (ax, (t, x, v)) in enumerate(zip(axes[:, 0], snapshots)):
        sc = strain_panel(ax, to_true_frame(x, frame_angle_deg), v, spacing, norm, allX,
                          f"t = {t:.2f} s" + (" (mechanism time)" if k == mech else "")
                          + (" (final)" if k == n - 1 and n > 1 else ""), scene)
    if scene is not None and scene.bedrock:
        axes[0, 0].legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("X, true horizontal (m)")
    fig.colorbar(sc, ax=axes[:, 0].tolist(), label=label + ", log scale", shrink=0.8)
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_profile(path: str | Path, initial: list, final: list, title: str = "",
                 scene=None) -> None:
    """Initial and final surface profiles (true frame), over the bedrock if ``scene``."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(11, 3.2))
    if scene is not None:
        a = scene.scene.frame_angle_deg
        for k, rock in enumerate(scene.bedrock):
            P = to_true_frame(np.asarray(rock.polygon, float), a)
            ax.fill(P[:, 0], P[:, 1], facecolor="0.85", edgecolor="0.4", hatch="//", lw=0.8,
                    zorder=0, label="bedrock" if k == 0 else None)
        draw_water(ax, scene)
    for prof, lab, st in ((initial, "initial surface", "k--"), (final, "final surface", "r-")):
        if prof:
            a = np.array(prof)
            ax.plot(a[:, 0], a[:, 1], st, label=lab)
    ax.set_xlabel("X, true horizontal (m)")
    ax.set_ylabel("Y (m)")
    ax.set_aspect("equal")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_energy(path: str | Path, kinetic: list, friction: list, title: str = "") -> None:
    """Kinetic energy [(t, kJ/m)] and the frictional dissipation so far [(t, kJ/m)] of a
    run with frictional bedrock, against time."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for rows, lab, st in ((kinetic, "kinetic energy (grid)", "k-"),
                          (friction, "dissipated by basal friction (cumulative)", "r-")):
        if rows:
            a = np.array(rows, float)
            ax.plot(a[:, 0], a[:, 1], st, label=lab)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("energy (kJ per m)")
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
