"""Subset-simulation campaigns of a scene on Dask: resumed after a kill, reused records.

Scene: ``tests/data/mc_tiny.toml`` (152 points, ~15 ms of CPU per realization); the
response is the maximum displacement, threshold 1 m (P ~ 0.07 with N = 100 per level:
two levels, 190 runs, so the Markov chains run).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api, cli
from fem_rmpm.campaign import subset_runner
from fem_rmpm.campaign.backends import ClusterSpec
from fem_rmpm.campaign.subset_runner import sample_noise

DATA = Path(__file__).resolve().parent / "data"
TINY = DATA / "mc_tiny.toml"
ROOT = Path(__file__).resolve().parents[1]
ARGS = ["--method", "subset", "--response", "max_displacement", "--threshold", "1.0",
        "-n", "100", "--quiet"]
#: Record keys that depend on where and when a sample ran, not on what it is.
_RUN_KEYS = ("worker", "wall_time", "cpu_time")


def _records(out: Path) -> dict[str, dict]:
    out = {p.name: json.loads(p.read_text()) for p in sorted((out / "records").glob("L*.json"))}
    for r in out.values():
        for k in _RUN_KEYS:
            r.pop(k, None)
    return out


def _subset(out: Path) -> dict:
    return json.loads((out / "summary.json").read_text())["subset"]


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """An uninterrupted campaign on ONE worker (``fem-rmpm mc --workers 1`` in a
    subprocess, its own LocalCluster): what 2 workers and a killed and resumed campaign
    must reproduce."""
    out = tmp_path_factory.mktemp("subset") / "reference"
    r = subprocess.run([sys.executable, "-m", "fem_rmpm.cli", "mc", str(TINY), "--out",
                        str(out), "--workers", "1", *ARGS], env=_env(), capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    run = summary["this_run"]
    assert run["computed"] == 190 and run["workers"] == "1 local worker process"
    assert [m["runs"] for m in summary["worker_machines"]] == [190]    # all on this machine
    assert len(_subset(out)["levels"]) == 2
    return out


def _wait_records(out: Path, proc, at_least: int, timeout: float = 300.0) -> None:
    import time
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if proc.poll() is not None:
            raise AssertionError(proc.stderr.read().decode()[-2000:])
        if len(list((out / "records").glob("L*.json"))) >= at_least:
            return
        time.sleep(0.05)
    raise AssertionError(f"no {at_least} records within {timeout} s")


def test_sigkill_during_a_level_then_rerun_on_two_workers_equals_one_worker(tmp_path, reference,
                                                                          dask_scheduler):
    """`fem-rmpm mc --method subset` on 2 workers is SIGKILLed (the client)
    during level 1 (after 100 level-0 records and at least 5 chain samples); the same
    command again computes only the samples without a record; estimate, thresholds and
    every record (but where and how long it ran) equal the 1-worker uninterrupted run."""
    out = tmp_path / "killed"
    argv = ["mc", str(TINY), "--out", str(out), "--workers", "2", *ARGS]
    proc = subprocess.Popen([sys.executable, "-m", "fem_rmpm.cli", *argv], env=_env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        _wait_records(out, proc, 105)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.stderr.close()
    done = len(list((out / "records").glob("L*.json")))
    assert 105 <= done < 190 and not (out / "summary.json").exists()
    # the rerun in this process, on the test run's 2-worker cluster (tests/conftest.py)
    argv[argv.index("--workers"):argv.index("--workers") + 2] = ["--scheduler", dask_scheduler]
    assert cli.main(argv) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["this_run"]["computed"] == 190 - done and s["this_run"]["reused_records"] == done
    assert _subset(out) == _subset(reference)
    assert _records(out) == _records(reference)
    assert (out / "samples.csv").read_bytes() == (reference / "samples.csv").read_bytes()


def test_records_hold_the_position_and_replay_the_noise(reference):
    """One record per sample with level, chain, step, seed or noise digest, response; the
    noise of a chain sample, replayed from the records, re-runs it to the same response."""
    recs = _records(reference)
    assert len(recs) == 190
    r0, r1 = recs["L00_C00007_S000.json"], recs["L01_C00003_S004.json"]
    assert r0["seed"] is not None and r0["noise_digest"] is None and r0["accepted"] is None
    assert r1["seed"] is None and len(r1["noise_digest"]) == 64 and r1["start"].startswith("L")
    assert r1["value"] == r1["measures"]["max_displacement"]
    assert isinstance(r1["accepted"], bool)
    scene = api.load_scene(TINY)
    noise = sample_noise(scene, reference, "L01_C00003_S004")
    again = api.run(scene, noise=noise)
    assert again.measures["max_displacement"] == r1["value"]
    s = _subset(reference)
    assert s["total_runs"] == 190 and s["failure"] == "max_displacement > 1 m"
    assert s["probability"] == pytest.approx(
        np.prod([lv["conditional_probability"] for lv in s["levels"]]), rel=1e-12)
    assert (reference / "subset_levels.png").stat().st_size > 10_000
    assert (reference / "report.html").exists()


def test_a_common_threshold_reuses_level_zero_and_says_it_is_not_rare(tmp_path, reference,
                                                                     capsys):
    """A threshold most level-0 samples exceed: no new run (the levels do
    not depend on the threshold), the crude estimate and a warning that says so."""
    import shutil
    out = tmp_path / "common"
    shutil.copytree(reference, out)
    argv = ["mc", str(TINY), "--out", str(out), "--workers", "1",
            *[a if a != "1.0" else "0.01" for a in ARGS]]
    assert cli.main(argv) == 0
    text = capsys.readouterr().out
    assert "WARNING: the failure max_displacement > 0.01 m occurs in" in text
    assert "crude Monte Carlo" in text
    s = _subset(out)
    level0 = [r for r in _records(out).values() if r["level"] == 0]
    k = sum(r["value"] > 0.01 for r in level0)
    assert k > 50 and s["probability"] == k / 100 and len(s["levels"]) == 1
    assert json.loads((out / "summary.json").read_text())["this_run"]["computed"] == 0


@pytest.mark.parametrize("extra,needle", [
    (["--p0", "0.7"], "--p0 0.7: the level probability must be in (0, 0.5]"),
    (["--p0", "0"], "(0, 0.5]"),
    (["-n", "50"], "N p0 = 5 seeds per level; at least 10 are needed"),
    (["--response", "volume"], "--response 'volume': not a response of a realization; "
                               "allowed: runout_distance"),
])
def test_bad_subset_input_is_one_line_and_writes_nothing(tmp_path, capsys, extra, needle):
    out = tmp_path / "bad"
    argv = ["mc", str(TINY), "--out", str(out), *ARGS, *extra]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_subset_needs_a_response_threshold_and_a_random_field(tmp_path, capsys):
    out = tmp_path / "bad"
    assert cli.main(["mc", str(TINY), "--out", str(out), "--method", "subset"]) == 2
    assert "--method subset needs --response NAME" in capsys.readouterr().err
    assert cli.main(["mc", str(TINY), "--out", str(out), "--method", "subset",
                     "--response", "runout"]) == 2
    assert "--response runout_distance needs --threshold X" in capsys.readouterr().err
    assert cli.main(["mc", str(TINY), "--out", str(out), "--threshold", "1"]) == 2
    assert "--threshold: only with --method subset" in capsys.readouterr().err
    assert cli.main(["mc", str(ROOT / "meshes" / "column.toml"), "--out", str(out), *ARGS]) == 2
    assert "subset simulation needs a [random_field]" in capsys.readouterr().err
    assert not out.exists()


def test_another_campaign_in_the_directory_is_refused(tmp_path, reference, capsys):
    argv = ["mc", str(TINY), "--out", str(reference), *ARGS, "--p0", "0.2"]
    before = sorted(p.name for p in reference.iterdir())
    assert cli.main(argv) == 2
    assert "holds a subset campaign with p0 = 0.1 there, 0.2 here" in capsys.readouterr().err
    crude = ["mc", str(TINY), "--out", str(reference), "-n", "3", "--quiet"]
    assert cli.main(crude) == 2
    assert "not a 'fem_rmpm campaign 1' campaign" in capsys.readouterr().err
    assert sorted(p.name for p in reference.iterdir()) == before


def test_subset_refuses_dry_run_in_one_line(tmp_path, capsys):
    """``--dry-run`` estimates crude campaigns only (a subset campaign's
    runs depend on its levels): exit 2, one line naming the option, nothing written."""
    out = tmp_path / "dry"
    assert cli.main(["mc", str(TINY), "--out", str(out), *ARGS, "--dry-run"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("fem-rmpm: error: --dry-run: only for crude campaigns"), err
    assert len(err.splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("argv, names", [
    (["--cluster", "slurmx"], "--cluster 'slurmx': unknown cluster kind"),
    (["--queue", "debug"], "--queue: options of batch-system workers"),
    (["--cluster", "sge", "--memory", "lots"], "--memory 'lots'"),
    (["--cluster", "pbs", "--scheduler", "tcp://127.0.0.1:1"], "--scheduler joins"),
    (["--cluster", "slurm", "--adapt", "3:1"], "--adapt '3:1'"),
])
def test_subset_checks_the_cluster_options_like_crude(tmp_path, capsys, argv, names):
    """The cluster options go through the crude campaign's checks: exit 2, one line,
    nothing written (before, ``--method subset`` ignored them)."""
    out = tmp_path / "c"
    assert cli.main(["mc", str(TINY), "--out", str(out), *ARGS, *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert names in err and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert not out.exists()


class _RecordingBackend:
    """A campaign backend that records its calls and runs on the test run's cluster."""
    description = "the recording backend"

    def __init__(self, client):
        self.client, self.calls = client, []

    def preflight(self, n_tasks):
        self.calls.append(("preflight", n_tasks))

    def start(self, n_tasks, out):
        self.calls.append(("start", (out / "campaign.json").exists()))
        return self.client

    def check_directory(self, client, out):
        self.calls.append(("check_directory", client is self.client))

    def close(self):
        self.calls.append(("close",))


