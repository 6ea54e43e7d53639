"""Monte Carlo campaigns on three-dimensional scenes: the failure rule and the slides along
the strike on a deposit made by hand, the records, resumption, results.csv and the report
of a small campaign of ``meshes/slope_small_3d.toml``, ``--dry-run``, and the options 3-D
campaigns refuse (exit 2, one line, nothing written)."""
from __future__ import annotations

import json
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm import campaign as mc
from fem_rmpm.campaign.decide import failure_threshold
from fem_rmpm.campaign.report import write_report
from fem_rmpm.cli import main
from fem_rmpm.measures import table
from fem_rmpm.measures.deposit3d import compute_measures_3d

MESHES = Path(__file__).parents[1] / "meshes"
SMALL = MESHES / "slope_small_3d.toml"


def _slab(moved_slices, shift=1.0):
    """A 4 x 2 x 6 block of unit cells (one point per cell, 1 m3 each) on a grid of
    1 m cells; the points of the z slices ``moved_slices`` moved ``shift`` m along x."""
    idx = np.stack(np.meshgrid(np.arange(4), np.arange(2), np.arange(6), indexing="ij"),
                   -1).reshape(-1, 3)
    x0 = idx + 0.5
    x = x0.copy()
    moved = np.isin(idx[:, 2], moved_slices)
    x[moved, 0] += shift
    n = len(x0)
    pts = SimpleNamespace(x=x, x0=x0, volume=np.ones(n), volume0=np.ones(n),
                          active=np.ones(n, bool), displacement=x - x0,
                          plastic_shear_strain=np.zeros(n))
    grid = SimpleNamespace(origin=np.zeros(3), cell=np.ones(3), shape=(8, 3, 6))
    return pts, grid


def test_failure_and_slides_along_the_strike_of_a_deposit_made_by_hand():
    """Slices 0 and 2 of six moved 1 m: two slides (an unmoved slice between them), each
    one slice long (1 m) holding 8 m3; sliding volume 16 m3, sliding area 16 / 6 m2/m.
    Failure needs a total sliding volume of at least failure_area x hz, a slide a slice
    holding that much: failure_area 8 m2/m (8 m3): failed, two slides; 9 m2/m: failed
    (16 >= 9 m3) but no slice holds 9 m3, so no slide; 17 m2/m: neither."""
    pts, grid = _slab([0, 2])
    m = compute_measures_3d(pts, grid, 0.0, 0.5, None, failure_area=8.0)
    assert m["failed"] and m["sliding_volume"] == 16.0
    assert m["sliding_area"] == pytest.approx(16.0 / 6.0)
    assert m["slide_count"] == 2 and m["slide_length_max"] == 1.0
    assert m["slide_volume_max"] == 8.0 and m["slides"] == [(0.0, 1.0, 8.0), (2.0, 3.0, 8.0)]
    m = compute_measures_3d(pts, grid, 0.0, 0.5, None, failure_area=9.0)
    assert m["failed"] and m["slide_count"] == 0 and m["slide_length_max"] == 0.0
    m = compute_measures_3d(pts, grid, 0.0, 0.5, None, failure_area=17.0)
    assert not m["failed"] and m["slide_count"] == 0
    pts.u_geostatic = np.full((len(pts.x), 3), 2.0)     # in-situ settlement: no sliding
    pts.displacement = pts.displacement + pts.u_geostatic
    m = compute_measures_3d(pts, grid, 0.0, 0.5, None, failure_area=8.0)
    assert m["sliding_volume"] == 16.0 and m["max_displacement"] == 1.0
    pts, grid = _slab([1, 2, 3])           # one slide three slices long
    m = compute_measures_3d(pts, grid, 0.0, 0.5, None, failure_area=1.0)
    assert m["slide_count"] == 1 and m["slide_length_max"] == 3.0
    assert m["slide_volume_max"] == 24.0 and m["runout_distance"] == 1.0
    assert m["runout_distance_mean"] == pytest.approx(0.5)
    for k in ("sliding_volume", "slide_count", "slide_length_max", "slide_volume_max"):
        assert k in table.strike() and table.MEASURES[k].source == table.THREE_D


def test_the_decision_rule_of_a_3d_scene_is_the_failure_volume():
    """Runs stopped once decided compare the moved volume with failure_area x hz."""
    scene = api.load_scene(SMALL)
    assert failure_threshold(scene) == scene.montecarlo.failure_area * scene.grid.cell[2]
    two_d = api.load_scene(MESHES / "slope_risk.toml")
    assert failure_threshold(two_d) == two_d.montecarlo.failure_area


def _strike_table(page: str) -> str:
    """The table of the report's section "Three-dimensional views"."""
    i = page.index("Three-dimensional views")
    return page[page.index("<table", i):page.index("</table>", i)]


def _records(out: Path) -> dict[int, dict]:
    return {json.loads(p.read_text())["index"]: json.loads(p.read_text())
            for p in sorted((out / "records").glob("realization_*.json"))}


