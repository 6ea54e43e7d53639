"""Measures of a realization and points leaving the grid."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.cli import main
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.measures.blocks import intact_blocks
from fem_rmpm.measures.deposit import compute_measures
from fem_rmpm.measures.geometry import surface_profile
from fem_rmpm.scene import load_scene, with_values


def _slope(meshes):
    scene = load_scene(meshes / "slope_elastic.toml")
    grid = make_grid(scene)
    return scene, grid, seed_particles(scene, grid)


def test_measures_of_a_prescribed_slide(meshes):
    """Move a known block of points: the sliding area is its initial volume, the run-out the
    travel of the toe front in the true horizontal, the retrogression the distance from the
    crest (x = 56 m, y = 5 m in the grid frame) back to the block's upslope end."""
    scene, grid, pts = _slope(meshes)
    a = math.radians(20.0)
    block = pts.x0[:, 0] > 40.0                     # everything down-slope of x = 40 m
    shift = 3.0                                     # m along the bedrock
    pts.x[block, 0] += shift
    m = compute_measures(pts, 20.0, 0.5, grid.cell, time_to_rest=12.5)
    assert m["failed"]
    assert math.isclose(m["sliding_area"], pts.volume0[block].sum(), rel_tol=1e-12)
    X0 = pts.x0[:, 0] * math.cos(a) + pts.x0[:, 1] * math.sin(a)
    X = pts.x[:, 0] * math.cos(a) + pts.x[:, 1] * math.sin(a)
    assert math.isclose(m["runout_distance"], X.max() - X0.max(), rel_tol=1e-12)
    assert math.isclose(m["runout_distance"], shift * math.cos(a), rel_tol=1e-9)
    crest = pts.x0[(pts.x0[:, 1] > 4.75)][:, 0].max()            # top layer, most down-slope
    y_crest = pts.x0[(pts.x0[:, 1] > 4.75) & (pts.x0[:, 0] == crest), 1][0]
    x_back = pts.x0[block, 0].min()
    y_back = pts.x0[block & (pts.x0[:, 0] == x_back), 1]
    expected = (crest * math.cos(a) + y_crest * math.sin(a)) - \
        (x_back * math.cos(a) + y_back.min() * math.sin(a))
    assert math.isclose(m["retrogression_distance"], expected, rel_tol=1e-9)
    assert m["time_to_rest"] == 12.5


def test_no_failure_below_threshold(meshes):
    """Displacements below failure_displacement: not failed, zero area and retrogression."""
    scene, grid, pts = _slope(meshes)
    pts.x[:, 0] += 0.4
    m = compute_measures(pts, 20.0, 0.5, grid.cell, None)
    assert not m["failed"] and m["sliding_area"] == 0.0 and m["retrogression_distance"] == 0.0


def test_a_few_points_moved_are_not_a_failure_and_the_failure_area_decides(meshes):
    """Two points inside the layer moved 0.6 m (more than failure_displacement, 0.5 m;
    0.03 m2/m on the 0.25 m grid): sliding area 2 x their volume, but not a failure at the
    default failure area (1 m2/m) -- debris; with ``failure_area = 0`` any sliding point
    fails.  A block of 1.5 m2/m fails at 1 m2/m and not at 2 m2/m (the rule is
    ``sliding_area >= failure_area``, exact areas summed by hand here)."""
    scene, grid, pts = _slope(meshes)
    near = np.argsort(np.hypot(pts.x0[:, 0] - 30.0, pts.x0[:, 1] - 2.5), kind="stable")
    debris = near[:2]                       # inside the layer: they stay in the deposit
    pts.x[debris, 0] += 0.6
    area = float(pts.volume0[debris].sum())
    kw = dict(frame_angle_deg=20.0, threshold=0.5, cell=grid.cell, time_to_rest=None)
    m = compute_measures(pts, **kw, failure_area=1.0)
    assert m["sliding_area"] == pytest.approx(area, rel=1e-12) and 0 < area < 0.1
    assert not m["failed"]
    assert compute_measures(pts, **kw, failure_area=0.0)["failed"]
    block = near[:int(round(1.5 / pts.volume0[0]))]
    pts.x[block, 0] += 0.6
    area = float(pts.volume0[block].sum())
    assert 1.0 <= area < 2.0
    assert compute_measures(pts, **kw, failure_area=1.0)["failed"]
    assert not compute_measures(pts, **kw, failure_area=2.0)["failed"]


