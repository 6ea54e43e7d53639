"""Where MPM fails, measured and cured: a stability map in four studies.

(a) **CFL.**  The explicit step is ``dt = cfl h / (c_p + |v|max)``; the textbook
    estimate is cfl <= 1.  The stable limit of the column (meshes/column.toml) is found
    by bisection on cfl (unstable: the run guard raises SimulationError, or |sigma| >
    10 gamma H), for linear elastodynamics (geostatic phase, points fixed) and for large
    deformation, undamped and with the default local damping 0.7; a 2-D box (rough
    walls) in the linear regime; and the theory of the scheme itself, the cfl at which
    the spectral radius of the linearised step exceeds 1
    (fem_rmpm/schemes/explicit/stability.py), for FLIP and PIC.
(b) **Cell crossing.**  The compaction column (Charlton et al. 2017: l0 = 50 m, E = 10 kPa,
    nu = 0; error norm sum_p |sigma_p - sigma_a| V_p / (rho0 g l0 V0)) under refinement,
    standard Q4 vs uGIMP (Bardenhagen & Kober 2004), implicit (50 load steps) and
    explicit (damped to rest).
(c) **Volumetric locking.**  nu from 0.3 to 0.4999 in the rough-walled box
    (meshes/column_nu0499.toml: 5 m x 5 m, fixed walls and base, self-weight), standard
    vs F-bar (de Souza Neto et al. 1996): the mean pressure at the points against the
    column's closed form p = (1 + 2 K0) / 3 gamma (H - y), which the box approaches as
    nu -> 0.5 (the deviatoric stress is O(G/K) p), and the in-cell oscillation index
    (fem_rmpm.schemes.locking.checkerboard_index); the laterally restrained 1-D column as the
    control that cannot lock.  Implicit geostatic step (one linear solve = the static
    state); explicit runs to rest at nu = 0.499 give the same numbers.
(d) **Points per cell** 1 / 4 / 9 (points_per_cell_dir 1, 2, 3): compaction error and cost
    (standard, uGIMP; implicit, explicit) and the nu = 0.499 box (standard, F-bar).

Writes ``validation/out/stability_cfl.png``, ``stability_cell_crossing.png``,
``stability_locking.png``, ``stability_ppc.png`` and ``stability_map.json``, and prints a
table per study.  Run: ``nice python validation/stability_map.py`` (a few minutes on 2
shared cores; ``--quick`` skips the finest meshes and the slowest spectral analyses).

The footing (limit load against Prandtl, with and without F-bar) is
``validation/footing.py``.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.explicit.loop import run_explicit
from fem_rmpm.schemes.explicit.stability import cfl_limit, spectral_cfl_limit
from fem_rmpm.schemes.implicit import run_implicit
from fem_rmpm.schemes.locking import checkerboard_index, mean_pressure

HERE = Path(__file__).parent
MESHES = HERE.parent / "meshes"
OUT = HERE / "out"


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


# ----------------------------------------------------------------------------- (a) CFL
def study_cfl(quick: bool):
    column = load_scene(MESHES / "column.toml")
    box = with_values(load_scene(MESHES / "column_nu0499.toml"), {
        "soil.poisson_ratio": 0.33, "solver.fbar": False})
    cases = []
    for label, scene in (
            ("column, linear (geostatic), undamped", with_values(column, {"solver.damping": 0.0})),
            ("column, linear (geostatic), damping 0.7", column),
            ("column, large deformation, undamped",
             with_values(column, {"solver.damping": 0.0, "solver.gravity_phase": "dynamic"})),
            ("column, large deformation, damping 0.7",
             with_values(column, {"solver.gravity_phase": "dynamic"})),
            ("2-D box (rough walls), linear, undamped", with_values(box, {"solver.damping": 0.0})),
            ("2-D box (rough walls), linear, damping 0.7", box)):
        t0 = time.perf_counter()
        lo, hi, trials = cfl_limit(scene, 3.0, 10 * 20.0 * 5.0, lo=0.5, hi=3.0, tol=0.005)
        cases.append({"case": label, "limit": 0.5 * (lo + hi), "lo": lo, "hi": hi,
                      "trials": [(c, ok) for c, ok, _ in trials],
                      "why_unstable": next((w for c, ok, w in trials if c == hi), ""),
                      "wall_s": time.perf_counter() - t0})
    short = with_values(column, {"solver.damping": 0.0, "grid.size": [0.25, 1.75],
                                 "soil.polygon": [[0, 0], [0.25, 0], [0.25, 1.25], [0, 1.25]]})
    spectral = {}
    for flip in (1.0, 0.0):
        lo, hi = spectral_cfl_limit(short, lo=1.0, hi=2.0, tol=0.005, flip=flip)
        spectral["FLIP" if flip == 1.0 else "PIC"] = 0.5 * (lo + hi)
    default = column.solver.cfl
    print("\n(a) explicit CFL limit (theory: cfl = 1, dt = h / (c_p + |v|))")
    print(f"{'case':<44} {'limit':>7} {'/theory':>8} {'default margin':>15}  first unstable")
    for c in cases:
        print(f"{c['case']:<44} {c['limit']:7.3f} {c['limit'] / 1.0:8.2f} "
              f"{c['limit'] / default:14.2f}x  {c['why_unstable'][:60]}")
    for k, v in spectral.items():
        print(f"{'spectral radius of the linearised step (' + k + ')':<44} {v:7.3f} {v:8.2f}")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4.2))
    for i, c in enumerate(cases):
        tr = np.array(c["trials"], dtype=float)
        ax.scatter(tr[tr[:, 1] == 1, 0], np.full((tr[:, 1] == 1).sum(), i), marker="o",
                   color="tab:green", s=18, zorder=3)
        ax.scatter(tr[tr[:, 1] == 0, 0], np.full((tr[:, 1] == 0).sum(), i), marker="x",
                   color="tab:red", s=22, zorder=3)
        ax.plot([0.5, c["limit"]], [i, i], color="tab:green", alpha=0.35, lw=6)
        ax.text(c["limit"], i + 0.22, f"{c['limit']:.2f}", ha="center", fontsize=8)
    ax.axvline(1.0, color="k", lw=1.5, label="textbook estimate (cfl = 1)")
    ax.axvline(spectral["FLIP"], color="tab:purple", ls="--",
               label=f"linearised MUSL step, FLIP ({spectral['FLIP']:.2f})")
    ax.axvline(spectral["PIC"], color="tab:purple", ls=":",
               label=f"linearised MUSL step, PIC ({spectral['PIC']:.2f})")
    ax.axvline(default, color="tab:blue", lw=2, label=f"default cfl = {default:g}")
    ax.set_yticks(range(len(cases)), [c["case"] for c in cases], fontsize=8)
    ax.set_xlabel("cfl   (dt = cfl h / (c_p + |v|max))")
    ax.set_xlim(0.4, 3.05)
    ax.set_title("explicit stability map: o stable, x unstable (bisection, 3 s each)")
    ax.set_ylim(-0.6, len(cases) - 0.4)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    fig.tight_layout()
    fig.savefig(OUT / "stability_cfl.png", dpi=130, bbox_inches="tight")
    plt.close(fig)
    return {"cases": cases, "spectral": spectral, "default_cfl": default}


# ----------------------------------------------------------------------------- (b) crossing
def compaction(cells: int, shape: str, scheme: str, ppc: int = 2) -> dict:
    """One compaction run (meshes/compaction.toml): error norm, top
    settlement, wall time, status."""
    h = 50.0 / cells
    scene = with_values(load_scene(MESHES / "compaction.toml"), {
        "grid.size": [h, 50.0], "grid.cell": h, "soil.polygon": [[0, 0], [h, 0], [h, 50], [0, 50]],
        "soil.points_per_cell_dir": ppc, "solver.shape": shape, "solver.scheme": scheme,
        "solver.damping": 0.7, "solver.gravity_ramp_time": 20.0, "solver.t_end": 400.0,
        "solver.rest_velocity": 1e-4, "solver.rest_energy_ratio": 1e-8})
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    t0 = time.perf_counter()
    try:
        rec = (run_implicit if scheme == "implicit" else run_explicit)(scene, grid, pts)
        status = rec.stop_reason
    except Exception as exc:                      # a failed run is a result here
        status = "failed: " + str(exc).split(";")[0][:70]
    wall = time.perf_counter() - t0
    sigma_a = -0.8 * (50.0 - pts.x0[:, 1])
    err = float(np.sum(np.abs(pts.stress[:, 1] - sigma_a) * pts.volume)
                / (0.8 * 50.0 * pts.volume0.sum()))
    return {"scheme": scheme, "shape": shape, "cells": cells, "h": h, "ppc": ppc ** 2,
            "points": pts.n, "error_norm": err, "u_top": float(pts.displacement[:, 1].min()),
            "status": status, "wall_s": wall}


def study_crossing(quick: bool):
    rows = []
    print("\n(b) cell crossing: compaction column, stress error norm under refinement")
    print(f"{'scheme':>9} {'shape':>9} {'cells':>5} {'error norm':>10} {'u_top m':>8} "
          f"{'wall s':>7}  status")
    for scheme in ("implicit", "explicit"):
        for shape in ("standard", "gimp"):
            for cells in ((4, 8, 16, 32, 64) if quick else (4, 8, 16, 32, 64, 128)):
                r = compaction(cells, shape, scheme)
                rows.append(r)
                print(f"{scheme:>9} {shape:>9} {cells:5d} {r['error_norm']:10.3e} "
                      f"{r['u_top']:8.3f} {r['wall_s']:7.2f}  {r['status']}", flush=True)
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for ax, scheme in zip(axes, ("implicit", "explicit")):
        for shape, mk in (("standard", "o-"), ("gimp", "s-")):
            r = [x for x in rows if x["scheme"] == scheme and x["shape"] == shape]
            ax.loglog([x["h"] for x in r], [x["error_norm"] for x in r], mk,
                      label="standard MPM (Q4)" if shape == "standard" else "uGIMP")
        r = [x for x in rows if x["scheme"] == scheme and x["shape"] == "gimp"]
        h = np.array([x["h"] for x in r])
        ax.loglog(h, r[1]["error_norm"] * h / h[1], "k:", lw=1, label="slope 1")
        ax.set_xlabel("cell size h (m)")
        ax.set_title(f"{scheme}: compaction stress error")
        ax.grid(True, which="both", alpha=0.3)
        ax.invert_xaxis()
    axes[0].set_ylabel(r"$\sum_p |\sigma_p - \sigma_a| V_p / (\rho_0 g l_0 V_0)$")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / "stability_cell_crossing.png", dpi=130)
    plt.close(fig)
    return rows


# ----------------------------------------------------------------------------- (c) locking
def locking_case(nu: float, fbar: bool, walls: str = "fixed", scheme: str = "implicit",
                 ppc: int = 2, shape: str = "standard"):
    """The box of meshes/column_nu0499.toml (walls "fixed") or the 5 m wide laterally
    restrained column (walls "roller") at Poisson's ratio ``nu``."""
    scene = with_values(load_scene(MESHES / "column_nu0499.toml"), {
        "soil.poisson_ratio": nu, "solver.fbar": fbar, "boundary.left": walls,
        "boundary.right": walls, "solver.scheme": scheme, "soil.points_per_cell_dir": ppc,
        "solver.shape": shape})
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    t0 = time.perf_counter()
    (run_implicit if scheme == "implicit" else run_explicit)(scene, grid, pts)
    wall = time.perf_counter() - t0
    K0 = nu / (1 - nu)
    p_base = (1 + 2 * K0) / 3 * 20.0 * 5.0
    pa = (1 + 2 * K0) / 3 * 20.0 * (5.0 - pts.x0[:, 1])
    p = mean_pressure(pts.stress)
    e = (p - pa) / p_base
    return {"nu": nu, "fbar": fbar, "walls": walls, "scheme": scheme, "ppc": ppc ** 2,
            "shape": shape, "max_dev": float(np.abs(e).max()),
            "rms_dev": float(np.sqrt(np.sum(e ** 2 * pts.volume) / pts.volume.sum())),
            "checkerboard": checkerboard_index(grid, pts.x, p, pts.volume),
            "settlement": float(pts.displacement[:, 1].min()), "wall_s": wall,
            "_field": (pts.x0.copy(), e)}


