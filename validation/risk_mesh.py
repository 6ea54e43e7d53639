"""The critical strength factor of a risk-slope realization on several meshes.

``lambda_crit`` of a realization is the factor on its strength (peak and residual cohesion
of every point multiplied by ``lambda``, the random field's pattern unchanged) at which the
MPM run passes from failing to standing: an "MPM factor of safety" ``1 / lambda_crit`` that
includes the progressive, post-peak part of the failure the peak-strength FS leaves out.
The realization fails in the campaign when ``lambda_crit > 1``, so P(failure) =
P(lambda_crit > 1), and the mesh dependence of the risk numbers becomes the shift of a
number between meshes (the random field lives on its own cells, ``cell_size``, so
realization i has the same field on every mesh).

Each run is the campaign's explicit run of the realization (same scene, seed
``realization_seed(campaign seed, i)``, same gravity phase), stopped early once decided:

* **fails** as soon as at least ``--fail-area`` m2 (default 1 m2, four points of a 0.5 m
  mesh) of points have moved more than the campaign's ``failure_displacement`` (0.5 m)
  -- checked at every output (1 s).  As in the campaign's ``failed`` measure, the
  displacement is ``x - x0``: the geostatic phase (fixed geometry) moves no point;
* **fails** also when it stands at the end with a point moved more than
  ``failure_displacement`` (the campaign's rule, stray points included here);
* **stands** when it comes to rest (the run's own stop), or at ``--t-cap`` (default 30 s)
  if then no point moved more than ``failure_displacement`` (standing slopes of the
  campaign come to rest by 14 s, failing ones have moved metres by 10 s).

``lambda_crit`` is bracketed from 1 in steps of ``--step`` (default 0.1) and bisected to
``--tol`` (default 0.01).  Every run is appended to ``runs.jsonl`` in ``--out`` and read back
on a re-run, so the script resumes after a kill and a new mesh or realization reuses nothing
it should not.  Usage::

    python validation/risk_mesh.py --case xi=48 --index 0 1 7 --cell 0.5 0.25 --out DIR
    python validation/risk_mesh.py --case homogeneous --cell 0.5 0.25 0.125 --out DIR
    python validation/risk_mesh.py --summary DIR        # the lambda_crit table
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from fem_rmpm import api
from fem_rmpm.campaign.cases import parse_case, realization_seed
from fem_rmpm.measures.deposit import moved_area
from fem_rmpm.scene import scene_from_dict, scene_to_dict, with_values
from fem_rmpm.schemes.explicit.loop import run_explicit


class _Decided(Exception):
    """Raised from the output callback once the run has failed."""


def scaled_scene(scene_path: str, case: str, cell: float, sets: dict):
    """The case's scene on cells of ``cell`` m, with the extra ``--set`` values; a value
    ``"-"`` removes a ``soil.`` key (e.g. ``softening_displacement`` when switching to
    ``regularisation = "nonlocal"``)."""
    scene = parse_case(case, api.load_scene(scene_path)).scene
    drop = [k.split(".", 1)[1] for k, v in sets.items() if v == "-" and k.startswith("soil.")]
    changes = {"grid.cell": cell, **{k: v for k, v in sets.items() if v != "-"}}
    if drop:
        data = scene_to_dict(scene)
        for so in data["soil"]:
            for k in drop:
                so.pop(k, None)
        for k, v in changes.items():
            sec, _, name = k.partition(".")
            for d in (data[sec] if isinstance(data[sec], list) else [data[sec]]):
                d[name] = v
        return scene_from_dict(data, scene.source)
    return with_values(scene, changes)


def block_mean(x0: np.ndarray, values: np.ndarray, size: float) -> np.ndarray:
    """Each point's value replaced by the mean of the points whose initial position
    ``x0`` (m) lies in the same square block of side ``size`` (m) from the origin."""
    ij = np.floor(x0 / size).astype(np.int64)
    _, label = np.unique(ij, axis=0, return_inverse=True)
    label = label.ravel()
    return (np.bincount(label, values) / np.bincount(label))[label]


def run_one(scene, seed, lam: float, fail_area: float, t_cap: float,
            average: float | None = None) -> dict:
    """One run of the realization with strength x ``lam`` (and, with ``average``, each
    point's strength the mean over blocks of ``average`` m); returns failed, decision time,
    CPU seconds and the geostatic end time."""
    grid, pts = api.prepare(scene, seed if scene.random_field is not None else None)
    s = pts.soil
    cp, cr = np.asarray(s.cohesion_peak, float), np.asarray(s.cohesion_residual, float)
    if average:
        ratio = cr / cp
        cp = block_mean(pts.x0, cp, average)
        cr = ratio * cp
    pts.soil = s.replace(cohesion_peak=lam * cp, cohesion_residual=lam * cr)
    thr = scene.montecarlo.failure_displacement
    scene = api.with_value(scene, "solver.t_end", min(scene.solver.t_end, t_cap))

    history = []

    def check(t, p):
        area = moved_area(p.x, p.x0, p.volume0, p.active, thr)
        ke = 0.5 * float((p.mass[:, None] * p.velocity ** 2).sum())
        history.append((round(t, 3), ke, area))
        if area >= fail_area:
            raise _Decided(t)

    c0 = time.process_time()
    out = {"lambda": lam}
    try:
        rec = run_explicit(scene, grid, pts, on_output=check)
    except _Decided as d:
        out.update(failed=True, t=float(d.args[0]), stop="moved")
    else:
        dmax = float(np.linalg.norm(pts.x - pts.x0, axis=1)[pts.active].max())
        out.update(failed=dmax > thr, t=rec.time, stop=rec.stop_reason, max_displacement=dmax,
                   geostatic_end=rec.solver.get("geostatic_end_time"))
    out["cpu"] = time.process_time() - c0
    out["history"] = history            # [(t s, point kinetic energy kJ/m, moved area m2)]
    return out


def critical_factor(runs: dict, do_run, step: float, tol: float,
                    start: float = 1.0) -> tuple[float, float]:
    """Bracket [lo, hi] of lambda_crit (fails at lo, stands at hi), from runs cached in
    ``runs`` {lambda: failed} and ``do_run(lam) -> failed`` for the missing ones; the
    search steps out from ``start`` by ``step``, then bisects to ``tol``."""
    def failed(lam):
        lam = round(lam, 4)
        if lam not in runs:
            runs[lam] = do_run(lam)
        return runs[lam]
    lam = start
    if failed(lam):
        lo, hi = lam, None
        while hi is None:
            lam = round(lam + step, 4)
            if failed(lam):
                lo = lam
            else:
                hi = lam
    else:
        lo, hi = None, lam
        while lo is None:
            lam = round(lam - step, 4)
            if failed(lam):
                lo = lam
            else:
                hi = lam
    while hi - lo > tol * 1.0001:
        mid = round(0.5 * (lo + hi), 4)
        if failed(mid):
            lo = mid
        else:
            hi = mid
    return lo, hi


def _key(r: dict) -> tuple:
    return (r["case"], r["index"], r["cell"], r["sets"])


def load_runs(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def summary(out: Path) -> list[dict]:
    """lambda_crit per (case, index, cell, sets) from ``runs.jsonl``: the bracket, its mid
    point and the CPU time of its runs."""
    groups: dict[tuple, list[dict]] = {}
    for r in load_runs(out / "runs.jsonl"):
        groups.setdefault(_key(r), []).append(r)
    rows = []
    for key, rs in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][3], kv[0][1], -kv[0][2])):
        fail = [r["lambda"] for r in rs if r["failed"]]
        stand = [r["lambda"] for r in rs if not r["failed"]]
        lo, hi = (max(fail) if fail else None), (min(stand) if stand else None)
        rows.append({"case": key[0], "index": key[1], "cell": key[2], "sets": key[3],
                     "lo": lo, "hi": hi, "runs": len(rs),
                     "mid": None if lo is None or hi is None else 0.5 * (lo + hi),
                     "fails_at_1": next((r["failed"] for r in rs if abs(r["lambda"] - 1) < 1e-9), None),
                     "cpu": sum(r["cpu"] for r in rs)})
    return rows


def markdown(rows: list[dict]) -> str:
    """The lambda_crit table: one line per (case, realization, scene change), one column
    per cell size (bracket mid point and half width), the shift of each finer mesh against
    the coarsest, and whether the realization fails at lambda = 1 on each mesh."""
    cells = sorted({r["cell"] for r in rows}, reverse=True)
    by: dict[tuple, dict] = {}
    for r in rows:
        by.setdefault((r["case"], r["index"], r["sets"]), {})[r["cell"]] = r
    head = ("| case | realization | change | " + " | ".join(f"lambda_crit at {c:g} m" for c in cells)
            + " | shift finer vs coarsest | fails at lambda = 1 | CPU s |")
    lines = [head, "|" + "---|" * (6 + len(cells))]
    for (case, index, sets), per in by.items():
        if all(r["lo"] is None or r["hi"] is None for r in per.values()):
            continue               # stand / fail runs only (--decide-only): see paired_decisions
        vals = []
        for c in cells:
            r = per.get(c)
            if r is None or r["mid"] is None:
                vals.append("-" if r is None else f"[{r['lo']}, {r['hi']}]")
            else:
                vals.append(f"{r['mid']:.3f} ± {0.5 * (r['hi'] - r['lo']):.3f}")
        mids = [(c, per[c]["mid"]) for c in cells if c in per and per[c]["mid"] is not None]
        shift = ", ".join(f"{(m / mids[0][1] - 1) * 100:+.1f} % ({c:g} m)" for c, m in mids[1:])
        fails = " / ".join({True: "yes", False: "no", None: "-"}[per[c]["fails_at_1"]]
                           for c in cells if c in per)
        cpu = sum(per[c]["cpu"] for c in per)
        lines.append(f"| {case} | {index} | {sets or '-'} | " + " | ".join(vals)
                     + f" | {shift or '-'} | {fails} | {cpu:.0f} |")
    return "\n".join(lines)


def paired_decisions(out: Path, case: str, coarse: float, fine: float, lam: float = 1.0) -> dict:
    """Stand / fail at ``lam`` of the realizations run on both meshes (no scene change):
    the count failing on each, the discordant pairs each way, with Wilson 95 % intervals."""
    from fem_rmpm.campaign import wilson_interval
    got: dict[int, dict[float, bool]] = {}
    for r in load_runs(out / "runs.jsonl"):
        if r["case"] == case and not r["sets"] and abs(r["lambda"] - lam) < 1e-9:
            got.setdefault(r["index"], {})[r["cell"]] = bool(r["failed"])
    pairs = [(v[coarse], v[fine]) for v in got.values() if coarse in v and fine in v]
    n = len(pairs)
    res = {"case": case, "lambda": lam, "pairs": n}
    for name, k in (("fail_coarse", sum(a for a, _ in pairs)), ("fail_fine", sum(b for _, b in pairs)),
                    ("fine_only", sum(b and not a for a, b in pairs)),
                    ("coarse_only", sum(a and not b for a, b in pairs))):
        res[name] = {"k": k, "p": k / n if n else None,
                     "wilson95": list(wilson_interval(k, n)) if n else None}
    return res


def plot_pairs(rows: list[dict], path: Path, coarse: float = 0.5, fine: float = 0.25) -> Path:
    """lambda_crit on the finer mesh against the coarser, one point per realization (and
    the homogeneous slope), with the averaged-field runs; the lines lambda = 1 split the
    plane into stands / fails on each mesh."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    mid = {(r["case"], r["index"], r["sets"], r["cell"]): r["mid"] for r in rows}
    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    styles = {"": ("o", "C0", "paired field, as drawn"),
              "average_field=0.5": ("s", "C1", "fine mesh, field averaged over 0.5 m cells")}
    for sets, (mk, col, lab) in styles.items():
        pts = [(mid.get((c, i, "", coarse)), m) for (c, i, st, cell), m in mid.items()
               if st == sets and cell == fine and c != "homogeneous"]
        pts = [(x, y) for x, y in pts if x is not None and y is not None]
        if pts:
            x, y = np.array(pts).T
            ax.plot(x, y, mk, color=col, label=f"xi = 48, {lab} ({len(pts)})")
    h = (mid.get(("homogeneous", 0, "", coarse)), mid.get(("homogeneous", 0, "", fine)))
    if None not in h:
        ax.plot(*h, "k^", ms=9, label="homogeneous")
    lo, hi = 0.75, 1.2
    ax.plot([lo, hi], [lo, hi], "k-", lw=0.8, label="same on both meshes")
    ax.axhline(1.0, color="grey", ls="--", lw=0.8)
    ax.axvline(1.0, color="grey", ls="--", lw=0.8)
    ax.set_xlim(lo, hi)
    ax.set_ylim(lo, hi)
    ax.set_xlabel(f"lambda_crit on {coarse:g} m cells")
    ax.set_ylabel(f"lambda_crit on {fine:g} m cells")
    ax.set_title("Critical strength factor, same field on both meshes\n"
                 "(fails in the campaign when lambda_crit > 1)", fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="meshes/slope_risk.toml")
    ap.add_argument("--case", default="xi=48")
    ap.add_argument("--index", type=int, nargs="+", default=[0])
    ap.add_argument("--cell", type=float, nargs="+", default=[0.5, 0.25])
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="scene change for every run (TOML value), e.g. solver.geostatic_time=12")
    ap.add_argument("--average-field", type=float, default=None, metavar="H",
                    help="replace each point's strength by its mean over H-m blocks (diagnostic)")
    ap.add_argument("--step", type=float, default=0.1)
    ap.add_argument("--start", type=float, default=1.0,
                    help="first lambda (e.g. the coarser mesh's lambda_crit)")
    ap.add_argument("--tol", type=float, default=0.01)
    ap.add_argument("--decide-only", action="store_true",
                    help="one run per realization and mesh, at lambda = --start (the paired check)")
    ap.add_argument("--fail-area", type=float, default=1.0)
    ap.add_argument("--t-cap", type=float, default=30.0)
    ap.add_argument("--out", type=Path, required=False)
    ap.add_argument("--summary", type=Path, default=None)
    ap.add_argument("--figure", type=Path, default=None,
                    help="with --summary: write the lambda_crit scatter (PNG) here")
    a = ap.parse_args(argv)
    if a.summary is not None:
        print(markdown(summary(a.summary)))
        if a.figure is not None:
            plot_pairs(summary(a.summary), a.figure)
        cells = sorted({r["cell"] for r in summary(a.summary)}, reverse=True)
        for case in sorted({r["case"] for r in summary(a.summary)} - {"homogeneous"}):
            if len(cells) >= 2:
                print(json.dumps(paired_decisions(a.summary, case, cells[0], cells[1])))
        return 0
    import tomllib
    sets = {k: tomllib.loads(f"v = {v}")["v"] for k, _, v in (s.partition("=") for s in a.set)}
    set_key = ";".join(a.set + ([f"average_field={a.average_field:g}"] if a.average_field else []))
    a.out.mkdir(parents=True, exist_ok=True)
    log = a.out / "runs.jsonl"
    done = load_runs(log)
    for index in a.index:
        for cell in a.cell:
            scene = scaled_scene(a.scene, a.case, cell, sets)
            seed = realization_seed(scene.montecarlo.seed, index)
            key = (a.case, index, cell, set_key)
            cache = {round(r["lambda"], 4): r["failed"] for r in done if _key(r) == key}

            def do_run(lam, scene=scene, seed=seed, key=key):
                r = run_one(scene, seed, lam, a.fail_area, a.t_cap, a.average_field)
                r.update(case=key[0], index=key[1], cell=key[2], sets=key[3])
                with log.open("a") as f:
                    f.write(json.dumps(r) + "\n")
                print(json.dumps(r), flush=True)
                return r["failed"]
            if a.decide_only:          # stand or fail at lambda = --start, no search
                lam = round(a.start, 4)
                failed = cache[lam] if lam in cache else do_run(lam)
                print(f"# {a.case} #{index} cell {cell} {set_key}: lambda {lam} "
                      f"{'fails' if failed else 'stands'}", flush=True)
                continue
            lo, hi = critical_factor(cache, do_run, a.step, a.tol, a.start)
            print(f"# {a.case} #{index} cell {cell} {set_key}: lambda_crit in [{lo}, {hi}]",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
