"""Runs stopped once decided (``[montecarlo] runs_to_rest``, fem_rmpm.campaign.decide).

A realization is a pure function of scene and seed, so a run stopped once its failure is
decided is the run to rest up to that time: P(failure) must be the same, record by record,
as with every run to rest, and the measures must come from the runs to rest only.
Scene: ``tests/data/mc_tiny.toml`` (152 points, ~20 ms per realization; failure_displacement
0.1 m, outputs every 0.5 s), on the test run's two-worker cluster.
"""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm import campaign as mc
from fem_rmpm.campaign import store
from fem_rmpm.campaign.decide import DECIDED, FailureWatch, decision_check, in_measure_sample

TINY = Path(__file__).resolve().parent / "data" / "mc_tiny.toml"
N = 8


def _records(out: Path) -> dict[int, dict]:
    return {json.loads(p.read_text())["index"]: json.loads(p.read_text())
            for p in sorted((out / "records").glob("realization_*.json"))}


def test_failure_watch_rule():
    """The rule: the first output at which >= 1 m2 (initial volume) of active points moved
    more than the threshold (x - x0); inactive (frozen) points do not count; with stop it
    then names the stop reason, without it only notes the time."""
    x0 = np.zeros((4, 2))
    pts = SimpleNamespace(x0=x0, x=x0.copy(), active=np.ones(4, bool),
                          volume0=np.array([0.5, 0.5, 0.25, 0.25]))
    w, s = FailureWatch(0.5), FailureWatch(0.5, stop=True)
    pts.x[:2, 0] = 0.5                       # exactly the threshold: not moved
    assert w(1.0, pts) is None and s(1.0, pts) is None and w.time is None
    pts.x[:2, 0] = 0.51
    pts.active[1] = False                    # 0.5 m2 moved and active: not yet 1 m2
    assert s(2.0, pts) is None and s.time is None
    pts.active[1] = True                     # 1.0 m2: decided
    assert w(3.0, pts) is None and w.time == 3.0 and w.moved_area == 1.0
    assert s(3.0, pts) == DECIDED and s.time == 3.0
    pts.x[:] = 0.0                           # the first time is kept
    assert w(4.0, pts) is None and w.time == 3.0


def test_runs_to_rest_is_not_part_of_the_campaign_identity():
    """A campaign resumes with another runs_to_rest (it changes which runs stop early, not
    a realization)."""
    scene = api.load_scene(TINY)
    other = api.with_value(scene, "montecarlo.runs_to_rest", 3)
    case = [mc.parse_case("scene", scene)], [mc.parse_case("scene", other)]
    assert store.campaign_doc(case[0], 11) == store.campaign_doc(case[1], 11)


def test_measure_sample_is_the_runs_to_rest_below_k():
    """A run to rest with index >= K (a stander of a decided run, or an older record)
    is left out of the measure sample, so the sample stays the first K realizations."""
    assert in_measure_sample({"index": 2, "stop_reason": "at rest"}, 3)
    assert not in_measure_sample({"index": 3, "stop_reason": "at rest"}, 3)
    assert not in_measure_sample({"index": 1, "stop_reason": DECIDED}, None)
    assert in_measure_sample({"index": 99, "stop_reason": "t_end reached"}, None)
    rows = [{"case": "c", "index": i, "status": "ok", "failed": i % 2 == 0,
             "sliding_area": float(i), "runout_distance": 1.0, "retrogression_distance": 0.0,
             "max_displacement": 0.0, "stop_reason": "at rest"} for i in range(6)]
    rows[4].update(stop_reason=DECIDED, sliding_area=None, runout_distance=None)
    st = mc.case_statistics(rows, 6, runs_to_rest=3)
    assert st["p_failure"] == pytest.approx(3 / 6) and st["mpm_runs"] == 6
    assert st["runs_to_rest"] == 3
    assert st["measure_runs"] == 3 and st["sliding_area"]["mean"] == pytest.approx(1.0)
    assert st["convergence"]["n_measure"] == [1, 2, 3] and len(st["convergence"]["n"]) == 6


@pytest.fixture(scope="module")
def to_rest(tmp_path_factory, dask_client) -> Path:
    out = tmp_path_factory.mktemp("decide") / "rest"
    mc.run_campaign(api.load_scene(TINY), out, N, client=dask_client, progress=False,
                    figures=False)
    return out


