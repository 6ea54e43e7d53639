"""Runs stopped once decided: ``[montecarlo] runs_to_rest = K``.

Realization ``i`` of a campaign runs to rest when ``i < K`` and otherwise stops as soon as
its outcome is decided.  The outcome of a run is decided as *failed* at the first output
(every ``[solver] output_interval`` s) at which at least ``[montecarlo] failure_area``
(default 1 m2 per m, initial volume; any moved point when 0) of active points have moved
more than ``[montecarlo] failure_displacement`` since the start of the large-deformation
phase (``x - x0``: the geostatic phase moves no point); such a run stops there, its record
has ``stop_reason =`` :data:`DECIDED` and carries only ``failed = true``, the decision
time ``decided_time`` (s) and the area moved then ``decided_area`` (m2/m).  A run never
decided so runs on to rest (or ``t_end``) and is in every way a run to rest: same
measures, same record.

In a 3-D scene the moved *volume* (m3) is compared with ``failure_area`` times one
slice's strike length (the grid's ``hz``; :func:`failure_threshold`): the same rule as
the measure ``failed`` of a 3-D run (:mod:`fem_rmpm.measures.deposit3d`), and the record's
``decided_area`` is that volume (m3).

Why it is exact for P(failure), and how it is checked: a realization is a pure function of
scene and seed, so the stopped run is the run to rest up to the decision time.  The rule
agrees with the measure ``failed`` of the run to rest (at the end, at least
``failure_area`` of counted points moved more than ``failure_displacement``: the same
threshold, so a few points of debris neither stop a run nor fail it) when every run to
rest that fails crosses it at some output and no run that stands ever does.  Every run to
rest records ``decided_time`` (the first output at which the rule would have stopped it,
``None`` if never), so each campaign checks it on its own runs to rest
(:func:`decision_check`).

Why the runs to rest are ``i < K``: the realizations are iid, so the failures among the
first K are a random subsample of all failures.  P(failure) comes from every realization;
the measures (sliding area, run-out, ...) and their distributions given failure come from
the first K (:func:`in_measure_sample`), and the unconditional exceedance of a measure
is P(failure) x its exceedance given failure.
"""
from __future__ import annotations

from typing import Iterable

from fem_rmpm.measures.deposit import moved_area

__all__ = ["DECIDED", "FailureWatch", "failure_threshold", "in_measure_sample",
           "is_decided", "decision_check"]

#: ``stop_reason`` of a run stopped once decided (failed).
DECIDED = "failure decided"


def failure_threshold(scene) -> float:
    """The moved amount that decides a failure: ``[montecarlo] failure_area`` (m2/m) in
    plane strain; in 3-D that area times the grid's strike cell ``hz`` (m3)."""
    area = float(scene.montecarlo.failure_area)
    return area * float(scene.grid.cell[2]) if scene.grid.dimension == 3 else area


class FailureWatch:
    """Output callback of a realization (``api.run(stop_when=...)``): notes the first output
    time ``time`` (s) at which at least ``area`` m2/m (``[montecarlo] failure_area``; 0:
    any) of active points have moved more than ``threshold`` m (``x - x0``), and the area
    then, ``moved_area``; with ``stop`` it then returns :data:`DECIDED` (stop the run),
    else None (the run goes on)."""

    def __init__(self, threshold: float, area: float = 1.0, stop: bool = False):
        self.threshold, self.area, self.stop = float(threshold), float(area), bool(stop)
        self.time: float | None = None
        self.moved_area: float | None = None

    def __call__(self, t: float, pts) -> str | None:
        if self.time is None:
            area = moved_area(pts.x, pts.x0, pts.volume0, pts.active, self.threshold)
            if area > 0.0 and area >= self.area:
                self.time, self.moved_area = float(t), area
        return DECIDED if (self.stop and self.time is not None) else None


def is_decided(row: dict) -> bool:
    """True for the record (or ``results.csv`` row) of a run stopped once decided."""
    return row.get("stop_reason") == DECIDED


def in_measure_sample(row: dict, runs_to_rest: int | None) -> bool:
    """True when the row's measures belong to the campaign's measure sample: a run to
    rest with index < ``runs_to_rest`` (None: every run to rest)."""
    return not is_decided(row) and (runs_to_rest is None or int(row["index"]) < runs_to_rest)


def decision_check(records: Iterable[dict]) -> dict:
    """On the records of runs to rest that hold ``decided_time``: how many agree (decided
    as failed exactly when ``failed``) and the indices of those that do not, either way.
    Only ``decided_but_stood`` would change P(failure): a failed run never decided runs on
    to rest when stopped once decided, and is recorded as failed all the same."""
    n, disagree_fail, disagree_stand = 0, [], []
    for r in records:
        m = r.get("measures") or {}
        if is_decided(r) or r.get("status") != "ok" or "decided_time" not in m:
            continue        # decided, failed numerically, or recorded before decided_time
        n += 1
        crossed, failed = m["decided_time"] is not None, bool(m.get("failed"))
        if failed and not crossed:
            disagree_fail.append(int(r["index"]))
        elif crossed and not failed:
            disagree_stand.append(int(r["index"]))
    return {"checked": n, "agree": n - len(disagree_fail) - len(disagree_stand),
            "failed_never_decided": disagree_fail, "decided_but_stood": disagree_stand}
