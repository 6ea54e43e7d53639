"""Subset simulation of P(FS < 1) on the Griffiths slope against its closed form.

The slope: ``meshes/griffiths_slope.toml`` (the undrained 2:1 slope on a foundation layer
of Griffiths & Lane 1999 and Griffiths & Fenton 2004), with a lognormal random field of
the undrained cohesion ``cohesion_peak`` of scale of fluctuation theta = 1e4 m (isotropic
Markov, COV ``--cov`` 0.3): the single-random-variable field.  On this 65 m x 20 m slope
the field library represents it by ONE standard-normal variable on every cell
(:class:`fem_rmpm.random_field.embedding.SingleVariable`, chosen when the correlation
between the two farthest field cells is >= 0.98; here exp(-2 x 68.0 / 1e4) = 0.9865, so a
true Markov field of theta = 1e4 m differs from a constant by less than
sqrt(2 (1 - 0.9865)) = 0.16 of its standard deviation anywhere).  The script checks that
the noise has one component and that the cohesion of every material point of a
realization is the same (to 1e-12 relative).

Every sample's FS is a full strength reduction (:mod:`fem_rmpm.schemes.implicit.strength_reduction`,
bracket tolerance ``--tolerance``) run by the subset campaign of
:func:`fem_rmpm.campaign.run_subset_campaign` (``--response factor_of_safety``,
failure FS < 1, p0 = 0.1, ``-n`` samples per level) on a local Dask cluster: records
per sample in ``--out``, so a killed run resumes where it stopped (re-run the same
command).  The search's first trial is F = 1 applied from zero (the failure
criterion: Newton does not converge in a load step after the cuts), so every sample is
classified against the FINAL threshold FS = 1 exactly, whatever the tolerance; the
tolerance only sets how finely the intermediate thresholds (quantiles of FS) are
resolved.  A coarse tolerance makes many samples share one FS value (the bisection
lattice), and tied values at a level's quantile bias that level's factor low (the
seeds are N p0 of them, the next level's domain holds all); the script prints the
number of samples tied at each intermediate threshold.

Closed form.  For an undrained (phi = 0) soil with one cohesion c everywhere, strength
reduction divides c by F, so the criterion "F = 1 fails" holds exactly when c <
c_crit, the cohesion at which the slope fails at F = 1: c_crit = c_0 / FS_0 with FS_0
the factor of safety of the homogeneous slope at c_0 = 50 kPa found with every trial
from zero (``continuation = False``, the criterion of the F = 1 trial) to a bracket of
``--crit-tolerance`` (1e-3).  P(FS < 1) = P(c < c_crit) = Phi((ln c_crit - m_ln) /
s_ln), s_ln^2 = ln(1 + COV^2); the mean cohesion is set so that this is ``--target``
(1e-3).  d ln P / d ln c_crit is about 11 here, so c_crit's 5e-4 search error moves
the closed form by about 0.6 %.  The script also prints how far the samples' FS are
from c / c_crit (the proportionality), which the tolerance bounds.

Criterion: the subset estimate within two of its own coefficients of variation of the
closed form, |P / P_exact - 1| <= 2 COV; printed with the number of FS evaluations
against the (1 - P) / (P 0.1^2) = 99 900 runs crude Monte Carlo needs for a 10 % COV.

Mesh and cost (one FS of the homogeneous slope, CPU time, shared machine, tolerance
0.005 unless said): 5 m cells (160 points) FS 1.478, 8 static
solves, 0.48 s; 2.5 m (640 points) 1.474, 0.87 s; 1 m (4000 points, tolerance 0.01)
1.464, 3.5 s; Taylor's chart 1.47.  The default ``--cell 5`` is the coarsest of these
and within 1.0 % of the 1 m value (0.5 % of Taylor's).

Usage::

    nice -n 10 python validation/subset_griffiths.py -n 500 --out runs/subset_griffiths
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
THETA = 1e4                   # m
C0 = 50.0                     # kPa, the scene's cohesion (C = c / (gamma H) = 0.25)


def griffiths_scene(cell: float, cohesion: float, cov: float | None = None, seed: int = 1):
    """The Griffiths slope with ``cell`` m cells and mean cohesion ``cohesion`` (kPa); with
    ``cov`` a lognormal theta = 1e4 m field of ``cohesion_peak`` and campaign seed ``seed``."""
    from fem_rmpm import api
    from fem_rmpm.scene import with_values
    values = {"grid.cell": cell, "soil.cohesion_peak": cohesion,
              "soil.cohesion_residual": cohesion}
    if cov is not None:
        values.update({"random_field.property": "cohesion_peak",
                       "random_field.distribution": "lognormal", "random_field.cov": cov,
                       "random_field.theta_v": THETA, "random_field.anisotropy": 1.0,
                       "montecarlo.seed": seed})
    return with_values(api.load_scene(ROOT / "meshes" / "griffiths_slope.toml"), values)


def critical_cohesion(cell: float, tolerance: float, out: Path) -> dict:
    """c_crit = C0 / FS(C0), every trial from zero; cached in ``out/c_crit.json``."""
    from fem_rmpm import api
    from fem_rmpm.schemes.implicit.strength_reduction import FSOptions, factor_of_safety
    path = out / "c_crit.json"
    if path.exists():
        doc = json.loads(path.read_text())
        if doc["cell"] == cell and doc["tolerance"] == tolerance:
            return doc
    scene = griffiths_scene(cell, C0)
    grid, pts = api.prepare(scene)
    c = time.process_time()
    res = factor_of_safety(scene, None, FSOptions(tolerance=tolerance, continuation=False),
                           grid=grid, pts=pts)
    doc = {"cell": cell, "tolerance": tolerance, "c0": C0, "fs0": res.fs,
           "bracket": list(res.bracket), "static_solves": res.static_solves,
           "cpu_time": time.process_time() - c, "c_crit": C0 / res.fs}
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=2))
    return doc


def check_single_variable(scene) -> dict:
    """The theta = 1e4 m field is one variable: noise size 1, one cohesion on all points."""
    from fem_rmpm import api
    from fem_rmpm.discretise.grid import make_grid
    from fem_rmpm.random_field import noise_shape
    shape = noise_shape(scene, make_grid(scene))
    spread = []
    for seed in (1, 2, 3):
        _, pts = api.prepare(scene, seed)
        c = pts.soil.cohesion_peak
        spread.append(float(np.ptp(c) / np.mean(c)))
    ok = math.prod(shape) == 1 and max(spread) <= 1e-12
    return {"noise_shape": list(shape), "relative_spread": max(spread), "constant": ok}


def lognormal(c_crit: float, cov: float, target: float):
    """(m_ln, s_ln, mean) of the lognormal cohesion with P(c < c_crit) = target."""
    from scipy.stats import norm
    s_ln = math.sqrt(math.log(1 + cov * cov))
    m_ln = math.log(c_crit) - s_ln * float(norm.ppf(target))
    return m_ln, s_ln, math.exp(m_ln + s_ln * s_ln / 2)


def tied_at_thresholds(levels) -> list[int]:
    """Per intermediate level: distinct-valued samples beyond one at its threshold."""
    ties = []
    for lv in levels[:-1]:
        y = np.asarray(lv.responses)
        ties.append(int(np.count_nonzero(y == lv.threshold)))
    return ties


def proportionality(scene, out: Path, m_ln: float, s_ln: float, c_crit: float) -> dict:
    """Largest |FS / (c / c_crit) - 1| over the samples with an exact FS ("=")."""
    from fem_rmpm.campaign.store import read_record
    from fem_rmpm.campaign.subset_runner import sample_noises
    dev, n = 0.0, 0
    for key, noise in sample_noises(scene, out):
        rec = read_record(out / "records" / f"{key}.json")
        m = (rec or {}).get("measures") or {}
        if rec is None or rec["status"] != "ok" or m.get("fs_bound") != "=":
            continue
        c = math.exp(m_ln + s_ln * float(np.ravel(noise)[0]))
        dev = max(dev, abs(rec["value"] / (c / c_crit) - 1.0))
        n += 1
    return {"max_deviation": dev, "samples": n}


def main(argv=None) -> int:
    from scipy.stats import norm

    from fem_rmpm.campaign import run_subset_campaign
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("-n", type=int, default=500, help="samples per level")
    p.add_argument("--p0", type=float, default=0.1)
    p.add_argument("--cov", type=float, default=0.3, help="COV of the cohesion")
    p.add_argument("--target", type=float, default=1e-3, help="closed-form P(FS < 1)")
    p.add_argument("--cell", type=float, default=5.0, help="cell size (m)")
    p.add_argument("--tolerance", type=float, default=0.005,
                   help="FS bracket tolerance of the samples")
    p.add_argument("--crit-tolerance", type=float, default=1e-3,
                   help="FS bracket tolerance of the closed form's c_crit")
    p.add_argument("--seed", type=int, default=1, help="campaign seed")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--out", default=str(ROOT / "runs" / "subset_griffiths"))
    a = p.parse_args(argv)
    t0, c0 = time.perf_counter(), time.process_time()
    out = Path(a.out)
    crit = critical_cohesion(a.cell, a.crit_tolerance, out)
    c_crit = crit["c_crit"]
    m_ln, s_ln, mean = lognormal(c_crit, a.cov, a.target)
    exact = float(norm.cdf((math.log(c_crit) - m_ln) / s_ln))
    print(f"FS({C0:g} kPa) = {crit['fs0']:.5f} (every trial from zero, bracket "
          f"{crit['bracket'][0]:.5f}-{crit['bracket'][1]:.5f}, {crit['static_solves']} solves, "
          f"{crit['cpu_time']:.1f} s CPU) -> c_crit = {c_crit:.4f} kPa; lognormal cohesion, "
          f"COV {a.cov}, mean {mean:.3f} kPa: closed-form P(FS < 1) = {exact:.4g}", flush=True)
    scene = griffiths_scene(a.cell, mean, a.cov, a.seed)
    single = check_single_variable(scene)
    print(f"theta = {THETA:g} m field: noise shape {tuple(single['noise_shape'])}, relative "
          f"spread of the points' cohesion {single['relative_spread']:.1e} -> "
          + ("one variable" if single["constant"] else "NOT constant"), flush=True)
    if not single["constant"]:
        return 1
    res = run_subset_campaign(scene, out / "campaign", "factor_of_safety", 1.0, p0=a.p0,
                              n=a.n, workers=a.workers,
                              fs_options={"tolerance": a.tolerance})
    r = res.result
    if r is None:
        print(f"{len(res.lost)} samples lost: re-run the same command", file=sys.stderr)
        return 3
    ratio = r.probability / exact - 1.0
    z = abs(ratio) / r.cov
    crude_10 = (1 - exact) / (exact * 0.1 ** 2)
    ties = tied_at_thresholds(r.levels)
    prop = proportionality(scene, out / "campaign", m_ln, s_ln, c_crit)
    summary = json.loads((out / "campaign" / "summary.json").read_text())
    cpu = summary["realization_cpu_time"]
    print(f"subset simulation: P(FS < 1) = {r.probability:.4g}, COV {r.cov:.3f} (Au & Beck), "
          f"{len(r.levels)} levels, thresholds "
          + ", ".join(f"FS < {-b:.4f}" for b in r.thresholds[:-1])
          + f"; samples tied at them: {ties}")
    print(f"closed form {exact:.4g}: P / P_exact - 1 = {ratio:+.3f} = {z:.2f} COV -> "
          + ("within" if z <= 2 else "NOT within") + " two COVs")
    print(f"FS evaluations: {r.total_runs} ({r.failed_runs} failed numerically) against "
          f"{crude_10:.0f} for crude Monte Carlo at a 10 % COV ({crude_10 / r.total_runs:.0f}x); "
          f"{r.crude_equivalent_runs:.0f} crude runs for this COV "
          f"({r.crude_equivalent_runs / r.total_runs:.1f}x)")
    print(f"FS(c) = c / c_crit within {prop['max_deviation']:.2%} over {prop['samples']} "
          f"samples; FS CPU {cpu['total']:.0f} s in all, {cpu['mean']:.2f} s mean (workers); "
          f"this process {time.process_time() - c0:.0f} s CPU, "
          f"{time.perf_counter() - t0:.0f} s wall")
    doc = {"args": vars(a), "critical": crit, "mean_cohesion": mean, "exact": exact,
           "field": single, "subset": summary["subset"], "ratio_minus_one": ratio,
           "deviations_in_cov": z, "within_two_covs": z <= 2, "tied_at_thresholds": ties,
           "proportionality": prop, "crude_runs_for_10_percent": crude_10,
           "fs_cpu_time": cpu, "wall_time": time.perf_counter() - t0}
    (out / "subset_griffiths.json").write_text(json.dumps(doc, indent=2))
    print(f"written {out / 'subset_griffiths.json'}")
    return 0 if z <= 2 else 1


if __name__ == "__main__":
    sys.exit(main())
