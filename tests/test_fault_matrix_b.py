"""A new user's mistakes that must end in one line and an exit code, never a traceback, a
hang or lost output: file-system errors, inputs that broke a library, unbounded work and
signals.

Each case checks the exit code, exactly one line on stderr (none for a closed pipe), no
traceback, and that nothing was written or left behind where that applies.

Permissions mean nothing to root, and the suite runs as root here: the permission cases
run the real command (``python -m fem_rmpm_entry``) in a subprocess started with
``user=65534`` (the ``nobody`` account; :func:`subprocess.run` calls ``setuid`` in the
child), in a world-writable temporary directory; as a normal user they run as that user.
The signal cases start the command in its own process group and send the signal to the
group, as a terminal's Ctrl-C does.
"""
from __future__ import annotations

import fcntl
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

import fem_rmpm_entry
from fem_rmpm.cli import main
from fem_rmpm.scene import SceneError, load_scene, polygon_problem, scene_from_dict
from fem_rmpm.scene.schema import _candidate_pairs

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
REFERENCE = ROOT / "fem_rmpm" / "data" / "slope_reference.toml"
NOBODY = 65534
COMMAND = [sys.executable, "-m", "fem_rmpm_entry"]


def _env(work: Path) -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(work / ".numba"),
            "HOME": str(work), "PYTHONWARNINGS": "default"}


def _one_line(err: str, *words: str) -> str:
    err = err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err and "Warning" not in err, err
    for w in words:
        assert w in err, err
    return err


def _cli(capsys, argv: list[str], code: int = 2, *words: str) -> str:
    got = main(argv)
    err = capsys.readouterr().err
    assert got == code, err
    return _one_line(err, *words)


@pytest.fixture
def shared_dir():
    """A world-writable directory outside pytest's private tree, for the ``nobody`` child."""
    work = Path(tempfile.mkdtemp(prefix="fem_rmpm_fault_"))
    work.chmod(0o777)
    yield work
    for p in work.rglob("*"):           # let root remove what the child made read-only
        if p.is_dir() and not p.is_symlink():
            p.chmod(0o777)
    shutil.rmtree(work, ignore_errors=True)


#: The child loads the package as root (the interpreter lives under /root here), then
#: drops to ``nobody`` with ``os.setuid`` before the command runs.
_AS_NOBODY = ("import os, sys, encodings.utf_8_sig; import fem_rmpm.cli, "
              "fem_rmpm.io.field_output, fem_rmpm.campaign.report; "
              "from fem_rmpm_entry import main; "
              "os.getuid() == 0 and (os.setgid({uid}), os.setuid({uid})); "
              "sys.argv[0] = 'fem-rmpm'; sys.exit(main())")


def _as_user(args: list[str], work: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    """The command as ``nobody`` (as the current user when not root), in ``work``."""
    code = _AS_NOBODY.format(uid=NOBODY)
    return subprocess.run([sys.executable, "-c", code, *args], cwd=work, env=_env(work),
                          capture_output=True, text=True, timeout=timeout)


def _scene_copy(work: Path, name: str = "column.toml", extra: str = "") -> Path:
    path = work / name
    path.write_text((ROOT / "meshes" / name).read_text() + extra)
    path.chmod(0o644)
    return path


# ----------------------------------------------------------------- 1. file-system errors

def test_unreadable_scene_is_exit_2(shared_dir):
    scene = _scene_copy(shared_dir)
    scene.chmod(0)
    r = _as_user(["run", str(scene), "--out", "new", "--quiet"], shared_dir)
    assert r.returncode == 2, r.stderr
    _one_line(r.stderr, str(scene), "cannot be read", "read permission")
    assert not (shared_dir / "new").exists()


@pytest.mark.parametrize("command", ["run", "fem", "field"])
@pytest.mark.parametrize("below", [False, True], ids=["read-only", "new-under-read-only"])
def test_out_in_a_read_only_directory_is_exit_2(shared_dir, command, below):
    scene = _scene_copy(shared_dir, "column.toml") if command != "field" else REFERENCE
    ro = shared_dir / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    out = ro / "new" if below else ro
    args = [command, str(scene), "--out", str(out)] + (["--quiet"] if command == "run" else [])
    r = _as_user(args, shared_dir)
    assert r.returncode == 2, r.stderr
    _one_line(r.stderr, str(out), "not writable", f"write permission on {ro}")
    assert list(ro.iterdir()) == []


def test_out_a_dangling_symlink_is_exit_2(capsys, meshes, tmp_path):
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "gone")
    _cli(capsys, ["run", str(meshes / "column.toml"), "--out", str(link), "--quiet"], 2,
         str(link), "symbolic link", "does not exist")
    assert link.is_symlink() and not (tmp_path / "gone").exists()