@pytest.mark.slow       # ~20 s idle (the workers load the 3-D kernels), 150 s loaded
def test_a_3d_campaign_records_resumes_and_reports(tmp_path, dask_client):
    """Two realizations (t_end 4.5 s), then a third: the records are 3-D (slides, the
    measures along the strike), ``failed`` follows the volume rule and a failed record has
    a slide; resuming computes only the new one and leaves the others bitwise; results.csv
    has the 3-D columns; the report has the 3-D section with its figures."""
    scene = api.with_value(api.load_scene(SMALL), "solver.t_end", 4.5)
    out = tmp_path / "mc3d"
    mc.run_campaign(scene, out, 2, client=dask_client, progress=False, keep_vtk=2)
    first = _records(out)
    res = mc.run_campaign(scene, out, 3, client=dask_client, progress=False, keep_vtk=2)
    assert (res.computed, res.skipped) == (1, 2)
    recs = _records(out)
    assert {i: recs[i] for i in (0, 1)} == first
    least = failure_threshold(scene)
    for r in recs.values():
        m = r["measures"]
        assert r["status"] == "ok" and r["dimension"] == 3
        assert m["failed"] == (m["sliding_volume"] >= least > 0 or
                               (least == 0 and m["sliding_volume"] > 0))
        assert (m["slide_count"] >= 1) <= m["failed"]
        assert len(r["slides"]) == m["slide_count"]
    header = (out / "results.csv").read_text().splitlines()[0].split(",")
    assert "sliding_volume" in header
    page = (out / "report.html").read_text()
    assert "Three-dimensional views" in page and "strike_distributions.png" in page
    assert (out / "views3d" / "strike_distributions.png").is_file()
    assert (out / "views3d" / "plan_view.png").is_file()
    # the strike table takes the measure sample (index < runs_to_rest), as the measures
    # table: with runs_to_rest = 1 in the summary, one run of the three
    summary = json.loads((out / "summary.json").read_text())
    summary["runs_to_rest"] = 1
    (out / "summary.json").write_text(json.dumps(summary))
    strike = _strike_table(write_report(out).read_text())
    assert re.search(r"<tbody><tr><td>[^<]*</td><td>1</td>", strike), strike


@pytest.mark.parametrize("options, key", [(["--fs"], "--fs"), (["--fs-only"], "--fs-only"),
                                          (["--method", "subset", "--response", "runout",
                                            "--threshold", "1"], "--method subset")])
def test_3d_campaigns_refuse_the_factor_of_safety_and_subset_simulation(capsys, tmp_path,
                                                                        options, key):
    out = tmp_path / "out"
    code = main(["mc", str(SMALL), "-n", "2", "--out", str(out), *options])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert key in err and "three-dimensional" in err and not out.exists()


@pytest.mark.slow       # the probe: three short 3-D runs, 30 s on a loaded machine
def test_dry_run_prices_a_3d_campaign(capsys, tmp_path):
    """``mc --dry-run`` of the small 3-D scene: nothing written; its points are the 3-D
    budget's and the cost comes from a probe of 3-D runs in this process."""
    from fem_rmpm.runtime.budget import estimate_run
    out = tmp_path / "dry"
    assert main(["mc", str(SMALL), "-n", "10", "--out", str(out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    points = estimate_run(api.load_scene(SMALL)).points
    assert f"{points:,} points" in text and "a probe in this process" in text
    assert "realizations to run: 10" in text and "core-hours" in text
    assert not out.exists()


def test_the_3d_report_section_is_empty_for_a_plane_strain_campaign(tmp_path):
    """A plane-strain campaign's report gains nothing (its page is unchanged): no 3-D
    section and no 3-D figure for records without ``dimension = 3``."""
    from fem_rmpm.campaign.report3d import figures_3d, report_3d
    recs = [{"case": "scene", "index": 0, "status": "ok", "measures": {"failed": True}}]
    assert report_3d(tmp_path, recs) == ""
    assert figures_3d(tmp_path, recs, 0.5) == [] and not (tmp_path / "views3d").exists()


def test_a_3d_probe_of_elastic_first_steps_is_floored_by_the_whole_run_cost():
    """The dry run's probe times the first (elastic) steps: in 3-D the cost per
    point-step is at least the budget's whole-run figure of the 3-D step, and the source
    says so; a plane-strain calibration is kept as measured."""
    from fem_rmpm.campaign.estimate import Calibration, _whole_run_floor
    from fem_rmpm.runtime.budget import estimate_run
    three = api.load_scene(SMALL)
    probe = 0.5 * estimate_run(three).ns_per_point_step      # a probe faster than the floor
    cal = Calibration(probe, 0.1, 4.0, 1.3, "a probe")
    floored = _whole_run_floor(cal, estimate_run(three), three)
    assert floored.ns_per_point_step == estimate_run(three).ns_per_point_step > probe
    assert "whole-run figure" in floored.source and floored.setup_seconds == 0.1
    two = api.load_scene(MESHES / "slope_risk.toml")
    assert _whole_run_floor(cal, estimate_run(two), two) is cal


def test_a_3d_run_stopped_once_decided_agrees_with_its_run_to_rest():
    """Realization 1 of the small slope (campaign seed 5) fails: stopped once decided, its
    record carries failed, the decision time, the moved volume (m3, at least
    failure_area x hz) and the failure displacement; run to rest, it fails too and records
    the same decision time; realization 0 stands and is never decided."""
    from fem_rmpm.campaign.cases import realization_seed
    from fem_rmpm.campaign.decide import DECIDED
    from fem_rmpm.campaign.task import run_realization
    scene = api.load_scene(SMALL)

    def run(i, decide):
        return run_realization({"case": "scene", "index": i, "seed": realization_seed(5, i),
                                "scene": scene, "vtk_dir": None, "decide": decide})
    stopped, rest = run(1, True), run(1, False)
    assert stopped["stop_reason"] == DECIDED and stopped["slides"] is None
    m = stopped["measures"]
    assert set(m) == {"failed", "decided_time", "decided_area", "failure_displacement"}
    assert m["failed"] and m["decided_area"] >= failure_threshold(scene)
    assert rest["measures"]["failed"] and rest["measures"]["decided_time"] == m["decided_time"]
    assert rest["measures"]["slide_count"] >= 1
    stands = run(0, True)["measures"]
    assert not stands["failed"] and stands["decided_time"] is None
