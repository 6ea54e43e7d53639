"""Campaigns through a real SLURM: the single-node cluster that ``.ci/run``
starts with ``.ci/slurm-start.sh``.  Marked ``slurm``: skipped without a running SLURM,
failed under CI=true (tests/conftest.py).

The command is run the way a user runs it: ``fem-rmpm mc SCENE --cluster slurm`` in a
subprocess, configured by a ``jobqueue.yaml`` in ``$DASK_CONFIG`` (interface ``lo``: on
this machine only loopback traffic is allowed; walltime; log directory).  The scene is
``tests/data/mc_slow.toml`` (624 points); the reference is the same campaign on a local
cluster, and the tables must be bitwise identical.
"""
from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.slurm

DATA = Path(__file__).resolve().parent / "data"
SLOW = DATA / "mc_slow.toml"
ROOT = Path(__file__).resolve().parents[1]
JOBQUEUE_YAML = """\
jobqueue:
  slurm:
    interface: lo
    walltime: "00:20:00"
    log-directory: {logs}
"""


@pytest.fixture(autouse=True)
def _one_slurm_test_at_a_time(tmp_path_factory):
    """These tests count the jobs in the one queue, so with pytest-xdist they run one at a
    time across the workers (an exclusive lock on a file beside the workers' temporary
    directories): a campaign's jobs from the other worker once showed up in the dry run's
    "nothing submitted" check in CI.  (pytest-xdist's ``xdist_group`` does not group
    under pytest 9.2: it renames ``item._nodeid``, which pytest no longer reads.)"""
    lock = tmp_path_factory.getbasetemp().parent / "fem-rmpm-slurm-tests.lock"
    with open(lock, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _env(config_dir: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env["DASK_CONFIG"] = str(config_dir)
    env["DASK_DISTRIBUTED__DEPLOY__LOST_WORKER_TIMEOUT"] = "2s"
    return env


@pytest.fixture(scope="module")
def config_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("dask-config")
    (d / "jobqueue.yaml").write_text(JOBQUEUE_YAML.format(logs=d / "logs"))
    return d


def _mc(args, config_dir, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "fem_rmpm.cli", "mc", *map(str, args)],
                            env=_env(config_dir), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def _run(args, config_dir, timeout=400) -> subprocess.CompletedProcess:
    p = _mc(args, config_dir)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        p.kill()
        out, err = p.communicate()
        raise AssertionError(f"fem-rmpm mc timed out; stderr: {err[-2000:]}")
    return subprocess.CompletedProcess(p.args, p.returncode, out, err)


def _our_jobs() -> list[str]:
    res = subprocess.run(["squeue", "-h", "-n", "dask-worker", "-o", "%i %t"],
                         capture_output=True, text=True, check=True)
    return [line.split()[0] for line in res.stdout.splitlines()
            if line.split() and line.split()[1] == "R"]


def _job_pids(job: str) -> set[int]:
    res = subprocess.run(["scontrol", "listpids", job], capture_output=True, text=True)
    return {int(line.split()[0]) for line in res.stdout.splitlines()[1:] if line.split()}


def _ancestors(pid: int) -> set[int]:
    """pid and its parents (from /proc): the worker process is a child of the job's nanny."""
    out = set()
    while pid > 1 and pid not in out:
        out.add(pid)
        try:
            pid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            break
    return out


def _records(out: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted((out / "records").rglob("*.json"))]


@pytest.fixture(scope="module")
def local_reference(tmp_path_factory, config_dir) -> Path:
    """The 4-realization campaign on a local cluster of 2 worker processes."""
    out = tmp_path_factory.mktemp("local") / "mc"
    res = _run([SLOW, "-n", 4, "--out", out, "--workers", 2, "--quiet"], config_dir)
    assert res.returncode == 0, res.stderr[-2000:]
    return out


def test_campaign_through_slurm_equals_the_local_campaign_bitwise(tmp_path, config_dir,
                                                                  local_reference):
    """4 realizations through `--cluster slurm` (2 worker jobs): results.csv
    is bitwise identical to the local cluster's; the records name the SLURM workers;
    the worker jobs are gone afterwards."""
    out = tmp_path / "slurm"
    res = _run([SLOW, "-n", 4, "--out", out, "--cluster", "slurm", "--workers", 2], config_dir)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "SLURM (dask-jobqueue): 2 worker(s) in 2 job(s)" in res.stdout
    assert (out / "results.csv").read_bytes() == (local_reference / "results.csv").read_bytes()
    recs = _records(out)
    assert sorted(r["index"] for r in recs) == [0, 1, 2, 3]
    summary = json.loads((out / "summary.json").read_text())["this_run"]
    assert summary["computed"] == 4 and summary["lost"] == []
    deadline = time.monotonic() + 60
    while _our_jobs() and time.monotonic() < deadline:   # close() scancels the jobs
        time.sleep(0.5)
    assert _our_jobs() == []


def test_scancel_of_a_worker_job_mid_realization_loses_nothing(tmp_path, config_dir):
    """One of two worker jobs is scancelled while it runs a realization (the
    job whose worker has just written the first record, so it is computing its next
    realization of ~1-10 s); Dask moves that realization to the other worker; the
    campaign completes with every realization recorded exactly once, none lost, and the
    table is bitwise the uncancelled one (a local campaign of the same scene)."""
    scene = tmp_path / "longer.toml"     # mc_slow with 12 s instead of 4 s of dynamics
    scene.write_text(SLOW.read_text().replace("t_end = 4.0", "t_end = 12.0"))
    out = tmp_path / "cancelled"
    p = _mc([scene, "-n", 6, "--out", out, "--cluster", "slurm", "--workers", 2, "--quiet"],
            config_dir)
    killed = None
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and p.poll() is None:
            recs = _records(out) if (out / "records").exists() else []
            if recs:
                pid = recs[0]["worker"]["pid"]
                jobs = {j: _job_pids(j) for j in _our_jobs()}
                killed = next((j for j, pids in jobs.items() if pids & _ancestors(pid)), None)
                assert killed is not None, (pid, jobs)
                records_at_kill = len(recs)
                subprocess.run(["scancel", killed], check=True)
                break
            time.sleep(0.1)
        stdout, stderr = p.communicate(timeout=400)
    finally:
        if p.poll() is None:
            p.kill()
    assert killed is not None, "no record appeared"
    assert records_at_kill < 6, "the job was cancelled mid-campaign"
    assert p.returncode == 0, stderr[-3000:]
    recs = _records(out)
    assert sorted(r["index"] for r in recs) == list(range(6)), "each realization exactly once"
    summary = json.loads((out / "summary.json").read_text())["this_run"]
    assert summary["computed"] == 6 and summary["lost"] == []
    killed_pid = recs[0]["worker"]["pid"]
    assert sum(r["worker"]["pid"] == killed_pid for r in recs) < 6
    ref = tmp_path / "reference"
    res = _run([scene, "-n", 6, "--out", ref, "--workers", 2, "--quiet"], config_dir)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (out / "results.csv").read_bytes() == (ref / "results.csv").read_bytes()


@pytest.mark.parametrize("args, says", [
    (["--queue", "nosuch"], "invalid partition specified: nosuch"),
    (["--memory", "100000GB"], "more than any node of the cluster has"),
])
def test_refused_jobs_are_one_line_exit_2_and_nothing_written(tmp_path, config_dir, args,
                                                              says):
    """A queue that does not exist (SLURM's own refusal) and a memory request
    above the node's: exit 2, one line, no campaign directory, no job left; the same
    for --dry-run."""
    out = tmp_path / "c"
    for dry in ([], ["--dry-run"]):
        res = _run([SLOW, "-n", 2, "--out", out, "--cluster", "slurm", *args, *dry],
                   config_dir, timeout=120)
        assert res.returncode == 2, res.stderr[-2000:]
        err = res.stderr.strip()
        assert err.count("\n") == 0 and says in err, err
        assert not out.exists()
    assert _our_jobs() == []


def test_a_directory_the_workers_do_not_share_is_refused(tmp_path, config_dir):
    """The worker jobs run in a private mount namespace where the campaign
    directory is an empty tmpfs of their own (like /tmp of a login node seen from a compute
    node): exit 2 with one line naming the directory and the shared-file-system rule; no
    realization ran, and the campaign can then be run from a shared directory."""
    out = tmp_path / "private"
    out.mkdir()
    wrapper = tmp_path / "python-on-another-node"
    wrapper.write_text("#!/bin/sh\nexec unshare -m sh -c 'mount -t tmpfs none "
                       f"{out} && exec {sys.executable} \"$@\"' python \"$@\"\n")
    wrapper.chmod(0o755)
    cfg = tmp_path / "cfg"
    cfg.mkdir()
    (cfg / "jobqueue.yaml").write_text(JOBQUEUE_YAML.format(logs=tmp_path / "logs")
                                       + f"    python: {wrapper}\n")
    res = _run([SLOW, "-n", 2, "--out", out, "--cluster", "slurm", "--quiet"], cfg, timeout=200)
    assert res.returncode == 2, res.stderr[-2000:]
    err = res.stderr.strip()
    assert err.count("\n") == 0, err
    assert f"--out {out}" in err and "does not see" in err and "share" in err
    assert not (out / "records").exists()


def test_dry_run_checks_the_job_script_with_slurm_and_starts_nothing(tmp_path, config_dir):
    out = tmp_path / "c"
    before = set(_our_jobs())
    res = _run([SLOW, "-n", 3, "--out", out, "--cluster", "slurm", "--workers", 2,
                "--dry-run"], config_dir, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "accepted by the batch system's test submission: sbatch: Job" in res.stdout
    assert "#SBATCH" in res.stdout and "--interface lo" in res.stdout
    assert not out.exists() and set(_our_jobs()) == before
