"""Benchmark of the three-dimensional explicit step: whole-run point-updates per second
from the run's own ``summary.json`` on one and two threads, the cost of each stage of the
step, and memory per point.  Plain script:

    nice python validation/bench_explicit_3d.py            # the extruded slab, 1 and 2 threads
    python validation/bench_explicit_3d.py --t-end 12      # the first 12 s
    python validation/bench_explicit_3d.py --t-end 80      # the slab to rest (at 76.1 s)
    python validation/bench_explicit_3d.py --stages-only   # the per-stage figures alone

Case: ``meshes/slope_extruded_3d.toml`` (the reference slope's section extruded 2 m,
0.5 m hexahedra, 36 448 points, von Mises softening), run with ``fem-rmpm run`` in a fresh
process after a short run that fills numba's cache.  MPUPS = points x steps / the time
loop's wall (and CPU) time from ``summary.json`` (imports, set-up and output after the
loop not included).  Memory per point: the peak resident set of the run's process (its own
``wait4`` accounting) minus that of a process that imports the package and loads the
scene, over the points.
Per stage: the slab run in this process to ``--stage-time`` (3 s: sliding, softening),
then ``--stage-steps`` steps with each stage of the one-thread step
(:mod:`fem_rmpm.schemes.explicit3d.step`: both halves of the points, one after the other)
called and timed alone (process CPU time), in ns per point-step; the sum is the step.
The machine is shared: CPU figures are the less noisy; the load average is printed.
Writes ``validation/out/bench_explicit_3d.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "meshes" / "slope_extruded_3d.toml"
TARGET_MPUPS = 5.0          # million point-updates per second on one thread (target)


def _run(threads: int, t_end: float) -> dict:
    """One ``fem-rmpm run`` in a fresh process; its summary and peak RSS (MiB)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        cmd = [sys.executable, "-m", "fem_rmpm.cli", "run", str(SCENE), "--out", str(out),
               "--quiet", "--set", f"solver.threads={threads}", "--set", f"solver.t_end={t_end}",
               "--set", "output.vtk=false", "--set", "output.png=false"]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)        # this child's own peak RSS
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode:
            raise subprocess.CalledProcessError(proc.returncode, cmd)
        summary = json.loads((out / "summary.json").read_text())
    return {"summary": summary, "peak_rss_mib": usage.ru_maxrss / 1024}


def stage_profile(stage_time: float, steps: int) -> dict:
    """ns of CPU per point-step of each stage of the 3-D step (module docstring), on the
    slab's state at ``stage_time`` s; also the fraction of points that yielded."""
    from fem_rmpm import api
    from fem_rmpm.schemes.explicit3d import step as S
    from fem_rmpm.schemes.explicit3d.loop import Workspace3D, run_explicit_3d

    scene = api.with_value(api.load_scene(SCENE), "solver.t_end", stage_time)
    grid, pts = api.prepare(scene)
    run_explicit_3d(scene, grid, pts)
    w = Workspace3D(grid, pts)
    P, G, W = w.points, w.grid, w.scratch
    g = np.array([*scene.gravity_vector, 0.0])
    dt, flip = 0.25 * float(np.min(grid.cell)) / 40.0, scene.solver.flip
    gamma0 = pts.state[:, 0].copy()
    # the stages of the one-thread step (step.step_3d), each half after the other
    stages = {
        "map to nodes": lambda: (S._map_half(P, G, W, 0), S._map_half(P, G, W, 1)),
        "solve on nodes": lambda: S._nodal(G, W, g, dt, 0.0),
        "map back": lambda: (S._back_half(P, G, W, 0, dt, flip, False),
                             S._back_half(P, G, W, 1, dt, flip, False)),
        "nodal velocity": lambda: S._nodal_velocity(G, W),
        "stress": lambda: (S._stress_half(P, G, W, 0, dt, False),
                           S._stress_half(P, G, W, 1, dt, False)),
    }
    cpu = dict.fromkeys(stages, 0.0)
    for k in range(steps + 1):
        for name, call in stages.items():
            c0 = time.process_time()
            call()
            if k:                                      # the first step compiles
                cpu[name] += time.process_time() - c0
    n = int(pts.active.sum())
    ns = {name: 1e9 * c / (steps * n) for name, c in cpu.items()}
    ns["step"] = sum(ns.values())
    yielded = float(np.mean(pts.state[:, 0] > gamma0))
    for name, v in ns.items():
        print(f"  {name:15s} {v:7.1f} ns per point-step (CPU)")
    print(f"  {n} points, {steps} steps from t = {stage_time:g} s, {yielded:.0%} of the "
          f"points yielded; {1e3 / ns['step']:.2f} MPUPS of CPU")
    return {"ns_per_point_step_cpu": ns, "points": n, "steps": steps,
            "stage_time": stage_time, "yielded_fraction": yielded}


