"""Validation of the random-field generator against its target statistics.

Prints the statistics table (mean, variance vs the variance function, excess kurtosis of the
domain average, correlation of local averages at 0.25, 0.5, 1, 2 theta along x and y, for
xi = 1, 12, 48), the cost per field (reference slope and 1e6 cells) and a comparison with
gstools, and writes to validation/out/:

* random_field_correlation.png  target vs empirical correlation, both axes, three xi
  (literature grid: 0.25 m cells, theta_v = 0.5 m, 60 m x 5 m)
* random_field_realizations.png single realizations of peak cohesion for xi = 1, 12, 48 on
  the reference slope (meshes/slope_elastic.toml with c = 20 kPa), like the paper's Fig. 3
* random_field_stats.json       all numbers printed

Targets: covariance of local averages from fem_rmpm.random_field.lattice_covariance, which
tests/test_random_field.py checks against scipy nquad and Vanmarcke's closed form.

    nice /work/venv/bin/python validation/random_field_stats.py [--quick]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fem_rmpm import random_field as rf  # noqa: E402
from fem_rmpm.discretise.grid import make_grid  # noqa: E402
from fem_rmpm.discretise.points import seed_particles  # noqa: E402
from fem_rmpm.io.output import to_true_frame  # noqa: E402
from fem_rmpm.io.plots import _plt, plot_field  # noqa: E402
from fem_rmpm.random_field import embedding as rf_embedding  # noqa: E402
from fem_rmpm.scene import load_scene, scene_from_dict, with_value  # noqa: E402

OUT = ROOT / "validation" / "out"
THETA_V = 0.5


def block_scene(size, cell, xi, distribution="normal", averaging=True):
    sx, sy = size
    return scene_from_dict({
        "scene": {"name": "rf_block"},
        "grid": {"size": [sx, sy], "cell": [cell[0], cell[1]]},
        "soil": [{"name": "clay", "polygon": [[0, 0], [sx, 0], [sx, sy], [0, sy]],
                  "unit_weight": 20.0, "youngs_modulus": 1000.0, "poisson_ratio": 0.33,
                  "model": "von_mises_softening", "cohesion_peak": 20.0,
                  "cohesion_residual": 4.0}],
        "random_field": {"distribution": distribution, "cov": 0.25, "theta_v": THETA_V,
                         "anisotropy": float(xi), "local_averaging": averaging}})


def corr_at(Z, lag, axis):
    m, v = Z.mean(), Z.var()
    a, b = ((Z[:, :, :-lag], Z[:, :, lag:]) if axis == "x" else (Z[:, :-lag, :], Z[:, lag:, :]))
    r = ((a - m) * (b - m)).reshape(len(Z), -1).mean(axis=1) / v
    return float(r.mean()), float(r.std(ddof=1) / math.sqrt(len(Z)))


def kurtosis(m):
    d = m - m.mean()
    return float((d ** 4).mean() / (d ** 2).mean() ** 2 - 3.0), math.sqrt(24.0 / len(m))


def run_case(name, xi, size, cell, n_real, lags_x, lags_y, seed0=0):
    scene = block_scene(size, cell, xi)
    grid = make_grid(scene)
    layout = rf.field_layout(scene, grid)
    emb = rf.circulant_embedding(rf.model_from_spec(scene.random_field), tuple(layout.cell),
                                 layout.shape, True)
    Z = np.stack([emb.sample(seed0 + s) for s in range(n_real)])
    model = emb.model
    var_pred = float(rf.lattice_covariance(model, layout.cell, 0, 0))
    m = Z.mean(axis=(1, 2))
    k, kse = kurtosis(m)
    c = rf.gaussian_to_property(Z, 20.0, scene.random_field).mean(axis=(1, 2))
    res = {"case": name, "xi": xi, "cells": list(layout.shape), "cell": layout.cell.tolist(),
           "realizations": n_real, "embedding": list(emb.padded),
           "lambda_min_over_max": emb.lambda_min / emb.lambda_max, "clipped": emb.clipped,
           "mean_gauss": float(m.mean()), "mean_se": float(m.std(ddof=1) / math.sqrt(n_real)),
           "mean_cohesion": float(c.mean()),
           "mean_cohesion_se": float(c.std(ddof=1) / math.sqrt(n_real)),
           "var_emp": float(Z.var()), "var_pred": var_pred, "excess_kurtosis": k,
           "kurtosis_se": kse, "corr": []}
    for axis, lags in (("x", lags_x), ("y", lags_y)):
        h = layout.cell[0] if axis == "x" else layout.cell[1]
        theta = model.theta_h if axis == "x" else model.theta_v
        for lag in lags:
            kl = (lag, 0) if axis == "x" else (0, lag)
            target = float(rf.lattice_covariance(model, layout.cell, *kl)) / var_pred
            est, se = corr_at(Z, lag, axis)
            res["corr"].append({"axis": axis, "lag_m": lag * h, "lag_theta": lag * h / theta,
                                "target": target, "point_rho": math.exp(-2 * lag * h / theta),
                                "empirical": est, "se": se})
    return res, Z


def print_case(r):
    print(f"\n{r['case']}: xi = {r['xi']}, {r['cells'][0]} x {r['cells'][1]} cells of "
          f"{r['cell'][0]:g} x {r['cell'][1]:g} m, {r['realizations']} realizations, embedding "
          f"{r['embedding'][0]} x {r['embedding'][1]} (lambda_min/max "
          f"{r['lambda_min_over_max']:.1e}, clipped {r['clipped']:g})")
    print(f"  mean of Z {r['mean_gauss']:+.4f} (SE {r['mean_se']:.4f}, "
          f"{abs(r['mean_gauss']) / r['mean_se']:.1f} SE); cohesion mean "
          f"{r['mean_cohesion']:.3f} kPa (SE {r['mean_cohesion_se']:.3f}, target 20)")
    print(f"  variance {r['var_emp']:.4f} vs variance function {r['var_pred']:.4f} "
          f"({100 * (r['var_emp'] / r['var_pred'] - 1):+.2f} %); excess kurtosis of the domain "
          f"average {r['excess_kurtosis']:+.3f} (SE {r['kurtosis_se']:.3f})")
    print("  axis  lag(m)  lag/theta  target(avg)  rho(point)  empirical    diff     SE")
    for c in r["corr"]:
        print(f"   {c['axis']}  {c['lag_m']:7.3f}  {c['lag_theta']:8.3f}  {c['target']:10.4f}"
              f"  {c['point_rho']:10.4f}  {c['empirical']:9.4f}  "
              f"{c['empirical'] - c['target']:+.4f}  {c['se']:.4f}")


def correlation_figure(path, n_real):
    """Target vs empirical correlation on the literature grid (0.25 m cells), 3 xi, 2 axes."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    colors = {1: "tab:blue", 12: "tab:orange", 48: "tab:green"}
    cases = []
    for xi in (1, 12, 48):
        th = xi * THETA_V
        nx = 240 if xi > 1 else 80
        size = (nx * 0.25, 5.0)
        step = max(1, int(round(th / 0.25 / 8)))
        lags_x = list(range(step, min(int(2.5 * th / 0.25), nx - 1) + 1, step))
        lags_y = list(range(1, 6))
        r, _ = run_case(f"literature grid xi={xi}", xi, size, (0.25, 0.25), n_real, lags_x, lags_y,
                        seed0=100_000 * xi)
        cases.append(r)
        for ax, axis, theta in ((axes[0], "x", th), (axes[1], "y", THETA_V)):
            cs = [c for c in r["corr"] if c["axis"] == axis]
            t = np.array([c["lag_theta"] for c in cs])
            tt = np.linspace(0, t.max(), 200)
            ax.plot(tt, np.exp(-2 * tt), ":", color=colors[xi], lw=1)
            ax.plot(np.r_[0, t], np.r_[1, [c["target"] for c in cs]], "-", color=colors[xi],
                    lw=1.2, label=f"xi = {xi}: target (local averages)")
            ax.errorbar(t, [c["empirical"] for c in cs], yerr=[2 * c["se"] for c in cs], fmt="o",
                        ms=3.5, color=colors[xi], label=f"xi = {xi}: empirical (+-2 SE)")
    for ax, name in ((axes[0], "along x (layering), lag / theta_h"),
                     (axes[1], "along y (across), lag / theta_v")):
        ax.set_xlabel(name)
        ax.set_ylabel("correlation")
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Markov field, 0.25 m cells, local averaging, {n_real} realizations each "
                 "(dotted: point correlation exp(-2 tau/theta))", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return cases


