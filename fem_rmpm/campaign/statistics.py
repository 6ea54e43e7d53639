"""Statistics of a case over its realizations: P(failure) with its standard error and
Wilson interval, moments and quantiles of every numeric measure, convergence with N."""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from fem_rmpm.campaign.decide import in_measure_sample
from fem_rmpm.campaign.store import RECORD_COLUMNS
from fem_rmpm.measures import table

__all__ = ["wilson_interval", "case_statistics"]


def wilson_interval(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n (Wilson 1927)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, mid - half), min(1.0, mid + half))


def _describe(x: np.ndarray) -> dict:
    if len(x) == 0:
        return {"mean": None, "std": None, "se": None, "q05": None, "q50": None, "q95": None}
    q = np.quantile(x, [0.05, 0.5, 0.95])
    std = float(np.std(x, ddof=1)) if len(x) > 1 else 0.0
    return {"mean": float(np.mean(x)), "std": std, "se": std / math.sqrt(len(x)),
            "q05": float(q[0]), "q50": float(q[1]), "q95": float(q[2])}


def case_statistics(rows: Sequence[dict], requested: int | None = None,
                    runs_to_rest: int | None = None) -> dict:
    """Statistics of one case from its rows (``read_results`` or records), in index order.

    ``p_failure`` = k/N over the ``ok`` rows, ``se`` = sqrt(p (1 - p) / N) (binomial
    standard error), ``wilson95`` its Wilson score interval; for each of
    ``runout_distance``, ``retrogression_distance``, ``sliding_area``: mean, std
    (ddof 1), se = std/sqrt(n), quantiles 5/50/95 % over the *measure sample*, the ``ok``
    runs to rest with index < ``runs_to_rest`` (None: all; :mod:`fem_rmpm.campaign.decide`),
    ``measure_runs`` = n of them; ``convergence``: running N, P(failure), its se, and the
    running mean run-out over the measure sample against ``n_measure``, in index order."""
    rows = sorted(rows, key=lambda r: r["index"])
    done = [r for r in rows if r["status"] == "ok"]
    ok = [r for r in done if _measure(r, "failed") is not None]   # with an MPM run (not --fs-only)
    sample = [r for r in ok if in_measure_sample(r, runs_to_rest)]
    n = len(ok)
    fails = np.array([bool(_measure(r, "failed")) for r in ok], dtype=float)
    k = int(fails.sum())
    p = k / n if n else None
    out: dict[str, Any] = {
        "requested": requested, "finished": len(rows), "ok": len(done), "mpm_runs": n,
        "numerical_failures": len(rows) - len(done),
        "errors": [{"index": r["index"], "seed": r["seed"], "error": r.get("error")}
                   for r in rows if r["status"] != "ok"],
        "slope_failures": k, "p_failure": p,
        "se": math.sqrt(p * (1 - p) / n) if n else None,
        "wilson95": list(wilson_interval(k, n)) if n else None,
    }
    out["runs_to_rest"], out["measure_runs"] = runs_to_rest, len(sample)
    for key in _statistic_names(sample):
        out[key] = _describe(np.array([float(_measure(r, key)) for r in sample]))
    if n:
        nn = np.arange(1, n + 1)
        pr = np.cumsum(fails) / nn
        ro = np.array([float(_measure(r, "runout_distance")) for r in sample])
        nm = np.arange(1, len(ro) + 1)
        out["convergence"] = {"n": nn.tolist(), "p_failure": pr.tolist(),
                              "se": np.sqrt(pr * (1 - pr) / nn).tolist(),
                              "n_measure": nm.tolist(),
                              "mean_runout": (np.cumsum(ro) / nm).tolist()}
    return out


def _statistic_names(ok: Sequence[dict]) -> list[str]:
    """The measures summarised over the rows ``ok`` (records or results.csv rows): the
    core summarised measures of :mod:`fem_rmpm.measures.table` always (in table order), then
    every other measure the table does not mark as not summarised (flags, profiles,
    settings) that is a number in every row (sorted)."""
    core = [k for k in table.core() if table.summarised(k)]
    if not ok:
        return core
    names = [set((r.get("measures") or {}) if "measures" in r else set(r) - set(RECORD_COLUMNS))
             for r in ok]
    extra = sorted(k for k in set.intersection(*names) - set(core) if table.summarised(k))
    extra = [k for k in extra if all(isinstance(_measure(r, k), (int, float))
                                     and not isinstance(_measure(r, k), bool) for r in ok)]
    return core + extra


def _measure(r: dict, key: str):
    if "measures" in r:
        return (r.get("measures") or {}).get(key)
    return r.get(key)