def test_surface_profile_is_top_of_each_bin():
    """Profile = max y per x bin."""
    X = np.array([[0.1, 1.0], [0.2, 3.0], [0.6, 2.0], [1.4, 0.5]])
    assert surface_profile(X, 0.5) == [(0.25, 3.0), (0.75, 2.0), (1.25, 0.5)]


def _falling_block(meshes, policy):
    """A block thrown off the free right edge of a small grid."""
    scene = load_scene(meshes / "column.toml")
    return with_values(scene, {
        "grid.size": [3.0, 2.0], "grid.cell": [0.25, 0.25], "boundary.right": "free",
        "boundary.bottom": "roller", "scene.frame_angle_deg": 60.0,
        "soil.polygon": [[0.5, 0.0], [1.5, 0.0], [1.5, 1.0], [0.5, 1.0]],
        "solver.gravity_phase": "dynamic", "solver.gravity_ramp_time": 0.0,
        "solver.damping": 0.0, "solver.t_end": 0.7, "solver.edge_policy": policy,
        "solver.output_interval": 0.25})


def test_points_leaving_the_grid_are_frozen_and_reported(meshes, tmp_path):
    """Policy 'freeze': points that leave through a free edge are kept (inactive, where they
    left), counted and named in summary.json; none is lost and nothing is NaN."""
    res = api.run(_falling_block(meshes, "freeze"), out=tmp_path / "o")
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    frozen = s["frozen_points"]
    assert frozen["count"] > 0 and frozen["count"] == len(frozen["indices"])
    assert sorted(frozen["indices"]) == sorted(np.nonzero(~res.particles.active)[0].tolist())
    assert res.particles.n == len(res.particles.mass)                 # nobody removed
    assert np.all(np.isfinite(res.particles.x))