def test_subset_runs_on_the_backend_of_the_cluster_options(tmp_path, capsys, monkeypatch,
                                                           dask_client):
    """``mc --method subset --cluster slurm ...`` builds the same ClusterSpec as crude
    Monte Carlo and runs its samples on that backend: checked before anything is written
    (preflight), started after campaign.json, the workers' directory checked, closed at
    the end; the samples ran on the backend's client.  (The real SLURM path is
    tests/test_slurm.py; here the backend is replaced by a recorder.)"""
    seen = {}

    def backend(spec, workers, scheduler, cases):
        seen.update(spec=spec, workers=workers, scheduler=scheduler,
                    cases=[c.name for c in cases], out_exists=out.exists())
        seen["backend"] = _RecordingBackend(dask_client)
        return seen["backend"]

    monkeypatch.setattr(subset_runner, "campaign_backend", backend)
    out = tmp_path / "cl"
    argv = ["mc", str(TINY), "--out", str(out), "--cluster", "slurm", "--queue", "debug",
            "--cores", "2", "--walltime", "00:10:00", "--workers", "2",
            *[a if a != "1.0" else "0.01" for a in ARGS]]
    assert cli.main(argv) == 0, capsys.readouterr().err
    spec = seen["spec"]
    assert isinstance(spec, ClusterSpec) and (spec.kind, spec.queue, spec.cores,
                                              spec.walltime) == ("slurm", "debug", 2, "00:10:00")
    assert seen["workers"] == 2 and seen["scheduler"] is None and seen["cases"] == ["scene"]
    assert not seen["out_exists"]
    assert seen["backend"].calls == [("preflight", 100), ("start", True),
                                     ("check_directory", True), ("close",)]
    run = json.loads((out / "summary.json").read_text())["this_run"]
    assert run["computed"] == 100 and run["workers"] == "the recording backend"