def realizations_figure(path, seed=2017):
    """Single realizations of peak cohesion for xi = 1, 12, 48 on the reference slope."""
    plt = _plt()
    base = load_scene(ROOT / "meshes" / "slope_elastic.toml")
    base = with_value(base, "soil.cohesion_peak", 20.0)
    base = with_value(base, "soil.cohesion_residual", 4.0)
    base = with_value(base, "soil.model", "von_mises_softening")
    fig, axes = plt.subplots(3, 1, figsize=(9, 9.4), sharex=True)
    fig.subplots_adjust(left=0.08, right=0.84, top=0.96, bottom=0.06, hspace=0.22)
    info = []
    for ax, xi, tag in zip(axes, (1, 12, 48), "abc"):
        scene = with_value(base, "random_field.anisotropy", float(xi))
        grid = make_grid(scene)
        pts = seed_particles(scene, grid)
        c = rf.sample_point_property(scene, grid, pts, seed)
        X = to_true_frame(pts.x0, scene.scene.frame_angle_deg)
        sc = plot_field(ax, X, c, 0.16, vmin=8, vmax=40, cmap="jet")   # Gauss points: gaps at 0.125
        ax.set_aspect("equal")
        ax.set_ylabel("Y (m)")
        ax.set_title(f"({tag}) xi = {xi}, random field of peak cohesion (kPa), seed {seed}",
                     fontsize=9, loc="left")
        info.append({"xi": xi, "min": float(c.min()), "mean": float(c.mean()),
                     "max": float(c.max()), "points": int(len(c))})
    axes[-1].set_xlabel("X, true horizontal (m)")
    cax = fig.add_axes([0.87, 0.25, 0.02, 0.5])
    fig.colorbar(sc, cax=cax, label="peak cohesion (kPa)")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return info


