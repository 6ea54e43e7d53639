"""Benchmark of the explicit step: MPUPS, ns per particle-step, per-stage breakdown,
memory per realization, compile cost, and the performance targets.  Plain script:

    nice python validation/bench_explicit.py              # all sizes, ~10 min on 2 cores
    python validation/bench_explicit.py --quick           # reference slope only
    nice python validation/bench_explicit.py --scaling-only  # 1e4 / 1e5 / 1e6 whole runs

Cases: the reference slope ``meshes/slope_elastic.toml`` (0.25 m cells, 18 260
points, the headline) and variants with finer or coarser cells (1/3, 0.1, 1/30 m:
~1e4, ~1e5, ~1e6 points), built with :func:`fem_rmpm.scene.with_value`.

What is timed: ``run_explicit`` itself (the whole time loop: CFL step, the step,
the guards, rest checks), for a fixed number of steps, from a fresh copy of the
points, after a warm-up run (so the numba compile cost, reported separately, is
not in the MPUPS).  Two phases: ``finite`` (large deformation: Hughes-Winget +
Hencky update, points move) and ``geostatic`` (small strain, points fixed).
MPUPS = points x steps / time; median of ``--repeats`` runs, wall clock and
process CPU time both (the machine is shared: CPU time is the less noisy one).

Per-stage breakdown: numba — each kernel called and timed alone, in the order of
``explicit_step``; numpy — the reference step's stages timed the same way.

Memory: ``tracemalloc`` peak of the arrays of one realization (grid, points,
workspace, a few steps), and the peak RSS of a fresh process that prepares and
runs 50 steps of the reference slope (interpreter + numpy/scipy/scikit-fem/numba
included), next to the RSS of the same process after imports only.

Compile cost: a fresh process with an empty ``NUMBA_CACHE_DIR`` (cold compile) and
a second one with that cache filled (cache load): the time to the end of the first
step.

Cold and warm start of the command itself: ``fem-rmpm run meshes/slope_reference.toml``
(a short ``t_end``) in a fresh process with an empty ``NUMBA_CACHE_DIR`` (it compiles
the kernels its thread count needs), then again with that cache filled: the run's own
``first_step_time`` (``summary.json``: set-up, compile or cache load and the first
step) and the process's CPU time, on one and on two threads
(``--first-step-only``: this alone, ~1-2 CPU-min).

Whole runs (the headline, what users get): ``fem-rmpm run meshes/slope_reference.toml``
(case (i): von Mises softening, to rest) in a fresh process, after a short run that
fills numba's cache; ns per point-step and MPUPS from the run's own ``summary.json``
(the time loop with its VTK output; imports, set-up and the end figures not included),
plus the process's CPU time.  One thread (``--quick`` and full) and two threads (full);
full also case (i) at ~1e4 (to rest), ~1e5 (first 1 s) and ~1e6 (first 0.25 s)
points (cells 1/3, 0.1, 1/30 m) for the linear-cost check.  The machine is named (CPU
model, cores, load average at start and end: wall figures mean something only on an
idle machine).  Writes ``validation/out/bench_explicit.json`` and prints the performance
targets this run measured (:func:`target_verdicts`).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fem_rmpm.discretise.basis import shape_at_points  # noqa: E402
from fem_rmpm.discretise.grid import make_grid  # noqa: E402
from fem_rmpm.discretise.points import seed_particles  # noqa: E402
from fem_rmpm.materials import hughes_winget_increment, stress_update  # noqa: E402
from fem_rmpm.runtime.compiled import kernel  # noqa: E402
from fem_rmpm.runtime.machine import describe  # noqa: E402
from fem_rmpm.scene import load_scene, with_values  # noqa: E402
from fem_rmpm.schemes.explicit import kernels as K  # noqa: E402
from fem_rmpm.schemes.explicit.kernels import hencky as H  # noqa: E402
from fem_rmpm.schemes.explicit.kernels import strain as KS
from fem_rmpm.schemes.explicit.loop import Workspace, explicit_step, run_explicit  # noqa: E402
from fem_rmpm.schemes.explicit.reference import (  # noqa: E402
    map_to_nodes,
    solve_on_mesh,
    stable_time_step,
)

OUT = ROOT / "validation" / "out"
REFERENCE = ROOT / "meshes" / "slope_elastic.toml"
CASES = {"1e4": 1 / 3, "ref": 0.25, "1e5": 0.1, "1e6": 1 / 30}   # cell size (m)
WORK_TARGET = 1.2e7          # point-steps per timed run (~1 s at 1e7 MPUPS)
CASE_I = ROOT / "meshes" / "slope_reference.toml"
# cell (m), t_end (s): each run >= 6e7 point-steps, so that the fixed cost of a run (loading
# the cached kernels at the first step and two snapshots: ~0.26 s CPU on case (i)) is
# <= ~5 ns per point-step (a run of 1 s at 1e4 points would be mostly that fixed cost)
SCALING = {"1e4": (1 / 3, 40.0), "1e5": (0.1, 1.0), "1e6": (1 / 30, 0.25)}


def machine() -> dict:
    """Which machine the figures come from (:func:`fem_rmpm.runtime.machine.describe`, as in every
    run's ``summary.json``): CPU model, cores, load average at the start, versions."""
    m = describe()
    return {**m, "cores": m["logical_cores"], "load_avg_start": m["load_average"]}


def whole_run(threads: int, changes=()) -> dict:
    """``fem-rmpm run`` of case (i) (with ``--set`` ``changes``) in a fresh process:
    the figures of its ``summary.json`` and the process's CPU time."""
    sets = [a for c in (f"solver.threads={threads}", *changes) for a in ("--set", c)]
    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "fem_rmpm.cli", "run", str(CASE_I), "--out", f"{d}/run",
               "--quiet", *sets]
        r0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
        wall, r1 = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
        s = json.loads(Path(d, "run", "summary.json").read_text())
    ns = s["ns_per_particle_step"]
    return {"threads": threads, "threads_used": s["solver"].get("threads"),
            "changes": list(changes), "points": s["particles"], "steps": s["steps"],
            "stop_reason": s["stop_reason"], "run_wall_s": s["wall_time"],
            "ns_per_point_step": ns, "mpups": 1e3 / ns, "process_wall_s": wall,
            "run_cpu_s": s.get("cpu_time"), "ns_per_point_step_cpu": s.get("ns_per_particle_step_cpu"),
            "process_cpu_s": r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime,
            "measures": {k: s["measures"][k] for k in ("runout_distance", "sliding_area",
                                                        "retrogression_distance")}}