def test_points_leaving_the_grid_stop_the_run_if_asked(meshes, tmp_path, capsys):
    """Policy 'stop': a clear error naming the point and what to change; exit code 3."""
    scene_file = tmp_path / "block.toml"
    from fem_rmpm.scene import scene_to_dict
    scene = _falling_block(meshes, "stop")
    d = scene_to_dict(scene)
    lines = []
    for sec, body in d.items():
        items = body if isinstance(body, list) else [body]
        for it in items:
            lines.append(f"[[{sec}]]" if isinstance(body, list) else f"[{sec}]")
            for k, v in it.items():
                lines.append(f"{k} = {json.dumps(v) if not isinstance(v, bool) else str(v).lower()}")
    scene_file.write_text("\n".join(lines).replace('"inf"', "inf"))
    code = main(["run", str(scene_file), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 3
    assert "left the grid" in err and "edge_policy" in err


def test_reference_slope_case_i_fails_and_comes_to_rest(meshes, tmp_path):
    """The explicit scheme (~30 s on one core): the homogeneous reference slope
    (infinite-slope factor of safety c/(gamma H sin b cos b) = 0.62 at peak, 0.12 at
    residual strength; Wang, Vardon & Hicks 2017) fails under its own weight, runs out and comes to
    rest inside the valley; summary.json holds every measure, nothing is NaN and no point
    leaves the grid unreported.  Bounds from the geometry (true frame; meshes/
    slope_reference.toml): at residual strength the whole layer must flow, so the slide
    reaches back to the up-slope edge (retrogression >= 98 % of the crest's X, 54.33 m;
    achieves 53.89 m) and nearly every point moves (sliding area > 99 % of 285.3 m2;
    achieves 284.84); the 285 m2 cannot stand on the 50 m valley floor at c_r = 4 kPa
    (a heap that thick needs c ~ gamma H / 4 = 28 kPa), so the front passes the end of the
    floor (run-out > 50.2 m from the toe at X = 57.10 m) and stops on the valley side below
    the grid edge (run-out < 70.3 m; achieves 63.95 m)."""
    res = api.run(load_scene(meshes / "slope_reference.toml"), out=tmp_path / "case_i")
    s = json.loads((tmp_path / "case_i" / "summary.json").read_text())
    m = s["measures"]
    assert s["stop_reason"] == "at rest" and s["status"] == "ok"
    assert m["failed"] and m["time_to_rest"] == s["simulated_time"]
    a = math.radians(20.0)
    assert m["retrogression_distance"] >= 0.98 * (56.0 * math.cos(a) + 5.0 * math.sin(a))
    assert m["sliding_area"] > 0.99 * res.particles.volume0.sum()
    assert 50.2 < m["runout_distance"] < 70.3
    assert s["frozen_points"]["count"] == int((~res.particles.active).sum())
    inside = (res.particles.x >= res.grid.origin) & (res.particles.x <= res.grid.upper)
    assert inside[res.particles.active].all()
    assert np.all(np.isfinite(res.particles.stress)) and np.all(np.isfinite(res.particles.x))
    assert (tmp_path / "case_i" / "plastic_shear_strain.png").exists()


def test_slip_surface_height_and_intact_blocks_of_prescribed_slides(meshes):
    """A slide of everything above y = 1.5 m has its failure surface at the highest point
    that stayed (the Gauss point just below 1.5 m); two separate, unsheared moved blocks
    count as two intact blocks, and the same blocks fully sheared count as none."""
    from fem_rmpm.measures.geometry import slip_surface_height
    scene, grid, pts = _slope(meshes)
    upper = (pts.x0[:, 1] > 1.5) & (pts.x0[:, 0] > 10) & (pts.x0[:, 0] < 50)
    pts.x[upper, 0] += 2.0
    sliding = np.linalg.norm(pts.x - pts.x0, axis=1) > 0.5
    expected = pts.x0[(pts.x0[:, 1] < 1.5), 1].max()
    assert math.isclose(slip_surface_height(pts.x0, sliding, 0.25), expected, rel_tol=1e-12)
    x = pts.x0.copy()
    a = (pts.x0[:, 0] > 10) & (pts.x0[:, 0] < 20)
    b = (pts.x0[:, 0] > 30) & (pts.x0[:, 0] < 40)
    x[a, 0] += 1.0
    x[b, 0] += 1.0
    gam = np.zeros(pts.n)
    assert intact_blocks(x, pts.x0, gam, 0.5, grid.origin, grid.cell, grid.shape) == 2
    assert intact_blocks(x, pts.x0, gam + 1.0, 0.5, grid.origin, grid.cell, grid.shape) == 0


def test_run_ends_cleanly_when_every_point_has_left_the_grid(meshes, tmp_path):
    """With policy 'freeze', a block that slides wholly off a free edge ends the run with
    stop reason 'all points left the grid'; every point is frozen and reported, none lost."""
    scene = with_values(_falling_block(meshes, "freeze"), {"solver.t_end": 3.0})
    res = api.run(scene, out=tmp_path / "gone")
    s = json.loads((tmp_path / "gone" / "summary.json").read_text())
    assert s["stop_reason"] == "all points left the grid" and s["status"] == "ok"
    assert s["frozen_points"]["count"] == res.particles.n
    assert s["simulated_time"] < 3.0


def _with_copies(pts, idx):
    """``pts`` with copies of the points ``idx`` appended (all per-point arrays)."""
    import dataclasses
    n = pts.n
    kw = {}
    for f in dataclasses.fields(pts):
        v = getattr(pts, f.name)
        if f.name == "soil":
            kw[f.name] = v.take(np.r_[np.arange(n), idx])
        elif isinstance(v, np.ndarray) and len(v) == n:
            kw[f.name] = np.concatenate([v, v[idx]])
        else:
            kw[f.name] = v
    return type(pts)(**kw)


def test_runout_ignores_frozen_and_stray_points(meshes):
    """A slid deposit, then one point frozen at the top edge of the
    grid far beyond it and four stray points 3 m beyond its front (one or two cells apart,
    as debris climbing the valley side).  The run-out moves by no more than one cell
    (achieves 0 m) and the five points are counted as excluded, with their volume."""
    scene, grid, pts = _slope(meshes)
    a = math.radians(20.0)
    pts.x[:, 0] += 4.0 * (pts.x0[:, 0] > 20.0)             # a slide of the lower 40 m by 4 m
    clean = compute_measures(pts, 20.0, 0.5, grid.cell, None, grid=grid)
    assert clean["excluded_stray_points"] == 0 and clean["excluded_frozen_points"] == 0
    front = int(np.argmax(pts.x[:, 0] * math.cos(a) + pts.x[:, 1] * math.sin(a)))
    debris = _with_copies(pts, np.full(5, front))
    n = pts.n
    debris.x[n] = [grid.upper[0] - 1e-9, grid.upper[1]]     # frozen at the top edge
    debris.active[n] = False
    for k in range(4):                                      # 3 m beyond, 0.3-0.6 m apart
        debris.x[n + 1 + k] = pts.x[front] + [3.0 + 0.3 * k + 0.3 * (k > 1), 0.2 * k]
    m = compute_measures(debris, 20.0, 0.5, grid.cell, None, grid=grid)
    assert abs(m["runout_distance"] - clean["runout_distance"]) <= float(grid.cell[0])
    assert m["excluded_frozen_points"] == 1
    assert m["excluded_frozen_volume"] == float(pts.volume0[front])
    assert m["excluded_stray_points"] == 4
    assert m["excluded_stray_volume"] == pytest.approx(4 * pts.volume0[front], rel=1e-12)
    assert m["sliding_area"] == clean["sliding_area"]
    # the old definition (max X over every point) would have moved by > 2.8 m
    X_all = debris.x[:, 0] * math.cos(a) + debris.x[:, 1] * math.sin(a)
    X0 = pts.x0[:, 0] * math.cos(a) + pts.x0[:, 1] * math.sin(a)
    assert X_all.max() - X0.max() > clean["runout_distance"] + 2.8


def test_a_film_touching_the_deposit_counts(meshes):
    """A continuous film one point thick (run-up) touching the deposit is part of it."""
    scene, grid, pts = _slope(meshes)
    clean = compute_measures(pts, 20.0, 0.5, grid.cell, None, grid=grid)
    a = math.radians(20.0)
    front = int(np.argmax(pts.x[:, 0] * math.cos(a) + pts.x[:, 1] * math.sin(a)))
    film = _with_copies(pts, np.full(8, front))
    for k in range(8):                                      # 0.2 m apart: cells touch
        film.x[pts.n + k] = pts.x[front] + [0.2 * (k + 1), 0.0]
    m = compute_measures(film, 20.0, 0.5, grid.cell, None, grid=grid)
    assert m["excluded_stray_points"] == 0
    assert m["runout_distance"] == pytest.approx(clean["runout_distance"] + 1.6 * math.cos(a),
                                                  abs=1e-9)


def test_summary_reports_excluded_points(meshes, tmp_path):
    """summary.json carries the excluded points per reason; frozen ones equal the run's
    frozen points."""
    api.run(_falling_block(meshes, "freeze"), out=tmp_path / "o")
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    ex = s["excluded_points"]
    assert ex["frozen"]["points"] == s["frozen_points"]["count"] > 0
    assert s["measures"]["excluded_frozen_points"] == ex["frozen"]["points"]
    assert ex["frozen"]["volume"] > 0 and ex["stray"]["points"] >= 0


def test_least_block_area_reaches_the_block_count_and_the_record(meshes):
    """``compute_measures(intact_block_area=A)`` counts the blocks of at least A m2 that
    :func:`intact_blocks` finds with ``min_area=A`` on the snapshot, and records A; the
    default is 1 m2.  The slide: the soil down-slope of x = 30 m moved 2 m, sheared in 1 m bands every 3 m,
    leaving 10 blocks of at least 1 m2 and 9 of at least 4 m2."""
    scene, grid, pts = _slope(meshes)
    pts.x[:, 0] += 2.0 * (pts.x0[:, 0] > 30.0)
    gamma = np.where((np.floor(pts.x0[:, 0]) % 3) == 0, 0.5, 0.0)
    snaps = [(3.0, pts.x.copy(), gamma)]
    counts = {}
    for area in (None, 4.0):
        kw = {} if area is None else {"intact_block_area": area}
        m = compute_measures(pts, 20.0, 0.5, grid.cell, None, snapshots=snaps, grid=grid, **kw)
        a = 1.0 if area is None else area
        assert m["intact_blocks"] == intact_blocks(pts.x, pts.x0, gamma, 0.5, grid.origin,
                                                   grid.cell, grid.shape, min_area=a)
        assert m["intact_block_area"] == a
        counts[a] = m["intact_blocks"]
    assert counts == {1.0: 10, 4.0: 9}
