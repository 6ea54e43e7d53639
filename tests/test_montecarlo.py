"""Monte Carlo campaigns on Dask: reproducible, resumable, lossless.

Scenes: ``tests/data/mc_tiny.toml`` (152 points, ~20 ms per realization) and
``tests/data/mc_slow.toml`` (624 points, ~0.3 s; for the tests that kill a worker or
the client mid-campaign).  Both have a lognormal random field of the peak cohesion,
so every realization is different and the seed matters.

References: the binomial standard error of a Monte Carlo probability
``sqrt(p (1 - p) / N)`` (Fenton & Griffiths 2008, Risk Assessment in
Geotechnical Engineering, sec. 6.2); the Wilson score interval (Wilson 1927; Brown,
Cai & DasGupta 2001, Statist. Sci. 16:101); seeds keyed by
``numpy.random.SeedSequence`` (NumPy docs, "Parallel random number generation").
"""
from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api, cli
from fem_rmpm import campaign as mc
from fem_rmpm.campaign import methods as cm
from fem_rmpm.campaign import store
from fem_rmpm.runtime.machine import cpu_model

DATA = Path(__file__).resolve().parent / "data"
TINY = DATA / "mc_tiny.toml"
SLOW = DATA / "mc_slow.toml"
ROOT = Path(__file__).resolve().parents[1]


def _table(out: Path) -> bytes:
    return (Path(out) / "results.csv").read_bytes()


def _summary(out: Path) -> dict:
    return json.loads((Path(out) / "summary.json").read_text())


def _records(out: Path) -> list[Path]:
    return sorted((Path(out) / "records").rglob("realization_*.json"))