def test_unreadable_data_csv_is_exit_2_and_leaves_no_out(shared_dir):
    data = shared_dir / "data.csv"
    data.write_text("x,y,value\n10,3,20\n")
    data.chmod(0)
    r = _as_user(["field", str(REFERENCE), "--data", str(data), "--out", "out"], shared_dir)
    assert r.returncode == 2, r.stderr
    _one_line(r.stderr, str(data), "cannot be read", "read permission")
    assert not (shared_dir / "out").exists()


@pytest.fixture(scope="module")
def campaign(mc_tiny_campaign, tmp_path_factory) -> Path:
    """A finished two-realization campaign of ``tests/data/mc_tiny.toml``: this module's
    copy of the shared one (``fem-rmpm mc -n 2 --workers 1``, conftest.py)."""
    out = tmp_path_factory.mktemp("fault_b") / "mc"
    shutil.copytree(mc_tiny_campaign, out)
    return out


def test_report_on_a_read_only_campaign_is_exit_2(campaign, shared_dir):
    work = shared_dir / "mc"
    shutil.copytree(campaign, work)
    (work / "report.html").unlink()
    work.chmod(0o555)
    r = _as_user(["report", str(work)], shared_dir)
    assert r.returncode == 2, r.stderr
    _one_line(r.stderr, "report.html", "cannot be written", f"write permission on {work}")
    assert not (work / "report.html").exists()
    assert not list(work.glob(".report.html*"))


# ----------------------------------------------------------------- 2. tracebacks

def test_deeply_nested_array_in_a_scene_is_exit_2(capsys, tmp_path):
    scene = tmp_path / "deep.toml"
    scene.write_text("a = " + "[" * 10_000 + "]" * 10_000 + "\n")
    out = tmp_path / "out"
    _cli(capsys, ["run", str(scene), "--out", str(out)], 2, "nested too deeply")
    assert not out.exists()


def test_report_on_a_campaign_json_list_is_exit_2(capsys, campaign, tmp_path):
    work = tmp_path / "mc"
    shutil.copytree(campaign, work)
    (work / "report.html").unlink()
    (work / "campaign.json").write_text("[1, 2]")
    _cli(capsys, ["report", str(work)], 2, "campaign.json", "JSON list")
    assert not (work / "report.html").exists()


def test_field_with_a_vanishing_scale_is_exit_2_and_writes_nothing(capsys, tmp_path):
    """theta_v = 1e-6 m on 0.25 m field cells: the cell averages' covariance underflows to
    0 (every eigenvalue of the embedding 0); refused, no RuntimeWarning, no file."""
    scene = tmp_path / "tiny_theta.toml"
    scene.write_text(REFERENCE.read_text() + "\n[random_field]\ntheta_v = 1e-6\n")
    out = tmp_path / "out"
    with _no_warnings():
        _cli(capsys, ["field", str(scene), "--out", str(out)], 2, "random_field.theta_v",
             "no variance")
    assert not out.exists()


class _no_warnings:
    """Fail on any warning raised inside the block."""

    def __enter__(self):
        self._cm = warnings.catch_warnings(record=True)
        self._log = self._cm.__enter__()
        warnings.simplefilter("always")
        return self

    def __exit__(self, *exc):
        self._cm.__exit__(*exc)
        assert not self._log, [str(w.message) for w in self._log]


def test_mc_into_a_closed_pipe_ends_quietly(campaign):
    """``fem-rmpm mc ... | head -1`` after a finished campaign: the reader leaves before
    the summary is printed; the command ends quietly with 141 (128 + SIGPIPE), as a Unix
    tool killed by SIGPIPE does, and no BrokenPipeError."""
    read, write = os.pipe()
    os.close(read)                      # the reader is gone before anything is written
    try:
        r = subprocess.run(COMMAND + ["mc", str(DATA / "mc_tiny.toml"), "-n", "2",
                                      "--workers", "1", "--out", str(campaign), "--quiet"],
                           env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=write,
                           stderr=subprocess.PIPE, text=True, timeout=300)
    finally:
        os.close(write)
    assert r.returncode == 128 + signal.SIGPIPE, r.stderr
    assert r.stderr.strip() == ""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_while_the_package_loads_is_quiet(capsys, monkeypatch, sig):
    """The console entry loads the command line inside its own interrupt handling: a
    signal while the heavy modules load (here: sent by a stand-in for that import) ends
    with 130 or 143 and one line."""

    class Interrupting:
        def find_spec(self, name, path=None, target=None):
            if name == "fem_rmpm.cli":
                os.kill(os.getpid(), sig)
                time.sleep(1.0)          # the handler runs here
            return None

    signal.signal(signal.SIGINT, signal.default_int_handler)   # a terminal's Ctrl-C
    monkeypatch.delitem(sys.modules, "fem_rmpm.cli")
    monkeypatch.setattr(sys, "meta_path", [Interrupting(), *sys.meta_path])
    before = signal.getsignal(signal.SIGTERM)
    assert fem_rmpm_entry.main() == 128 + sig
    assert signal.getsignal(signal.SIGTERM) == before
    _one_line(capsys.readouterr().err, "interrupted while starting")


