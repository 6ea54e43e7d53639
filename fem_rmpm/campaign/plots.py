"""Figures of a Monte Carlo campaign (matplotlib, Agg backend), one PNG each.

* ``exceedance.png`` — empirical exceedance curves P[X > x] = (number of ``ok``
  realizations with X > x) / N of the headline measures (:mod:`fem_rmpm.measures.table`:
  run-out, retrogression, sliding area), one curve per case (a deterministic case is a
  vertical dashed line);
* ``histograms.png`` — their histograms (shared bins per measure), and those of the
  measures of the mechanism when recorded (slip-surface height, intact blocks, sliding
  area at the mechanism time: the literature's distinctions between the cases);
* ``convergence.png`` — the running P(failure) against N with the Wilson 95 %
  band, and the running mean run-out with mean +- 1.96 SE (SE = s / sqrt(N));
* ``cases.png`` — the final plastic shear strain of one kept realization per
  case (the first kept ``ok`` realization with VTK), side by side, true frame,
  one logarithmic colour scale from 1e-3 to the largest strain, over the bedrock
  and the initial soil outline; ``cases_mechanism.png`` the same at the
  mechanism time.
"""
from __future__ import annotations

import math
from pathlib import Path

import meshio
import numpy as np

from fem_rmpm.io.output import read_pvd, to_true_frame
from fem_rmpm.io.plots import _plt, strain_norm, strain_panel
from fem_rmpm.measures import table

__all__ = ["campaign_figures", "plot_exceedance", "plot_histograms", "plot_convergence",
           "plot_cases", "final_snapshot"]

def _values(records, case: str, key: str) -> np.ndarray:
    return np.array([float(r["measures"][key]) for r in records
                     if r["case"] == case and r["status"] == "ok"
                     and (r["measures"] or {}).get(key) is not None])


def plot_exceedance(path: Path, cases, records) -> Path:
    plt = _plt()
    keys = table.headline()
    fig, axes = plt.subplots(1, len(keys), figsize=(13 * len(keys) / 3, 3.8), squeeze=False)
    axes = axes[0]
    for ax, key in zip(axes, keys):
        for k, c in enumerate(cases):
            x = np.sort(_values(records, c.name, key))
            if len(x) == 0:
                continue
            col = f"C{k}"
            if c.deterministic:
                ax.axvline(x[0], color=col, ls="--", label=f"{c.label}")
                continue
            n = len(x)
            p = 1.0 - np.arange(1, n + 1) / n            # P[X > x_(i)]
            ax.step(np.r_[x[0], x], np.r_[1.0, p], where="post", color=col,
                    ls=_STYLES[k % len(_STYLES)][1], label=f"{c.label} (N = {n})")
        ax.set_xlabel(table.axis_label(key))
        ax.set_ylabel("P[X > x] (-)")
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Exceedance probability (empirical, over the realizations run to rest)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_histograms(path: Path, cases, records) -> Path:
    plt = _plt()
    from matplotlib.ticker import MaxNLocator  # lazy, as _plt: matplotlib only for figures
    ok = [r for r in records if r["status"] == "ok"]
    panels = table.headline() + [k for k in table.mechanism()
                                 if ok and all((r["measures"] or {}).get(k) is not None
                                               for r in ok)]
    rows = (len(panels) + 2) // 3
    fig, axes = plt.subplots(rows, 3, figsize=(13, 0.6 + 3.3 * rows), squeeze=False)
    axes = axes.ravel()
    for ax in axes[len(panels):]:
        ax.set_visible(False)
    for ax, key in zip(axes, panels):
        allv = np.concatenate([_values(records, c.name, key) for c in cases] or [np.zeros(0)])
        if len(allv) == 0:
            continue
        lo, hi = float(allv.min()), float(allv.max())
        if table.MEASURES[key].kind == "count":       # one bin per integer
            bins = np.arange(lo - 0.5, hi + 1.5)
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        else:
            bins = np.linspace(lo, hi if hi > lo else lo + 1.0, 16)
        for k, c in enumerate(cases):
            v = _values(records, c.name, key)
            if len(v) == 0:
                continue
            if c.deterministic:
                ax.axvline(v[0], color=f"C{k}", ls="--", label=c.label)
            else:
                ax.hist(v, bins=bins, histtype="step", lw=1.6, color=f"C{k}",
                        label=f"{c.label} (N = {len(v)})")
        ax.set_xlabel(table.axis_label(key))
        ax.set_ylabel("realizations (count)")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _wilson(k, n, z=1.959963984540054):
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return np.clip(mid - half, 0, 1), np.clip(mid + half, 0, 1)


