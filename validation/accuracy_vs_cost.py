"""Accuracy against cost of the schemes: one PNG, error vs wall time, Pareto front.

    nice python validation/accuracy_vs_cost.py            # ~15 min on a shared 2-core machine
    python validation/accuracy_vs_cost.py --quick         # a subset, ~2 min

Two problems, each over mesh sizes and points per cell (ppc), for the explicit
scheme with the numba kernels and with the numpy reference step, uGIMP (numba
explicit), and the implicit scheme (:func:`fem_rmpm.schemes.implicit.run_implicit`, Q4 and
uGIMP):

* **Column compaction** (large deformation; Charlton et al.
  2017): ``meshes/compaction.toml``, l0 = 50 m, E = 10 kPa, nu = 0, rho0 g = 0.8
  kN/m3, one cell wide, 4 ... 64 cells over the height.  Closed form
  sigma_yy = -rho0 g (l0 - Y) at the initial height Y of each point, for any
  elastic law.  Error: sum_p |sigma_p - sigma_a| V_p / (rho0 g l0 V0).  Explicit:
  gravity ramped over 10 s with local damping 0.7 until at rest (dynamic
  relaxation to the static state); implicit: 50 quasi-static load steps.
* **Elastic slope** (``meshes/slope_elastic.toml``; small strain, geostatic
  phase to rest): reference = the static FEM (:func:`fem_rmpm.schemes.fem.solve_static`,
  Q4, scikit-fem) on a fine grid of 1/16 m cells, its stress evaluated at each
  material point (Q4 gradient of the FEM displacement in the fine cell holding
  the point; points whose fine cell is not soil, at the staircase edge, are left
  out and counted).  Error: volume-weighted relative L2 of the particle stress,
  sqrt(sum_p |sigma_p - sigma_ref|^2 V_p / sum_p |sigma_ref|^2 V_p), the
  measure of ``tests/test_explicit.py``.  Implicit: the geostatic phase in one
  load step (linear elastic: one Newton step is the FEM solution of that mesh).

Wall time: the run alone (not the seeding, not the FEM reference), measured
once per configuration after a warm-up of the numba kernels, so on a loaded
machine the times carry noise of tens of percent.  Writes
``validation/out/accuracy_vs_cost.png`` and ``.json`` (every number of the plot).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fem_rmpm.discretise.basis import q4_values  # noqa: E402
from fem_rmpm.discretise.grid import locate, make_grid  # noqa: E402
from fem_rmpm.discretise.points import seed_particles, soil_cells  # noqa: E402
from fem_rmpm.scene import load_scene, with_values  # noqa: E402
from fem_rmpm.schemes.explicit.loop import run_explicit  # noqa: E402
from fem_rmpm.schemes.fem import solve_static  # noqa: E402

OUT = ROOT / "validation" / "out"
L0, E_COL, GAMMA = 50.0, 10.0, 0.8


def _implicit():
    try:
        from fem_rmpm.schemes.implicit import run_implicit
        return run_implicit
    except ImportError:
        return None


# --------------------------------------------------------------------------- runs
def run_case(scene, scheme, kernel):
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    t0 = time.perf_counter()
    if scheme == "implicit":
        rec = _implicit()(scene, grid, pts)
    else:
        rec = run_explicit(scene, grid, pts, kernel=kernel)
    wall = time.perf_counter() - t0
    return grid, pts, rec, wall


def column_scene(cells, ppc, shape, scheme):
    h = L0 / cells
    ch = {"grid.size": [h, L0], "grid.cell": [h, h],
          "soil.polygon": [[0, 0], [h, 0], [h, L0], [0, L0]], "soil.points_per_cell_dir": ppc,
          "solver.shape": shape, "solver.scheme": scheme}
    if scheme == "explicit":
        ch.update({"solver.gravity_phase": "dynamic", "solver.damping": 0.7,
                   "solver.gravity_ramp_time": 10.0, "solver.t_end": 300.0,
                   "solver.rest_velocity": 1e-3, "solver.rest_energy_ratio": 1e-7,
                   "solver.output_interval": 1e6})
    else:
        ch.update({"solver.load_steps": 50})
    return with_values(load_scene(ROOT / "meshes" / "compaction.toml"), ch)


def column_error(pts):
    sigma_a = -GAMMA * (L0 - pts.x0[:, 1])
    return float(np.sum(np.abs(pts.stress[:, 1] - sigma_a) * pts.volume)
                 / (GAMMA * L0 * pts.volume0.sum()))


def slope_scene(cell, ppc, shape, scheme):
    ch = {"grid.cell": [cell, cell], "soil.points_per_cell_dir": ppc, "solver.shape": shape,
          "solver.scheme": scheme, "solver.output_interval": 1e6}
    if scheme == "implicit":
        ch.update({"solver.load_steps": 1, "solver.dynamic": False})
    return with_values(load_scene(ROOT / "meshes" / "slope_elastic.toml"), ch)


class SlopeReference:
    """Fine-grid static FEM; stress at any point of its soil cells (Q4 gradient)."""

    def __init__(self, cell):
        self.scene = with_values(load_scene(ROOT / "meshes" / "slope_elastic.toml"),
                                 {"grid.cell": [cell, cell]})
        t0 = time.perf_counter()
        self.fem = solve_static(self.scene)
        self.wall = time.perf_counter() - t0
        self.grid = self.fem.grid
        self.soil = soil_cells(self.scene, self.grid) >= 0
        s = self.scene.soils[0]
        nu, E = s.poisson_ratio, s.youngs_modulus
        self.lam, self.mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))

    def stress_at(self, x):
        cell, xi, inside = locate(self.grid, x)
        ok = inside & self.soil[cell]
        _, dN = q4_values(xi, self.grid.cell)
        u = self.fem.displacement[self.grid.cells[cell]]           # (n, 4, 2)
        G = np.einsum("pak,pal->pkl", u, dN)
        exx, eyy, exy = G[:, 0, 0], G[:, 1, 1], 0.5 * (G[:, 0, 1] + G[:, 1, 0])
        tr = exx + eyy
        sig = np.stack([self.lam * tr + 2 * self.mu * exx, self.lam * tr + 2 * self.mu * eyy,
                        self.lam * tr, 2 * self.mu * exy], axis=1)
        return sig, ok


def slope_error(pts, ref):
    sig, ok = ref.stress_at(pts.x0)
    V = pts.volume0[ok]
    d = pts.stress[ok] - sig[ok]
    err = float(np.sqrt(np.sum(np.sum(d * d, 1) * V) / np.sum(np.sum(sig[ok] ** 2, 1) * V)))
    return err, int((~ok).sum())


# --------------------------------------------------------------------------- Pareto
def pareto(rows, rtol=1e-3):
    """Indices of the rows not dominated in (wall time, error), sorted by time; a slower
    run joins the front only if its error is lower by more than ``rtol`` (relative)."""
    order = sorted(range(len(rows)), key=lambda i: (rows[i]["wall_s"], rows[i]["error"]))
    front, best = [], np.inf
    for i in order:
        if rows[i]["error"] < best * (1 - rtol):
            front.append(i)
            best = rows[i]["error"]
    return front


def configs(quick):
    """(problem, label, scheme, kernel, shape, size, ppc) for every run."""
    out = []
    col_cells = (4, 8, 16, 32) if quick else (4, 8, 16, 32, 64)
    slope_cells = (0.5, 0.25) if quick else (0.5, 0.25, 0.125)
    for c in col_cells:
        for ppc in ((2,) if quick else (1, 2, 3)):
            out.append(("column", "explicit numba Q4", "explicit", "numba", "standard", c, ppc))
        out.append(("column", "explicit numpy Q4", "explicit", "numpy", "standard", c, 2))
        out.append(("column", "explicit numba uGIMP", "explicit", "numba", "gimp", c, 2))
        out.append(("column", "implicit Q4", "implicit", None, "standard", c, 2))
        out.append(("column", "implicit uGIMP", "implicit", None, "gimp", c, 2))
    for h in slope_cells:
        for ppc in ((2,) if quick else (2, 3)):
            out.append(("slope", "explicit numba Q4", "explicit", "numba", "standard", h, ppc))
        if h >= 0.25:
            out.append(("slope", "explicit numpy Q4", "explicit", "numpy", "standard", h, 2))
        if h >= 0.25:       # at 1/8 m the uGIMP run (to t_end) takes ~10 min
            out.append(("slope", "explicit numba uGIMP", "explicit", "numba", "gimp", h, 2))
        out.append(("slope", "implicit Q4", "implicit", None, "standard", h, 2))
        out.append(("slope", "implicit uGIMP", "implicit", None, "gimp", h, 2))
    return out


STYLE = {"explicit numba Q4": ("tab:blue", "o"), "explicit numpy Q4": ("tab:gray", "v"),
         "explicit numba uGIMP": ("tab:green", "s"), "implicit Q4": ("tab:red", "^"),
         "implicit uGIMP": ("tab:purple", "D")}


def plot(res, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    titles = {"column": "column compaction (large deformation)\nerror: "
              r"$\sum_p|\sigma_p-\sigma_a|V_p/(\rho_0 g l_0 V_0)$ vs closed form",
              "slope": "elastic slope (geostatic)\nerror: relative L2 of particle stress vs "
              "fine FEM (h = 1/16 m)"}
    for ax, prob in zip(axes, ("column", "slope")):
        rows = [r for r in res["runs"] if r["problem"] == prob and r.get("error") is not None]
        for lab, (col, mk) in STYLE.items():
            rr = [r for r in rows if r["label"] == lab]
            if rr:
                ax.loglog([r["wall_s"] for r in rr], [r["error"] for r in rr], mk, color=col,
                          ms=7, mfc="none" if "numpy" in lab else col, alpha=0.85, label=lab)
                for r in rr:
                    ax.annotate(f"{r['size']:g}/{r['ppc']}", (r["wall_s"], r["error"]),
                                fontsize=6, xytext=(3, 2), textcoords="offset points")
        front = [rows[i] for i in pareto(rows)]
        if front:
            xs = [r["wall_s"] for r in front]
            ys = [r["error"] for r in front]
            ax.step(xs + [xs[-1] * 3], ys + [ys[-1]], where="post", color="k", lw=1.2,
                    ls="--", label="Pareto front")
            ax.plot(xs, ys, "o", ms=13, mfc="none", mec="k", mew=1.0)
        ax.set_xlabel("wall time of the run (s, one core, shared machine)")
        ax.set_ylabel("stress error")
        ax.set_title(titles[prob], fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.text(0.01, 0.01, "labels: cells over the height (column) or cell size in m (slope) / "
             "points per cell direction", fontsize=7)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    fig.savefig(path, dpi=130)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--plot-only", action="store_true",
                    help="redraw the PNG from the JSON of a previous run")
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.plot_only:
        res = json.loads((out / "accuracy_vs_cost.json").read_text())
        for prob in ("column", "slope"):
            rows = [r for r in res["runs"] if r["problem"] == prob and r.get("error") is not None]
            res[f"pareto_{prob}"] = [{k: rows[i][k] for k in ("label", "size", "ppc", "wall_s",
                                                              "error")} for i in pareto(rows)]
        (out / "accuracy_vs_cost.json").write_text(json.dumps(res, indent=1))
        plot(res, out / "accuracy_vs_cost.png")
        return
    has_implicit = _implicit() is not None
    res = {"implicit_available": has_implicit, "load_avg_start": os.getloadavg(), "runs": []}
    # warm-up: compile / load the numba kernels outside any timed run
    run_case(column_scene(4, 2, "standard", "explicit"), "explicit", "numba")
    run_case(column_scene(4, 2, "gimp", "explicit"), "explicit", "numba")
    ref = SlopeReference(1 / 16)
    res["slope_reference"] = {"cell": 1 / 16, "fem_wall_s": ref.wall,
                              "soil_cells": int(ref.soil.sum())}
    print(f"slope reference: FEM on 1/16 m cells ({int(ref.soil.sum())} soil cells), "
          f"{ref.wall:.1f} s; implicit scheme available: {has_implicit}")
    print(f"{'problem':7} {'label':22} {'size':>6} {'ppc':>3} {'points':>7} {'steps':>6} "
          f"{'wall s':>8} {'error':>10}")
    for prob, label, scheme, kernel, shape, size, ppc in configs(args.quick):
        row = {"problem": prob, "label": label, "scheme": scheme, "kernel": kernel,
               "shape": shape, "size": size, "ppc": ppc}
        if scheme == "implicit" and not has_implicit:
            row["error"], row["note"] = None, "fem_rmpm.schemes.implicit not available"
            res["runs"].append(row)
            continue
        try:
            if prob == "column":
                scene = column_scene(size, ppc, shape, scheme)
            else:
                scene = slope_scene(size, ppc, shape, scheme)
            grid, pts, rec, wall = run_case(scene, scheme, kernel)
            if prob == "column":
                err, left_out = column_error(pts), 0
                top = int(np.argmax(pts.x0[:, 1]))
                row["u_top"] = float(pts.displacement[top, 1])
            else:
                err, left_out = slope_error(pts, ref)
            row.update({"points": pts.n, "steps": rec.steps, "wall_s": wall, "error": err,
                        "stop_reason": rec.stop_reason, "points_left_out": left_out,
                        "ns_per_point_step": wall / max(rec.steps, 1) / pts.n * 1e9})
        except Exception as exc:                      # record and go on: the chart shows the rest
            row["error"], row["note"] = None, f"{type(exc).__name__}: {exc}"[:300]
        res["runs"].append(row)
        if row.get("error") is None:
            print(f"{prob:7} {label:22} {size:>6g} {ppc:>3d}  failed: {row.get('note')}",
                  flush=True)
        else:
            print(f"{prob:7} {label:22} {size:>6g} {ppc:>3d} {row['points']:>7d} "
                  f"{row['steps']:>6d} {row['wall_s']:>8.2f} {row['error']:>10.3e}", flush=True)
    for prob in ("column", "slope"):
        rows = [r for r in res["runs"] if r["problem"] == prob and r.get("error") is not None]
        res[f"pareto_{prob}"] = [{k: rows[i][k] for k in ("label", "size", "ppc", "wall_s",
                                                          "error")} for i in pareto(rows)]
        print(f"Pareto front, {prob}: " + "; ".join(
            f"{p['label']} {p['size']:g}/{p['ppc']} ({p['wall_s']:.2g} s, {p['error']:.2g})"
            for p in res[f"pareto_{prob}"]))
    res["load_avg_end"] = os.getloadavg()
    (out / "accuracy_vs_cost.json").write_text(json.dumps(res, indent=1))
    plot(res, out / "accuracy_vs_cost.png")
    print(f"wrote {out / 'accuracy_vs_cost.png'} and {out / 'accuracy_vs_cost.json'}")


if __name__ == "__main__":
    main()
