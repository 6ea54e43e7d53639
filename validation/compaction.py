"""Column compaction under self-weight, implicit MPM under refinement.

Reference: Charlton, Coombs & Augarde 2017 (AMPLE, "iGIMP",
Computers & Structures 190).  l0 = 50 m, E = 10 kPa, nu = 0, rho0 = 0.08 t/m3, g = 10,
one cell wide, rollers on the sides, fixed base, gravity in ``load_steps`` quasi-static
steps.  With nu = 0 and Cauchy equilibrium sigma_yy = -rho0 g (l0 - Y) (Y the initial
height) for any elastic law; Hencky/Kirchhoff tau = E ln(lambda) gives
lambda = exp(-W0(s)), s = rho0 g (l0 - Y)/E and u(Y) = integral_0^Y (lambda - 1) dY,
top -25.940 m.

Prints, for standard Q4 MPM and uGIMP at 4 ... 128 cells over the height: the stress error
norm  sum_p |sigma_p - sigma_a| V_p / (rho0 g l0 V0)  (V0 the initial column volume), the
top displacement against the closed form, Newton iterations and wall time.  Writes
``validation/out/compaction.png`` (error norm against cell size; stress profiles) and
``validation/out/compaction.json``.  Run: ``nice python validation/compaction.py``
(about a minute).
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from scipy.integrate import quad
from scipy.special import lambertw

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene
from fem_rmpm.schemes.implicit import run_implicit

HERE = Path(__file__).parent
OUT = HERE / "out"
L0, E, GAMMA = 50.0, 10.0, 0.8          # m, kPa, kN/m3 (rho0 g)


def stretch(Y):
    return np.exp(-lambertw(GAMMA * (L0 - np.asarray(Y)) / E).real)


def u_exact(Y: float) -> float:
    return quad(lambda y: float(stretch(y)) - 1.0, 0.0, Y, limit=200)[0]


def run(cells: int, shape: str, load_steps: int):
    scene = load_scene(HERE.parent / "meshes" / "compaction.toml")
    h = L0 / cells
    scene = dataclasses.replace(
        scene, grid=dataclasses.replace(scene.grid, size=(h, L0), cell=(h, h)),
        soils=(dataclasses.replace(scene.soils[0], polygon=((0, 0), (h, 0), (h, L0), (0, L0))),),
        solver=dataclasses.replace(scene.solver, shape=shape, load_steps=load_steps))
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    t0 = time.perf_counter()
    rec = run_implicit(scene, grid, pts)
    wall = time.perf_counter() - t0
    sigma_a = -GAMMA * (L0 - pts.x0[:, 1])
    err = float(np.sum(np.abs(pts.stress[:, 1] - sigma_a) * pts.volume)
                / (GAMMA * L0 * pts.volume0.sum()))
    top = int(np.argmax(pts.x0[:, 1]))
    ua = u_exact(pts.x0[top, 1])
    its = [s["iterations"] for s in rec.solver["steps"]]
    row = {"shape": shape, "cells": cells, "cell_m": h, "load_steps": load_steps,
           "points": pts.n, "error_norm": err, "u_top": float(pts.displacement[top, 1]),
           "u_top_exact": ua, "u_top_rel_error": float(pts.displacement[top, 1] / ua - 1),
           "newton_max": max(its), "newton_mean": float(np.mean(its)), "wall_s": wall}
    order = np.argsort(pts.x0[:, 1])
    return row, (pts.x[order, 1], pts.stress[order, 1], pts.x0[order, 1])


def main():
    OUT.mkdir(exist_ok=True)
    rows, profiles = [], {}
    print(f"Column compaction, l0 = {L0} m, E = {E} kPa, nu = 0, rho0 g = {GAMMA} kN/m3; "
          f"closed-form top settlement {u_exact(L0):.3f} m (Hencky/Kirchhoff)")
    print(f"{'shape':>8} {'cells':>5} {'h m':>7} {'steps':>5} {'error norm':>10} "
          f"{'u_top':>9} {'exact':>9} {'rel err':>8} {'Newton':>9} {'wall s':>6}")
    for shape in ("standard", "gimp"):
        for cells in (4, 8, 16, 32, 64, 128):
            row, prof = run(cells, shape, 50)
            rows.append(row)
            profiles[(shape, cells)] = prof
            print(f"{shape:>8} {cells:5d} {row['cell_m']:7.4f} {row['load_steps']:5d} "
                  f"{row['error_norm']:10.3e} {row['u_top']:9.4f} {row['u_top_exact']:9.4f} "
                  f"{row['u_top_rel_error']:8.1e} {row['newton_max']:4d} max "
                  f"{row['wall_s']:6.2f}", flush=True)
    # load-step sensitivity at 32 cells
    for shape in ("standard", "gimp"):
        for steps in (10, 100):
            row, _ = run(32, shape, steps)
            rows.append(row)
            print(f"{shape:>8} {32:5d} {row['cell_m']:7.4f} {steps:5d} {row['error_norm']:10.3e} "
                  f"{row['u_top']:9.4f} {row['u_top_exact']:9.4f} {row['u_top_rel_error']:8.1e} "
                  f"{row['newton_max']:4d} max {row['wall_s']:6.2f}", flush=True)
    (OUT / "compaction.json").write_text(json.dumps(rows, indent=2))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    for shape, mk in (("standard", "o-"), ("gimp", "s-")):
        r = [x for x in rows if x["shape"] == shape and x["load_steps"] == 50]
        a1.loglog([x["cell_m"] for x in r], [x["error_norm"] for x in r], mk,
                  label="standard MPM (Q4)" if shape == "standard" else "uGIMP")
    h = np.array([x["cell_m"] for x in rows if x["shape"] == "gimp" and x["load_steps"] == 50])
    e = [x["error_norm"] for x in rows if x["shape"] == "gimp" and x["load_steps"] == 50]
    a1.loglog(h, e[0] * (h / h[0]), "k:", label="slope 1")
    a1.set_xlabel("cell size h (m)")
    a1.set_ylabel(r"$\sum_p |\sigma_p - \sigma_a| V_p / (\rho_0 g l_0 V_0)$")
    a1.set_title("compaction: stress error norm (50 load steps)")
    a1.legend()
    a1.grid(True, which="both", alpha=0.3)
    Y = np.linspace(0, L0, 200)
    a2.plot(-GAMMA * (L0 - Y), Y + np.array([u_exact(y) for y in Y]), "k-", lw=2,
            label="closed form")
    for shape, c in (("standard", "tab:red"), ("gimp", "tab:blue")):
        y, s, _ = profiles[(shape, 32)]
        a2.plot(s, y, ".", ms=3, color=c, label=f"{shape} MPM, 32 cells")
    a2.set_xlabel(r"$\sigma_{yy}$ (kPa)")
    a2.set_ylabel("current height y (m)")
    a2.set_title("stress against current height")
    a2.legend()
    fig.tight_layout()
    fig.savefig(OUT / "compaction.png", dpi=130)
    print(f"wrote {OUT / 'compaction.png'} and {OUT / 'compaction.json'}")


if __name__ == "__main__":
    main()
