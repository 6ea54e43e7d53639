"""Subset simulation against crude Monte Carlo on the risk slope.

From a finished crude campaign of a scene (``fem-rmpm mc SCENE --out CRUDE``; its
per-realization records ``CRUDE/records/<case>/realization_*.json``) the script takes one
case and a response threshold at which crude Monte Carlo reaches the probability
(``--threshold X``, or ``--target 0.05``: the threshold midway between the k-th and
(k+1)-th largest crude responses, k = round(0.05 N)), and

* the crude estimate: P = k / N over the case's ok records (numerically failed
  realizations left out and counted), its standard error and Wilson 95 % interval;
* the subset estimate: :func:`fem_rmpm.campaign.run_subset_campaign` on the SAME case
  scene (rebuilt from ``SCENE`` and the case text and checked against the crude
  campaign's ``campaign.json``) with campaign seed ``--seed`` (default 1818, not the crude
  campaign's seed: subset level 0 would otherwise be the crude realizations 0..N-1 and
  the two estimates would share samples), p0 = 0.1, ``-n`` per level; P, its Au & Beck
  COV, and a 95 % interval P exp(+-1.96 s), s^2 = ln(1 + COV^2) (lognormal: the subset
  estimator is a product of level factors).

Agreement: the two 95 % intervals overlap; also printed, the difference
in units of its standard error sqrt(SE_crude^2 + (COV P_subset)^2) and whether each
estimate lies inside the other's interval.  Records of the subset campaign are in
``--out`` (a killed run resumes: re-run the same command).

Usage::

    nice -n 10 python validation/subset_vs_crude.py meshes/slope_risk.toml runs/risk \\
        --case xi=12 --response runout_distance --target 0.05 -n 200 --out runs/subset_risk
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

Z95 = 1.959963984540054


def case_scene(scene_file: str, crude: Path, case: str, sets: list[str] = ()):
    """(Case, crude campaign seed) of ``case`` (its name or spec) rebuilt from ``scene_file``
    with the crude campaign's ``--set KEY=VALUE`` overrides ``sets``; CampaignError unless
    it is the scene of that case in ``crude/campaign.json``."""
    from fem_rmpm import api
    from fem_rmpm.campaign.cases import CampaignError, parse_case
    from fem_rmpm.campaign.store import _identity_dict, _strip_identity
    from fem_rmpm.cli import parse_settings
    from fem_rmpm.scene import with_values
    doc = json.loads((crude / "campaign.json").read_text())
    stored = [c for c in doc["cases"] if case in (c["name"], c["spec"])]
    if not stored:
        raise CampaignError(f"{crude}: no case {case!r}; it has "
                            + ", ".join(c["spec"] for c in doc["cases"]))
    base = with_values(api.load_scene(scene_file), parse_settings(list(sets), scene_file))
    c = parse_case(stored[0]["spec"], base)
    if _identity_dict(c.scene) != _strip_identity(stored[0]["scene"]):
        raise CampaignError(f"{scene_file} with case {c.spec!r} is not the scene of the "
                            f"campaign in {crude} (the scene file changed since)")
    return c, int(doc["campaign_seed"])


def crude_records(crude: Path, case: str, response: str, n: int | None) -> dict:
    """Responses of the case's ok records (index < n if given), CPU, failed count."""
    from fem_rmpm.campaign.store import read_record
    values, cpu, failed, idx = [], 0.0, 0, []
    for path in sorted((crude / "records" / case).glob("realization_*.json")):
        rec = read_record(path)
        if rec is None or (n is not None and rec["index"] >= n):
            continue
        cpu += float(rec.get("cpu_time") or 0.0)
        if rec["status"] != "ok":
            failed += 1
            continue
        values.append(float(rec["measures"][response]))
        idx.append(int(rec["index"]))
    return {"values": np.array(values), "indices": idx, "cpu_time": cpu, "failed": failed}


def threshold_for(values: np.ndarray, target: float) -> float:
    """Midway between the k-th and (k+1)-th largest value, k = round(target N)."""
    y = np.sort(values)[::-1]
    k = max(1, min(len(y) - 1, int(round(target * len(y)))))
    return float(0.5 * (y[k - 1] + y[k]))


def crude_estimate(values: np.ndarray, threshold: float) -> dict:
    from fem_rmpm.campaign import wilson_interval
    n, k = len(values), int(np.count_nonzero(values > threshold))
    p = k / n
    return {"n": n, "k": k, "p": p, "se": math.sqrt(p * (1 - p) / n),
            "interval95": list(wilson_interval(k, n))}


def subset_interval(p: float, cov: float) -> list[float]:
    s = math.sqrt(math.log(1 + cov * cov))
    return [p * math.exp(-Z95 * s), p * math.exp(Z95 * s)]