def fill_cache(threads=(1, 2)) -> None:
    """Fill numba's cache with a short run on each thread count of ``threads`` (the serial
    and the threaded drivers are cached apart), so no timed run compiles."""
    for th in threads:
        whole_run(th, ["solver.t_end=0.02"])


def scaling_changes(name: str) -> list[str]:
    """The ``--set`` changes of case (i) at the size ``name`` of :data:`SCALING`."""
    cell, t_end = SCALING[name]
    return [f"grid.cell=[{cell!r}, {cell!r}]", f"solver.t_end={t_end}"]


def whole_runs(quick: bool) -> dict:
    """Case (i) on 1 (and, full, 2) threads; full: the 1e4 / 1e5 / 1e6 scaling runs."""
    threads = (1,) if quick else (1, 2)
    fill_cache(threads)
    out = {"case_i": [whole_run(th) for th in threads]}
    for r in out["case_i"]:
        print(f"WHOLE RUN case (i) {r['points']} points x {r['steps']} steps, {r['threads']} "
              f"thread(s) (used {r['threads_used']}): {r['mpups']:.2f} MPUPS, "
              f"{r['ns_per_point_step']:.1f} ns per point-step (summary.json, wall "
              f"{r['run_wall_s']:.1f} s; CPU {r['ns_per_point_step_cpu']:.1f} ns); process "
              f"{r['process_wall_s']:.1f} s wall, "
              f"{r['process_cpu_s']:.1f} s CPU", flush=True)
    if quick:
        return out
    out.update(scaling_runs(two_threads=True))
    return out


