"""Robustness, part C: the soil-overlap check at the largest allowed polygons, consistent
outputs of an interrupted ``field``, and an interrupted campaign's kept run directory.

Overlap references are exact by construction (unit squares and triangles whose common
area is known by hand: a shared edge, a shared corner, a T-junction, a crossing, nesting,
identity); the large cases are two soils meeting along one wavy boundary of 20 000
points, touching (no common area) or shifted 1 cm into each other (a strip of area).
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm.cli import main
from fem_rmpm.io import field_output
from fem_rmpm.scene import overlap
from fem_rmpm.scene.overlap import overlap_point

TINY = Path(__file__).resolve().parent / "data" / "mc_tiny.toml"

SQUARE = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]


def _inside(poly, x) -> bool:
    """Crossing-number test of a point off the boundary (independent of the module)."""
    p = np.asarray(poly, dtype=float)
    a, b = p, np.roll(p, -1, axis=0)
    span = (a[:, 1] > x[1]) != (b[:, 1] > x[1])
    xs = a[span, 0] + (x[1] - a[span, 1]) * (b[span, 0] - a[span, 0]) / (b[span, 1] - a[span, 1])
    return bool(np.count_nonzero(xs > x[0]) % 2)


def _inside_many(poly, pts: np.ndarray) -> np.ndarray:
    """:func:`_inside` for many points at once."""
    p = np.asarray(poly, dtype=float)
    a, b = p[None, :, :], np.roll(p, -1, axis=0)[None, :, :]
    x, y = pts[:, None, 0], pts[:, None, 1]
    span = (a[..., 1] > y) != (b[..., 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = a[..., 0] + (y - a[..., 1]) * (b[..., 0] - a[..., 0]) / (b[..., 1] - a[..., 1])
    return np.count_nonzero(span & (xs > x), axis=1) % 2 == 1


@pytest.mark.parametrize("other", [
    [[2.0, 0.0], [4.0, 0.0], [4.0, 1.0], [2.0, 1.0]],               # a shared edge
    [[2.0, 1.0], [4.0, 1.0], [4.0, 2.0], [2.0, 2.0]],               # a shared corner
    [[0.5, 1.0], [1.5, 1.0], [1.0, 2.0]],                           # an edge on an edge
    [[1.0, 1.0], [3.0, 2.0], [-1.0, 2.0]],                          # a vertex on an edge
    [[1.0, -1.0], [3.0, 1.0], [3.0, -1.0]],                         # an edge through a corner
    [[2.0, -1.0], [3.0, -1.0], [3.0, 2.0], [2.0, 2.0]],             # an edge longer than ours
    [[5.0, 5.0], [6.0, 5.0], [6.0, 6.0]],                           # apart
    [[0.0, 1.0], [1.0, 1.0], [2.0, 1.0], [2.0, 3.0], [0.0, 3.0]],   # an extra point on the edge
])
def test_touching_or_apart_is_no_overlap(other):
    assert overlap_point(SQUARE, other) is None
    assert overlap_point(other, SQUARE) is None
    assert overlap_point(SQUARE[::-1], other[::-1]) is None      # clockwise the same


@pytest.mark.parametrize("other", [
    [[1.5, 0.5], [3.0, 0.5], [3.0, 1.5], [1.5, 1.5]],               # edges crossing
    SQUARE,                                                         # the same square
    [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]],   # the same, a point more
    [[0.5, 0.25], [1.0, 0.25], [1.0, 0.75]],                        # nested, apart
    [[-1.0, -1.0], [3.0, -1.0], [3.0, 2.0], [-1.0, 2.0]],           # containing
    [[0.0, 0.0], [1.0, 0.5], [0.0, 1.0]],                           # inside, on two edges
    [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],               # inside, on three edges
    [[1.0, 0.5], [3.0, 2.0], [-1.0, 2.0]],                          # a vertex poking in
    [[1.0, -1.0], [3.0, 1.0], [1.0, 1.0]],                          # through a corner, in
    [[2.0, 0.0], [3.0, 0.0], [3.0, 1.0], [1.0, 1.0], [1.0, 0.5], [2.0, 0.5]],  # a notch
])
def test_common_area_is_overlap_with_a_point_inside_both(other):
    for p, q in ((SQUARE, other), (other, SQUARE), (SQUARE[::-1], other)):
        at = overlap_point(p, q)
        assert at is not None
        assert _inside(SQUARE, at) and _inside(other, at), at


def _wavy_pair(n: int, shift: float):
    """Two soils (lower, upper) meeting along one wavy line of ``n`` points; the upper one
    moved down by ``shift`` (m)."""
    x = np.linspace(0.0, 100.0, n)
    y = 5.0 + np.sin(0.7 * x) + 0.3 * np.sin(13.1 * x)
    line = np.c_[x, y]
    lower = np.r_[[[0.0, 0.0], [100.0, 0.0]], line[::-1]]
    upper = np.r_[line - [0.0, shift], [[100.0, 20.0], [0.0, 20.0]]]
    return lower, upper


def test_large_touching_soils_are_decided_without_quadratic_work():
    """20 000 points along a shared boundary: no overlap when they touch, a point of the
    1 cm strip when shifted (a quadratic check took minutes at this size)."""
    lower, upper = _wavy_pair(20_000, 0.0)
    assert overlap_point(lower, upper) is None
    lower, upper = _wavy_pair(20_000, 0.01)
    at = overlap_point(lower, upper)
    assert at is not None and _inside(lower, at) and _inside(upper, at), at


@pytest.mark.parametrize("all_pairs", [4096, 0], ids=["every-pair", "bucketed"])
def test_random_polygons_agree_with_a_sampled_area(monkeypatch, all_pairs):
    """Random star-shaped polygons (some snapped to a 0.5 m lattice, so they share points
    and edges): where the check says "overlap", its point is inside both; where it says
    "none", none of 4 000 sample points lies strictly inside both (N = 300 pairs); with
    every pair of edges compared and with the edges bucketed (as for large polygons)."""
    monkeypatch.setattr(overlap, "ALL_PAIRS", all_pairs)
    rng = np.random.default_rng(7)
    samples = rng.uniform(-2.5, 6.5, size=(4000, 2))

    def star(snap):
        ang = np.sort(rng.uniform(0, 2 * np.pi, rng.integers(3, 9)))
        r = rng.uniform(0.5, 2.0, len(ang))
        p = rng.integers(0, 4, 2) + np.c_[r * np.cos(ang), r * np.sin(ang)]
        return np.round(p * 2) / 2 if snap else p

    from fem_rmpm.scene import polygon_problem
    checked = 0
    for k in range(300):
        p, q = star(k % 2), star(k % 2)
        if polygon_problem(p) or polygon_problem(q):
            continue
        checked += 1
        at = overlap_point(p, q)
        if at is not None:
            assert _inside(p, at) and _inside(q, at), (p, q, at)
        else:
            both = samples[_inside_many(p, samples) & _inside_many(q, samples)]
            assert not len(both), (p.tolist(), q.tolist(), both[:3])
    assert checked > 150


# ------------------------------------------------------------------ an interrupted field
@pytest.fixture
def handlers_restored():
    """The test process's SIGINT / SIGTERM handlers as before (an interrupt leaves both
    ignored, as the command's clean-up needs)."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for s, handler in saved.items():
        signal.signal(s, handler)


