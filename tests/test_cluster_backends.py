"""Cluster backends and ``--dry-run`` without a batch system.

The tests that need a real SLURM are in ``tests/test_slurm.py`` (marker ``slurm``).
Here: option checking (one line, exit 2, nothing written), the job scripts dask-jobqueue
would submit for SLURM, PBS, SGE and LSF with fem_rmpm's worker environment, the
shared-directory probe, and the dry run (writes nothing, starts no worker, counts only
the realizations without a record, calibrates from the records when there are some).
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fem_rmpm import cli
from fem_rmpm.campaign import backends as B
from fem_rmpm.campaign import run_campaign
from fem_rmpm.campaign.estimate import estimate_campaign, records_calibration
from fem_rmpm.runtime.budget import STEPS_FACTOR, THREAD_EFFICIENCY, estimate_run
from fem_rmpm.scene import load_scene

DATA = Path(__file__).resolve().parent / "data"
TINY = DATA / "mc_tiny.toml"


def _tree(out: Path) -> dict:
    return {str(p.relative_to(out)): (p.read_bytes(), p.stat().st_mtime_ns)
            for p in sorted(Path(out).rglob("*")) if p.is_file()}


@pytest.mark.parametrize("argv, names", [
    (["--cluster", "slurmx"], "--cluster 'slurmx': unknown cluster kind; allowed: local, "
                              "slurm, pbs, sge, lsf"),
    (["--queue", "debug"], "--queue: options of batch-system workers"),
    (["--cluster", "slurm", "--adapt", "3:1"], "--adapt '3:1'"),
    (["--cluster", "slurm", "--adapt", "0:4", "--workers", "2"], "--workers keeps"),
    (["--cluster", "pbs", "--scheduler", "tcp://127.0.0.1:1"], "--scheduler joins"),
    (["--cluster", "sge", "--memory", "lots"], "--memory 'lots'"),
    (["--cluster", "lsf", "--cores", "0"], "--cores 0"),
])
def test_bad_cluster_options_are_one_line_exit_2_and_write_nothing(tmp_path, capsys, argv,
                                                                   names):
    out = tmp_path / "c"
    for dry in ([], ["--dry-run"]):
        assert cli.main(["mc", str(TINY), "-n", "2", "--out", str(out), "--quiet",
                         *argv, *dry]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "Traceback" not in err, err
        assert names in err, err
        assert not out.exists()


def test_a_refused_option_leaves_an_existing_campaign_untouched(tmp_path, capsys,
                                                               dask_scheduler):
    out = tmp_path / "c"
    assert cli.main(["mc", str(TINY), "-n", "2", "--out", str(out), "--scheduler",
                     dask_scheduler, "--quiet"]) == 0
    before = _tree(out)
    capsys.readouterr()
    assert cli.main(["mc", str(TINY), "-n", "4", "--out", str(out), "--cluster", "nope"]) == 2
    assert _tree(out) == before


@pytest.mark.parametrize("kind, directive", [("slurm", "#SBATCH"), ("pbs", "#PBS"),
                                             ("sge", "#$"), ("lsf", "#BSUB")])
def test_job_scripts_carry_the_options_and_one_thread_per_worker(kind, directive):
    """The job script of each batch system: queue, account, walltime, extra directives,
    the interface, `cores` single-thread worker processes sharing `memory`, and the
    worker environment exported before the worker starts."""
    spec = B.ClusterSpec(kind=kind, queue="short", account="geo42", cores=4, memory="8GB",
                         walltime="01:30:00", interface="lo",
                         job_directives=("extra-directive",))
    backend = B.open_backend(spec)
    kw = backend._job_kwargs()
    script = backend._script(backend._jobqueue_class(), kw)
    assert "short" in script and "geo42" in script and "01:30" in script
    assert f"{directive} extra-directive\n" in script
    assert "--nworkers 4" in script and "--nthreads 1" in script
    assert "--interface lo" in script
    for line in B.job_environment_lines():
        assert line in script
    assert script.index("OMP_NUM_THREADS") < script.index("distributed.cli.dask_worker")
    assert kw["processes"] == 4 and B._memory_bytes(kw["memory"]) == 8e9


def test_local_workers_get_the_threads_the_scene_asks_for(monkeypatch):
    """``[solver] threads = 2`` in a campaign: each local worker process gets a numba pool
    of 2 threads (``NUMBA_NUM_THREADS=2``; BLAS and OpenMP stay at 1) and 4 usable CPUs
    hold 2 such workers; ``threads = 0`` (the default) keeps one thread per worker.
    (Before, every local worker had ``NUMBA_NUM_THREADS=1``, so a campaign asked for two
    threads silently ran on one.)"""
    from types import SimpleNamespace

    from fem_rmpm.campaign import cluster
    from fem_rmpm.scene import with_values
    monkeypatch.setattr(cluster, "_usable_cpus", lambda: 4)
    scene = load_scene(TINY)
    assert scene.solver.threads == 0
    for threads, workers, per_worker in ((0, 4, 1), (1, 4, 1), (2, 2, 2), (3, 1, 3)):
        case = SimpleNamespace(scene=with_values(scene, {"solver.threads": threads}))
        plan = B.campaign_backend(None, None, None, [case]).plan(10)
        assert (plan["workers"], plan["cores_per_worker"]) == (workers, per_worker)
        env = cluster.worker_environment(per_worker)
        assert env["NUMBA_NUM_THREADS"] == str(per_worker) and env["OMP_NUM_THREADS"] == "1"
    assert B.campaign_backend(None, 3, None, [case]).plan(10)["workers"] == 3   # --workers wins


def test_fewer_threads_than_asked_is_one_warning_line():
    """Records that ran on fewer numba threads than the case asks for (workers of a running
    cluster keep their own ``NUMBA_NUM_THREADS``) give one warning line naming both counts;
    as many as asked, more, or records without a thread count (older campaigns): none."""
    from types import SimpleNamespace

    from fem_rmpm.campaign.case_campaign import thread_shortfall
    from fem_rmpm.scene import with_values
    scene = load_scene(TINY)
    cases = [SimpleNamespace(name="a", scene=with_values(scene, {"solver.threads": 2})),
             SimpleNamespace(name="b", scene=scene)]
    rec = lambda case, threads: {"case": case, "worker": {"pid": 1, "threads": threads}}
    text = thread_shortfall(cases, [rec("a", 1), rec("a", 2), rec("b", 1), rec("a", 1)])
    assert text.startswith("fem-rmpm: warning: 2 realization(s) ran on 1 numba thread(s), "
                           "fewer than [solver] threads = 2") and "\n" not in text
    assert thread_shortfall(cases, [rec("a", 2), rec("b", 1), rec("b", 2)]) is None
    assert thread_shortfall(cases, [{"case": "a", "worker": {"pid": 1}}]) is None


def test_default_job_memory_follows_the_estimate():
    """Without --memory or a configured one: per worker the larger of 1 GiB and twice the
    estimated peak of one realization."""
    small = B.open_backend(B.ClusterSpec(kind="slurm", worker_memory_estimate=200e6))
    assert B._memory_bytes(small._job_kwargs()["memory"]) == 2**30
    big = B.open_backend(B.ClusterSpec(kind="slurm", cores=2, worker_memory_estimate=3e9))
    assert abs(B._memory_bytes(big._job_kwargs()["memory"]) - 2 * 2 * 3e9) < 2**20


def test_dask_configuration_is_read_when_an_option_is_not_given():
    import dask
    with dask.config.set({"jobqueue.slurm.queue": "from-config",
                          "jobqueue.slurm.cores": 2, "jobqueue.slurm.memory": "3GB"}):
        backend = B.open_backend(B.ClusterSpec(kind="slurm", queue="from-cli"))
        script = backend._script(backend._jobqueue_class(), backend._job_kwargs())
    assert "-p from-cli" in script and "--mem=3G" in script and "--nworkers 2" in script


def test_probe_directory_reports_what_a_worker_cannot_see(tmp_path):
    """The worker task of the shared-directory check: a directory without the client's
    probe file (another machine's /tmp) is refused with the reason."""
    res = B.probe_directory(str(tmp_path / "elsewhere"), "abc")
    assert not res["ok"] and "does not see" in res["reason"]
    (tmp_path / f"{B._PROBE_PREFIX}abc").write_text("abc")
    assert B.probe_directory(str(tmp_path), "abc")["ok"]
    assert (tmp_path / f"{B._PROBE_PREFIX}abc.worker").exists()


def test_dry_run_writes_nothing_starts_no_worker_and_counts_what_is_left(tmp_path, capsys,
                                                                        dask_scheduler):
    """--dry-run on a fresh directory (nothing created), then on a campaign with 2 of 5
    records: 3 to run, and the cost per point-step comes from those records."""
    import distributed
    out = tmp_path / "c"
    before = set(distributed.Client._instances) if hasattr(distributed.Client, "_instances") \
        else None
    assert cli.main(["mc", str(TINY), "-n", "5", "--out", str(out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert not out.exists()
    assert "realizations to run: 5 (0 already finished)" in text
    for item in ("points", "steps each", "ns CPU", "core-hours:", "memory per worker:",
                 "wall time with"):
        assert item in text, item
    if before is not None:
        assert set(distributed.Client._instances) == before
    assert cli.main(["mc", str(TINY), "-n", "2", "--out", str(out), "--scheduler",
                     dask_scheduler, "--quiet"]) == 0
    capsys.readouterr()
    snapshot = _tree(out)
    assert cli.main(["mc", str(TINY), "-n", "5", "--out", str(out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "realizations to run: 3 (2 already finished)" in text
    assert "the 2 finished record(s) of this campaign" in text
    assert _tree(out) == snapshot


def test_records_calibration_is_cpu_time_over_point_steps():
    """Two records: 1 s and 3 s CPU for 100 x 1000 and 100 x 3000 point-steps -> 10 000 ns;
    budget steps 1000 -> steps factor (1 + 3) / 2 = 2."""
    scene = load_scene(TINY)
    e = estimate_run(scene)
    budget = {"scene": type(e)(**{**e.to_dict(), "steps": 1000})}
    recs = [{"case": "scene", "status": "ok", "cpu_time": 1.0, "steps": 1000, "particles": 100},
            {"case": "scene", "status": "ok", "cpu_time": 3.0, "steps": 3000, "particles": 100},
            {"case": "scene", "status": "failed", "cpu_time": 9.0, "steps": 5, "particles": 1}]
    cal = records_calibration(recs, budget)
    assert cal.ns_per_point_step == pytest.approx(1e4)
    assert cal.steps_factor == pytest.approx(2.0)
    assert records_calibration([], budget) is None


def test_dry_run_estimate_adds_up(tmp_path):
    """core-hours = sum over the realizations of (setup + points x steps x ns) plus one
    worker start per worker; steps = the budget's count x the steps factor."""
    scene = load_scene(TINY)
    est = estimate_campaign(scene, tmp_path / "c", realizations=3, workers=2)
    c, cal = est.cases[0], est.calibration
    assert c.to_run == 3 and c.budget_steps == estimate_run(scene).steps
    assert c.steps == round(c.budget_steps * STEPS_FACTOR)
    per = cal.setup_seconds + c.points * c.steps * cal.ns_per_point_step * 1e-9
    assert c.cpu_seconds == pytest.approx(per)
    assert est.cpu_seconds == pytest.approx(3 * per + 2 * cal.worker_start_seconds)
    assert est.workers == 2 and est.wall_seconds == pytest.approx(
        cal.worker_start_seconds + 2 * per)
    assert not (tmp_path / "c").exists()
    # threads = 2: one local worker of two threads runs each realization THREAD_EFFICIENCY
    # x 2 times faster (no probe: the budget's constant)
    from fem_rmpm.scene import with_values
    two = estimate_campaign(with_values(scene, {"solver.threads": 2}), tmp_path / "c",
                            realizations=3, workers=1, probe=False)
    c2, cal2 = two.cases[0], two.calibration
    assert two.plan["cores_per_worker"] == 2 and two.wall_seconds == pytest.approx(
        cal2.worker_start_seconds + 3 * c2.cpu_seconds / (2 * THREAD_EFFICIENCY))
