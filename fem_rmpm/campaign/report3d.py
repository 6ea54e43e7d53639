"""The three-dimensional part of a campaign's figures and report.

For a campaign of a 3-D scene (records with ``dimension = 3``) the campaign writes, in
``views3d/`` of its directory:

* ``strike_distributions.png``: per case, the distributions over the realizations run to
  rest of the sliding volume (m3), the number of separate slides along the strike, and
  of every slide's strike length (m) and volume (m3) (the slides of
  :mod:`fem_rmpm.measures.deposit3d`);
* ``plan_view.png``: the plan (x along the slope, z along the strike, the grid frame) of
  a representative realization that kept its VTK (the kept failed realization of median
  sliding volume, else the kept realization of median run-out): each material point at
  its initial plan position, coloured by its displacement at the end of the run, with
  the sliding points (displacement above the failure displacement) marked; the slides'
  strike ranges are drawn at the side;
* ``render_3d.png``: an off-screen PyVista render of the same realization's points at the
  end of the run, coloured by displacement (when PyVista renders headless here; else the
  report says it could not and shows the plan view only).

The report (:mod:`.report`) gains a section "Three-dimensional views" with these figures
and, per case, the means of the measures along the strike
(:func:`fem_rmpm.measures.table.strike`); a plane-strain campaign's report is unchanged
(the section is empty).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from fem_rmpm.campaign.html_parts import esc, html_figure, html_table
from fem_rmpm.io.output import read_pvd
from fem_rmpm.measures import table

__all__ = ["VIEWS", "is_three_d_campaign", "figures_3d", "report_3d", "representative_3d",
           "render_points_3d"]

#: The folder of the 3-D views in a campaign directory (apart from the campaign figures).
VIEWS = "views3d"


def _pyplot():
    """matplotlib's pyplot on the Agg backend."""
    import matplotlib  # lazy: figures only (the command line starts without matplotlib)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: figures only, after the backend
    return plt


def is_three_d_campaign(records: Sequence[dict]) -> bool:
    """True when a record of the campaign is of a 3-D run."""
    return any(r.get("dimension") == 3 for r in records)


def _ok(records: Sequence[dict]) -> list[dict]:
    return [r for r in records if r.get("status") == "ok" and r.get("dimension") == 3
            and r.get("slides") is not None and r.get("measures")]


