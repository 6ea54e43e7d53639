"""Outputs of a strength reduction: ``fs.json``, the plot of the maximum displacement
against the trial factor and the mechanism (points at the bracket's lower end)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from fem_rmpm.io.output import to_true_frame, write_json, write_particles
from fem_rmpm.io.plots import _plt, plot_field
from fem_rmpm.scene import Scene

#: The result of a search (:class:`fem_rmpm.schemes.implicit.strength_reduction.FSResult`;
#: not imported: that module imports this one).
FSResult = Any

__all__ = ["write_outputs", "plot_displacement", "plot_mechanism"]


def write_outputs(res: FSResult, scene: Scene, out: str | Path) -> None:
    """``fs.json``, ``fs_displacement.png`` (max displacement against F), and the
    mechanism: ``mechanism.vtu`` (points at the largest converged F) with
    ``mechanism.png``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    d = res.to_dict()
    d["scene"] = scene.scene.name
    if res.mechanism is not None:
        d["mechanism_F"] = res.bracket[0] if res.bound != ">" else res.options.f_max
        write_particles(out / "mechanism.vtu", res.mechanism)
        plot_mechanism(out / "mechanism.png", res, scene)
    write_json(out / "fs.json", d)
    plot_displacement(out / "fs_displacement.png", res, scene.scene.name)


def plot_displacement(path: Path, res: FSResult, name: str = "") -> None:
    """Maximum displacement (log scale) against the trial F; failed trials hollow, at the
    displacement of their last converged load step, labelled with the gravity fraction
    reached."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ok = sorted((t for t in res.trials if t.converged), key=lambda t: t.F)
    bad = [t for t in res.trials if not t.converged]
    if ok:
        ax.plot([t.F for t in ok], [t.max_displacement for t in ok], "o-", color="tab:blue",
                label="converged at full gravity")
    if bad:
        ax.plot([t.F for t in bad], [max(t.max_displacement, 1e-12) for t in bad], "o",
                mfc="none", color="tab:red", label="failed (at the last converged load step)")
        for t in bad:
            ax.annotate(f"{t.load_factor:.2g} g", (t.F, max(t.max_displacement, 1e-12)),
                        textcoords="offset points", xytext=(5, -10), fontsize=7,
                        color="tab:red")
    if res.bound == "=":
        ax.axvline(res.fs, color="k", ls="--", lw=1, label=res.text)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("trial factor F (strengths divided by F)")
    ax.set_ylabel("max displacement (m)")
    ax.set_title(f"{name}: strength reduction, {res.text} ({res.static_solves} static solves)",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_mechanism(path: Path, res: FSResult, scene: Scene) -> None:
    """Displacement magnitude of the last converged state just below FS (true frame)."""
    plt = _plt()
    p = res.mechanism
    X = to_true_frame(p.x0, scene.scene.frame_angle_deg)
    u = np.sqrt(np.sum(p.u_geostatic ** 2, axis=1))
    span = np.ptp(X, axis=0)
    fig, ax = plt.subplots(figsize=(10, 1.5 + 8 * span[1] / max(span[0], 1e-9)))
    sc = plot_field(ax, X, u, float(np.max(res.grid.cell)) / 2, 0.0, float(u.max()),
                    cmap="turbo")
    ax.set_aspect("equal")
    ax.set_xlabel("X, true horizontal (m)")
    ax.set_ylabel("Y (m)")
    ax.set_title(f"{scene.scene.name}: mechanism, |u| at F = {res.bracket[0]:.4g} "
                 f"(just below {res.text})", fontsize=10)
    fig.colorbar(sc, ax=ax, label="displacement (m)", shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
