"""The measure table (:mod:`fem_rmpm.measures.table`): a measure is declared once and every
consumer reads it.

The extension test adds a toy measure — the mean initial height of the sliding points, in m
— as one entry of the table and finds it in every output of a tiny crude Monte Carlo
campaign (``tests/data/mc_tiny.toml``: each run's ``summary.json``, the records,
``results.csv`` and its units, the statistics of ``summary.json``, ``report.html``) and as
the response of a tiny subset-simulation campaign.

The campaigns run on the shared Dask cluster of the test run (``dask_client`` of
``tests/conftest.py``: two worker *processes*), so a monkeypatch of the table in this
process alone would not reach the realizations. The entry is installed in this process with
``monkeypatch`` and in every worker with ``Client.run`` (this module's functions are pickled
by value, so the workers need not import it), and removed from the workers afterwards.
"""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import cloudpickle
import numpy as np
import pytest

from fem_rmpm import api, cli
from fem_rmpm.campaign import run_campaign
from fem_rmpm.campaign.cases import CampaignError
from fem_rmpm.campaign.report import write_report
from fem_rmpm.campaign.store import column_unit
from fem_rmpm.campaign.subset_runner import parse_response, run_subset_campaign
from fem_rmpm.measures import table
from fem_rmpm.measures.deposit import compute_measures
from fem_rmpm.measures.table import MEASURES, Measure

TINY = Path(__file__).resolve().parent / "data" / "mc_tiny.toml"


def _mean_sliding_height(d) -> float:
    """Mean initial grid-y (m) of the sliding points; 0 when none slides."""
    return float(d.pts.x0[d.sliding, 1].mean()) if d.sliding.any() else 0.0


TOY = Measure("toy_sliding_height", "m", "toy sliding height",
              "Mean initial height of the sliding points (0 when none slides).",
              _mean_sliding_height, response="above", aliases=("toy",))


def _install(on: bool) -> bool:
    """Add (or remove) the toy entry in this process's table (run on every worker); whether
    the table holds it now."""
    from fem_rmpm.measures import table as worker_table
    if on:
        worker_table.MEASURES[TOY.name] = TOY
    else:
        worker_table.MEASURES.pop(TOY.name, None)
    return TOY.name in worker_table.MEASURES


@pytest.fixture
def toy(monkeypatch, dask_client):
    """The toy measure in the table, here and on the cluster's workers."""
    monkeypatch.setitem(MEASURES, TOY.name, TOY)
    module = sys.modules[__name__]
    cloudpickle.register_pickle_by_value(module)
    try:
        assert all(dask_client.run(_install, True).values())
        yield TOY
    finally:
        held = dask_client.run(_install, False)
        cloudpickle.unregister_pickle_by_value(module)
    assert not any(held.values()), held           # the other tests' workers are unchanged


# ----------------------------------------------------------------------------- the table

def test_every_entry_is_consistent():
    """Units have one spelling, kinds, roles and directions are known, the names are the
    keys; the measures computed on the deposit are exactly the entries with a function, in
    table order; the core and headline measures are the ones the campaign outputs lead with."""
    for name, m in MEASURES.items():
        assert name == m.name and m.unit in table.UNIT_SPELLINGS and m.label and m.definition
        assert (m.compute is None) == (m.source != "deposit")
        assert not m.aliases or m.response is not None
    assert table.core() == ["failed", "runout_distance", "retrogression_distance",
                            "sliding_area", "max_displacement", "time_to_rest"]
    assert table.headline() == ["runout_distance", "retrogression_distance", "sliding_area"]
    assert table.unit("sliding_area") == table.unit("sliding_area_early") == "m2/m"
    assert column_unit("sliding_area") == "m2/m" and column_unit("steps") == "count"
    doc = table.markdown().splitlines()
    assert len(doc) == 2 + len(MEASURES) and doc[2].startswith("| `failed` | 0/1 | flag |")
    with pytest.raises(ValueError, match="unit 'm2 per m' is not one of"):
        Measure("x", "m2 per m", "x", "x")
    with pytest.raises(ValueError, match="response 'up' is not one of"):
        Measure("x", "m", "x", "x", response="up")


