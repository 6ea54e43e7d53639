"""Kernel timers along case (i): the three compiled stages of the explicit step, on one
and on two threads, from the states of case (i) at given times.

For each ``--times`` value the reference slope is run to that time, its points sorted by
host cell as the run keeps them (``--unsorted``: in their original order), then 300 further steps
(dt = 0.9 x the smallest step so far, no damping) are timed stage by stage: map to nodes;
solve on the mesh + map back, move, re-map; nodal velocities + the stress pass.  Prints the
median ns per point of each stage and their sum, and the ratio of one thread to two::

    python validation/stages_case_i.py                 # t = 2, 8, 25 s, ~3 min
    python validation/stages_case_i.py --times 8      # one state

The states on one and two threads are the same (the runs are bitwise equal).  The machine
must be idle: the stages of a two-thread step wait for the slower thread.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fem_rmpm import api  # noqa: E402
from fem_rmpm.discretise.point_order import plane_point_order  # noqa: E402
from fem_rmpm.scene import load_scene, with_values  # noqa: E402
from fem_rmpm.schemes.explicit import kernels as K
from fem_rmpm.schemes.explicit.loop import Workspace, explicit_step, run_explicit  # noqa: E402

STAGES = ("map to nodes", "solve + map back", "nodal velocities + stress pass")


def stage_times(t_state: float, threads: int, steps: int = 300, sort: bool = True) -> dict:
    """Median ns per point of each stage over ``steps`` steps from the state at
    ``t_state`` seconds of case (i); ``sort``: the points sorted by host cell first, as
    the run keeps them (else in their original order, as the run returns them)."""
    scene = with_values(load_scene(ROOT / "meshes" / "slope_reference.toml"),
                        {"solver.t_end": t_state, "solver.threads": threads})
    grid, pts = api.prepare(scene)
    rec = run_explicit(scene, grid, pts)
    if sort:                        # as the run holds them (it restores the order at its end)
        plane_point_order(grid, pts).sort()
    sv = scene.solver
    w = Workspace.for_grid(grid, pts.n)
    g = np.array(scene.gravity_vector)
    explicit_step(grid, pts, 1e-4, g, 0.0, sv.flip, sv.shape, False, "numba", w,
                  threads=threads)
    (P, M), N, S, call = w.bind(grid, pts), w.nodes, w.scratch, w.call
    dt = 0.9 * rec.dt_min
    T = {k: [] for k in STAGES}
    clk = time.perf_counter
    for _ in range(steps):
        o = K.StepOptions(dt, float(g[0]), float(g[1]), 0.0, sv.flip, False, False, False,
                          threads, w.model, w.block)
        t = [clk()]
        if threads > 1:
            top = K.top_of(N)
            call(K.map_to_nodes_parallel, o.gimp, P, M, top, N.half, S, o)
            t.append(clk())
            call(K.solve_and_move_parallel, o.gimp, P, M, top, N.half, S, o)
        else:
            call(K.map_to_nodes, o.gimp, P, M, N, S, o)
            t.append(clk())
            call(K.solve_and_move, o.gimp, P, M, N, S, o)
        t.append(clk())
        K.update_stress(P, M, N, S, o, call)
        t.append(clk())
        for k, a, b in zip(STAGES, t[:-1], t[1:]):
            T[k].append((b - a) / pts.n * 1e9)
    return {k: float(np.median(v)) for k, v in T.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--times", type=float, nargs="+", default=[2.0, 8.0, 25.0])
    ap.add_argument("--unsorted", action="store_true",
                    help="the points in their original (seeding) order, not the run's "
                         "host-cell order")
    args = ap.parse_args()
    for t_state in args.times:
        res = {th: stage_times(t_state, th, sort=not args.unsorted) for th in (1, 2)}
        for th, r in res.items():
            print(f"t = {t_state:g} s, {th} thread(s): "
                  + "  ".join(f"{k} {v:.2f}" for k, v in r.items())
                  + f"  | sum {sum(r.values()):.2f} ns per point", flush=True)
        print(f"t = {t_state:g} s: one / two threads = "
              f"{sum(res[1].values()) / sum(res[2].values()):.2f}x", flush=True)


if __name__ == "__main__":
    main()