def test_decided_campaign_gives_the_same_failures(tmp_path, dask_client, to_rest):
    """runs_to_rest = 3 on N = 8: realization by realization the same ``failed`` as the
    campaign run to rest (7 of 8 fail here); the failures with index >= 3 stop once decided
    (records say so and carry only failed, decided_time, decided_area, failure_displacement);
    the others are the runs to rest themselves (same measures); every run to rest records
    its decision time, and it agrees with its ``failed``; the report is written."""
    rest = _records(to_rest)
    scene = api.with_value(api.load_scene(TINY), "montecarlo.runs_to_rest", 3)
    res = mc.run_campaign(scene, tmp_path / "dec", N, client=dask_client, progress=False)
    dec = _records(tmp_path / "dec")
    assert sorted(dec) == list(range(N))
    assert [dec[i]["measures"]["failed"] for i in range(N)] == \
        [rest[i]["measures"]["failed"] for i in range(N)]
    decided = [i for i in range(N) if dec[i]["stop_reason"] == DECIDED]
    assert decided and min(decided) >= 3
    for i in range(N):
        if i in decided:
            m = dec[i]["measures"]
            assert set(m) == {"failed", "decided_time", "decided_area", "failure_displacement"}
            assert m["decided_time"] == rest[i]["measures"]["decided_time"]
            assert dec[i]["simulated_time"] == m["decided_time"] < rest[i]["simulated_time"]
        else:
            assert dec[i]["measures"] == rest[i]["measures"]
    assert res.stats["scene"]["p_failure"] == pytest.approx(
        np.mean([rest[i]["measures"]["failed"] for i in range(N)]))
    assert res.stats["scene"]["measure_runs"] == 3
    check = json.loads((tmp_path / "dec" / "summary.json").read_text())["decision_check"]
    assert check["scene"]["checked"] == N - len(decided) and check["scene"]["agree"] == \
        check["scene"]["checked"]
    assert decision_check(rest.values())["agree"] == N
    assert (tmp_path / "dec" / "report.html").is_file()


def test_a_larger_k_reruns_the_decided_records_to_rest(tmp_path, dask_client, to_rest):
    """Resuming with runs_to_rest = 6 computes exactly the decided records with index < 6
    (to rest), and they then equal the campaign run to rest; records of index >= 6 stay."""
    scene = api.load_scene(TINY)
    out = tmp_path / "grow"
    mc.run_campaign(api.with_value(scene, "montecarlo.runs_to_rest", 3), out, N,
                    client=dask_client, progress=False, figures=False)
    before = _records(out)
    again = [i for i in range(3, 6) if before[i]["stop_reason"] == DECIDED]
    res = mc.run_campaign(api.with_value(scene, "montecarlo.runs_to_rest", 6), out, N,
                          client=dask_client, progress=False, figures=False)
    assert res.computed == len(again) > 0
    after, rest = _records(out), _records(to_rest)
    for i in range(6):
        assert after[i]["measures"] == rest[i]["measures"]
    for i in range(6, N):
        assert after[i] == before[i]


def test_import_records_checks_the_scene_and_resumes(tmp_path, dask_client, to_rest):
    """Records of a finished campaign are imported into a campaign of more cases when the
    common case has the same scene (runs_to_rest may differ: not identity); the campaign
    then computes only the rest, and the imported records are unchanged.  A source whose
    scene differs is refused and nothing is written."""
    scene = api.with_value(api.load_scene(TINY), "montecarlo.runs_to_rest", 2)
    cases = [mc.parse_case(c, scene) for c in ("homogeneous", "scene")]
    doc = store.campaign_doc(cases, scene.montecarlo.seed)
    dst = tmp_path / "study"
    assert store.import_records(to_rest, dst, doc, cases) == {"scene": N}
    assert store.import_records(to_rest, dst, doc, cases) == {"scene": 0}   # kept
    res = mc.run_campaign(scene, dst, N, cases=cases, client=dask_client, progress=False,
                          figures=False)
    assert res.computed == 1 and res.skipped == N                   # the homogeneous run
    rest = _records(to_rest)
    got = {json.loads(p.read_text())["index"]: json.loads(p.read_text())
           for p in (dst / "records" / "scene").glob("realization_*.json")}
    assert all(got[i]["measures"] == rest[i]["measures"] for i in range(N))
    other = api.with_value(api.load_scene(TINY), "random_field.cov", 0.4)
    cases2 = [mc.parse_case("scene", other)]
    with pytest.raises(mc.CampaignError, match="different scene"):
        store.import_records(to_rest, tmp_path / "other", store.campaign_doc(
            cases2, other.montecarlo.seed), cases2)
    assert not (tmp_path / "other").exists()
