"""Run directories never claim a success they do not hold.

``fem-rmpm run`` is started as a real process and killed with SIGKILL in the middle of
its output (once its 5th particle file exists), into a fresh directory and into one
holding a finished run (``--force``).  After the kill the directory must never hold a
``summary.json`` saying ``ok``; a finished run's summary lists exactly the files that
exist, and every file of its ``particles.pvd`` exists.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from fem_rmpm.cli import main

ROOT = Path(__file__).resolve().parents[1]
#: The reference slope on 0.5 m cells (4 556 points), a snapshot every 0.1 s: a few
#: seconds of output to kill into.
SLOW = ["--set", "grid.cell=0.5", "--set", "solver.output_interval=0.1",
        "--set", "solver.t_end=20.0", "--quiet"]


def _env():
    return {**os.environ, "PYTHONPATH": str(ROOT)}


def _run_and_kill(out: Path, extra: list[str]) -> int:
    """Start ``run`` into ``out``, SIGKILL it once it has written particles_0005.vtu."""
    t0 = time.time() - 1e-3
    proc = subprocess.Popen([sys.executable, "-m", "fem_rmpm.cli", "run", "--out", str(out),
                             *SLOW, *extra], env=_env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    deadline = time.monotonic() + 600
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            written = (out / "particles_0005.vtu").stat().st_mtime > t0
        except FileNotFoundError:      # not yet, or the earlier run's file being removed
            written = False
        if written:
            proc.send_signal(signal.SIGKILL)
            break
        time.sleep(0.002)
    proc.wait()
    return proc.returncode


def _assert_consistent(out: Path) -> dict | None:
    """A summary that says ok holds every file it lists (and the pvd's files)."""
    path = out / "summary.json"
    if not path.exists():
        return None
    s = json.loads(path.read_text())
    if s["status"] == "ok":
        for name in s["files"]:
            assert (out / name).is_file(), name
        for ds in ET.parse(out / "particles.pvd").getroot().iter("DataSet"):
            assert (out / ds.get("file")).is_file()
    return s


def test_sigkill_into_fresh_directory(tmp_path):
    out = tmp_path / "fresh"
    assert _run_and_kill(out, []) == -signal.SIGKILL
    s = _assert_consistent(out)
    assert s is not None and s["status"] == "running"


def test_sigkill_into_reused_directory_then_refuse_then_force(tmp_path, capsys, meshes):
    out = tmp_path / "reused"
    assert main(["run", str(meshes / "column.toml"), "--out", str(out), "--quiet"]) == 0
    capsys.readouterr()
    first = json.loads((out / "summary.json").read_text())
    assert first["status"] == "ok" and set(first["files"]) <= set(os.listdir(out))
    old_files = set(os.listdir(out))

    assert _run_and_kill(out, ["--force"]) == -signal.SIGKILL
    s = _assert_consistent(out)
    assert s["status"] == "running"
    # the column run wrote particles_0000..N; only the files of the killed run remain
    assert s["scene"]["scene"]["name"] == "slope_reference"

    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    code = main(["run", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--force" in err
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before

    assert main(["run", str(meshes / "column.toml"), "--out", str(out), "--quiet",
                 "--force"]) == 0
    s = _assert_consistent(out)
    assert s["status"] == "ok"
    assert set(os.listdir(out)) == set(s["files"]) | {"summary.json"}
    assert not any(n.startswith(".") for n in os.listdir(out))     # temporaries cleaned
    assert set(os.listdir(out)) == old_files                       # no stale slope files


@pytest.mark.parametrize("kind", ["file", "run"])
def test_out_refused_nothing_changed(tmp_path, capsys, meshes, kind):
    """``--out`` naming a file, or a directory holding a run, is exit 2 on one line."""
    out = tmp_path / "o"
    if kind == "file":
        out.write_text("keep me")
    else:
        out.mkdir()
        (out / "summary.json").write_text('{"status": "ok"}')
    code = main(["run", str(meshes / "column.toml"), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(out) in err
    if kind == "file":
        assert out.read_text() == "keep me"
    else:
        assert os.listdir(out) == ["summary.json"]