def _by_case(records: Sequence[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in records:
        out.setdefault(str(r.get("case")), []).append(r)
    return out


def plot_strike_distributions(path: Path, records: Sequence[dict]) -> Path | None:
    """``strike_distributions.png`` (module docstring); None without a 3-D run to rest."""
    cases = _by_case(_ok(records))
    if not cases:
        return None
    panels = [("sliding_volume", table.axis_label("sliding_volume")),
              ("slide_count", table.axis_label("slide_count")),
              ("slide_length", "strike length of each slide (m)"),
              ("slide_volume", "volume of each slide (m3)")]
    plt = _pyplot()
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.6))
    for (key, xlabel), ax in zip(panels, axes):
        for case, recs in cases.items():
            if key == "slide_length":
                v = [s[1] - s[0] for r in recs for s in r["slides"]]
            elif key == "slide_volume":
                v = [s[2] for r in recs for s in r["slides"]]
            else:
                v = [r["measures"].get(key) for r in recs]
                v = [x for x in v if x is not None]
            if not v:
                continue
            if key == "slide_count":
                bins = np.arange(-0.5, max(v) + 1.5)
            else:
                bins = max(5, min(20, int(math.sqrt(len(v))) + 2))
            ax.hist(v, bins=bins, alpha=0.6, label=f"{case} ({len(v)})")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("count")
    axes[0].legend(fontsize=8)
    fig.suptitle("Along the strike: sliding volume and slides per realization run to rest "
                 "(legend: values in each histogram)", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def representative_3d(campaign: Path, records: Sequence[dict]) -> dict | None:
    """The kept (VTK) 3-D realization the views show (module docstring), or None."""
    kept = [r for r in _ok(records) if r.get("vtk") and (campaign / r["vtk"]).is_dir()]
    if not kept:
        return None
    failed = [r for r in kept if r["measures"].get("failed")]
    pool, key = (failed, "sliding_volume") if failed else (kept, "runout_distance")
    pool.sort(key=lambda r: (float(r["measures"].get(key) or 0.0), r["index"]))
    return pool[(len(pool) - 1) // 2]


def _last_points(vtk_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(current positions (n, 3), displacements (n, 3)) of the last output of a kept run."""
    import meshio   # lazy: VTK reading only for the 3-D views
    series = read_pvd(vtk_dir / "particles.pvd")
    if not series:
        raise FileNotFoundError(f"{vtk_dir}: no particles.pvd series of particles_*.vtu")
    m = meshio.read(series[-1][1])
    return np.asarray(m.points, float), np.asarray(m.point_data["displacement"], float)


def _strike_cell(vtk_dir: Path) -> float | None:
    """The grid's strike cell hz (m) from the kept run's ``grid.vtu``, or None."""
    import meshio   # lazy: VTK reading only for the 3-D views
    try:
        z = np.unique(np.round(meshio.read(vtk_dir / "grid.vtu").points[:, 2], 9))
    except Exception:     # noqa: BLE001 - no grid file: the plan view bins by points
        return None
    return float(np.min(np.diff(z))) if len(z) > 1 else None


def plot_plan_view(path: Path, x: np.ndarray, u: np.ndarray, threshold: float,
                   slides: Sequence, title: str, hz: float | None = None) -> Path:
    """``plan_view.png``: points at their initial plan position (x, z) coloured by
    |displacement| (m), the crown of the sliding points (above ``threshold``, m: the
    most up-slope one of each strike slice of ``hz`` m, the grid's strike cell) as a
    line; the slides' strike ranges as bars beside the plan, with their volumes."""
    x0 = x - u
    d = np.linalg.norm(u, axis=1)
    order = np.argsort(d)
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 5))
    sc = ax.scatter(x0[order, 0], x0[order, 2], c=d[order], s=6, cmap="viridis",
                    vmin=0.0, vmax=max(float(d.max()), threshold))
    slid = d > threshold
    if slid.any():        # the crown: the most up-slope sliding point of each strike slice
        h = hz or max(float(np.ptp(x0[:, 2])) / 40.0, 1e-9)
        k = np.floor(x0[:, 2] / h).astype(np.int64)        # strike slice of each point
        ks = np.unique(k[slid])
        crown = [float(x0[slid & (k == j), 0].min()) for j in ks]
        ax.step(crown, (ks + 0.5) * h, where="mid", color="r", lw=1.5,
                label=f"crown: up-slope limit of sliding "
                f"(|u| > {threshold:g} m)")
    left = float(x0[:, 0].min()) - 0.03 * float(np.ptp(x0[:, 0]) or 1.0)
    for k, (z0, z1, vol) in enumerate(slides):
        ax.plot([left, left], [z0, z1], lw=5, color="k", solid_capstyle="butt",
                label="slides along the strike" if k == 0 else None)
        ax.text(left, 0.5 * (z0 + z1), f"{vol:.3g} m3 ", va="center", ha="right",
                fontsize=7, rotation=90)
    if slid.any() or len(slides):
        ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    fig.colorbar(sc, ax=ax, label="displacement at the end (m)")
    ax.set_xlabel("x, along the slope (grid frame, m)")
    ax.set_ylabel("z, along the strike (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title.replace(": ", ":\n", 1), fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def render_points_3d(path: Path, x: np.ndarray, u: np.ndarray, title: str) -> Path | None:
    """``render_3d.png``: an off-screen PyVista render of the points ``x`` (n, 3, m)
    coloured by |u| (m); None when PyVista cannot render off screen here."""
    try:
        import pyvista as pv   # lazy and optional: the render only
        from vtkmodules.vtkCommonCore import vtkLogger   # lazy: with pyvista
        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)   # no X server: no display
        pv.OFF_SCREEN = True
        cloud = pv.PolyData(np.asarray(x, float))
        cloud["displacement (m)"] = np.linalg.norm(u, axis=1)
        p = pv.Plotter(off_screen=True, window_size=(1000, 600))
        p.add_mesh(cloud, scalars="displacement (m)", point_size=4,
                   render_points_as_spheres=True, cmap="viridis")
        p.add_text(title, font_size=9)
        p.camera_position = "iso"
        p.camera.up = (0.0, 1.0, 0.0)
        p.show_axes()
        path.parent.mkdir(parents=True, exist_ok=True)
        p.screenshot(str(path))
        p.close()
    except Exception:      # noqa: BLE001 - no headless OpenGL: the plan view stands alone
        return None
    return path if path.is_file() else None


def figures_3d(campaign: Path, records: Sequence[dict], threshold: float) -> list[Path]:
    """The 3-D views of a campaign (module docstring) in ``campaign/views3d``;
    ``threshold`` the failure displacement (m).  Nothing for a plane-strain campaign."""
    if not is_three_d_campaign(records):
        return []
    views = Path(campaign) / VIEWS
    out = [p for p in [plot_strike_distributions(views / "strike_distributions.png",
                                                 records)] if p is not None]
    rep = representative_3d(Path(campaign), records)
    if rep is None:
        return out
    x, u = _last_points(Path(campaign) / rep["vtk"])
    who = (f"case {rep['case']}, realization {rep['index']} (seed {rep['seed']}): "
           f"{table.value_text('sliding_volume', rep['measures'].get('sliding_volume'), '.1f')}"
           f", {len(rep['slides'])} slide(s)")
    out.append(plot_plan_view(views / "plan_view.png", x, u, threshold, rep["slides"], who,
                              _strike_cell(Path(campaign) / rep["vtk"])))
    render = render_points_3d(views / "render_3d.png", x, u, who)
    if render is not None:
        out.append(render)
    (views / "representative.json").write_text(json.dumps(
        {"case": rep["case"], "index": rep["index"], "seed": rep["seed"], "vtk": rep["vtk"],
         "render": render is not None}))
    return out


def _means(recs: list[dict]) -> list[str]:
    cells = []
    for k in table.strike():
        v = [r["measures"].get(k) for r in recs if r["measures"].get(k) is not None]
        cells.append("–" if not v else f"{np.mean(v):.3g}")
    return cells


def report_3d(campaign: Path, records: Sequence[dict]) -> str:
    """The report's section "Three-dimensional views" (module docstring); "" for a
    plane-strain campaign."""
    if not is_three_d_campaign(records):
        return ""
    views = Path(campaign) / VIEWS
    cases = _by_case(_ok(records))
    header = ["case", "runs to rest (measures)"] + [table.axis_label(k) + " (mean)"
                                         for k in table.strike()]
    rows = [[esc(c), str(len(r))] + _means(r) for c, r in cases.items()]
    parts = ["<h2>Three-dimensional views</h2><p>Measures along the strike (slices one grid "
             "cell long; a slide is a run of slices each holding at least the failure area "
             "x the slice length of sliding volume), means over the realizations run to "
             "rest of the measure sample (index below runs_to_rest, as the measures "
             "above):</p>", html_table(header, rows)]
    rep_file = views / "representative.json"
    rep = json.loads(rep_file.read_text()) if rep_file.is_file() else None
    for name, caption in (
            ("strike_distributions.png", "Distributions along the strike: sliding volume, "
             "slide count, each slide's strike length and volume"),
            ("plan_view.png", "Plan view (x-z) of the sliding zones of the representative "
             "realization"),
            ("render_3d.png", "Off-screen PyVista render of the representative realization "
             "at the end of its run (colour: displacement)")):
        if (views / name).is_file():
            parts.append(html_figure(views / name, caption, name))
    if rep is None:
        parts.append("<p>No 3-D realization kept its VTK: no plan view or render "
                     "(use <code>--keep-vtk</code>).</p>")
    else:
        parts.append(f"<p>Representative realization: case {esc(rep['case'])}, realization "
                     f"{rep['index']} (seed {rep['seed']}), "
                     f'<a href="{esc(rep["vtk"])}/particles.pvd">particles.pvd</a>.'
                     + ("" if rep.get("render") else " PyVista could not render off "
                        "screen here: plan view only.") + "</p>")
    return "".join(parts)