def compare(crude: dict, p: float, cov: float) -> dict:
    lo_c, hi_c = crude["interval95"]
    lo_s, hi_s = subset_interval(p, cov)
    se = math.sqrt(crude["se"] ** 2 + (cov * p) ** 2)
    return {"subset_interval95": [lo_s, hi_s], "overlap": lo_s <= hi_c and lo_c <= hi_s,
            "subset_in_crude": lo_c <= p <= hi_c, "crude_in_subset": lo_s <= crude["p"] <= hi_s,
            "difference_in_se": (p - crude["p"]) / se if se > 0 else math.inf}


def main(argv=None) -> int:
    from fem_rmpm.campaign import run_subset_campaign
    from fem_rmpm.scene import with_value
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", help="the crude campaign's scene file")
    ap.add_argument("crude", help="the crude campaign directory (records/<case>/)")
    ap.add_argument("--case", required=True, help="case name or text, e.g. xi=12")
    ap.add_argument("--response", default="runout_distance")
    ap.add_argument("--threshold", type=float, default=None, help="failure: response > X")
    ap.add_argument("--target", type=float, default=0.05,
                    help="without --threshold: the crude P the threshold is placed at")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a scene override the crude campaign was run with")
    ap.add_argument("--crude-n", type=int, default=None, help="use crude realizations < N")
    ap.add_argument("-n", type=int, default=200, help="subset samples per level")
    ap.add_argument("--p0", type=float, default=0.1)
    ap.add_argument("--seed", type=int, default=1818, help="subset campaign seed")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", required=True, help="subset campaign directory")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    crude_dir = Path(a.crude)
    case, crude_seed = case_scene(a.scene, crude_dir, a.case, a.set)
    if a.seed == crude_seed:
        print(f"--seed {a.seed} is the crude campaign's seed: the estimates would share "
              "their level-0 samples; choose another", file=sys.stderr)
        return 2
    rec = crude_records(crude_dir, case.name, a.response, a.crude_n)
    thr = a.threshold if a.threshold is not None else threshold_for(rec["values"], a.target)
    crude = crude_estimate(rec["values"], thr)
    crude.update(failed_numerically=rec["failed"], cpu_time=rec["cpu_time"])
    print(f"crude ({crude_dir}, case {case.spec}, seed {crude_seed}): P({a.response} > "
          f"{thr:.4g}) = {crude['k']}/{crude['n']} = {crude['p']:.4f}, SE {crude['se']:.4f}, "
          f"Wilson 95 % [{crude['interval95'][0]:.4f}, {crude['interval95'][1]:.4f}]; "
          f"{rec['failed']} failed numerically; {rec['cpu_time']:.0f} s CPU", flush=True)
    scene = with_value(case.scene, "montecarlo.seed", a.seed)
    res = run_subset_campaign(scene, a.out, a.response, thr, p0=a.p0, n=a.n, workers=a.workers)
    r = res.result
    if r is None:
        print(f"{len(res.lost)} subset samples lost: re-run the same command", file=sys.stderr)
        return 3
    summary = json.loads((Path(a.out) / "summary.json").read_text())
    cmp_ = compare(crude, r.probability, r.cov)
    lo, hi = cmp_["subset_interval95"]
    cpu = summary["realization_cpu_time"]["total"]
    print(f"subset (seed {a.seed}, N = {a.n} per level, p0 = {a.p0}): P = {r.probability:.4f}, "
          f"COV {r.cov:.3f}, 95 % [{lo:.4f}, {hi:.4f}], {len(r.levels)} levels, thresholds "
          + ", ".join(f"{b:.4g}" for b in r.thresholds[:-1])
          + f"; {r.total_runs} runs ({r.failed_runs} failed numerically), {cpu:.0f} s CPU")
    for note in r.notes:
        print(f"  note: {note}")
    print("intervals " + ("overlap" if cmp_["overlap"] else "DO NOT overlap")
          + f"; difference {cmp_['difference_in_se']:+.2f} SE; subset inside crude's "
          f"interval: {cmp_['subset_in_crude']}; crude inside subset's: "
          f"{cmp_['crude_in_subset']}; wall {time.perf_counter() - t0:.0f} s")
    doc = {"args": vars(a), "case": case.spec, "threshold": thr, "crude": crude,
           "subset": summary["subset"], "subset_cpu_time": cpu, "comparison": cmp_}
    (Path(a.out) / "subset_vs_crude.json").write_text(json.dumps(doc, indent=2))
    print(f"written {Path(a.out) / 'subset_vs_crude.json'}")
    return 0 if cmp_["overlap"] else 1


if __name__ == "__main__":
    sys.exit(main())
