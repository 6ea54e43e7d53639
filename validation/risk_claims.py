"""The seed paper's claims, tested over many realizations of its slope
(``meshes/slope_reference.toml``, Wang, Vardon & Hicks 2017).

Claims (from the paper's single realizations per case):

* "xi = 48 fails about a third of the depth above the base": the failure surface's height
  above the base (``slip_surface_height``, m) above H/4 = 1.25 m (H = 5 m, the layer at
  the crest).  The fraction of the xi = 48 realizations with height > H/4, with its Wilson
  95 % interval.  Verdict: "supported as the typical outcome" when the interval lies above
  0.5, "not supported as the typical outcome" when it lies below 0.5 (and "occurs in ..."
  when it is above 0), "undecided" otherwise.
* "xi = 12 is the most disturbed": intact blocks at the mechanism time (``intact_blocks``):
  the mean per case with its 95 % interval (mean +- 1.96 SE); "supported" when xi = 12's
  mean exceeds each other random case's by more than 1.96 SE of the difference (Welch),
  "not supported" when another case's exceeds xi = 12's that way, "undecided" otherwise.

Run (resumable; every realization run to rest)::

    fem-rmpm mc meshes/slope_reference.toml -n 50 --case xi=1 --case xi=12 --case xi=48 \\
        --keep-vtk 0 --out runs/claims
    python validation/risk_claims.py runs/claims [--figures]

``--figures`` re-runs the realization closest to each claim (``fem_rmpm.api.run`` with its
seed, ~40 s CPU each) and writes its plastic-strain figure.  Writes ``claims.json`` and
``claims.md`` (the table of the documentation page) into the campaign directory.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from fem_rmpm.campaign.statistics import wilson_interval

H = 5.0                    # m, the layer's thickness on the main slope
HEIGHT_LIMIT = H / 4       # m


def _mean_ci(x: np.ndarray, exact: bool = False) -> dict:
    """Mean, SE and mean +- 1.96 SE; ``exact``: a deterministic case (SE 0)."""
    n = len(x)
    if n == 0:
        return {"n": 0, "mean": None, "se": None, "ci95": None}
    se = 0.0 if exact else (float(np.std(x, ddof=1) / math.sqrt(n)) if n > 1 else math.inf)
    m = float(np.mean(x))
    return {"n": n, "mean": m, "se": se, "ci95": [m - 1.96 * se, m + 1.96 * se]}


def case_claims(rows: list[dict], deterministic: bool = False) -> dict:
    """Per case: N, failures, the slip-surface heights (quantiles), how many lie above
    H/4 (of the failures, with the Wilson interval), and the intact blocks (mean, CI,
    distribution)."""
    ok = [r for r in rows if r["status"] == "ok" and r.get("failed") is not None]
    fails = [r for r in ok if r["failed"] and r.get("slip_surface_height") is not None]
    h = np.array([float(r["slip_surface_height"]) for r in fails])
    k = int((h > HEIGHT_LIMIT).sum())
    blocks = np.array([float(r["intact_blocks"]) for r in ok
                       if r.get("intact_blocks") is not None])
    q = np.quantile(h, [0.05, 0.5, 0.95]).tolist() if len(h) else [None] * 3
    return {"n": len(ok), "failures": sum(bool(r["failed"]) for r in ok),
            "height": {"n": len(h), "q05": q[0], "median": q[1], "q95": q[2],
                       "above_h4": k, "fraction_above_h4": k / len(h) if len(h) else None,
                       "wilson95": list(wilson_interval(k, len(h))) if len(h) else None},
            "blocks": {**_mean_ci(blocks, deterministic),
                       "counts": {int(v): int((blocks == v).sum()) for v in np.unique(blocks)}}}


def verdict_height(c: dict) -> str:
    h = c["height"]
    if not h["n"]:
        return "undecided: no failure"
    lo, hi = h["wilson95"]
    tail = (f"at N = {h['n']} failures, {h['above_h4']} above H/4, fraction "
            f"{h['fraction_above_h4']:.2f}, Wilson 95 % [{lo:.2f}, {hi:.2f}]")
    if lo > 0.5:
        return "supported as the typical outcome " + tail
    if hi < 0.5:
        return ("not supported as the typical outcome" + (" (it occurs) " if h["above_h4"]
                                                          else " (never seen) ") + tail)
    return "undecided " + tail


def verdict_blocks(cases: dict[str, dict], claim_case: str = "xi12") -> str:
    b = cases[claim_case]["blocks"]
    if not b["n"]:
        return "undecided: no realization"
    others = {k: v["blocks"] for k, v in cases.items() if k != claim_case and v["blocks"]["n"]}
    diffs = {k: (b["mean"] - o["mean"], 1.96 * math.hypot(b["se"], o["se"]))
             for k, o in others.items()}
    txt = "; ".join(f"xi = 12 minus {k}: {d:+.2f} +- {e:.2f}" for k, (d, e) in diffs.items())
    lo, hi = b["ci95"]
    head = f"at N = {b['n']}, mean blocks {b['mean']:.2f} [{lo:.2f}, {hi:.2f}]; "
    if diffs and all(d > e for d, e in diffs.values()):
        return "supported " + head + txt
    if any(d < -e for d, e in diffs.values()):
        return "not supported " + head + txt
    return "undecided " + head + txt


def closest(rows: list[dict], key: str, target: float) -> dict | None:
    """The failed realization whose ``key`` is closest to ``target`` (lowest index first)."""
    c = [r for r in rows if r["status"] == "ok" and r.get("failed") and r.get(key) is not None]
    return min(c, key=lambda r: (abs(float(r[key]) - target), r["index"])) if c else None


def markdown(cases: dict[str, dict], verdicts: dict[str, str]) -> str:
    lines = ["| case | N | failures | slip-surface height: median [5 %, 95 %] (m) | "
             "above H/4: k / n [Wilson 95 %] | intact blocks: mean [95 %] |",
             "|---|---|---|---|---|---|"]
    for name, c in cases.items():
        h, b = c["height"], c["blocks"]
        w = h["wilson95"] or [float("nan")] * 2
        lines.append(f"| {name} | {c['n']} | {c['failures']} | {h['median'] or 0:.2f} "
                     f"[{h['q05'] or 0:.2f}, {h['q95'] or 0:.2f}] | {h['above_h4']} / {h['n']} "
                     f"[{w[0]:.2f}, {w[1]:.2f}] | {b['mean'] or 0:.2f} "
                     f"[{(b['ci95'] or [0, 0])[0]:.2f}, {(b['ci95'] or [0, 0])[1]:.2f}] |")
    lines += ["", f"- xi = 48 fails about H/3 above the base: {verdicts['height']}",
              f"- xi = 12 is the most disturbed: {verdicts['blocks']}"]
    return "\n".join(lines) + "\n"


def figures(campaign: Path, picks: dict[str, dict]) -> dict[str, str]:
    """Re-run each picked realization (its case scene and seed) and keep its figure."""
    from fem_rmpm import api
    from fem_rmpm.campaign.cases import parse_case
    scene = api.load_scene(Path(__file__).resolve().parents[1] / "meshes" /
                           "slope_reference.toml")
    out = {}
    for claim, r in picks.items():
        if r is None:
            continue
        case = parse_case("xi=" + r["case"][2:], scene)
        d = campaign / f"claim_{claim}"
        api.run(case.scene, out=d, seed=r["seed"], progress=False, force=True)
        out[claim] = str(d / "plastic_shear_strain.png")
    return out


def read_rows(campaign: Path) -> list[dict]:
    """One flat row per finished record (``records/<case>/*.json``; works on a campaign
    that was stopped before it wrote ``results.csv``)."""
    rows = []
    for p in sorted((campaign / "records").rglob("*.json")):
        r = json.loads(p.read_text())
        rows.append({"case": r["case"], "index": r["index"], "seed": r["seed"],
                     "status": r["status"], **(r.get("measures") or {})})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("campaign", type=Path)
    p.add_argument("--figures", action="store_true")
    a = p.parse_args(argv)
    rows = read_rows(a.campaign)
    names = list(dict.fromkeys(r["case"] for r in rows))
    cases = {n: case_claims([r for r in rows if r["case"] == n], n == "homogeneous")
             for n in names}
    verdicts = {"height": verdict_height(cases["xi48"]) if "xi48" in cases else "no xi = 48",
                "blocks": verdict_blocks(cases) if "xi12" in cases else "no xi = 12"}
    picks = {"height": closest([r for r in rows if r["case"] == "xi48"],
                               "slip_surface_height", H / 3),
             "blocks": max((r for r in rows if r["case"] == "xi12" and r["status"] == "ok"
                            and r.get("intact_blocks") is not None),
                           key=lambda r: (r["intact_blocks"], -r["index"]), default=None)}
    doc = {"H": H, "height_limit": HEIGHT_LIMIT, "cases": cases, "verdicts": verdicts,
           "closest": {k: (None if r is None else {"case": r["case"], "index": r["index"],
                                                     "seed": r["seed"],
                                                     "slip_surface_height": r.get(
                                                         "slip_surface_height"),
                                                     "intact_blocks": r.get("intact_blocks")})
                       for k, r in picks.items()}}
    if a.figures:
        doc["figures"] = figures(a.campaign, picks)
    (a.campaign / "claims.json").write_text(json.dumps(doc, indent=2))
    md = markdown(cases, verdicts)
    (a.campaign / "claims.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