def scaling_runs(two_threads: bool) -> dict:
    """Case (i) at ~1e4 / 1e5 / 1e6 points (:data:`SCALING`: to rest at 1e4, the first 1 s
    at 1e5, 0.25 s at 1e6), one thread (and two at 1e6): whole-run wall and CPU ns per
    point-step and their spread."""
    out: dict = {"scaling": {}}
    for name, (_, t_end) in SCALING.items():
        ch = scaling_changes(name)
        ths = (1, 2) if (name == "1e6" and two_threads) else (1,)
        out["scaling"][name] = [whole_run(th, ch) for th in ths]
        for r in out["scaling"][name]:
            print(f"WHOLE RUN case (i) to t = {t_end} s at {r['points']} points, {r['threads']} "
                  f"thread(s): {r['ns_per_point_step']:.1f} ns per point-step "
                  f"({r['mpups']:.2f} MPUPS), {r['ns_per_point_step_cpu']:.1f} CPU ns",
                  flush=True)
    for key, label in (("ns_per_point_step", "wall"), ("ns_per_point_step_cpu", "CPU")):
        ns = [out["scaling"][k][0][key] for k in SCALING]
        out[f"scaling_spread_{label}"] = max(ns) / min(ns) - 1
        print(f"whole-run {label} ns per point-step 1e4 / 1e5 / 1e6: "
              f"{' / '.join(f'{v:.1f}' for v in ns)} "
              f"(largest / smallest - 1 = {out[f'scaling_spread_{label}']:.1%})")
    out["scaling_spread"] = out["scaling_spread_wall"]
    return out


def make_case(cell: float, phase: str, softening: bool = False):
    changes = {"grid.cell": [cell, cell], "solver.gravity_ramp_time": 1.0,
               "solver.gravity_phase": "dynamic" if phase == "finite" else "geostatic",
               "solver.geostatic_time": 1e6, "solver.output_interval": 1e6,
               "solver.rest_velocity": 0.0}
    if softening:
        changes.update({"soil.model": "von_mises_softening", "soil.cohesion_peak": 8.0,
                        "soil.cohesion_residual": 4.0, "soil.softening_strain": 0.5})
    scene = with_values(load_scene(REFERENCE), changes)
    grid = make_grid(scene)
    return scene, grid, seed_particles(scene, grid)


def with_steps(scene, grid, pts, steps):
    dt = stable_time_step(pts, grid.cell, scene.solver.cfl)
    return with_values(scene, {"solver.t_end": steps * dt * 0.999})


def time_runs(scene, grid, pts0, kernel, repeats):
    """Median wall / CPU ns per particle-step of run_explicit over ``repeats`` fresh runs."""
    walls, cpus, steps = [], [], 0
    run_explicit(scene, grid, pts0.copy(), kernel=kernel)            # warm-up (compile, caches)
    for _ in range(repeats):
        pts = pts0.copy()
        w0, c0 = time.perf_counter(), time.process_time()
        rec = run_explicit(scene, grid, pts, kernel=kernel)
        w1, c1 = time.perf_counter(), time.process_time()
        steps = rec.steps
        walls.append((w1 - w0) / (steps * pts.n) * 1e9)
        cpus.append((c1 - c0) / (steps * pts.n) * 1e9)
    return {"steps": steps, "ns_wall_runs": walls, "ns_cpu_runs": cpus,
            "ns_wall": float(np.median(walls)), "ns_cpu": float(np.median(cpus)),
            "mpups_wall": 1e3 / float(np.median(walls)), "mpups_cpu": 1e3 / float(np.median(cpus))}


@kernel
def _exp_stage(P, W, ta, tb, tc):
    """The stress pass's exp series alone, over all points in its blocks (scratch W, ta,
    tb, tc of n rows: each block a slice)."""
    n = np.uint64(P.x.shape[0])
    for b in range(np.uint64(0), n, np.uint64(K.BLOCK)):
        e = min(b + np.uint64(K.BLOCK), n)
        H.exp_block(P.log_strain, tb[b:e], tc[b:e], b, e)


@kernel
def _kinematics_stage(P, M, N, S, o, W, ta, tb, tc):
    """The stress pass's kinematics alone (velocity gradient, dF, V, B_tr)."""
    n = np.uint64(P.x.shape[0])
    split = np.uint64(K.half_split(P.x.shape[0]))
    for b in range(np.uint64(0), n, np.uint64(K.BLOCK)):
        e = min(b + np.uint64(K.BLOCK), n)
        vn = N.v_musl if b < split else N.half.v_musl
        KS.kinematics_points(o.gimp, P, M, vn, S, o, W[:, b:e], ta[b:e], tb[b:e], tc[b:e], b, e)