def _timed(model, cell, shape, n_fields):
    """Embedding set-up time (s) and median time per field (ms) of ``n_fields`` samples."""
    t0 = time.perf_counter()
    emb = rf.circulant_embedding(model, cell, shape, True)
    setup = time.perf_counter() - t0
    ts = []
    for s in range(n_fields):
        t0 = time.perf_counter()
        emb.sample(s)
        ts.append(time.perf_counter() - t0)
    return {"embedding": list(emb.padded), "setup_s": setup,
            "ms_per_field": 1e3 * float(np.median(ts))}


def timings(quick):
    out = {}
    base = load_scene(ROOT / "meshes" / "slope_elastic.toml")
    base = with_value(base, "soil.cohesion_peak", 20.0)
    for xi in (1, 12, 48):
        scene = with_value(base, "random_field.anisotropy", float(xi))
        grid = make_grid(scene)
        layout = rf.field_layout(scene, grid)
        rf_embedding._embedding_cached.cache_clear()
        out[f"slope_xi{xi}"] = {"cells": layout.n_cells, **_timed(
            rf.model_from_spec(scene.random_field), tuple(layout.cell), layout.shape, 60)}
    for xi in ((12,) if quick else (1, 12, 48)):
        model = rf.MarkovModel(xi * THETA_V, THETA_V)
        out[f"1e6_xi{xi}"] = {"cells": 10 ** 6,
                              **_timed(model, (0.25, 0.25), (1000, 1000), 3)}
    return out


