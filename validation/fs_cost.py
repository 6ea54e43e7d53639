"""Cost of the strength-reduction factor of safety beside the MPM run.

For one scene (default: the reference slope, case (i)), interleaved in one process and
repeated: the FS with strength continuation (the default search), the FS with gravity
applied anew at every trial (``continuation = False``, the plain search) and the
explicit MPM run of the same realization (no output files).  CPU time is
``time.process_time`` of this process (one numba thread, as a campaign worker), so the
figures compare on a loaded machine; wall times are printed with the load average.

    nice python validation/fs_cost.py [--scene meshes/slope_reference.toml] [--repeats 2]

Writes ``validation/out/fs_cost.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numba

from fem_rmpm import api
from fem_rmpm.schemes.implicit.strength_reduction import FSOptions, factor_of_safety

ROOT = Path(__file__).resolve().parents[1]


def timed(fn):
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c0, time.perf_counter() - w0


def fs_run(scene, continuation: bool) -> dict:
    grid, pts = api.prepare(scene)
    res = factor_of_safety(scene, options=FSOptions(continuation=continuation),
                           grid=grid, pts=pts)
    return {"fs": res.fs, "text": res.text, "bracket": list(res.bracket),
            "static_solves": res.static_solves,
            "newton_iterations": sum(t.iterations for t in res.trials)}


def mpm_run(scene) -> dict:
    res = api.run(scene, out=None, progress=False, vtk=False, figures=False)
    return {"steps": res.summary["steps"], "stop_reason": res.summary["stop_reason"],
            "simulated_time": res.summary["simulated_time"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "meshes" / "slope_reference.toml"))
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--no-classic", action="store_true",
                    help="skip the plain search (gravity anew at every trial)")
    a = ap.parse_args()
    numba.set_num_threads(1)
    scene = api.load_scene(a.scene)
    kinds = {"fs_continuation": lambda: fs_run(scene, True),
             "fs_gravity_anew": lambda: fs_run(scene, False),
             "mpm_run": lambda: mpm_run(scene)}
    if a.no_classic:
        kinds.pop("fs_gravity_anew")
    rows = []
    for r in range(a.repeats):
        for name, fn in kinds.items():
            out, cpu, wall = timed(fn)
            row = {"repeat": r, "kind": name, "cpu_time": cpu, "wall_time": wall,
                   "load": os.getloadavg()[0], **out}
            rows.append(row)
            print(json.dumps(row), flush=True)
    dest = ROOT / "validation" / "out"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "fs_cost.json").write_text(json.dumps({"scene": a.scene, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
