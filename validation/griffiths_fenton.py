"""P(FS < 1) of the Griffiths slope against the COV of the undrained cohesion, for several
scales of fluctuation, beside the single-random-variable closed form (Griffiths & Fenton
2004, J. Geotech. Geoenviron. Eng. 130(5) 507-518).

The slope: ``meshes/griffiths_slope.toml`` (2:1, H = 10 m, D = 2), mean C = c / (gamma H)
= 0.25 (homogeneous FS 1.47, Taylor), a lognormal isotropic Markov field of the cohesion
with theta = Theta H for Theta in {0.5, 1, 2, 4, 1e4} (1e4: one random variable) and COV
0.1 .. 0.5.  Each realization needs one static solve: whether the slope stands at F = 1
under full gravity (:func:`fem_rmpm.schemes.implicit.strength_reduction.stable_at`),
exactly the event FS < 1 the strength reduction reports, as RFEM does (Griffiths & Fenton
2004).

Closed form (perfect correlation): FS = FS_hom c / mu, so P(FS < 1) = Phi((ln(mu / FS_hom)
- m_ln) / s_ln) with s_ln^2 = ln(1 + COV^2), m_ln = ln mu - s_ln^2 / 2; FS_hom is computed
on the same mesh (to a 0.2 % bracket) and drawn with Taylor's 1.47 as well.

    python validation/griffiths_fenton.py --n 100 --cell 2.5 --workers 2 --out runs/gf

Writes ``griffiths_fenton.json`` (every point: N, k, P, its standard error and Wilson 95 %
interval, the closed form) and ``griffiths_fenton.png`` (P against COV per Theta, Wilson
intervals as error bars, the closed form as a black line).  Points are appended to the
JSON as they finish; a re-run skips the finished ones (same N, cell and seed).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

THETAS = (0.5, 1.0, 2.0, 4.0, 1e4)          # Theta = theta / H
COVS = (0.1, 0.2, 0.3, 0.4, 0.5)
H, GAMMA, C_MEAN = 10.0, 20.0, 50.0          # m, kN/m3, kPa: C = 0.25


def scene_for(cell: float, theta: float | None, cov: float | None):
    from fem_rmpm.scene import load_scene, with_values
    sc = with_values(load_scene(ROOT / "meshes" / "griffiths_slope.toml"), {"grid.cell": cell})
    if theta is None:
        return sc
    return with_values(sc, {"random_field.property": "cohesion_peak",
                            "random_field.distribution": "lognormal", "random_field.cov": cov,
                            "random_field.theta_v": theta * H, "random_field.anisotropy": 1.0})


def closed_form(fs_hom: float, cov: float) -> float:
    """P(FS < 1) with one lognormal random variable (perfect correlation)."""
    s = math.sqrt(math.log(1 + cov * cov))
    z = (-math.log(fs_hom) + 0.5 * s * s) / s
    return 0.5 * math.erfc(-z / math.sqrt(2))


def _one(job) -> bool:
    """Realization ``index`` of the point (Theta, COV): True if it fails at F = 1."""
    cell, theta, cov, seed = job
    from fem_rmpm import api
    from fem_rmpm.schemes.implicit.strength_reduction import stable_at
    sc = scene_for(cell, theta, cov)
    grid, pts = api.prepare(sc, seed)
    return not stable_at(sc, 1.0, seed=seed, grid=grid, pts=pts).converged


def run_point(pool, cell, theta, cov, n, seed0) -> dict:
    from fem_rmpm.campaign import realization_seed, wilson_interval
    t0 = time.perf_counter()
    jobs = [(cell, theta, cov, realization_seed(seed0, i)) for i in range(n)]
    fails = list(pool.map(_one, jobs, chunksize=4))
    k = sum(fails)
    p = k / n
    return {"Theta": theta, "cov": cov, "n": n, "k": k, "p": p, "se": math.sqrt(p * (1 - p) / n),
            "wilson95": list(wilson_interval(k, n)), "wall_time": time.perf_counter() - t0}


def plot(path: Path, doc: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    fig, ax = plt.subplots(figsize=(7.5, 5))
    cv = np.linspace(0.05, 0.55, 101)
    ax.plot(cv, [closed_form(doc["fs_homogeneous"], c) for c in cv], "k-", lw=1.8,
            label=f"single random variable, closed form (FS_hom {doc['fs_homogeneous']:.3f})")
    ax.plot(cv, [closed_form(1.47, c) for c in cv], "k:", lw=1,
            label="closed form with Taylor's FS 1.47")
    marks = dict(zip(THETAS, "osD^v"))
    for j, th in enumerate(THETAS):
        pts = sorted((p for p in doc["points"] if p["Theta"] == th), key=lambda p: p["cov"])
        if not pts:
            continue
        x = np.array([p["cov"] for p in pts]) + 0.004 * (j - 2)
        y = np.array([p["p"] for p in pts])
        lo = np.maximum(y - np.array([p["wilson95"][0] for p in pts]), 0.0)
        hi = np.maximum(np.array([p["wilson95"][1] for p in pts]) - y, 0.0)
        ax.errorbar(x, y, yerr=[lo, hi], marker=marks[th], ms=5, capsize=3, lw=1,
                    label=f"Theta = {th:g}" + (" (perfect correlation)" if th > 100 else ""))
    ns = sorted({p["n"] for p in doc["points"]})
    ax.set_xlabel("COV of the undrained cohesion")
    ax.set_ylabel("P(FS < 1)")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(f"Griffiths slope, mean C = 0.25, {doc['cell']:g} m cells; N = "
                 f"{'/'.join(map(str, ns))} per point, Wilson 95 % intervals", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100, help="realizations per point (default 100)")
    ap.add_argument("--cell", type=float, default=2.5, help="grid cell (m), default 2.5")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=2004)
    ap.add_argument("--thetas", default=",".join(map(str, THETAS)))
    ap.add_argument("--covs", default=",".join(map(str, COVS)))
    ap.add_argument("--out", default="runs/griffiths_fenton")
    a = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from fem_rmpm.io.output import write_json
    from fem_rmpm.schemes.implicit.strength_reduction import FSOptions, factor_of_safety
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    jpath = out / "griffiths_fenton.json"
    doc = json.loads(jpath.read_text()) if jpath.exists() else {}
    if doc.get("cell") != a.cell or doc.get("seed") != a.seed:
        from fem_rmpm import api
        hom = api.factor_of_safety(scene_for(a.cell, None, None), tolerance=0.002)
        doc = {"cell": a.cell, "seed": a.seed, "fs_homogeneous": hom.fs,
               "fs_homogeneous_solves": hom.static_solves, "points": [],
               "machine": os.uname().nodename, "criterion": "fails at F = 1 (one static "
               "solve per realization, the event FS < 1 of the strength reduction)"}
    thetas = [float(t) for t in a.thetas.split(",")]
    covs = [float(c) for c in a.covs.split(",")]
    with ProcessPoolExecutor(a.workers) as pool:
        for cov in covs:
            for th in thetas:
                if any(p["Theta"] == th and p["cov"] == cov and p["n"] >= a.n
                       for p in doc["points"]):
                    continue
                pt = run_point(pool, a.cell, th, cov, a.n, a.seed)
                pt["closed_form"] = closed_form(doc["fs_homogeneous"], cov)
                doc["points"] = [p for p in doc["points"]
                                 if not (p["Theta"] == th and p["cov"] == cov)] + [pt]
                write_json(jpath, doc)
                plot(out / "griffiths_fenton.png", doc)
                print(f"Theta {th:g} COV {cov:g}: P(FS<1) = {pt['p']:.3f} +- {pt['se']:.3f} "
                      f"(N {a.n}, Wilson [{pt['wilson95'][0]:.3f}, {pt['wilson95'][1]:.3f}]); "
                      f"closed form {pt['closed_form']:.3f}; {pt['wall_time']:.0f} s",
                      flush=True)
    plot(out / "griffiths_fenton.png", doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