_STYLES = (("o", "-"), ("s", "--"), ("^", "-."), ("D", ":"), ("v", "-"), ("P", "--"))


def plot_convergence(path: Path, cases, stats, runouts: dict) -> Path:
    """``runouts``: case -> run-out of the ok realizations in index order.  Each case has
    its own marker and line style and is shifted by a few hundredths of a realization
    so that equal curves (e.g. every case at P = 1) stay visible; N axis in integers."""
    plt = _plt()
    from matplotlib.ticker import MaxNLocator  # lazy, as _plt: matplotlib only for figures
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 3.8))
    shown = [c for c in cases if stats[c.name].get("convergence") and not c.deterministic]
    for k, c in enumerate(cases):
        if c not in shown:
            continue
        conv = stats[c.name]["convergence"]
        j = shown.index(c)
        dx = 0.06 * (j - (len(shown) - 1) / 2)
        n = np.array(conv["n"], dtype=float)
        p = np.array(conv["p_failure"])
        lo, hi = _wilson(np.round(p * n), n)
        col, (mk, ls) = f"C{k}", _STYLES[j % len(_STYLES)]
        a1.plot(n + dx, p, marker=mk, ls=ls, ms=5, mfc="none", color=col, label=c.label)
        a1.fill_between(n + dx, lo, hi, color=col, alpha=0.10, lw=0)
        a1.plot(n + dx, lo, ls=ls, lw=0.7, color=col)
        m = np.array(conv["mean_runout"])
        nm = np.array(conv.get("n_measure", conv["n"]), dtype=float)   # runs to rest
        a2.plot(nm + dx, m, marker=mk, ls=ls, ms=5, mfc="none", color=col, label=c.label)
        ro = np.array(runouts.get(c.name, []))
        if len(ro) == len(nm) and len(ro) > 1:   # running SE of the mean (ddof 1)
            se = np.array([np.std(ro[:i], ddof=1) / math.sqrt(i) if i > 1 else np.nan
                           for i in range(1, len(ro) + 1)])
            a2.fill_between(nm + dx, m - 1.96 * se, m + 1.96 * se, color=col, alpha=0.10, lw=0)
            a2.plot(nm + dx, m - 1.96 * se, ls=ls, lw=0.7, color=col)
            a2.plot(nm + dx, m + 1.96 * se, ls=ls, lw=0.7, color=col)
    a1.set_xlabel("realizations N (count)")
    a1.set_ylabel("P(failure) (-)")
    a1.set_ylim(-0.02, 1.05)
    a1.set_title("P(failure); band and thin line: Wilson 95 % lower bound", fontsize=10)
    a2.set_xlabel("realizations run to rest, n (count)")
    a2.set_ylabel(f"mean {table.axis_label('runout_distance')}")
    a2.set_title("mean run-out; band: +- 1.96 SE", fontsize=10)
    for a in (a1, a2):
        a.xaxis.set_major_locator(MaxNLocator(integer=True))
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def snapshot_at(vtk_dir: Path, time: float | None = None):
    """(points (n, 2) grid frame, plastic shear strain (n,), time) of the entry of
    ``vtk_dir/particles.pvd`` (our own PvdSeries file) nearest to ``time`` (None: the
    last), or None."""
    series = read_pvd(Path(vtk_dir) / "particles.pvd")
    if not series:
        return None
    times = np.array([t for t, _ in series])
    t, vtu = series[-1] if time is None else series[int(np.argmin(np.abs(times - time)))]
    mesh = meshio.read(vtu)
    return (np.asarray(mesh.points[:, :2]), np.asarray(mesh.point_data["plastic_shear_strain"]),
            t)