def _field_files(out):
    return sorted(p.name for p in out.iterdir()) if out.exists() else []


@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_field_stopped_after_its_vtu_leaves_no_partial_set(tmp_path, capsys, monkeypatch,
                                                           handlers_restored, signum, code):
    """A real SIGTERM / SIGINT while the picture is drawn (``field.vtu`` already written):
    exit 143 / 130 with one line, and no ``field.vtu`` or ``field.png`` without
    ``field.json`` (they used to stay behind without it); no staging directory left."""
    def stopped(*args, **kwargs):
        os.kill(os.getpid(), signum)
        time.sleep(5)                               # the handler raises before this ends
    monkeypatch.setattr(field_output, "plot_realization", stopped)
    out = tmp_path / "field"
    assert main(["field", str(TINY), "--seed", "1", "--out", str(out)]) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "interrupted" in err[0], err
    assert _field_files(out) == []


def test_an_error_mid_field_keeps_the_previous_set(tmp_path, capsys, monkeypatch):
    """``--force`` over a finished field: an error part-way (after the new ``field.vtu``)
    leaves the previous three files exactly as they were."""
    out = tmp_path / "field"
    assert main(["field", str(TINY), "--seed", "1", "--out", str(out)]) == 0
    before = {n: (out / n).read_bytes() for n in _field_files(out)}
    assert sorted(before) == ["field.json", "field.png", "field.vtu"]

    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(field_output, "plot_realization", broken)
    with pytest.raises(OSError):
        main(["field", str(TINY), "--seed", "2", "--out", str(out), "--force"])
    assert {n: (out / n).read_bytes() for n in _field_files(out)} == before


