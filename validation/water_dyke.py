"""River dyke with a phreatic line: FS and P(failure) at two river levels.

``meshes/dyke_water.toml`` (cross-correlated random c' and phi' of the dyke) at mean
water (river 6 m, 2 m above the ground) and high water (river 9 m, the scene's), on the
same N realizations (the same seeds: each realization's fields are the same at both
levels, so the change of FS is the water's).  Per realization the strength-reduction
FS (bracketed to 1 %); P(failure) = P(FS < 1) with its Wilson 95 % interval, the mean FS
with a t interval, and the paired differences.  Writes ``water_dyke.json`` and the
figures ``water_dyke_fs.png`` (FS of each realization, low against high water, and the
empirical distributions) and ``water_dyke_scene.png`` (the dyke and both phreatic lines)
to ``--out``.

    python validation/water_dyke.py -n 20 --out docs/validation/figures
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from fem_rmpm import api
from fem_rmpm.io.plots import _plt, draw_ground
from fem_rmpm.scene import load_scene, with_values

SCENE = Path(__file__).parents[1] / "meshes" / "dyke_water.toml"
LEVELS = {"mean water (river 6 m)": [[0.0, 6.0], [8.0, 6.0], [31.0, 4.2], [40.0, 3.8]],
          "high water (river 9 m)": [[0.0, 9.0], [14.0, 9.0], [31.0, 4.4], [40.0, 3.8]]}


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion k / n."""
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def mean_interval(x: np.ndarray) -> tuple[float, float, float]:
    """Mean and its 95 % t interval (scipy's t quantile)."""
    from scipy.stats import t
    m, s = float(np.mean(x)), float(np.std(x, ddof=1))
    h = t.ppf(0.975, len(x) - 1) * s / math.sqrt(len(x))
    return m, m - h, m + h


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=20)
    ap.add_argument("--out", default=".")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = load_scene(SCENE)
    seeds = [base.montecarlo.seed + k for k in range(args.n)]
    fs = {name: [] for name in LEVELS}
    cpu = 0.0
    for seed in seeds:
        for name, line in LEVELS.items():
            t0 = time.process_time()
            res = api.factor_of_safety(with_values(base, {"water.phreatic_surface": line}),
                                       seed=seed)
            cpu += time.process_time() - t0
            fs[name].append(res.fs)
        print(seed, *(f"{fs[k][-1]:.3f}" for k in LEVELS), flush=True)
    rows = {}
    for name in LEVELS:
        x = np.array(fs[name])
        k = int(np.sum(x < 1.0))
        m, lo, hi = mean_interval(x)
        rows[name] = {"fs": x.tolist(), "mean_fs": m, "mean_fs_95": [lo, hi],
                      "failures": k, "p_failure": k / len(x), "p_failure_95": wilson(k, len(x))}
    a, b = (np.array(fs[k]) for k in LEVELS)
    d = mean_interval(b - a)
    summary = {"n": args.n, "seeds": seeds, "levels": rows, "paired_change_fs": d,
               "realizations_with_lower_fs_at_high_water": int(np.sum(b < a)),
               "cpu_s": cpu}
    (out / "water_dyke.json").write_text(json.dumps(summary, indent=1))
    print("| river level | mean FS (95 %) | P(FS < 1) (95 % Wilson) |")
    print("|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {r['mean_fs']:.3f} ({r['mean_fs_95'][0]:.3f}-{r['mean_fs_95'][1]:.3f})"
              f" | {r['failures']}/{args.n} = {r['p_failure']:.2f} ({r['p_failure_95'][0]:.2f}-"
              f"{r['p_failure_95'][1]:.2f}) |")
    print(f"paired change of FS, high - mean water: {d[0]:.3f} ({d[1]:.3f} to {d[2]:.3f}); "
          f"lower in {summary['realizations_with_lower_fs_at_high_water']}/{args.n}; "
          f"CPU {cpu:.0f} s")
    _figures(out, base, fs)


def _figures(out: Path, base, fs: dict) -> None:
    plt = _plt()
    names = list(LEVELS)
    a, b = (np.array(fs[k]) for k in names)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].plot(a, b, "o", ms=4)
    lim = [min(a.min(), b.min()) - 0.05, max(a.max(), b.max()) + 0.05]
    ax[0].plot(lim, lim, "k:", lw=0.8, label="equal FS")
    ax[0].axhline(1.0, color="r", lw=0.8)
    ax[0].axvline(1.0, color="r", lw=0.8, label="FS = 1")
    ax[0].set_xlabel(f"FS, {names[0]}")
    ax[0].set_ylabel(f"FS, {names[1]}")
    ax[0].legend(fontsize=8)
    ax[0].set_title("each realization at both levels")
    for name, x in zip(names, (a, b)):
        xs = np.sort(x)
        ax[1].step(xs, np.arange(1, len(xs) + 1) / len(xs), where="post", label=name)
    ax[1].axvline(1.0, color="r", lw=0.8)
    ax[1].set_xlabel("FS")
    ax[1].set_ylabel("P(FS <= x)")
    ax[1].legend(fontsize=8)
    ax[1].set_title(f"empirical distribution, N = {len(a)}")
    fig.tight_layout()
    fig.savefig(out / "water_dyke_fs.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(10, 3.6))
    draw_ground(ax, dataclasses.replace(base, water=None))
    for name, line in LEVELS.items():
        L = np.array(line)
        ax.plot(L[:, 0], L[:, 1], lw=1.2, label=f"phreatic line, {name}")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_ylim(-0.5, 11)
    ax.legend(fontsize=7, loc="upper right")
    ax.set_title("river dyke: soils and the two phreatic lines")
    fig.tight_layout()
    fig.savefig(out / "water_dyke_scene.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