# ----------------------------------------------------------------- 3. hangs, unbounded work

def _traced_peak(fn):
    """``(fn(), peak bytes of traced Python/numpy memory while it ran)``."""
    tracemalloc.start()
    try:
        got = fn()
        return got, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_absurd_realization_count_is_refused_at_once(capsys, tmp_path, monkeypatch):
    """Refused from the campaign's arithmetic: no realization runs (not even the dry run's
    probe) and nothing per realization is made (traced peak below 64 MiB; a seed per
    realization alone would be 8 GB)."""
    import fem_rmpm.api as api
    import fem_rmpm.campaign.estimate as estimate

    def no_run(*args, **kwargs):
        raise AssertionError("a realization ran before the campaign size was checked")
    monkeypatch.setattr(api, "run", no_run)
    monkeypatch.setattr(estimate, "run_one", no_run)         # the dry run's probe
    out = tmp_path / "mc"
    err, peak = _traced_peak(lambda: _cli(
        capsys, ["mc", str(DATA / "mc_tiny.toml"), "-n", "1000000000", "--dry-run", "--out",
                 str(out)], 2, "-n 1000000000", "core-hours", "at most"))
    assert peak < 64 * 2**20, (peak, err)
    assert not out.exists()


def _star(n: int) -> np.ndarray:
    th = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    r = 10.0 + 3.0 * np.sin(7 * th)
    return np.column_stack([20 + r * np.cos(th), 20 + r * np.sin(th)])


def _first_crossing_brute_force(p: np.ndarray):
    """The first pair (i, j), i < j, of non-adjacent edges that cross or touch (O(n^2))."""
    n = len(p)
    q = np.roll(p, -1, axis=0)

    def orient(u, v, w):
        return np.sign((v[0] - u[0]) * (w[1] - u[1]) - (v[1] - u[1]) * (w[0] - u[0]))
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue
            a, b, c, d = p[i], q[i], p[j], q[j]
            if (orient(a, b, c) * orient(a, b, d) <= 0 and orient(c, d, a) * orient(c, d, b) <= 0
                    and all(min(a[k], b[k]) <= max(c[k], d[k])
                            and min(c[k], d[k]) <= max(a[k], b[k]) for k in (0, 1))):
                return i, j
    return None


def test_polygon_check_is_near_linear_and_finds_the_same_crossing():
    """5 000 and 20 000 points: the edge pairs tested grow linearly with the edges (at most
    one per edge, 0.10-0.11 measured, against n^2 / 2 for the all-pairs check: 12.5
    million at 5 000 points) and the traced peak stays below 64 MiB (2.7 and 10.9 MiB
    measured; the all-pairs check took 1 GB); a crossing,
    also through a long spike edge, is the first one a brute-force search finds (same
    message)."""
    for n in (5000, 20000):
        p = _star(n)
        i, j = _candidate_pairs(p, np.roll(p, -1, axis=0))
        assert len(i) <= n, (n, len(i))
        got, peak = _traced_peak(lambda: polygon_problem(p.tolist()))
        assert got is None
        assert peak < 64 * 2**20, (n, peak)
    spiked = np.vstack([p[:2500], [[60.0, 60.0]], p[2500:]])
    spiked[10] = [59.0, 58.0]
    msg = polygon_problem(spiked.tolist())
    assert msg is not None and "is self-intersecting" in msg
    rng = np.random.default_rng(1)
    for _ in range(200):
        small = rng.integers(0, 5, (int(rng.integers(4, 9)), 2)).astype(float)
        msg = polygon_problem(small.tolist())
        if msg and "self-intersecting" in msg:
            closed = len(small) > 3 and np.array_equal(small[0], small[-1])
            i, j = _first_crossing_brute_force(small[:-1] if closed else small)
            assert f"edge {i + 1} (from point {i + 1}) crosses or touches edge {j + 1}" in msg