def _baseline_rss() -> float:
    code = ("from fem_rmpm import api; api.load_scene(%r); import resource; "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)" % str(SCENE))
    res = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True)
    return float(res.stdout.strip()) / 1024


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--t-end", type=float, default=2.0, help="simulated time per run, s")
    ap.add_argument("--stage-time", type=float, default=3.0,
                    help="simulated time before the per-stage figures, s")
    ap.add_argument("--stage-steps", type=int, default=100, help="steps timed per stage")
    ap.add_argument("--stages-only", action="store_true", help="the per-stage figures alone")
    a = ap.parse_args(argv)
    env_load = os.getloadavg()
    if a.stages_only:
        print(f"per stage (load average {env_load[0]:.2f}):")
        stage_profile(a.stage_time, a.stage_steps)
        return 0
    _run(1, 0.05)                                   # fills numba's cache (one thread
    _run(2, 0.05)                                   # and the threaded kernels)
    base = _baseline_rss()
    rows = {}
    for threads in (1, 2):
        r = _run(threads, a.t_end)
        s = r["summary"]
        work = s["particles"] * s["steps"]
        rows[threads] = {
            "points": s["particles"], "steps": s["steps"],
            "wall_s": s["wall_time"], "cpu_s": s["cpu_time"],
            "mpups_wall": work / s["wall_time"] / 1e6, "mpups_cpu": work / s["cpu_time"] / 1e6,
            "ns_per_point_step_cpu": s["ns_per_particle_step_cpu"],
            "threads_used": s["solver"].get("threads"),
            "first_step_s": s["solver"].get("first_step_time"),
            "load_average": os.getloadavg()[0],
            "bytes_per_point": (r["peak_rss_mib"] - base) * 2**20 / s["particles"],
        }
        print(f"{threads} thread(s) asked, {rows[threads]['threads_used']} used: "
              f"{s['particles']} points x {s['steps']} steps, wall {s['wall_time']:.2f} s "
              f"({rows[threads]['mpups_wall']:.2f} MPUPS), CPU {s['cpu_time']:.2f} s "
              f"({rows[threads]['mpups_cpu']:.2f} MPUPS), first step (the kernels' load) "
              f"{rows[threads]['first_step_s']:.2f} s wall; memory "
              f"{rows[threads]['bytes_per_point']:.0f} B per point above the "
              f"{base:.0f} MiB of imports; load average {rows[threads]['load_average']:.2f}")
    # after the runs: a child's peak RSS counts its parent's at the fork (Linux keeps the
    # high-water mark across exec), so this process stays small until they are done
    print(f"per stage (load average {os.getloadavg()[0]:.2f}):")
    stages = stage_profile(a.stage_time, a.stage_steps)
    verdict = rows[1]["mpups_cpu"] >= TARGET_MPUPS
    print(f"target >= {TARGET_MPUPS:g} MPUPS on one thread (CPU): "
          f"{'met' if verdict else 'NOT met'} ({rows[1]['mpups_cpu']:.2f}); load average "
          f"{env_load[0]:.2f} at start, {os.getloadavg()[0]:.2f} at end")
    out = ROOT / "validation" / "out"
    out.mkdir(exist_ok=True)
    (out / "bench_explicit_3d.json").write_text(json.dumps(
        {"rows": rows, "stages": stages, "baseline_rss_mib": base, "load_start": env_load,
         "load_end": os.getloadavg(), "target_met": verdict}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