@kernel
def _log_stage(W, ta, tb, tc):
    """The stress pass's log series alone."""
    n = np.uint64(ta.shape[0])
    for b in range(np.uint64(0), n, np.uint64(K.BLOCK)):
        e = min(b + np.uint64(K.BLOCK), n)
        H.log_block(W[:, b:e], ta[b:e], tb[b:e], tc[b:e], e - b)


def stages_numba(scene, grid, pts, geostatic, steps):
    """Median ns per particle of each kernel, called in the order of explicit_step; the
    stress pass also as its four parts, each over all points with scratch of n rows (in the
    pass a block's scratch is one row of BLOCK points per thread, in L1)."""
    w = Workspace.for_grid(grid, pts.n)
    g = np.array(scene.gravity_vector)
    sv = scene.solver
    names = ("1 map_to_nodes", "2 + 3a solve on the mesh, map back, move, re-map",
             "3b + 3c stress pass (nodal velocities + all of it)", "3c part: exp series",
             "3c part: L, dF, V, B_tr", "3c part: log series",
             "3c part: material model + stress")
    T = {k: [] for k in names}
    clk = time.perf_counter
    explicit_step(grid, pts, 1e-4, g, sv.damping, sv.flip, sv.shape, geostatic, "numba", w)
    (P, M), N, S, call = w.bind(grid, pts), w.nodes, w.scratch, w.call
    stress_pass = K.material_kernels(w.model)[0]
    finish = _finish_stage(w.model)
    saved = ("log_strain", "state", "F", "volume", "stress")
    blk = (np.zeros((8, pts.n)), np.zeros(pts.n), np.zeros(pts.n), np.zeros(pts.n))
    for _ in range(steps):
        dt = stable_time_step(pts, grid.cell, sv.cfl)
        o = K.StepOptions(dt, float(g[0]), float(g[1]), sv.damping, sv.flip, geostatic, False,
                          False, 1, w.model, w.block)
        spans = []                     # (start, end) of each stage, in the order of names
        t0 = clk()
        call(K.map_to_nodes, o.gimp, P, M, N, S, o)
        t1 = clk()
        call(K.solve_and_move, o.gimp, P, M, N, S, o)
        spans += [(t0, t1), (t1, clk())]
        before = {f: getattr(pts, f).copy() for f in saved}
        t0 = clk()
        call(stress_pass, P, M, N, S, o)
        spans.append((t0, clk()))
        after = {f: getattr(pts, f).copy() for f in saved}
        for f in saved:                # the parts again from the state before the pass
            getattr(pts, f)[...] = before[f]
        t0 = clk()
        if not geostatic:
            call(_exp_stage, P, *blk)
        t1 = clk()
        call(_kinematics_stage, P, M, N, S, o, *blk)
        t2 = clk()
        if not geostatic:
            call(_log_stage, *blk)
        t3 = clk()
        call(finish, P, o, *blk, S.Z[0])
        spans += [(t0, t1), (t1, t2), (t2, t3), (t3, clk())]
        for f in saved:
            getattr(pts, f)[...] = after[f]
        for k, (a, b) in zip(names, spans):
            T[k].append((b - a) / pts.n * 1e9)
    return {k: float(np.median(v)) for k, v in T.items()}


_FINISH = {}


def _finish_stage(only):
    """The stress pass's material model + stress part alone, through the model's block
    update where the run's points take it (``o.block``), as in the pass (the model
    dispatch needs the registry version and the model as literals: a kernel made per
    pair)."""
    version = K.stress.registry.version()
    if (version, only) not in _FINISH:
        @kernel
        def finish(P, o, W, ta, tb, tc, Z):
            n = np.uint64(P.x.shape[0])
            for b in range(np.uint64(0), n, np.uint64(K.BLOCK)):
                e = min(b + np.uint64(K.BLOCK), n)
                K.stress._finish(version, only, o.block, P, o, W[:, b:e], ta[b:e], tb[b:e],
                                 Z, b, e)
        _FINISH[(version, only)] = finish
    return _FINISH[(version, only)]


