"""Random-field figures and VTU of ``fem-rmpm field``: the realization on the material
points, the variogram fit (matplotlib, Agg) and the points with the field value."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fem_rmpm.io.output import particle_fields, to_true_frame, write_points_vtu
from fem_rmpm.io.plots import _plt, plot_field
from fem_rmpm.random_field import FitResult

__all__ = ["plot_realization", "plot_variogram", "write_field_vtu"]


def plot_realization(path, scene, pts, values, mask, title, label="peak cohesion (kPa)"):
    plt = _plt()
    X = to_true_frame(pts.x0, scene.scene.frame_angle_deg)
    span = np.ptp(X, axis=0) + 1e-9
    fig, ax = plt.subplots(figsize=(11, float(np.clip(1.4 + 8.5 * span[1] / span[0], 2.5, 9.0))))
    # Gauss points are not evenly spaced: squares 1.3x the mean spacing leave no gaps
    spacing = 1.3 * float(np.min(pts.half_width)) * 2.0 if pts.half_width is not None else 0.1
    if (~mask).any():
        plot_field(ax, X[~mask], np.zeros((~mask).sum()), spacing, cmap="Greys", vmin=-1, vmax=4)
    sc = plot_field(ax, X[mask], values[mask], spacing, cmap="jet")
    ax.set_aspect("equal")
    ax.set_xlabel("X, true horizontal (m)")
    ax.set_ylabel("Y (m)")
    ax.set_title(title, fontsize=10)
    fig.colorbar(sc, ax=ax, label=label, shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_variogram(path, fit: FitResult, title: str):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    for h, g, th, lab, mk in ((fit.lags_x, fit.gamma_x, fit.theta_h, "x (horizontal)", "o"),
                              (fit.lags_y, fit.gamma_y, fit.theta_v, "y (vertical)", "s")):
        ax.plot(h, g, mk, ms=4, label=f"empirical along {lab}")
        hh = np.linspace(0, h.max(), 200)
        ax.plot(hh, fit.sill * -np.expm1(-2 * hh / th), "-", label=f"fit, theta = {th:.3g} m")
    ax.set_xscale("symlog", linthresh=max(min(fit.lags_y.min(), fit.lags_x.min()), 1e-3))
    ax.set_xlabel("lag (m)")
    ax.set_ylabel("semivariance" + (" of ln(value)" if fit.log else ""))
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_field_vtu(path: Path, pts, shown: np.ndarray) -> None:
    """The material points with the usual point data plus ``random_field`` (the field value,
    -1 where the field does not apply), written atomically."""
    fields = particle_fields(pts)
    fields["random_field"] = shown
    write_points_vtu(path, np.hstack([pts.x, np.zeros((pts.n, 1))]), fields)

