"""Benchmark of the three-dimensional explicit step: whole-run point-updates per second
from the run's own ``summary.json`` on one and two threads, and memory per point.
Plain script:

    nice python validation/bench_explicit_3d.py            # the extruded slab, 1 and 2 threads
    python validation/bench_explicit_3d.py --t-end 1.0     # a shorter run

Case: ``meshes/slope_extruded_3d.toml`` (the reference slope's section extruded 2 m,
0.5 m hexahedra, 36 448 points, von Mises softening), run with ``fem-rmpm run`` in a fresh
process after a short run that fills numba's cache.  MPUPS = points x steps / the time
loop's wall (and CPU) time from ``summary.json`` (imports, set-up and output after the
loop not included).  Memory per point: the peak resident set of the run's process minus
that of a process that imports the package and loads the scene, over the points.
The machine is shared: CPU figures are the less noisy; the load average is printed.
Writes ``validation/out/bench_explicit_3d.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

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
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        summary = json.loads((out / "summary.json").read_text())
    return {"summary": summary, "peak_rss_mib": max(rss, before) / 1024}


def _baseline_rss() -> float:
    code = ("from fem_rmpm import api; api.load_scene(%r); import resource; "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)" % str(SCENE))
    res = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True)
    return float(res.stdout.strip()) / 1024


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--t-end", type=float, default=2.0, help="simulated time per run, s")
    a = ap.parse_args(argv)
    env_load = os.getloadavg()
    _run(1, 0.05)                                   # fills numba's cache
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
            "bytes_per_point": (r["peak_rss_mib"] - base) * 2**20 / s["particles"],
        }
        print(f"{threads} thread(s) asked, {rows[threads]['threads_used']} used: "
              f"{s['particles']} points x {s['steps']} steps, wall {s['wall_time']:.2f} s "
              f"({rows[threads]['mpups_wall']:.2f} MPUPS), CPU {s['cpu_time']:.2f} s "
              f"({rows[threads]['mpups_cpu']:.2f} MPUPS); memory "
              f"{rows[threads]['bytes_per_point']:.0f} B per point above the "
              f"{base:.0f} MiB of imports")
    verdict = rows[1]["mpups_cpu"] >= TARGET_MPUPS
    print(f"target >= {TARGET_MPUPS:g} MPUPS on one thread (CPU): "
          f"{'met' if verdict else 'NOT met'} ({rows[1]['mpups_cpu']:.2f}); load average "
          f"{env_load[0]:.2f} at start, {os.getloadavg()[0]:.2f} at end")
    out = ROOT / "validation" / "out"
    out.mkdir(exist_ok=True)
    (out / "bench_explicit_3d.json").write_text(json.dumps(
        {"rows": rows, "baseline_rss_mib": base, "load_start": env_load,
         "load_end": os.getloadavg(), "target_met": verdict}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
