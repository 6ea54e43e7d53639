"""First use: a cold numba cache is detected and announced before the compile."""
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


def test_cold_cache_detected_for_the_threaded_kernels_too(tmp_path):
    """The threaded drivers are cached apart from the serial ones: with an empty cache both
    are cold (a two-thread run compiles its own; before, a warm two-thread install still
    announced a compile at every run because only the serial drivers were checked)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(tmp_path / "nc")}
    out = subprocess.run([sys.executable, "-c", "from fem_rmpm import api; "
                          "print(api.kernels_cold(1), api.kernels_cold(2))"], env=env,
                         capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True"]


def test_notice_asks_about_the_run_s_threads(meshes, monkeypatch):
    """The notice checks the kernels of the thread count the run will use."""
    asked = []
    monkeypatch.setattr(api, "kernels_cold",
                        lambda threads=1, fbar=False: asked.append(threads) or True)
    scene = api.load_scene(meshes / "column.toml")
    one = api.compile_notice(api.with_value(scene, "solver.threads", 1))
    two = api.compile_notice(api.with_value(scene, "solver.threads", 2))
    assert asked == [1, 2, 2, 1]          # the run's drivers, then the other ones
    lo, hi = api.COMPILE_SECONDS
    assert one == (f"compiling kernels (first run only, {lo:.0f}-{hi:.0f} s by the machine; "
                   "cached on disk after)")
    lo2, hi2 = lo + api.COMPILE_SECONDS_THREADED[0], hi + api.COMPILE_SECONDS_THREADED[1]
    assert two.startswith(f"compiling kernels for 2 threads (first run only, {lo2:.0f}-{hi2:.0f} s")


def test_notice_when_only_the_drivers_compile(meshes, monkeypatch):
    """After a two-thread run only the serial drivers are missing: a short compile."""
    monkeypatch.setattr(api, "kernels_cold", lambda threads=1, fbar=False: threads == 1)
    scene = api.load_scene(meshes / "column.toml")
    one = api.compile_notice(api.with_value(scene, "solver.threads", 1))
    lo, hi = api.COMPILE_SECONDS_DRIVERS[0]
    assert f"{lo:.0f}-{hi:.0f} s by the machine" in one
    assert api.compile_notice(api.with_value(scene, "solver.threads", 2)) is None


def test_notice_printed_when_cold(tmp_path, capsys, meshes, monkeypatch):
    monkeypatch.setattr(api, "kernels_cold", lambda threads=1, fbar=False: True)
    assert main(["run", str(meshes / "column.toml"), "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert "compiling kernels" in err and "(first run only, " in err
    assert "estimate: 80 material points" in err


def test_no_notice_when_quiet_or_warm(tmp_path, capsys, meshes, monkeypatch):
    monkeypatch.setattr(api, "kernels_cold", lambda threads=1, fbar=False: False)
    assert main(["run", str(meshes / "column.toml"), "--out", str(tmp_path / "o")]) == 0
    assert "compiling" not in capsys.readouterr().err


def test_notice_and_run_use_one_thread_count(tmp_path, capsys, meshes, monkeypatch):
    """``threads = 0`` (auto) is resolved once per run: the free-core count can change
    between two asks (two threads announced, the run then on one), so the notice and
    the run must not ask apart.  The stub answers 2, then 1 to any later ask."""
    from fem_rmpm.schemes.explicit import threads as explicit_threads
    answers = iter([2, 1, 1, 1])
    asks = []

    def auto_threads():
        asks.append(1)
        return next(answers)

    monkeypatch.setattr(api, "auto_threads", auto_threads)
    monkeypatch.setattr(explicit_threads, "auto_threads", auto_threads)
    monkeypatch.setattr(api, "kernels_cold", lambda threads=1, fbar=False: True)
    scene = api.with_value(api.load_scene(meshes / "column.toml"), "solver.t_end", 0.05)
    res = api.run(scene, out=tmp_path / "o", progress=True, vtk=False, figures=False)
    assert "compiling kernels for 2 threads" in capsys.readouterr().err
    assert len(asks) == 1 and res.record.solver["threads"] == 2
    assert res.summary["scene"]["solver"]["threads"] == 0      # the scene as given: auto


def test_two_threads_with_f_bar_ask_about_the_driver_they_compile():
    """Two threads without F-bar run the one-region driver; with F-bar (and on three or
    more threads) the driver with a region per stage: the notice checks the cache of the
    one the run will compile."""
    assert api._always_compiled(1, False) is api._ALWAYS_COMPILED
    assert api._always_compiled(2, False) is api._ALWAYS_COMPILED_PAIR
    assert api._always_compiled(2, True) is api._ALWAYS_COMPILED_THREADED
    assert api._always_compiled(3, False) is api._ALWAYS_COMPILED_THREADED
