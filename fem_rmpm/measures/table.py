"""The measures of a realization: one table, one entry per measure.

Each entry (:class:`Measure`) declares a measure once: its name (the key in a run's
``summary.json``, in the campaign records and the column of ``results.csv``), its unit, the
words that name it in figures, the report and the command line, its kind, where it is
shown, whether subset simulation may take it as its response (and in which direction
failure lies), and how it is computed from a realization's :class:`Deposit
<fem_rmpm.measures.deposit.Deposit>`.  Every consumer reads this table:
:func:`fem_rmpm.measures.deposit.compute_measures` computes the entries that have a
``compute`` function in table order; ``results.csv`` takes its first columns and every
unit from it; the campaign statistics, figures and report, the subset-simulation responses
and the command line's text take their names, labels and units from it.

Adding a measure is one entry in :data:`MEASURES` (``tests/test_measure_table.py`` adds
one and finds it in every output).  A measure recorded by another stage of a campaign (the
factor of safety of strength reduction, the stopping rule's decision) has no ``compute``
function and names its ``source``.

Units, one spelling each (:data:`UNIT_SPELLINGS`): ``m``, ``m2/m`` (an area of the plane
section, i.e. a volume per metre of slope), ``m2`` (a true area), ``m3`` (a volume of a
3-D run), ``s``, ``count``, ``0/1`` (a flag) and ``-`` (dimensionless).

A 3-D run (:mod:`fem_rmpm.measures.deposit3d`) records the measures shared with plane
strain (``failed``, ``runout_distance``, ``retrogression_distance``, ``sliding_area``, ...,
taken slice by slice along the strike, see there) and the entries whose ``source`` is
:data:`THREE_D` (the measures along the strike: sliding volume, slides, means and profiles
over the slices); :func:`strike` lists those a 3-D campaign summarises.

Notation of the definitions: ``d_p`` is the distance
point p moved since the end of the geostatic phase, ``X`` the true horizontal coordinate
pointing down-slope, *counted* the points of the deposit
(:func:`fem_rmpm.measures.deposit.deposit_points`), *sliding* the counted points with
``d_p > failure_displacement`` (``[montecarlo] failure_displacement``, default 0.5 m).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from fem_rmpm.io.output import to_true_frame
from fem_rmpm.measures.blocks import intact_blocks
from fem_rmpm.measures.geometry import (
    crest_position,
    moved_area,
    slip_surface_height,
    surface_profile,
)

__all__ = ["Measure", "MEASURES", "UNIT_SPELLINGS", "KINDS", "ROLES", "DIRECTIONS", "unit",
           "label", "axis_label", "value_text", "core", "headline", "mechanism", "strike",
           "summarised", "THREE_D",
           "responses", "responses_text", "response_aliases", "resolve_response", "markdown"]

UNIT_SPELLINGS = ("m", "m2/m", "m2", "m3", "s", "count", "0/1", "-")
#: ``scalar``: a number; ``count``: a whole number; ``flag``: true or false; ``profile``: a
#: list of (x, y) pairs (written to ``profiles/``, never to ``results.csv``); ``list``: a
#: list of tuples of a run (a 3-D run's slides; in its record, never in ``results.csv``).
KINDS = ("scalar", "count", "flag", "profile", "list")
#: Where a measure is shown besides the records, ``results.csv``, the statistics and the
#: report's table: ``headline`` — exceedance curves, histograms, the report's first rows,
#: the command line's summary (mean, standard error and quantiles); ``mechanism`` —
#: histograms and the command line's means when every run recorded it; ``strike`` — the
#: measures along the strike of a 3-D run (the 3-D report's distributions,
#: :mod:`fem_rmpm.campaign.report3d`); ``None``: nowhere else.
ROLES = ("headline", "mechanism", "strike", None)
#: Failure direction of a subset-simulation response: the value ``above`` or ``below`` the
#: threshold (None: not a response).
DIRECTIONS = ("above", "below", None)


@dataclass(frozen=True)
class Measure:
    """One measure of a realization (see the module docstring)."""
    name: str
    unit: str
    label: str
    definition: str
    #: A function of the realization's :class:`fem_rmpm.measures.deposit.Deposit` (not
    #: imported here: the deposit module reads this table), or None.
    compute: Callable[[Any], Any] | None = None
    kind: str = "scalar"
    role: str | None = None
    #: Recorded by every run to rest: one of the first columns of ``results.csv`` (kept even
    #: when constant) and, when summarised, in the statistics of every campaign.
    core: bool = False
    #: Summarised over the realizations (mean, standard error, quantiles) when every run of
    #: the sample recorded a number; False for flags, profiles, echoed settings and the
    #: run's own times (time to rest, decision time).
    statistic: bool = True
    response: str | None = None
    aliases: tuple[str, ...] = ()
    #: What records it when there is no ``compute``: the stage of the campaign.
    source: str = "deposit"

    def __post_init__(self):
        if self.unit not in UNIT_SPELLINGS:
            raise ValueError(f"measure {self.name}: unit {self.unit!r} is not one of "
                             f"{', '.join(UNIT_SPELLINGS)}")
        for what, value, allowed in (("kind", self.kind, KINDS), ("role", self.role, ROLES),
                                     ("response", self.response, DIRECTIONS)):
            if value not in allowed:
                raise ValueError(f"measure {self.name}: {what} {value!r} is not one of "
                                 f"{allowed}")


# ----------------------------------------------------------------------------- computations
# Each takes the realization's Deposit ``d`` (fem_rmpm.measures.deposit.Deposit) and returns a
# Python value (float, int, bool, None, or a list for a profile).

def _failed(d) -> bool:
    return bool(d.sliding.any()) and _sliding_area(d) >= d.failure_area


def _sliding_area(d) -> float:
    return float(d.pts.volume0[d.sliding].sum())


def _runout(d) -> float:
    front = float(d.X[:, 0].max()) if len(d.X) else float(d.X0[:, 0].max())
    return float(max(0.0, front - d.X0[:, 0].max()))


def _retrogression(d) -> float:
    if not d.sliding.any():
        return 0.0
    crest = to_true_frame(crest_position(d.pts, float(d.cell[1]))[None], d.frame_angle_deg)[0]
    return float(max(0.0, crest[0] - d.X0[d.sliding, 0].min()))


def _max_displacement(d) -> float:
    return float(d.displacement[d.counted].max(initial=0.0))


def _slip_surface_height(d) -> float:
    return slip_surface_height(d.pts.x0[d.counted], d.sliding[d.counted], float(d.cell[0]))


def _intact_blocks(d) -> int | None:
    if d.mechanism is None:
        return None
    xs, gs = d.mechanism
    g = d.grid
    return intact_blocks(xs, d.pts.x0, gs, d.threshold, g.origin, g.cell, g.shape,
                         min_area=d.intact_block_area)


def _sliding_area_early(d) -> float | None:
    if d.mechanism is None:
        return None
    return moved_area(d.mechanism[0], d.pts.x0, d.pts.volume0, d.pts.active, d.threshold)


def _points(mask_of: str) -> Callable[[Any], int]:
    return lambda d: int(getattr(d, mask_of).sum())


def _volume(mask_of: str) -> Callable[[Any], float]:
    return lambda d: float(d.pts.volume0[getattr(d, mask_of)].sum())


def _profile(d, X: np.ndarray) -> list[tuple[float, float]]:
    return surface_profile(X, float(np.min(d.cell)))


# ----------------------------------------------------------------------------- the table

_FS = "strength reduction (fem_rmpm.campaign.factor_of_safety)"
_DECIDE = "the stopping rule (fem_rmpm.campaign.decide)"
#: The ``source`` of the measures of 3-D runs only.
THREE_D = "the 3-D deposit (fem_rmpm.measures.deposit3d)"

#: The measures, in the order every output lists them.
MEASURES: dict[str, Measure] = {m.name: m for m in (
    Measure("failed", "0/1", "failed",
            "The sliding area is at least the failure area ([montecarlo] failure_area, "
            "default 1 m2/m) and not zero: a few points moved far are debris, not a "
            "failure.", _failed, kind="flag", core=True, statistic=False),
    Measure("runout_distance", "m", "run-out",
            "max X of the counted points now minus max X of all points at the start: how "
            "far the deposit's front travelled beyond the original toe, >= 0.",
            _runout, role="headline", core=True, response="above",
            aliases=("runout", "run-out")),
    Measure("retrogression_distance", "m", "retrogression",
            "X_crest - min X0 over the sliding points, where X_crest is the initial true "
            "horizontal position of the slope crest (the most down-slope point of the top "
            "soil layer in the grid frame), >= 0: how far behind the original crest the "
            "failure reached.", _retrogression, role="headline", core=True,
            response="above", aliases=("retrogression",)),
    Measure("sliding_area", "m2/m", "sliding area",
            "Total initial volume of the sliding points.", _sliding_area, role="headline",
            core=True, response="above"),
    Measure("max_displacement", "m", "max displacement",
            "The largest d_p of a counted point.", _max_displacement, core=True,
            response="above"),
    Measure("time_to_rest", "s", "time to rest",
            "Simulated time at which the run stopped at rest (None otherwise).",
            lambda d: d.time_to_rest, core=True, statistic=False),
    Measure("slip_surface_height", "m", "slip-surface height",
            "How high above the base (grid y, normal to the bedrock) the failure surface "
            "lies, averaged over the failed part of the slope: per column of one cell "
            "(initial x), the highest initial y of a counted point that stayed (d_p <= "
            "threshold) below the lowest sliding point; 0 where the whole column slid.",
            _slip_surface_height, role="mechanism"),
    Measure("intact_blocks", "count", "intact blocks",
            "At the mechanism time, the number of intact blocks the sliding mass has broken "
            "into: connected groups (4-neighbour grid cells) of cells holding sliding points "
            "with plastic shear strain < 0.1 whose area (cells x cell area) is at least the "
            "intact block area (None without snapshots).", _intact_blocks, kind="count",
            role="mechanism"),
    Measure("sliding_area_early", "m2/m", "early sliding area",
            "Initial volume of the active points moved more than the failure displacement at "
            "the mechanism time (None without snapshots): how fast it fails.",
            _sliding_area_early, role="mechanism"),
    Measure("intact_block_area", "m2", "least intact block area",
            "The least area of an intact block ([montecarlo] intact_block_area).",
            lambda d: d.intact_block_area, statistic=False),
    Measure("mechanism_time", "s", "mechanism time",
            "Time of the snapshot the mechanism measures are taken at (3 s after the end of "
            "the geostatic phase in a run).", lambda d: d.mechanism_time, statistic=False),
    Measure("failure_displacement", "m", "failure displacement",
            "The displacement above which a counted point is sliding.",
            lambda d: d.threshold, statistic=False),
    Measure("excluded_frozen_points", "count", "frozen points excluded",
            "Points frozen at the grid edge (never counted).", _points("frozen"),
            kind="count"),
    Measure("excluded_frozen_volume", "m2/m", "frozen volume excluded",
            "Initial volume of the points frozen at the grid edge.", _volume("frozen")),
    Measure("excluded_stray_points", "count", "stray points excluded",
            "Active points in no body of the deposit.", _points("stray"), kind="count"),
    Measure("excluded_stray_volume", "m2/m", "stray volume excluded",
            "Initial volume of the stray points.", _volume("stray")),
    Measure("final_profile", "m", "final surface",
            "The surface (max Y per X bin of one cell width) of the counted points now.",
            lambda d: _profile(d, d.X), kind="profile", statistic=False),
    Measure("initial_profile", "m", "initial surface",
            "The surface (max Y per X bin of one cell width) of all points at the start.",
            lambda d: _profile(d, d.X0), kind="profile", statistic=False),
    Measure("factor_of_safety", "-", "factor of safety",
            "Strength-reduction factor of safety of the in-situ slope (Griffiths & Lane "
            "1999); failure: below the threshold.", source=_FS, response="below",
            aliases=("fs", "factor-of-safety")),
    Measure("fs_bound", "-", "factor of safety bound",
            "-1: the factor of safety is below the search's least factor, 0: found, 1: above "
            "its largest.", source=_FS),
    Measure("fs_below_1", "0/1", "factor of safety below 1",
            "The slope is unstable at its own strength (the search's first trial failed).",
            kind="flag", statistic=False, source=_FS),
    Measure("fs_static_solves", "count", "static solves of the factor of safety",
            "Static solves the strength-reduction search took.", kind="count", source=_FS),
    Measure("decided_time", "s", "decision time",
            "First output at which the failure area of active points had moved more than the "
            "failure displacement (None if never).", statistic=False, source=_DECIDE),
    Measure("decided_area", "m2/m", "area moved at the decision",
            "Initial volume of the active points moved more than the failure displacement "
            "at the decision time (a 3-D run: m3).", statistic=False, source=_DECIDE),
    # -- three-dimensional runs only (fem_rmpm.measures.deposit3d); slices one cell long
    Measure("sliding_volume", "m3", "sliding volume",
            "3-D: total initial volume of the sliding points; failed when at least the "
            "failure area times one slice's strike length (hz).", source=THREE_D,
            role="strike"),
    Measure("slide_count", "count", "slides along the strike",
            "3-D: the number of separate slides: runs of consecutive slices each holding at "
            "least the failure area x hz of sliding volume (an empty slice separates two).",
            kind="count", source=THREE_D, role="strike"),
    Measure("slide_length_max", "m", "longest slide",
            "3-D: strike length (slices x hz) of the longest slide (0 without one).",
            source=THREE_D, role="strike"),
    Measure("slide_volume_max", "m3", "largest slide volume",
            "3-D: sliding volume of the largest slide (0 without one).", source=THREE_D,
            role="strike"),
    Measure("runout_distance_mean", "m", "mean run-out along the strike",
            "3-D: the run-out of each slice, averaged over the slices.", source=THREE_D,
            role="strike"),
    Measure("retrogression_distance_mean", "m", "mean retrogression along the strike",
            "3-D: the retrogression of each slice, averaged over the slices.",
            source=THREE_D, role="strike"),
    Measure("strike_length", "m", "strike length",
            "3-D: strike length of the soil (its slices x hz).", source=THREE_D,
            statistic=False),
    Measure("runout_profile", "m", "run-out along the strike",
            "3-D: [(z, run-out)] per slice, z its mid strike coordinate.", kind="profile",
            statistic=False, source=THREE_D),
    Measure("retrogression_profile", "m", "retrogression along the strike",
            "3-D: [(z, retrogression)] per slice.", kind="profile", statistic=False,
            source=THREE_D),
    Measure("slides", "m3", "slides",
            "3-D: [(z0, z1, volume m3)] of each slide, z0 and z1 the strike ends (m) of its "
            "slices.", kind="list", statistic=False, source=THREE_D),
)}


# ----------------------------------------------------------------------------- reading it

def unit(name: str) -> str:
    """The unit of measure ``name``; ``-`` for a name the table does not hold."""
    m = MEASURES.get(name)
    return m.unit if m is not None else "-"


def label(name: str) -> str:
    """The words that name measure ``name`` (its name with spaces if the table lacks it)."""
    m = MEASURES.get(name)
    return m.label if m is not None else name.replace("_", " ")


def axis_label(name: str) -> str:
    """``label (unit)``, for a figure's axis or a table's row."""
    return f"{label(name)} ({unit(name)})"


def value_text(name: str, value: Any, fmt: str = ".2f") -> str:
    """``label value unit`` (e.g. ``run-out 12.34 m``); no unit for ``count``, ``0/1``
    and ``-``; ``value`` None gives ``label –``."""
    if value is None:
        return f"{label(name)} –"
    u = unit(name)
    return f"{label(name)} {value:{fmt}}" + (f" {u}" if u not in ("count", "0/1", "-") else "")


def core() -> list[str]:
    """The core measures (the first columns of ``results.csv``), in table order."""
    return [m.name for m in MEASURES.values() if m.core]


def headline() -> list[str]:
    """The headline measures (exceedance curves, first in every summary), in table order."""
    return [m.name for m in MEASURES.values() if m.role == "headline"]


def mechanism() -> list[str]:
    """The measures of the mechanism (histograms and means when recorded)."""
    return [m.name for m in MEASURES.values() if m.role == "mechanism"]


def summarised(name: str) -> bool:
    """Whether measure ``name`` is summarised over realizations (a name the table lacks is,
    when it is a number in every run)."""
    m = MEASURES.get(name)
    return m is None or (m.statistic and m.kind in ("scalar", "count"))


def strike() -> list[str]:
    """The measures along the strike of a 3-D run (its report's distributions)."""
    return [m.name for m in MEASURES.values() if m.role == "strike"]


def responses() -> dict[str, Measure]:
    """The measures subset simulation takes as its response, by name, in table order."""
    return {m.name: m for m in MEASURES.values() if m.response is not None}


def responses_text() -> str:
    """The responses with their units, grouped by failure direction, for help texts:
    ``runout_distance (m), ... (failure above); factor_of_safety (-) (failure below)``."""
    groups = []
    for direction in ("above", "below"):
        names = [f"{k} ({m.unit})" for k, m in responses().items() if m.response == direction]
        if names:
            groups.append(", ".join(names) + f" (failure {direction})")
    return "; ".join(groups)


def response_aliases() -> dict[str, str]:
    """``{alias: response name}`` of the responses' aliases."""
    return {a: m.name for m in responses().values() for a in m.aliases}


def resolve_response(text: str) -> str | None:
    """The response named by ``text`` (a name or an alias, any case), None if none."""
    key = text.strip().lower()
    key = response_aliases().get(key, key)
    return key if key in responses() else None


def markdown() -> str:
    """The table as a Markdown table (name, unit, kind, subset response, definition), for
    the documentation."""
    rows = ["| measure | unit | kind | subset response | definition |", "|---|---|---|---|---|"]
    for m in MEASURES.values():
        resp = f"failure {m.response}" if m.response else ""
        source = "" if m.compute is not None else f" (recorded by {m.source})"
        rows.append(f"| `{m.name}` | {m.unit} | {m.kind} | {resp} | {m.definition}{source} |")
    return "\n".join(rows) + "\n"