def final_snapshot(vtk_dir: Path):
    """The last snapshot of a kept realization (see :func:`snapshot_at`)."""
    return snapshot_at(vtk_dir, None)


def plot_cases(path: Path, panels, frame_angle_deg: float, spacing: float,
               title: str = "Final state of one realization per case", scene=None) -> Path:
    """``panels``: list of (title, x (n, 2) grid frame, plastic shear strain (n,)); one
    logarithmic colour scale; with ``scene`` the bedrock and initial soil are drawn."""
    plt = _plt()
    Xs = [to_true_frame(x, frame_angle_deg) for _, x, _ in panels]
    allX = np.vstack(Xs)
    span = np.ptp(allX, axis=0) + 2.0
    h = min(4.0, max(1.2, 9.5 * span[1] / span[0]))       # panel height for equal aspect
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 0.8 + (h + 0.45) * len(panels)),
                             squeeze=False, sharex=True, layout="constrained")
    sc = None
    norm = strain_norm(max(float(v.max()) for _, _, v in panels))
    for ax, (label, _, v), X in zip(axes[:, 0], panels, Xs):
        sc = strain_panel(ax, X, v, spacing, norm, allX, label, scene)
    axes[-1, 0].set_xlabel("X, true horizontal (m)")
    if scene is not None and scene.bedrock:
        axes[0, 0].legend(fontsize=7, loc="upper right")
    fig.colorbar(sc, ax=axes[:, 0].tolist(), label="plastic shear strain (-), log scale",
                 shrink=0.9)
    fig.suptitle(title, fontsize=11)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def campaign_figures(out: Path, cases, stats, records, layout, scene) -> list[Path]:
    """All figures of a campaign into ``out``; returns their paths."""
    out = Path(out)
    figs = [plot_exceedance(out / "exceedance.png", cases, records),
            plot_histograms(out / "histograms.png", cases, records)]
    runouts = {}
    for c in cases:
        ok = sorted((r for r in records if r["case"] == c.name and r["status"] == "ok"),
                    key=lambda r: r["index"])
        runouts[c.name] = [float(r["measures"]["runout_distance"]) for r in ok]
    if any(not c.deterministic and stats[c.name].get("convergence") for c in cases):
        figs.append(plot_convergence(out / "convergence.png", cases, stats, runouts))
    mech_t = next((float(r["measures"].get("mechanism_time") or 3.0) for r in records
                   if r.get("measures")), 3.0)
    for name, when, title in (
            ("cases.png", None, "Final state of one realization per case"),
            ("cases_mechanism.png", mech_t, f"One realization per case at t = {mech_t:g} s: "
             "how the mass breaks up")):
        panels = []
        for c in cases:
            ok = sorted((r for r in records if r["case"] == c.name and r["status"] == "ok"
                         and r.get("vtk")), key=lambda r: r["index"])
            for r in ok:
                snap = snapshot_at(out / r["vtk"], when)
                if snap is None:
                    continue
                x, g, t = snap
                m = r["measures"]
                who = "" if c.deterministic else f" #{r['index']} (seed {r['seed']})"
                what = (", ".join(table.value_text(k, m[k], ".1f") for k in table.headline())
                        if when is None else table.value_text("intact_blocks",
                                                              m.get("intact_blocks"), "d"))
                panels.append((f"{c.label}{who}, t = {t:.1f} s: {what}", x, g))
                break
        if panels:
            spacing = float(min(scene.grid.cell)) / 2
            figs.append(plot_cases(out / name, panels, scene.scene.frame_angle_deg, spacing,
                                   title, scene=scene))
    return figs

