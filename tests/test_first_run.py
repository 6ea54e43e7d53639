"""First use: a cold numba cache is detected and announced before the compile (issue 12)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from fem_rmpm import api
from fem_rmpm.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_cold_cache_detected(tmp_path):
    """With an empty NUMBA_CACHE_DIR nothing is compiled yet: cold (import only, no
    compile)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(tmp_path / "nc")}
    out = subprocess.run([sys.executable, "-c", "from fem_rmpm import api; "
                          "print(api.kernels_cold())"], env=env, capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == "True"


def test_notice_printed_when_cold(tmp_path, capsys, meshes, monkeypatch):
    monkeypatch.setattr(api, "kernels_cold", lambda: True)
    assert main(["run", str(meshes / "column.toml"), "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "compiling kernels (first run only, about 45 s, the threaded ones about 15 s more" in err
    assert "estimate: 80 material points" in err


def test_no_notice_when_quiet_or_warm(tmp_path, capsys, meshes, monkeypatch):
    monkeypatch.setattr(api, "kernels_cold", lambda: False)
    assert main(["run", str(meshes / "column.toml"), "--out", str(tmp_path / "o")]) == 0
    assert "compiling" not in capsys.readouterr().err