# ------------------------------------------------------------------ a worker killed mid-campaign
_WORKER_SCRIPT = """
import json, os, sys, time, dask
from pathlib import Path
if __name__ == "__main__":
    dask.config.set({"distributed.scheduler.allowed-failures": 0})   # no second try
    from fem_rmpm.campaign import start_local_cluster
    from fem_rmpm.campaign.task import run_realization
    from fem_rmpm.scene import load_scene, with_values
    scene = with_values(load_scene(sys.argv[1]), {"solver.t_end": float(sys.argv[4]), "solver.threads": 1})
    summary = Path(sys.argv[2]) / "summary.json"
    client, cluster = start_local_cluster(1)
    future = client.submit(run_realization, {"case": "scene", "index": 0, "seed": 3,
                           "scene": scene, "vtk_dir": sys.argv[2], "vtk_rel": "vtk"})
    print(*client.run(os.getpid).values(), flush=True)
    if sys.argv[3] == "close":             # as a campaign stopped by Ctrl-C closes its cluster
        while not (summary.exists() and '"running"' in summary.read_text()):
            time.sleep(0.05)
        client.close()
        cluster.close(timeout=10)
        sys.exit(0)
    try:
        future.result(timeout=120)
    except Exception as exc:
        print(type(exc).__name__, flush=True)
        # as a campaign goes on after a death: the worker back (its nanny has seen the
        # death) before the cluster closes, which would silence the notice
        client.wait_for_workers(1, timeout=60)
    client.close()
    cluster.close()
"""


def _status(path):
    try:
        return json.loads(path.read_text())["status"]
    except (OSError, ValueError, KeyError):
        return None


def test_a_worker_terminated_mid_realization_marks_its_kept_run_interrupted(tmp_path):
    """SIGTERM to the Dask worker process running a realization that keeps its VTK (a
    batch system's time limit, ``kill``): its ``summary.json`` says ``"interrupted"``, not
    ``"running"`` (the worker still ends by SIGTERM, and the task is lost, as before), and
    the death is one warning line on stderr (it was silenced with Dask's logs)."""
    vtk = tmp_path / "vtk"
    proc = subprocess.Popen([sys.executable, "-c", _WORKER_SCRIPT, str(TINY), str(vtk), "kill", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        pid = int(proc.stdout.readline())
        deadline = time.monotonic() + 120
        while _status(vtk / "summary.json") != "running" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _status(vtk / "summary.json") == "running"
        os.kill(pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    summary = json.loads((vtk / "summary.json").read_text())
    assert summary["status"] == "interrupted", (summary, err[-2000:])
    assert "SIGTERM" in summary["stop_reason"]
    assert "KilledWorker" in out, (out, err[-2000:])
    # the death is told in one line (Dask's own logs stay silenced), without a traceback
    deaths = [line for line in err.splitlines() if "worker process died" in line]
    assert len(deaths) == 1 and "killed by signal 15" in deaths[0], err[-2000:]
    assert "Traceback" not in err, err[-2000:]


# ------------------------------------------------------------------ argument errors
@pytest.mark.parametrize("argv", [["fs", str(TINY)], ["fem", str(TINY), "--out", "o", "--bogus"],
                                  ["runn"], []])
def test_an_argument_error_is_one_line(capsys, argv):
    """A missing or unknown option or command: exit 2 and one line naming it and
    ``--help`` (argparse printed its usage first: several lines)."""
    with pytest.raises(SystemExit) as ei:
        main(argv)
    assert ei.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "error:" in err[0] and "--help" in err[0], err


# ------------------------------------------------------------------ new parents of --out
def test_bad_data_under_new_parents_leaves_none_of_them(tmp_path, capsys, monkeypatch):
    """``field --data nope.csv --out a/b/c`` in an empty folder: exit 2, one line, and
    no ``a/`` or ``a/b/`` left (only ``a/b/c`` was removed)."""
    monkeypatch.chdir(tmp_path)
    assert main(["field", str(TINY), "--data", "nope.csv", "--out", "a/b/c"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_a_cluster_closed_mid_realization_marks_its_kept_run_interrupted(tmp_path):
    """A campaign stopped by Ctrl-C closes its local cluster with a realization still
    running: the nanny kills the busy worker (SIGKILL after its stop timeout, which no
    handler sees), and the worker's closing has marked the kept run ``"interrupted"``."""
    vtk = tmp_path / "vtk"
    # 1e5 s of simulated time is about 1e7 steps (minutes with warm kernels): the run
    # cannot finish by itself within the cluster's 10 s closing timeout (600 s could).
    r = subprocess.run([sys.executable, "-c", _WORKER_SCRIPT, str(TINY), str(vtk), "close", "100000"],
                       capture_output=True, text=True, timeout=300)
    summary = json.loads((vtk / "summary.json").read_text())
    assert summary["status"] == "interrupted", (summary["status"], r.stderr[-2000:])
    assert "closed" in summary["stop_reason"]
    assert "Traceback" not in r.stderr and "died" not in r.stderr, r.stderr[-2000:]