def stages_numpy(scene, grid, pts, geostatic, steps):
    """Median ns per particle of the numpy reference step's stages."""
    from fem_rmpm.materials import small_strain_update
    g = np.array(scene.gravity_vector)
    sv = scene.solver
    names = ("1 shape (locate + Q4)", "1 map_to_nodes", "2 solve_on_mesh",
             "3 g2p + move + remap", "3 velocity gradient + stress update + state")
    T = {k: [] for k in names}
    clk = time.perf_counter
    nn = grid.n_nodes
    for _ in range(steps):
        dt = stable_time_step(pts, grid.cell, sv.cfl)
        t = [clk()]
        x, v, mass, vol = pts.x, pts.velocity, pts.mass, pts.volume
        _, nodes, N, dN, _ = shape_at_points(grid, x, "standard")
        t.append(clk())
        m, p, f = map_to_nodes(nodes, N, dN, mass, v, pts.stress, vol, g, nn)
        t.append(clk())
        _, v_new, a = solve_on_mesh(m, p, f, grid.fixed, dt, sv.damping)
        t.append(clk())
        v_pic = np.einsum("pa,pak->pk", N, v_new[nodes])
        v = v + dt * np.einsum("pa,pak->pk", N, a[nodes])
        x = x if geostatic else x + dt * v_pic
        _, p2, _ = map_to_nodes(nodes, N, dN, mass, v, pts.stress * 0, vol, g * 0, nn)
        t.append(clk())
        v_nodes = np.where(grid.fixed, 0.0, p2 / np.where(m > 1e-14, m, 1.0)[:, None])
        L = np.einsum("pak,pal->pkl", v_nodes[nodes], dN)
        if geostatic:
            ls, gp, tau = small_strain_update(L * dt, pts.log_strain, pts.plastic_shear_strain,
                                              pts.soil)
            J = 1.0
        else:
            dF = hughes_winget_increment(L, dt)
            ls, gp, tau = stress_update(dF, pts.log_strain, pts.plastic_shear_strain, pts.soil)
            J = np.linalg.det(dF)
        pts.x[:], pts.velocity[:], pts.volume[:] = x, v, vol * J
        pts.log_strain[:], pts.plastic_shear_strain[:] = ls, gp
        pts.stress[:] = tau * (pts.volume0 / pts.volume)[:, None]
        t.append(clk())
        for k, a_, b_ in zip(names, t[:-1], t[1:]):
            T[k].append((b_ - a_) / pts.n * 1e9)
    return {k: float(np.median(v)) for k, v in T.items()}


def traced_memory(cell):
    """tracemalloc peak (MB) of one realization's arrays: grid, points, workspace, 5 steps."""
    tracemalloc.start()
    scene, grid, pts = make_case(cell, "finite")
    w = Workspace.for_grid(grid, pts.n)
    g = np.array(scene.gravity_vector)
    for _ in range(5):
        explicit_step(grid, pts, stable_time_step(pts, grid.cell, 0.5), g, 0.7, 1.0,
                      "standard", False, "numba", w)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


_CHILD = r"""
import resource, sys, time
t0 = time.perf_counter()
sys.path.insert(0, {root!r})
import numpy as np
from fem_rmpm import api
from fem_rmpm.schemes.explicit.loop import Workspace, explicit_step, stable_time_step
rss_imports = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
scene = api.load_scene({ref!r})
grid, pts = api.prepare(scene)
w = Workspace.for_grid(grid, pts.n)
g = np.array(scene.gravity_vector)
t1 = time.perf_counter()
def step(geo):
    dt = stable_time_step(pts, grid.cell, 0.5)
    explicit_step(grid, pts, dt, g, 0.7, 1.0, "standard", geo, "numba", w)
step(False)
t2 = time.perf_counter()
for k in range(50):
    step(k < 10)
print(rss_imports, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, t1 - t0, t2 - t1)
"""


def child_process(cache_dir):
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    code = _CHILD.format(root=str(ROOT), ref=str(REFERENCE))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    rss_imports, rss_peak, t_setup, t_first = map(float, out[-4:])
    return {"rss_after_imports_mb": rss_imports, "rss_peak_mb": rss_peak,
            "imports_and_setup_s": t_setup, "first_step_s": t_first}