def gstools_comparison(n_real):
    """gstools' randomization method (Exponential = point Markov with len_scale = theta/2)."""
    try:
        import gstools as gs
    except ImportError:  # pragma: no cover
        return None
    res = {}
    x = (np.arange(244) + 0.5) * 0.25
    y = (np.arange(20) + 0.5) * 0.25
    for xi in (1, 12):
        th = xi * THETA_V
        model = gs.Exponential(dim=2, var=1.0, len_scale=[th / 2, THETA_V / 2])
        srf = gs.SRF(model)
        t0 = time.perf_counter()
        F = np.stack([srf.structured([x, y], seed=1000 + s).T for s in range(n_real)])
        t_gs = (time.perf_counter() - t0) / n_real
        emb = rf.circulant_embedding(rf.MarkovModel(th, THETA_V), (0.25, 0.25), (244, 20), False)
        t0 = time.perf_counter()
        Z = np.stack([emb.sample(s) for s in range(n_real)])
        t_ce = (time.perf_counter() - t0) / n_real
        row = {}
        for name, A, t in (("gstools", F, t_gs), ("circulant", Z, t_ce)):
            k, kse = kurtosis(A.mean(axis=(1, 2)))
            lag = max(1, int(round(th / 0.25)))
            row[name] = {"s_per_field": t, "variance": float(A.var()), "excess_kurtosis": k,
                         "kurtosis_se": kse, "corr_x_at_theta": corr_at(A, lag, "x")[0],
                         "corr_y_at_theta": corr_at(A, 2, "y")[0],
                         "target_at_theta": math.exp(-2)}
        res[f"xi{xi}"] = row
    return res


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="fewer realizations")
    a = p.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    n = 500 if a.quick else 2000
    t_all = time.perf_counter()
    print("Random field statistics (cell-averaged standard Gaussian, Markov elliptic, "
          "theta_v = 0.5 m; cells theta/4 so the lags 0.25, 0.5, 1, 2 theta are cell lags)")
    table = []
    for xi, size in ((1, (5.0, 5.0)), (12, (60.0, 5.0)), (48, (60.0, 5.0))):
        th = xi * THETA_V
        r, _ = run_case(f"theta/4 cells xi={xi}", xi, size, (th / 4, THETA_V / 4), n,
                        (1, 2, 4, 8), (1, 2, 4, 8), seed0=10_000 * xi)
        print_case(r)
        table.append(r)
    r, _ = run_case("literature grid xi=48 (theta_h = 24 m on 60 m)", 48, (60.0, 5.0),
                    (0.25, 0.25), n, (24, 48, 96, 192), (1, 2, 4))
    print_case(r)
    table.append(r)
    worst = max(abs(c["empirical"] - c["target"]) for r in table for c in r["corr"])
    print(f"\nlargest |empirical - target| correlation over all cases: {worst:.4f} (allowed 0.05)")

    cases = correlation_figure(OUT / "random_field_correlation.png", n)
    print("\nLiterature grid (0.25 m cells) for the correlation figure:")
    for r in cases:
        print_case(r)
    print(f"wrote {OUT / 'random_field_correlation.png'}")
    info = realizations_figure(OUT / "random_field_realizations.png")
    print(f"wrote {OUT / 'random_field_realizations.png'}: "
          + "; ".join(f"xi {i['xi']}: {i['min']:.1f}-{i['max']:.1f} kPa (mean {i['mean']:.2f})"
                      for i in info))

    tm = timings(a.quick)
    print("\nCost (median per field after the cached set-up):")
    for k, v in tm.items():
        print(f"  {k:12s} {v['cells']:8d} cells, embedding {v['embedding'][0]} x "
              f"{v['embedding'][1]}: set-up {v['setup_s']:.2f} s, "
              f"{v['ms_per_field']:.2f} ms per field")

    gs_n = 40 if a.quick else 150
    gsr = gstools_comparison(gs_n)
    if gsr:
        print(f"\ngstools (randomization, 1000 modes) vs circulant embedding, point field on "
              f"244 x 20 cells of 0.25 m, {gs_n} realizations:")
        for k, row in gsr.items():
            for name, v in row.items():
                print(f"  {k:5s} {name:9s} {1e3 * v['s_per_field']:8.1f} ms/field, variance "
                      f"{v['variance']:.3f}, corr at theta x {v['corr_x_at_theta']:.3f} y "
                      f"{v['corr_y_at_theta']:.3f} (target {v['target_at_theta']:.3f}), excess "
                      f"kurtosis of the domain average {v['excess_kurtosis']:+.2f} "
                      f"(SE {v['kurtosis_se']:.2f})")
    (OUT / "random_field_stats.json").write_text(json.dumps(
        {"table": table, "figure_cases": cases, "realizations": info, "timings": tm,
         "gstools": gsr}, indent=1))
    print(f"wrote {OUT / 'random_field_stats.json'} ({time.perf_counter() - t_all:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