def study_locking(quick: bool):
    nus = (0.3, 0.4, 0.45, 0.49, 0.495, 0.499, 0.4999)
    rows = []
    print("\n(c) volumetric locking: rough-walled box 5 m x 5 m, self-weight; mean pressure vs "
          "the column closed form (relative to its base value)")
    print(f"{'walls':>6} {'scheme':>9} {'nu':>7} {'remedy':>9} {'max dev':>8} {'rms dev':>8} "
          f"{'in-cell osc.':>12} {'settle m':>9}")

    def show(r):
        print(f"{r['walls']:>6} {r['scheme']:>9} {r['nu']:7.4f} "
              f"{'F-bar' if r['fbar'] else 'standard':>9} {r['max_dev']:8.4f} "
              f"{r['rms_dev']:8.4f} {r['checkerboard']:12.5f} {r['settlement']:9.5f}", flush=True)
    for walls in ("fixed", "roller"):
        for nu in (nus if walls == "fixed" else (0.3, 0.499)):
            for fbar in (False, True):
                r = locking_case(nu, fbar, walls)
                rows.append(r)
                show(r)
    for fbar in (False, True):
        r = locking_case(0.499, fbar, "fixed", "explicit")
        rows.append(r)
        show(r)
    plt = _plt()
    fig, axes = plt.subplots(1, 4, figsize=(16, 4.2), gridspec_kw={"width_ratios": [1, 1, 1, 1]})
    fx = [r for r in rows if r["walls"] == "fixed" and r["scheme"] == "implicit"]
    for fbar, mk, lab in ((False, "o-", "standard Q4"), (True, "s-", "F-bar")):
        r = [x for x in fx if x["fbar"] == fbar]
        x = [0.5 - v["nu"] for v in r]
        axes[0].loglog(x, [v["max_dev"] for v in r], mk, label=lab)
        axes[1].semilogx(x, [100 * v["checkerboard"] for v in r], mk, label=lab)
    for ax in axes[:2]:
        ax.invert_xaxis()
        ax.set_xlabel(r"$0.5 - \nu$")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].axhline(0.05, color="k", ls=":", lw=1)
    axes[0].set_ylabel("max |p - p_closed form| / p_base")
    axes[0].set_title("pressure vs closed form (holds as nu -> 0.5;\naway from it the rough "
                      "walls carry weight: silo)", fontsize=9)
    axes[1].set_ylabel("in-cell pressure oscillation (% of max p)")
    axes[1].set_title("checkerboard index")
    for ax, fbar in zip(axes[2:], (False, True)):
        r = next(v for v in fx if v["nu"] == 0.499 and v["fbar"] == fbar)
        X, e = r["_field"]
        sc = ax.scatter(X[:, 0], X[:, 1], c=100 * e, s=28, marker="s", cmap="RdBu_r",
                        vmin=-10, vmax=10)
        ax.set_aspect("equal")
        ax.set_title(f"nu = 0.499, {'F-bar' if fbar else 'standard'}: (p - p_a) / p_base,\n"
                     "bottom-left corner of the box", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_xlim(0, 1.5)
        ax.set_ylim(0, 1.5)
    fig.colorbar(sc, ax=axes[2:], label="%", shrink=0.8)
    fig.savefig(OUT / "stability_locking.png", dpi=130, bbox_inches="tight")
    plt.close(fig)
    for r in rows:
        r.pop("_field")
    return rows


# ----------------------------------------------------------------------------- (d) ppc
def study_ppc(quick: bool):
    rows = []
    print("\n(d) points per cell: compaction (error norm, wall s) and the nu = 0.499 box")
    print(f"{'case':>28} {'ppc':>4} {'error / dev':>11} {'osc.':>8} {'wall s':>7}  status")
    for scheme in ("implicit", "explicit"):
        for shape in ("standard", "gimp"):
            for n in (1, 2, 3):
                r = compaction(32, shape, scheme, n)
                rows.append(r)
                print(f"{'compaction ' + scheme + ' ' + shape + ' 32':>28} {r['ppc']:4d} "
                      f"{r['error_norm']:11.3e} {'':>8} {r['wall_s']:7.2f}  {r['status']}",
                      flush=True)
    for fbar in (False, True):
        for n in (1, 2, 3):
            r = locking_case(0.499, fbar, ppc=n)
            r.pop("_field")
            rows.append(r)
            print(f"{'box nu 0.499 ' + ('F-bar' if fbar else 'standard'):>28} {r['ppc']:4d} "
                  f"{r['max_dev']:11.4f} {r['checkerboard']:8.5f} {r['wall_s']:7.2f}",
                  flush=True)
    plt = _plt()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4.2))
    for scheme, ls in (("implicit", "-"), ("explicit", "--")):
        for shape, mk in (("standard", "o"), ("gimp", "s")):
            r = [x for x in rows if x.get("scheme") == scheme and x.get("shape") == shape
                 and "error_norm" in x]
            ok = [x for x in r if not x["status"].startswith("failed")]
            a1.semilogy([x["ppc"] for x in ok], [x["error_norm"] for x in ok], mk + ls,
                        label=f"{scheme}, {shape}")
            for x in r:
                if x["status"].startswith("failed"):
                    a1.plot([x["ppc"]], [0.2], "x", color="tab:red")
                    a1.annotate(f"{scheme} {shape}: failed", (x["ppc"], 0.2), fontsize=7,
                                color="tab:red", xytext=(4, 4), textcoords="offset points")
    a1.set_xticks([1, 4, 9])
    a1.set_xlabel("points per cell")
    a1.set_ylabel("compaction error norm (32 cells)")
    a1.set_title("compaction: error vs points per cell")
    a1.legend(fontsize=7)
    a1.grid(True, which="both", alpha=0.3)
    for fbar, mk in ((False, "o-"), (True, "s-")):
        r = [x for x in rows if "max_dev" in x and x["fbar"] == fbar]
        a2.plot([x["ppc"] for x in r], [x["max_dev"] for x in r], mk,
                label="F-bar" if fbar else "standard Q4")
    a2.axhline(0.05, color="k", ls=":", lw=1)
    a2.set_xticks([1, 4, 9])
    a2.set_xlabel("points per cell")
    a2.set_ylabel("max pressure deviation / p_base")
    a2.set_title("nu = 0.499 box: locking vs points per cell")
    a2.legend(fontsize=8)
    a2.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(OUT / "stability_ppc.png", dpi=130)
    plt.close(fig)
    return rows


def main(argv=None):
    global OUT
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="skip the finest meshes")
    ap.add_argument("--only", choices=("cfl", "crossing", "locking", "ppc"), nargs="*")
    ap.add_argument("--out", default=str(OUT), help="output directory (default validation/out)")
    args = ap.parse_args(argv)
    OUT = Path(args.out)
    OUT.mkdir(parents=True, exist_ok=True)
    studies = {"cfl": study_cfl, "crossing": study_crossing, "locking": study_locking,
               "ppc": study_ppc}
    path = OUT / "stability_map.json"
    res = json.loads(path.read_text()) if path.exists() else {}
    t0 = time.perf_counter()
    for name in args.only or studies:
        res[name] = studies[name](args.quick)
    path.write_text(json.dumps(res, indent=1, default=lambda o: o if not isinstance(
        o, float) or math.isfinite(o) else str(o)))
    print(f"\nwrote {OUT}/stability_*.png and {path.name} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