def _tree(out: Path) -> dict:
    """Every file under ``out`` with its bytes and mtime (to prove nothing changed)."""
    return {str(p.relative_to(out)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(Path(out).rglob("*")) if p.is_file()}


def _wait(pred, timeout: float, what: str, step: float = 0.02):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if pred():
            return
        time.sleep(step)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def _kill_group(proc: subprocess.Popen, sig=signal.SIGKILL) -> None:
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:  # pragma: no cover
        pass


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture(scope="module")
def client(dask_client):
    """The test run's local cluster (2 single-thread worker processes, tests/conftest.py),
    shared by the tests that do not test cluster start-up itself."""
    return dask_client


@pytest.fixture(scope="module")
def slow_reference(tmp_path_factory, client) -> Path:
    """An uninterrupted campaign of mc_slow: the table the interrupted, resumed and
    cluster campaigns must reproduce bitwise."""
    out = tmp_path_factory.mktemp("mc") / "reference"
    res = mc.run_campaign(api.load_scene(SLOW), out, client=client, progress=False,
                          figures=False)
    assert res.computed == 12 and not res.lost
    return out


# --------------------------------------------------------------------------- seeds, statistics

def test_realization_seed_is_a_documented_function_of_campaign_seed_and_index():
    """seed_i = SeedSequence([campaign_seed, i]).generate_state(1, uint64)[0] >> 1: the same
    for any N, worker or order; distinct per index and per campaign seed; 63 bits."""
    seeds = [mc.realization_seed(2017, i) for i in range(200)]
    ref = [int(np.random.SeedSequence([2017, i]).generate_state(1, np.uint64)[0]) >> 1
           for i in range(200)]
    assert seeds == ref
    assert len(set(seeds)) == 200
    assert all(0 <= s < 2**63 for s in seeds)
    assert mc.realization_seed(2018, 0) != mc.realization_seed(2017, 0)
    with pytest.raises(ValueError):
        mc.realization_seed(1, -1)


def test_statistics_standard_error_and_wilson_interval():
    """P(failure) = k/N, SE = sqrt(p(1-p)/N) (binomial; Fenton & Griffiths 2008), and the
    Wilson score interval equals scipy's (Wilson 1927); quantiles are numpy's."""
    from scipy.stats import binomtest
    rng = np.random.default_rng(3)
    fails = rng.random(37) < 0.3
    runout = rng.gamma(2.0, 3.0, 37)
    rows = [{"index": i, "seed": i, "status": "ok", "failed": bool(f), "runout_distance": r,
             "retrogression_distance": r / 2, "sliding_area": 3 * r, "max_displacement": r}
            for i, (f, r) in enumerate(zip(fails, runout))]
    rows.append({"index": 37, "seed": 37, "status": "failed", "error": "boom"})
    s = mc.case_statistics(rows, 38)
    k, n = int(fails.sum()), 37
    p = k / n
    assert s["ok"] == n and s["numerical_failures"] == 1 and s["errors"][0]["error"] == "boom"
    assert s["p_failure"] == p
    assert s["se"] == pytest.approx(math.sqrt(p * (1 - p) / n), rel=1e-15, abs=0)
    ci = binomtest(k, n).proportion_ci(0.95, method="wilson")
    assert s["wilson95"] == pytest.approx([ci.low, ci.high], rel=1e-9)
    d = s["runout_distance"]
    assert d["mean"] == pytest.approx(runout.mean())
    assert d["se"] == pytest.approx(runout.std(ddof=1) / math.sqrt(n))
    assert [d["q05"], d["q50"], d["q95"]] == pytest.approx(np.quantile(runout, [.05, .5, .95]))
    conv = s["convergence"]
    assert conv["n"] == list(range(1, n + 1))
    assert conv["p_failure"][-1] == pytest.approx(p)
    assert conv["mean_runout"][9] == pytest.approx(runout[:10].mean())
    # p = 0: SE 0 but the Wilson interval still has width (the reason it is plotted)
    lo, hi = mc.wilson_interval(0, 10)
    assert lo == 0 and hi == pytest.approx(binomtest(0, 10).proportion_ci(method="wilson").high)


def test_cases_and_keep_vtk_parsing():
    scene = api.load_scene(TINY)
    hom, xi12 = mc.parse_case("homogeneous", scene), mc.parse_case("xi=12", scene)
    assert hom.scene.random_field is None and hom.deterministic
    assert xi12.name == "xi12" and xi12.scene.random_field.anisotropy == 12.0
    assert mc.parse_case("solver.cfl=0.3", scene).scene.solver.cfl == 0.3
    with pytest.raises(mc.CampaignError):
        mc.parse_case("cfl", scene)
    with pytest.raises(api.SceneError, match="solver.cfl"):
        mc.parse_case("solver.cfl=-1", scene)
    assert [c.name for c in mc.literature_cases(scene)] == ["homogeneous", "xi1", "xi12", "xi48"]
    assert mc.parse_keep_vtk("3") == 3 and mc.parse_keep_vtk(None, 2) == 2
    assert mc.parse_keep_vtk("0,5,9") == frozenset({0, 5, 9})
    assert mc.parse_keep_vtk("none") == 0
    for bad in ("-1", "x", "1,a", "1,-2"):
        with pytest.raises(mc.CampaignError):
            mc.parse_keep_vtk(bad)


# --------------------------------------------------------------------------- workers

def test_one_and_two_workers_give_identical_tables(tmp_path, client):
    """The same campaign on 1 and on 2 local worker processes writes the
    same results.csv byte for byte (measures bitwise equal), and each row equals the
    realization run alone in this process with api.run(scene, seed=realization_seed).
    One worker: ``fem-rmpm mc --workers 1`` in a subprocess (its own LocalCluster); two:
    the test run's shared cluster (one in-process cluster start per test run)."""
    scene = api.load_scene(TINY)
    r1 = subprocess.run([sys.executable, "-m", "fem_rmpm.cli", "mc", str(TINY), "-n", "6",
                         "--workers", "1", "--quiet", "--out", str(tmp_path / "w1")],
                        env=_env(), capture_output=True, text=True, timeout=300)
    assert r1.returncode == 0, r1.stderr[-2000:]
    run1 = json.loads((tmp_path / "w1" / "summary.json").read_text())["this_run"]
    assert run1["workers"] == "1 local worker process"
    r2 = mc.run_campaign(scene, tmp_path / "w2", 6, client=client, progress=False,
                         figures=False)
    assert len(client.nthreads()) == 2
    assert run1["computed"] == r2.computed == 6
    assert _table(tmp_path / "w1") == _table(tmp_path / "w2")
    rows = mc.read_results(tmp_path / "w1" / "results.csv")
    assert [r["index"] for r in rows] == list(range(6))
    assert len({r["seed"] for r in rows}) == 6
    # the realizations differ (the seed drives the random field) ...
    assert len({r["sliding_area"] for r in rows}) > 1
    # ... and a realization is a pure function of (scene, seed): every scalar measure of
    # api.run is a column of the table, bitwise equal
    for r in rows[:2]:
        res = api.run(scene, seed=mc.realization_seed(scene.montecarlo.seed, r["index"]))
        scalars = {k: v for k, v in res.measures.items() if not isinstance(v, list)}
        assert {"sliding_area", "runout_distance", "retrogression_distance"} <= set(scalars)
        for key, value in scalars.items():
            assert r[key] == value, key
    workers = [json.loads(p.read_text())["worker"] for p in _records(tmp_path / "w2")]
    assert len({w["pid"] for w in workers}) == 2, "both workers computed realizations"
    # each record names its worker's machine; the summary counts them (here: this one)
    assert {w["cpu_model"] for w in workers} == {cpu_model()}
    summary = json.loads((tmp_path / "w2" / "summary.json").read_text())
    assert summary["worker_machines"] == [{"host": socket.gethostname(),
                                           "cpu_model": cpu_model(), "runs": 6}]


# --------------------------------------------------------------------------- running cluster

@pytest.fixture
def loopback_cluster(tmp_path):
    """`dask scheduler` and two single-thread `dask worker` processes on 127.0.0.1, each in
    its own process group; all killed at teardown (bounded waits)."""
    procs, files = [], []
    sched_file = tmp_path / "scheduler.json"
    logs = tmp_path / "dask-logs"
    logs.mkdir()

    def start(args, name):
        log = open(logs / f"{name}.log", "w")
        files.append(log)
        p = subprocess.Popen([sys.executable, "-m", *args], stdout=log, stderr=log,
                             env=_env(), cwd=tmp_path, start_new_session=True)
        procs.append(p)
        return p
    try:
        start(["distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
               "--no-dashboard", "--scheduler-file", str(sched_file)], "scheduler")
        _wait(lambda: sched_file.exists() and sched_file.stat().st_size > 0, 60,
              "the scheduler file")
        time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        workers = [start(["distributed.cli.dask_worker", address, "--nthreads", "1",
                          "--nworkers", "1", "--no-dashboard", "--name", f"w{i}",
                          "--memory-limit", "0"], f"worker{i}") for i in range(2)]
        from distributed import Client
        with Client(address, timeout="20s", set_as_default=False) as c:
            c.wait_for_workers(2, timeout=60)
        yield address, workers
    finally:
        for p in reversed(procs):
            _kill_group(p, signal.SIGTERM)
        for p in procs:
            _kill_group(p)
        for f in files:
            f.close()


def test_loopback_cluster_survives_a_killed_worker(tmp_path, loopback_cluster, slow_reference):
    """A real scheduler and two workers on 127.0.0.1 (separate processes
    started with the dask CLI); one worker is SIGKILLed in the middle of the campaign;
    Dask moves its task to the other worker; every realization is recorded exactly once
    and the table equals the local single-worker campaign bitwise."""
    import threading
    address, workers = loopback_cluster
    out = tmp_path / "cluster"
    killed = {}

    def killer():
        try:
            _wait(lambda: len(_records(out)) >= 2, 120, "two records")
            killed["records_at_kill"] = len(_records(out))
            os.killpg(workers[0].pid, signal.SIGKILL)
            killed["done"] = True
        except AssertionError as exc:  # pragma: no cover - reported below
            killed["error"] = str(exc)
    t = threading.Thread(target=killer, daemon=True)
    t.start()
    res = mc.run_campaign(api.load_scene(SLOW), out, scheduler=address, progress=False,
                          figures=False)
    t.join(timeout=30)
    assert killed.get("done"), killed
    assert killed["records_at_kill"] < 12, "the worker was killed mid-campaign"
    workers[0].wait(timeout=10)
    assert not res.lost
    recs = [json.loads(p.read_text()) for p in _records(out)]
    assert sorted(r["index"] for r in recs) == list(range(12))     # exactly once each
    rows = mc.read_results(out / "results.csv")
    assert [r["index"] for r in rows] == list(range(12))
    assert _table(out) == _table(slow_reference)


# --------------------------------------------------------------------------- resuming

def test_sigkill_of_the_client_then_rerun_finishes_only_the_missing(tmp_path, slow_reference,
                                                                  dask_scheduler):
    """`fem-rmpm mc` is SIGKILLed (the client process only) after its first
    records; its local workers exit with it (they watch their parent); re-running the
    same campaign (in this process, on the test run's cluster) computes only the
    realizations without a record, and the final table equals the uninterrupted
    campaign's bitwise."""
    out = tmp_path / "killed"
    argv = ["mc", str(SLOW), "--out", str(out), "--workers", "2", "--quiet"]
    proc = subprocess.Popen([sys.executable, "-m", "fem_rmpm.cli", *argv], env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        _wait(lambda: len(_records(out)) >= 1 or proc.poll() is not None, 120, "a record")
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        # the spawned worker processes notice their parent is gone and exit
        _wait(lambda: not _group_alive(proc.pid), 30, "the orphaned workers to exit", 0.2)
    finally:
        _kill_group(proc)
        proc.stderr.close()
    done = len(_records(out))
    assert 1 <= done < 12, f"{done} records at the kill: not mid-campaign"
    assert not (out / "results.csv").exists()
    rerun = [a for a in argv if a not in ("--workers", "2")] + ["--scheduler", dask_scheduler]
    assert cli.main(rerun) == 0
    s = _summary(out)["this_run"]
    assert s["computed"] == 12 - done and s["skipped_finished"] == done
    assert _table(out) == _table(slow_reference)
    # once more, the command as first given: nothing left to compute, no cluster started
    assert cli.main(argv) == 0
    assert _summary(out)["this_run"]["computed"] == 0
    assert _table(out) == _table(slow_reference)


def test_larger_n_appends_and_force_recomputes(tmp_path, client):
    """Seeds do not depend on N, so a larger N appends realizations and keeps the finished
    records untouched; --force recomputes all, to the same table."""
    scene = api.load_scene(TINY)
    out = tmp_path / "grow"
    mc.run_campaign(scene, out, 3, client=client, progress=False, figures=False)
    first = {p.name: p.read_bytes() for p in _records(out)}
    res = mc.run_campaign(scene, out, 5, client=client, progress=False, figures=False)
    assert res.computed == 2 and res.skipped == 3
    assert all(first[p.name] == p.read_bytes() for p in _records(out) if p.name in first)
    table = _table(out)
    res = mc.run_campaign(scene, out, 5, client=client, progress=False, figures=False,
                          force=True)
    assert res.computed == 5 and res.skipped == 0
    assert _table(out) == table


# --------------------------------------------------------------------------- failures

def test_failed_realization_is_recorded_with_its_message(tmp_path, client):
    """With softening_strain = 0.022 the softening modulus
    h = (c_peak - c_res) / softening_strain reaches the shear modulus for points whose
    random peak cohesion is high, which api.prepare refuses (SimulationError) for some
    seeds only.  Those realizations are listed as failed with the message api.run gives
    for the same seed; the others complete; the summary counts them."""
    scene = api.with_value(api.load_scene(TINY), "soil.softening_strain", 0.022)
    expected = {}
    for i in range(8):
        try:
            api.prepare(scene, mc.realization_seed(scene.montecarlo.seed, i))
        except api.SimulationError as exc:
            expected[i] = str(exc)
    assert 0 < len(expected) < 8, "the scene must make some but not all seeds fail"
    res = mc.run_campaign(scene, tmp_path / "fail2", 8, client=client, progress=False)
    rows = mc.read_results(tmp_path / "fail2" / "results.csv")
    assert [r["index"] for r in rows] == list(range(8))
    for r in rows:
        if r["index"] in expected:
            assert r["status"] == "failed"
            assert r["error"] == expected[r["index"]]
            assert "softening modulus" in r["error"]
            assert r["sliding_area"] is None
        else:
            assert r["status"] == "ok" and r["error"] is None
            assert r["sliding_area"] is not None
    st = res.stats["scene"]
    assert st["numerical_failures"] == len(expected) and st["ok"] == 8 - len(expected)
    assert "failed numerically" in cli.summary_text(res)
    # re-running does not retry recorded failures (they are results); --force would
    assert mc.run_campaign(scene, tmp_path / "fail2", 8, client=client, progress=False,
                           figures=False).computed == 0


def test_unstable_case_fails_loudly_and_other_cases_complete(tmp_path, client):
    """A case with [solver] cfl = 3 (the top of its range, about twice the largest measured
    limit) blows up in every realization; its records say so; the stable case's
    realizations complete."""
    scene = api.load_scene(TINY)
    res = mc.run_campaign(scene, tmp_path / "cfl", 3, cases=["scene", "solver.cfl=3"],
                          client=client, progress=False, figures=False)
    rows = mc.read_results(tmp_path / "cfl" / "results.csv")
    assert [(r["case"], r["index"]) for r in rows] == \
        [("scene", i) for i in range(3)] + [("solver.cfl=3", i) for i in range(3)]
    assert all(r["status"] == "ok" for r in rows[:3])
    assert all(r["status"] == "failed" and "unstable" in r["error"] for r in rows[3:])
    assert res.stats["solver.cfl=3"]["ok"] == 0
    # common random numbers: the same index has the same seed in every case
    assert [r["seed"] for r in rows[:3]] == [r["seed"] for r in rows[3:]]


# --------------------------------------------------------------------------- bad input

def _one_line_error(capsys, argv) -> str:
    code = cli.main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and err.startswith("fem-rmpm: error:"), err
    return err


def test_bad_input_is_one_line_and_writes_nothing(tmp_path, capsys):
    """N <= 0, an unreachable scheduler, a bad address, --workers 0, a bad
    --keep-vtk: exit 2 with one line, and no campaign directory is created."""
    out = tmp_path / "none"
    for argv, words in (
            (["-n", "0"], "-n 0"), (["-n", "-3"], "positive"),
            (["--workers", "0"], "--workers 0"), (["--keep-vtk", "x"], "--keep-vtk"),
            (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--scheduler")):
        err = _one_line_error(capsys, ["mc", str(TINY), "--out", str(out), *argv])
        assert words in err
        assert not out.exists()
    afile = tmp_path / "afile"
    afile.write_text("mine")
    assert "not a directory" in _one_line_error(capsys, ["mc", str(TINY), "--out", str(afile)])
    assert "cannot write" in _one_line_error(capsys, ["mc", str(TINY), "--out",
                                                      str(afile / "sub")])
    assert afile.read_text() == "mine"
    with socket.socket() as s:        # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    import dask
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        err = _one_line_error(capsys, ["mc", str(TINY), "--out", str(out), "--scheduler",
                                       f"tcp://127.0.0.1:{port}"])
        assert "cannot reach the Dask scheduler" in err and str(port) in err
        assert "within 2s" in err              # dask's configured connect timeout, used
        err = _one_line_error(capsys, ["mc", str(TINY), "--out", str(out), "--scheduler",
                                       "nonsense://nowhere"])
        assert "not a scheduler address" in err      # its syntax: refused before connecting
    assert not out.exists()


def test_directory_of_another_campaign_is_refused_untouched(tmp_path, capsys, client):
    """An output directory that holds a different scene's campaign (here:
    another peak cohesion, another seed, other cases) or something that is not a campaign
    is refused with one line naming the difference; not a byte or a time stamp changes,
    also with --force.  (The two campaigns that do run use the module's shared cluster
    rather than a second in-process LocalCluster.)"""
    out = tmp_path / "camp"
    mc.run_campaign(api.load_scene(TINY), out, 2, client=client, progress=False, keep_vtk="0")
    capsys.readouterr()
    before = _tree(out)
    other = tmp_path / "other.toml"
    other.write_text(TINY.read_text().replace("cohesion_peak = 6.5", "cohesion_peak = 7.0"))
    err = _one_line_error(capsys, ["mc", str(other), "-n", "2", "--out", str(out), "--force"])
    assert "different scene" in err and "soil[0].cohesion_peak" in err and "7.0" in err
    seed = tmp_path / "seed.toml"
    seed.write_text(TINY.read_text().replace("seed = 11", "seed = 12"))
    assert "seed" in _one_line_error(capsys, ["mc", str(seed), "--out", str(out)])
    assert _tree(out) == before
    # a directory that is not a campaign
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "notes.txt").write_text("mine")
    assert "not a campaign" in _one_line_error(capsys, ["mc", str(TINY), "--out", str(junk)])
    assert [p.name for p in junk.iterdir()] == ["notes.txt"]
    # the same scene from another path, with another N, keep_vtk, description: the same
    # campaign (those keys do not change a realization)
    same = tmp_path / "same.toml"
    same.write_text(TINY.read_text().replace("keep_vtk = 1", "keep_vtk = 0").replace(
        'name = "mc_tiny"', 'name = "mc_tiny"\ndescription = "another description"'))
    mc.run_campaign(api.load_scene(same), out, 3, client=client, progress=False)
    assert _summary(out)["this_run"]["computed"] == 1


def test_a_scene_key_added_later_with_its_default_keeps_the_campaign(tmp_path):
    """A campaign started before fem_rmpm grew a scene key (here: its stored scene lacks
    [solver] kernel) is still the same campaign when the key holds its default; another
    value of the key is a different scene."""
    scene = api.load_scene(TINY)
    doc = store.campaign_doc([mc.parse_case("scene", scene)], scene.montecarlo.seed)
    old = json.loads(json.dumps(doc))
    del old["cases"][0]["scene"]["solver"]["kernel"]
    (tmp_path / "campaign.json").write_text(json.dumps(old))
    assert store.check_directory(tmp_path, doc) is True
    other = api.with_value(scene, "solver.kernel", "numpy")
    with pytest.raises(mc.CampaignError, match=r"solver\.kernel \(only in this scene\)"):
        store.check_directory(tmp_path, store.campaign_doc([mc.parse_case("scene", other)],
                                                       scene.montecarlo.seed))


def test_a_running_campaign_locks_its_directory(tmp_path, capsys):
    out = tmp_path / "locked"
    out.mkdir()
    with store.Lock(out):
        err = _one_line_error(capsys, ["mc", str(TINY), "-n", "1", "--out", str(out),
                                       "--workers", "1"])
    assert "being run by pid" in err
    assert not (out / "campaign.json").exists()


# --------------------------------------------------------------------------- cases, VTK, figures

def test_literature_cases_with_kept_vtk_and_figures(tmp_path, client):
    """The four literature cases (homogeneous, xi = 1, 12, 48) on the tiny scene: the
    homogeneous case is deterministic and runs once; each random case runs N with the
    same seeds; VTK is kept for the named realizations only (0 and 2; the homogeneous
    case has only 0); all figures are written."""
    scene = api.load_scene(TINY)
    out = tmp_path / "cases"
    res = mc.run_campaign(scene, out, 3, cases=mc.LITERATURE_CASES, client=client,
                          keep_vtk="0,2", progress=False)
    assert res.realizations == {"homogeneous": 1, "xi1": 3, "xi12": 3, "xi48": 3}
    rows = mc.read_results(out / "results.csv")
    assert [r["case"] for r in rows] == ["homogeneous"] + ["xi1"] * 3 + ["xi12"] * 3 + \
        ["xi48"] * 3
    vtk = sorted(p.relative_to(out).as_posix() for p in (out / "vtk").glob("*/*"))
    assert vtk == ["vtk/homogeneous/realization_00000"] + [
        f"vtk/{c}/realization_{i:05d}" for c in ("xi1", "xi12", "xi48") for i in (0, 2)]
    assert (out / "vtk/xi12/realization_00002/particles.pvd").exists()
    assert not (out / "vtk/xi12/realization_00001").exists()
    for name in ("exceedance.png", "histograms.png", "convergence.png", "cases.png"):
        assert (out / name).stat().st_size > 10_000, name
    camp = json.loads((out / "campaign.json").read_text())
    assert [c["name"] for c in camp["cases"]] == ["homogeneous", "xi1", "xi12", "xi48"]
    assert "random_field" not in camp["cases"][0]["scene"]
    assert camp["cases"][3]["scene"]["random_field"]["anisotropy"] == 48.0
    text = cli.summary_text(res)
    assert "deterministic" in text and "xi = 12" in text and "P(failure)" in text


def test_default_scene_runs_the_literature_cases():
    """`fem-rmpm mc` without SCENE runs the four literature cases of the embedded default."""
    path = cli.default_scene_path()
    assert cli.campaign_cases(api.load_scene(path), path) == list(mc.LITERATURE_CASES)
    assert cli.campaign_cases(api.load_scene(TINY), TINY) == ["scene"]


# --------------------------------------------------------------------------- validation script

def test_validation_script_writes_the_case_figures(tmp_path, dask_scheduler):
    """validation/montecarlo_cases.py on the tiny scene with N = 2 runs the four
    literature cases (the deterministic one once) with common random
    numbers, writes results.csv, summary.json and the figures (valid PNGs), and prints per
    case the P(failure) that the table's rows give.  It runs on the test run's cluster
    (``--scheduler``; a command that starts a cluster of its own:
    :func:`test_one_and_two_workers_give_identical_tables`)."""
    import csv
    out = tmp_path / "val"
    r = subprocess.run([sys.executable, str(ROOT / "validation" / "montecarlo_cases.py"),
                        "--scene", str(TINY), "-n", "2", "--scheduler", dask_scheduler,
                        "--out", str(out)],
                       env=_env(), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    rows = list(csv.DictReader((out / "results.csv").open()))
    by_case = {}
    for row in rows:
        by_case.setdefault(row["case"], []).append(row)
    assert list(by_case) == ["homogeneous", "xi1", "xi12", "xi48"]
    assert [len(v) for v in by_case.values()] == [1, 2, 2, 2]
    assert all(row["status"] == "ok" for row in rows)
    for i in range(2):                                   # common random numbers
        assert len({v[i]["seed"] for k, v in by_case.items() if k != "homogeneous"}) == 1
    summary = _summary(out)
    for case in summary["cases"]:
        fails = [int(row["failed"]) for row in by_case[case["name"]]]
        assert case["p_failure"] == sum(fails) / len(fails)
        if not case["deterministic"]:
            assert f"{case['label']}: N = 2 ok; P(failure) = {case['p_failure']:.3f}" in r.stdout
    for name in ("exceedance.png", "histograms.png", "convergence.png", "cases.png",
                 "cases_mechanism.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name


# The four cases on the reference slope with the script's documented N, against the table
# of docs/validation/reference_slope.md:
# tests/test_readme_figures.py::test_four_literature_cases_match_docs
# (slow; it writes to a temporary directory, not validation/out).



# --------------------------------------------------------------------------- campaign methods

class _FirstN(cm.BatchMethod):
    """A toy case method: realizations 0 .. n-1 asked for one at a time (n batches), the
    same samples as crude Monte Carlo in another batching; P = k/n."""
    name = "first_n"

    def __init__(self, n: int, seed: int):
        self.n, self.seed, self.on_failure = n, seed, "reject"
        self._start()

    def _process(self):
        ys = []
        for i in range(self.n):
            y = yield [cm.Sample(0, i, 0, seed=mc.realization_seed(self.seed, i))]
            ys.extend(y)
        k = int(np.count_nonzero(np.asarray(ys) > 0.5))
        return cm.MethodResult("first_n", 0.5, k / self.n, math.nan, self.n)


def test_a_method_of_the_table_runs_through_the_one_runner_from_the_command_line(
        tmp_path, monkeypatch, dask_scheduler):
    """A third method registered in ``METHODS`` (one row) is a ``--method`` choice and runs
    through the campaign runner: its one-sample batches give the records, table and
    statistics of the crude campaign of the same N (the samples are the same realizations,
    a pure function of their seed)."""
    monkeypatch.setitem(mc.METHODS, "first_n", cm.MethodEntry(
        lambda o: _FirstN(o.n, o.seed), response=False, help="toy: 0 .. n-1, one at a time"))
    tables = {}
    for method in ("first_n", "crude"):
        out = tmp_path / method
        argv = ["mc", str(TINY), "-n", "3", "--out", str(out), "--quiet", "--keep-vtk", "0",
                "--scheduler", dask_scheduler, "--method", method]
        assert cli.main(argv) == 0
        assert _summary(out)["this_run"]["computed"] == 3
        tables[method] = (_table(out), _summary(out)["cases"])
    assert tables["first_n"] == tables["crude"]
    assert cli.main(argv[:-1] + ["first_n"]) == 0      # crude's records serve first_n
    assert _summary(tmp_path / "crude")["this_run"]["computed"] == 0