def test_compute_measures_follows_the_table():
    """A hand-made slide: the keys are the table's computed entries in order; the text
    helpers give ``label value unit``."""
    from tests.test_measures_details import _points
    x0 = np.array([[0.25 + 0.5 * i, 0.25 + 0.5 * j] for i in range(4) for j in range(2)])
    x = x0 + [[1.0, 0.0] if j else [0.0, 0.0] for i in range(4) for j in range(2)]
    m = compute_measures(_points(x0, x), 0.0, 0.5, np.array([0.5, 0.5]), 2.0)
    assert list(m) == [k for k, e in MEASURES.items() if e.compute is not None]
    assert m["failed"] and m["sliding_area"] == pytest.approx(4 * 0.25)
    assert table.value_text("runout_distance", 1.234) == "run-out 1.23 m"
    assert table.value_text("intact_blocks", 3, "d") == "intact blocks 3"
    assert table.axis_label("sliding_area") == "sliding area (m2/m)"


def test_responses_come_from_the_table():
    """Subset simulation's responses, aliases and units are the table's."""
    assert list(table.responses()) == ["runout_distance", "retrogression_distance",
                                       "sliding_area", "max_displacement", "factor_of_safety"]
    assert parse_response("run-out", 3.0).describe() == "runout_distance > 3 m"
    assert parse_response("sliding_area", 2.0).describe() == "sliding_area > 2 m2/m"
    fs = parse_response("fs", None)
    assert fs.below and fs.threshold == 1.0 and fs.describe() == "factor_of_safety < 1"
    with pytest.raises(CampaignError, match="allowed: runout_distance, retrogression_distance"):
        parse_response("volume", 1.0)


# ----------------------------------------------------------------------------- one entry more

def _csv_header(path: Path) -> list[str]:
    with open(path, newline="") as fh:
        return next(csv.reader(fh))


def test_one_table_entry_reaches_every_output(toy, dask_client, tmp_path, capsys):
    """The toy entry alone makes the toy measure a column of ``results.csv`` (with its unit),
    a key of each run's ``summary.json`` and record, a statistic of the campaign summary, a
    row of ``report.html``, a choice of ``--response`` and the response of a subset
    campaign whose records hold its value."""
    scene = api.load_scene(TINY)
    out = tmp_path / "mc"
    res = run_campaign(scene, out, 3, client=dask_client, progress=False, keep_vtk=3,
                       figures=False)
    write_report(out)          # as the campaign does with figures (left out: seconds)
    assert res.computed == 3
    runs = sorted((out / "vtk").glob("realization_*/summary.json"))
    records = sorted((out / "records").glob("realization_*.json"))
    assert len(runs) == len(records) == 3
    values = []
    for run, rec in zip(runs, records):
        measures = json.loads(run.read_text())["measures"]
        assert measures[toy.name] == json.loads(rec.read_text())["measures"][toy.name]
        values.append(measures[toy.name])
    assert len(set(values)) > 1, values          # differs: not a constant, dropped column
    assert toy.name in _csv_header(out / "results.csv")
    units = json.loads((out / "results.units.json").read_text())["units"]
    assert units[toy.name] == "m" and units["sliding_area"] == "m2/m"
    stats = json.loads((out / "summary.json").read_text())["cases"][0][toy.name]
    assert stats["mean"] == pytest.approx(np.mean(values), rel=1e-15)
    page = (out / "report.html").read_text(encoding="utf-8")
    assert f'<span title="{toy.name}">{toy.label}</span> <small>(m)</small>' in page

    with pytest.raises(SystemExit):
        cli.main(["mc", "--help"])
    assert toy.name in capsys.readouterr().out
    sub = run_subset_campaign(scene, tmp_path / "subset", "toy", 1.0, p0=0.5, n=20,
                              client=dask_client, progress=False, figures=False)
    summary = json.loads((tmp_path / "subset" / "summary.json").read_text())["subset"]
    assert summary["response"] == toy.name and summary["failure"] == f"{toy.name} > 1 m"
    assert sub.result is not None and sub.computed == sub.result.total_runs >= 20
    for p in (tmp_path / "subset" / "records").glob("L*.json"):
        rec = json.loads(p.read_text())
        if rec["status"] == "ok":
            assert rec["value"] == rec["measures"][toy.name]
    assert toy.name in _csv_header(tmp_path / "subset" / "samples.csv")