def test_huge_polygon_and_huge_scene_file_are_refused_at_once(tmp_path, monkeypatch):
    """Refused from their sizes: the polygon before its shape is checked, the file before
    it is read (both checks made to fail if reached)."""
    import fem_rmpm.scene.schema as schema

    def reached(*args, **kwargs):
        raise AssertionError("the work the size check guards was started")
    data = {"grid": {"origin": [0.0, 0.0], "size": [40.0, 40.0], "cell": 1.0},
            "soil": [{"name": "s", "polygon": _star(100_001).tolist(), "unit_weight": 20.0,
                      "youngs_modulus": 1e4, "poisson_ratio": 0.3, "model": "linear_elastic"}]}
    monkeypatch.setattr(schema, "polygon_problem", reached)
    with pytest.raises(SceneError, match="100001 points; allowed: at most 100000"):
        scene_from_dict(data, "huge")
    big = tmp_path / "big.toml"
    with open(big, "w") as fh:
        fh.write("# " + "x" * (17 * 2**20) + "\n")
    monkeypatch.setattr(Path, "read_text", reached)
    with pytest.raises(SceneError, match="MiB; allowed"):
        load_scene(big)


def test_malformed_scheduler_address_is_refused_before_connecting(capsys, tmp_path,
                                                                  monkeypatch):
    """Refused from the address's form, without trying to connect (the connect timeout is
    30 s; a connection attempt is made to fail here)."""
    import fem_rmpm.campaign.cluster as cluster

    def no_connect(*args, **kwargs):
        raise AssertionError("a connection was attempted")
    monkeypatch.setattr(cluster, "Client", no_connect)
    out = tmp_path / "mc"
    _cli(capsys, ["mc", str(DATA / "mc_tiny.toml"), "-n", "2", "--scheduler", "not a url",
                  "--out", str(out)], 2, "--scheduler 'not a url'", "host:port")
    assert not out.exists()


# ----------------------------------------------------------------- 4. signals

def _start(args: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen(COMMAND + args, cwd=cwd, env={**os.environ, "PYTHONPATH": str(ROOT)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)


def _wait_for(test, limit: float = 240.0) -> None:
    t0 = time.monotonic()
    while not test():
        assert time.monotonic() - t0 < limit, "the command did not get going"
        time.sleep(0.1)


def _status(out: Path) -> str | None:
    try:
        return json.loads((out / "summary.json").read_text()).get("status")
    except (OSError, ValueError):
        return None


def _lock_free(out: Path) -> bool:
    with open(out / ".campaign.lock") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False
        fcntl.flock(fh, fcntl.LOCK_UN)
    return True


def _stopped(p: subprocess.Popen, sig: signal.Signals) -> str:
    os.killpg(p.pid, sig)               # the whole group, as a terminal's Ctrl-C
    _, err = p.communicate(timeout=120)
    assert p.returncode == 128 + sig, err
    return _one_line(err, "interrupted")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_during_run_marks_the_summary_interrupted(tmp_path, sig):
    out = tmp_path / "run"
    p = _start(["run", str(DATA / "mc_slow.toml"), "--out", str(out), "--quiet",
                "--set", "solver.t_end=400"], tmp_path)
    _wait_for(lambda: _status(out) == "running")
    time.sleep(0.5)
    _stopped(p, sig)
    assert _status(out) == "interrupted"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stop_reason"].startswith("interrupted")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_during_mc_keeps_records_and_frees_the_lock(tmp_path, sig):
    out = tmp_path / "mc"
    p = _start(["mc", str(DATA / "mc_slow.toml"), "-n", "400", "--workers", "2", "--out",
                str(out), "--quiet"], tmp_path)
    _wait_for(lambda: len(list((out / "records").glob("realization_*.json"))) >= 2
              if (out / "records").exists() else False)
    _stopped(p, sig)
    records = list((out / "records").glob("realization_*.json"))
    assert len(records) >= 2
    assert all(json.loads(r.read_text())["status"] in ("ok", "failed") for r in records)
    assert _lock_free(out)
    assert not (out / "summary.json").exists()      # the campaign did not end


def test_entry_restores_what_it_changed():
    """The console entry and the command line leave the signal handlers as they found
    them when no signal came (a driver script calling ``main`` keeps its own)."""
    before = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM))
    with pytest.raises(SystemExit):
        main(["--help"])
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


def test_interrupt_inside_a_native_callback_is_raised_after_it(monkeypatch):
    """A signal that arrives while numba loads a kernel (inside llvmlite's ctypes callback,
    where ctypes would print the exception's traceback and drop it) is raised a moment
    later, once Python code outside the callback runs."""
    from types import SimpleNamespace

    from fem_rmpm.runtime import signals
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGALRM)}
    monkeypatch.setattr(logging.getLogger("distributed"), "level",
                        logging.getLogger("distributed").level)
    callback = SimpleNamespace(f_code=SimpleNamespace(
        co_filename="/venv/site-packages/llvmlite/binding/executionengine.py"), f_back=None)
    try:
        with pytest.raises(signals.Terminated):
            with signals.graceful_interrupts():
                signals._on_signal(signal.SIGTERM, callback)      # returns: deferred
                assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
                time.sleep(2.0)                                   # the retry raises here
        assert not signals._pending
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        for s, handler in saved.items():
            signal.signal(s, handler)