def cli_first_step(cache_dir: str, threads: int) -> dict:
    """A fresh ``fem-rmpm run`` of the reference slope (t_end 0.05 s) with numba's cache in
    ``cache_dir``: ``first_step_s`` (its summary.json's ``first_step_time``: imports
    excluded, set-up + compile or load + first step, wall), the process's ``wall_s`` and
    ``cpu_s`` (user + system, all threads)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    with tempfile.TemporaryDirectory() as out:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "fem_rmpm.cli", "run", str(CASE_I), "--set",
                        f"solver.threads={threads}", "--set", "solver.t_end=0.05",
                        "--out", out], env=env, capture_output=True, text=True, check=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        summary = json.loads((Path(out) / "summary.json").read_text())
    return {"threads": threads, "first_step_s": summary["solver"]["first_step_time"],
            "wall_s": wall, "cpu_s": (after.ru_utime - before.ru_utime)
            + (after.ru_stime - before.ru_stime)}


def cli_start_times() -> dict:
    """Cold and warm :func:`cli_first_step` on one and two threads (a fresh cache each)."""
    res = {}
    for threads in (1, 2):
        with tempfile.TemporaryDirectory() as cache:
            res[f"{threads}_thread"] = {"cold": cli_first_step(cache, threads),
                                        "warm": cli_first_step(cache, threads)}
        r = res[f"{threads}_thread"]
        print(f"fem-rmpm run (reference slope, {threads} thread{'s' * (threads > 1)}): first "
              f"step {r['cold']['first_step_s']:.1f} s cold (process CPU "
              f"{r['cold']['cpu_s']:.1f} s, wall {r['cold']['wall_s']:.1f} s), "
              f"{r['warm']['first_step_s']:.2f} s warm (process CPU {r['warm']['cpu_s']:.1f} s, "
              f"wall {r['warm']['wall_s']:.1f} s); load average {os.getloadavg()[0]:.2f}",
              flush=True)
    return res


#: The explicit scheme's performance targets: case (i) on one thread (ns per point-step),
#: two threads against one (case (i) and ~1e6 points), the spread of the cost per
#: point-step over 1e4 / 1e5 / 1e6 points, and a fresh process's imports, setup and first
#: step with the kernels in numba's cache (s).
TARGETS = {"one_thread_ns": 67.0, "two_threads": 1.8, "spread": 0.25, "warm_start_s": 3.0}


def target_verdicts(res: dict) -> list[str]:
    """The performance targets (:data:`TARGETS`) that this run measured, each with its
    figure, its target and ``met`` / ``NOT met`` on this machine (one run each: a ratio
    near its target needs interleaved pairs before a decision,
    ``validation/bench_threads.py``).  Not here: the agreement with the reference
    solution (``validation/explicit_reference.py``), the identical ``results.csv`` of a
    campaign on 1 and 2 threads (``validation/threads_campaign.py``) and the implicit cost
    (``validation/bench_implicit.py``)."""
    def verdict(ok: bool) -> str:
        return "met" if ok else "NOT met"
    runs = {r["threads"]: r for r in res["whole_run"]["case_i"]}
    ns1 = runs[1]["ns_per_point_step"]
    T = TARGETS
    out = [f"one thread: case (i) whole run {ns1:.1f} ns per point-step "
           f"(<= {T['one_thread_ns']:g}): {verdict(ns1 <= T['one_thread_ns'])}"]
    if 2 in runs:
        r_ref = ns1 / runs[2]["ns_per_point_step"]
        scaling = res["whole_run"]          # (the full run's scaling runs: whole_runs)
        big = {r["threads"]: r["ns_per_point_step"] for r in scaling["scaling"]["1e6"]}
        r_big = big[1] / big[2]
        out.append(f"two threads: case (i) {r_ref:.2f}x, ~1e6 points {r_big:.2f}x "
                   f"(>= {T['two_threads']:g}): {verdict(min(r_ref, r_big) >= T['two_threads'])}")
        spread = scaling["scaling_spread"]
        out.append(f"scaling: 1e4 / 1e5 / 1e6 points, largest / smallest - 1 = {spread:.1%} "
                   f"(<= {T['spread']:.0%}): {verdict(spread <= T['spread'])}")
    warm = res["compile"]["warm_cache"]
    first = warm["imports_and_setup_s"] + warm["first_step_s"]
    out.append(f"warm start: a fresh process's imports, setup and first step, kernels from "
               f"numba's cache: {first:.2f} s (<= {T['warm_start_s']:g} s): "
               f"{verdict(first <= T['warm_start_s'])}")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="reference slope only, fewer repeats")
    ap.add_argument("--repeats", type=int, default=None, help="runs per case (5; --quick: 3)")
    ap.add_argument("--out", default=str(OUT / "bench_explicit.json"))
    ap.add_argument("--scaling-only", action="store_true",
                    help="only the 1e4 / 1e5 / 1e6 whole-run scaling, one thread (~3 CPU-min)")
    ap.add_argument("--first-step-only", action="store_true",
                    help="only the cold and warm first step of fem-rmpm run (1 and 2 threads)")
    args = ap.parse_args(argv)
    if args.first_step_only:
        res = {"machine": machine(), "cli_start": cli_start_times()}
        res["machine"]["load_avg_end"] = os.getloadavg()
        out = Path(args.out).with_name("bench_explicit_first_step.json")
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=1))
        return res
    if args.scaling_only:
        fill_cache((1,))
        res = {"machine": machine(), **scaling_runs(two_threads=False)}
        res["machine"]["load_avg_end"] = os.getloadavg()
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(res, indent=1))
        return res
    cases = ["ref"] if args.quick else list(CASES)
    repeats = args.repeats or (3 if args.quick else 5)
    res = {"machine": machine(), "repeats": repeats, "cases": {}}
    m = res["machine"]
    print(f"machine: {m['cpu_model']}, {m['cores']} cores, load average "
          f"{' '.join(f'{v:.2f}' for v in m['load_avg_start'])} at start", flush=True)
    res["whole_run"] = whole_runs(args.quick)

    with tempfile.TemporaryDirectory() as cache:
        res["compile"] = {"cold_cache": child_process(cache), "warm_cache": child_process(cache)}
    res["cli_start"] = cli_start_times()
    c = res["compile"]
    print(f"numba first step: cold compile {c['cold_cache']['first_step_s']:.1f} s, "
          f"from cache {c['warm_cache']['first_step_s']:.2f} s (kept out of the MPUPS)")
    print(f"RSS of a realization process (reference slope): peak "
          f"{c['warm_cache']['rss_peak_mb']:.0f} MB, of which after imports "
          f"{c['warm_cache']['rss_after_imports_mb']:.0f} MB")

    for name in cases:
        cell = CASES[name]
        entry = {"cell": cell}
        for phase in ("finite", "geostatic"):
            scene, grid, pts = make_case(cell, phase)
            steps = int(np.clip(WORK_TARGET / pts.n, 10, 600))
            sc = with_steps(scene, grid, pts, steps)
            r = {"points": pts.n, "active_nodes_of_grid": None,
                 "numba": time_runs(sc, grid, pts, "numba", repeats if pts.n < 5e5 else 3)}
            r["stages_numba_ns"] = stages_numba(scene, grid, pts.copy(), phase == "geostatic",
                                                max(10, min(100, steps)))
            if name in ("ref", "1e4"):
                sc_np = with_steps(scene, grid, pts, max(10, steps // 10))
                r["numpy"] = time_runs(sc_np, grid, pts, "numpy", 3)
                r["stages_numpy_ns"] = stages_numpy(scene, grid, pts.copy(),
                                                    phase == "geostatic", 10)
            w = Workspace.for_grid(grid, pts.n)
            P, M = w.bind(grid, pts)
            K.map_to_nodes(False, P, M, w.nodes, w.scratch, K.StepOptions(0.0, 0.0, 0.0, 0.0, 1.0, False, False,
                                                         False))
            half = w.nodes.half          # the nodes of the second half not in the first's
            only_second = half.touched[:half.n_touched[0]]
            r["active_nodes_of_grid"] = [int(w.nodes.n_touched[0])
                                         + int((w.nodes.flag[only_second] == 0).sum()),
                                         grid.n_nodes]
            entry[phase] = r
            nb = r["numba"]
            line = (f"{name:>4} {phase:9} {pts.n:>8d} pts {nb['steps']:>4d} steps  numba "
                    f"{nb['mpups_wall']:6.2f} MPUPS wall ({nb['ns_wall']:6.1f} ns)  "
                    f"{nb['mpups_cpu']:6.2f} MPUPS cpu ({nb['ns_cpu']:6.1f} ns)")
            if "numpy" in r:
                npy = r["numpy"]
                line += f"   numpy {npy['mpups_cpu']:5.2f} MPUPS cpu ({npy['ns_cpu']:6.0f} ns)"
            print(line, flush=True)
        if name == "ref":
            scene, grid, pts = make_case(cell, "finite", softening=True)
            sc = with_steps(scene, grid, pts, 400)
            entry["finite_softening"] = {"points": pts.n,
                                         "numba": time_runs(sc, grid, pts, "numba", repeats)}
            nb = entry["finite_softening"]["numba"]
            print(f" ref finite, von Mises softening: {nb['mpups_wall']:.2f} MPUPS wall, "
                  f"{nb['mpups_cpu']:.2f} cpu", flush=True)
        entry["tracemalloc_peak_mb"] = traced_memory(cell)
        res["cases"][name] = entry

    print("\nper-stage breakdown, ns per particle-step (median), numba kernels:")
    for name in cases:
        for phase in ("finite", "geostatic"):
            st = res["cases"][name][phase]["stages_numba_ns"]
            print(f"  {name:>4} {phase:9} " + "  ".join(f"{k.split(' ', 1)[1]} {v:.1f}"
                                                         for k, v in st.items() if v > 0)
                  + f"  | sum of the three stages "
                    f"{sum(v for k, v in st.items() if 'part:' not in k):.1f} (the parts "
                    f"{sum(v for k, v in st.items() if 'part:' in k):.1f} are inside the "
                    "stress pass, timed alone)")
    for name in cases:
        for phase in ("finite", "geostatic"):
            st = res["cases"][name][phase].get("stages_numpy_ns")
            if st:
                print(f"  {name:>4} {phase:9} numpy: "
                      + "  ".join(f"{k} {v:.0f}" for k, v in st.items())
                      + f"  | sum {sum(st.values()):.0f}")
    print("\nmemory per realization (tracemalloc peak of the arrays, MB): "
          + ", ".join(f"{n} {res['cases'][n]['tracemalloc_peak_mb']:.1f}" for n in cases))
    if "1e4" in res["cases"] and "1e6" in res["cases"]:
        for phase in ("finite", "geostatic"):
            a = res["cases"]["1e4"][phase]["numba"]["mpups_cpu"]
            b = res["cases"]["1e6"][phase]["numba"]["mpups_cpu"]
            res.setdefault("scaling_1e6_over_1e4_cpu", {})[phase] = b / a
            print(f"scaling {phase}: MPUPS(1e6) / MPUPS(1e4) = {b / a:.2f} (cpu time)")
    ref = res["cases"]["ref"]["finite"]["numba"]
    one = res["whole_run"]["case_i"][0]
    res["headline"] = {"case": "case (i), fem-rmpm run meshes/slope_reference.toml, 1 thread, "
                               "summary.json", "points": one["points"], "steps": one["steps"],
                       "mpups": one["mpups"], "ns_per_point_step": one["ns_per_point_step"],
                       "kernel_step_mpups_wall": ref["mpups_wall"],
                       "kernel_step_mpups_cpu": ref["mpups_cpu"],
                       "rss_peak_mb": c["warm_cache"]["rss_peak_mb"]}
    res["machine"]["load_avg_end"] = os.getloadavg()
    m = res["machine"]
    print(f"\nHEADLINE case (i) whole run ({one['points']} points, {one['steps']} steps, 1 "
          f"thread): {one['mpups']:.2f} MPUPS, {one['ns_per_point_step']:.1f} ns per "
          f"point-step (summary.json); step alone (reference slope, finite strain): "
          f"{ref['mpups_wall']:.2f} MPUPS wall, {ref['mpups_cpu']:.2f} cpu (median of "
          f"{repeats}).  {m['cpu_model']}, {m['cores']} cores, load average "
          f"{m['load_avg_start'][0]:.2f} at start, {m['load_avg_end'][0]:.2f} at end")
    res["targets"] = target_verdicts(res)
    print(f"TARGETS on this machine ({m['cpu_model']}, {m['cores']} cores):\n  "
          + "\n  ".join(res["targets"]))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
