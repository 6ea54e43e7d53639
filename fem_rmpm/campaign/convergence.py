"""Mesh convergence of a campaign (``fem-rmpm converge SCENE --cells 0.5,0.25,0.125 -n N
--out DIR``): the same realizations of the same cases on two or three cell sizes.

Each cell size is an ordinary campaign (:func:`fem_rmpm.campaign.run_campaign`) in
``DIR/cell_<h>`` (resumable: re-run the command to finish or extend it).  Realization
``i`` has the seed ``realization_seed(campaign_seed, i)`` on every mesh; with the random
field's ``box`` (``[random_field] box``) the field's rectangle does not move with the
grid, so it is *the same field* on every mesh and the meshes are compared pair by pair
(``paired_fields``: false when the scene has a random field without ``box``: the same
seed then draws unrelated fields on different meshes).

Per case and mesh (:func:`convergence_statistics`, ``DIR/convergence.json``): P(failure)
with its binomial SE and Wilson 95 % interval, and the given-failure means (± SE) of
sliding area, run-out and retrogression over the runs to rest.  Per case and pair of
meshes: the discordant pairs (``b``: fails on the first mesh and stands on the second,
``c``: the reverse) over the realizations finished on both, the exact McNemar test
(two-sided binomial test of ``b`` against ``Bin(b + c, 1/2)``; McNemar 1947), the paired
difference of P(failure) ``(b - c) / n`` with its SE ``sqrt(b + c - (b - c)^2 / n) / n``
and the unpaired check ``|p1 - p2| <= 2 sqrt(se1^2 + se2^2)``.  Table and figure in
``DIR/convergence.html`` and ``DIR/convergence.png``.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
from scipy import stats as sps

from fem_rmpm.campaign.case_campaign import run_campaign
from fem_rmpm.campaign.cases import CampaignError
from fem_rmpm.campaign.convergence_report import plot_convergence_mesh, write_html
from fem_rmpm.campaign.decide import in_measure_sample
from fem_rmpm.campaign.statistics import wilson_interval
from fem_rmpm.campaign.store import read_results
from fem_rmpm.io.output import write_json
from fem_rmpm.scene import Scene, with_value

__all__ = ["parse_cells", "mesh_scene", "mesh_directory", "run_convergence",
           "convergence_statistics", "mcnemar_exact", "GIVEN_FAILURE", "ConvergenceResult"]

#: The measures averaged over the failures of each mesh.
GIVEN_FAILURE = ("sliding_area", "runout_distance", "retrogression_distance")


def parse_cells(text: str) -> list[float]:
    """``"0.5,0.25,0.125"`` -> cell sizes (m), two or three distinct positive numbers,
    coarse to fine; CampaignError otherwise."""
    try:
        cells = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        cells = []
    if (not 2 <= len(cells) <= 3 or len(set(cells)) != len(cells)
            or not all(math.isfinite(h) and h > 0 for h in cells)):
        raise CampaignError(f"--cells {text!r}: expected two or three distinct positive cell "
                            "sizes in m, e.g. 0.5,0.25,0.125")
    return sorted(cells, reverse=True)


def mesh_scene(scene: Scene, h: float) -> Scene:
    """``scene`` on square cells of ``h`` m (the grid size must hold a whole number)."""
    return with_value(scene, "grid.cell", [h, h])


def mesh_directory(out: Path, h: float) -> Path:
    """The campaign directory of cell size ``h`` inside ``out``: ``cell_<h>``."""
    return Path(out) / f"cell_{h:g}"


@dataclass
class ConvergenceResult:
    """What :func:`run_convergence` did: the statistics, the per-mesh campaign results
    (:class:`~fem_rmpm.campaign.case_campaign.CampaignResult`) and the files written."""
    out: Path
    statistics: dict
    campaigns: list
    files: list


def run_convergence(scene: Scene, out: str | Path, cells: Sequence[float],
                    realizations: int | None = None, cases: Sequence[str] | None = None,
                    **campaign_options) -> ConvergenceResult:
    """Run (or finish) the campaign of every cell size in ``out/cell_<h>`` with the same
    cases and realizations, then write ``convergence.json``, ``.png`` and ``.html``.
    ``campaign_options`` go to :func:`fem_rmpm.campaign.run_campaign` (workers, scheduler,
    force, keep_vtk, progress, cluster).  Every mesh scene is checked before any runs."""
    out = Path(out)
    scenes = [(h, mesh_scene(scene, h)) for h in cells]      # refuses a bad cell first
    results = [run_campaign(s, mesh_directory(out, h), realizations, cases, **campaign_options)
               for h, s in scenes]
    st = convergence_statistics(out, cells, paired=_paired(scene))
    files = [write_json(out / "convergence.json", st) or out / "convergence.json"]
    files.append(plot_convergence_mesh(out / "convergence.png", st))
    files.append(write_html(out / "convergence.html", st, out / "convergence.png"))
    return ConvergenceResult(out, st, results, files)


def _paired(scene: Scene) -> bool:
    rf = scene.random_field
    return rf is None or getattr(rf, "box", None) is not None


def mcnemar_exact(b: int, c: int) -> float:
    """Two-sided exact McNemar p-value: ``b`` against Binomial(b + c, 1/2) (1 if b + c = 0)."""
    if b + c == 0:
        return 1.0
    return float(min(1.0, 2.0 * sps.binom.cdf(min(b, c), b + c, 0.5)))


def _mesh_case(rows: list[dict], runs_to_rest: int | None) -> dict:
    ok = [r for r in rows if r["status"] == "ok" and r.get("failed") is not None]
    n = len(ok)
    k = sum(bool(r["failed"]) for r in ok)
    p = k / n if n else None
    out = {"n": n, "failures": k, "p_failure": p,
           "se": math.sqrt(p * (1 - p) / n) if n else None,
           "wilson95": list(wilson_interval(k, n)) if n else None, "given_failure": {}}
    fails = [r for r in ok if r["failed"] and in_measure_sample(r, runs_to_rest)]
    for key in GIVEN_FAILURE:
        x = np.array([float(r[key]) for r in fails if r.get(key) is not None])
        sd = float(np.std(x, ddof=1)) if len(x) > 1 else None
        out["given_failure"][key] = {
            "n": len(x), "mean": float(x.mean()) if len(x) else None,
            "se": sd / math.sqrt(len(x)) if sd is not None else None}
    return out


def _pair(a: dict[int, bool], b: dict[int, bool], pa: dict, pb: dict) -> dict:
    both = sorted(set(a) & set(b))
    n = len(both)
    b_ = [i for i in both if a[i] and not b[i]]
    c_ = [i for i in both if b[i] and not a[i]]
    nb, nc = len(b_), len(c_)
    se_pair = math.sqrt(max(nb + nc - (nb - nc) ** 2 / n, 0.0)) / n if n else None
    diff = (pa["p_failure"] - pb["p_failure"]) if n and pa["n"] and pb["n"] else None
    se_un = (math.sqrt(pa["se"] ** 2 + pb["se"] ** 2)
             if pa["se"] is not None and pb["se"] is not None else None)
    return {"n_paired": n, "fail_first_only": nb, "fail_second_only": nc,
            "discordant": nb + nc, "discordant_indices": {"fail_first_only": b_,
                                                          "fail_second_only": c_},
            "mcnemar_p": mcnemar_exact(nb, nc),
            "paired_difference": (nb - nc) / n if n else None, "paired_se": se_pair,
            "p_difference": diff, "unpaired_se": se_un,
            "within_2se": (None if diff is None or se_un is None
                           else bool(abs(diff) <= 2 * se_un + 1e-12))}


def convergence_statistics(out: str | Path, cells: Sequence[float], paired: bool = True,
                           runs_to_rest: int | None = None) -> dict:
    """The statistics of ``out/cell_<h>/results.csv`` for every ``h`` in ``cells`` (module
    docstring).  ``runs_to_rest``: read from each mesh's summary.json when None."""
    out = Path(out)
    meshes, by_mesh = [], {}
    for h in cells:
        d = mesh_directory(out, h)
        if not (d / "results.csv").is_file():
            raise CampaignError(f"{d}: no results.csv (run the campaign of cell {h:g} m first)")
        rows = read_results(d / "results.csv")
        k_rest = runs_to_rest
        if k_rest is None and (d / "summary.json").is_file():
            k_rest = json.loads((d / "summary.json").read_text()).get("runs_to_rest")
        meshes.append({"cell": h, "directory": d.name, "runs_to_rest": k_rest})
        by_mesh[h] = (rows, k_rest)
    case_names = list(dict.fromkeys(r["case"] for rows, _ in by_mesh.values() for r in rows))
    cases = []
    for name in case_names:
        per = {h: _mesh_case([r for r in rows if r["case"] == name], k)
               for h, (rows, k) in by_mesh.items()}
        flags = {h: {r["index"]: bool(r["failed"]) for r in rows if r["case"] == name
                     and r["status"] == "ok" and r.get("failed") is not None}
                 for h, (rows, _) in by_mesh.items()}
        pairs = [{"cells": [h1, h2], **_pair(flags[h1], flags[h2], per[h1], per[h2])}
                 for i, h1 in enumerate(cells) for h2 in cells[i + 1:]]
        cases.append({"name": name, "meshes": [{"cell": h, **per[h]} for h in cells],
                      "pairs": pairs})
    return {"cells": list(cells), "paired_fields": paired, "meshes": meshes, "cases": cases,
            "given_failure_measures": list(GIVEN_FAILURE)}
