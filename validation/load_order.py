"""A run is the same whether its kernels were compiled in the process or loaded from
numba's cache, on 1 and on 2 threads (a realization is a pure function of the scene).

Why this can fail.  numba compiles every function into a code library of its own, and a
caller's library gets a copy of each compiled callee it calls (``linkonce_odr``, a weak
symbol), optimized a second time inside the caller.  Which copy of a shared kernel a run
executes depends on what the process loaded first: a process that *compiles* the serial
driver compiles (and loads) the callees first, so calls go to the callees' own libraries;
a process that *loads* the drivers from the cache loads the drivers' copies first; a
process on two threads loads the threaded driver's copies.  The copies run the same
arithmetic only if the second optimization does not change it.  With numba's default
passes it does not (the runs this script compares are bitwise the same); with
LLVM's SLP vectorizer switched on (``NUMBA_SLP_VECTORIZE=1``, which numba leaves off) and
FMA contraction, the copies of the map to nodes and the map back packed and fused
differently when the kernels leave the packing to LLVM: a run compiled in its process and
the same run from the cache took 2 115 and 2 114 steps to t = 6 s.  So those kernels
write their vector operations and fused multiply-adds out
(``fem_rmpm/schemes/explicit/kernels/pairs.py``): with ``--slp`` the four runs agree as
well (t = 2 and 12 s), but SLP stays off.  Without SLP the copies can still differ where
LLVM chooses the arithmetic itself: with FMA contraction ("contract") allowed, the stress
pass's copies fuse differently in AVX2 code (an AMD EPYC Zen 1 host; ``--cpu znver1`` on a
newer host): compiled 1 thread and the three others gave two hashes at t = 2 s (478
steps).  So the kernels carry no flag that changes a value
(``fem_rmpm/runtime/compiled.py``): one hash, with and without ``--cpu znver1``.

The check runs case (i) of the reference slope (or ``--scene`` with ``--set`` changes,
e.g. ``--set solver.shape=gimp --set solver.fbar=true``) to ``--t-end`` in child
processes sharing a numba cache directory of their own (empty at the start): on 1 thread
compiled, then from the cache; on 2 threads with the threaded driver compiled (its
callees from the cache), then all from the cache; and compares a sha1 of the points'
positions, velocities, stresses, log strains and material states and the step counts.
~20 s of compile, then a few seconds per run at ``--t-end 2``.  Exit status 0 when all
agree, 1 otherwise.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from fem_rmpm.cli import parse_settings
from fem_rmpm.runtime.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "meshes" / "slope_reference.toml"

# The child: one run, then "<steps> <sha1>" on its last line.
_CHILD = """
import hashlib, json, sys
import numpy as np
from fem_rmpm import api
from fem_rmpm.schemes.explicit.loop import run_explicit
from fem_rmpm.scene import load_scene, with_values
changes = dict(json.loads(sys.argv[4]), **{"solver.t_end": float(sys.argv[2]),
                                            "solver.threads": int(sys.argv[3])})
scene = with_values(load_scene(sys.argv[1]), changes)
grid, pts = api.prepare(scene)
rec = run_explicit(scene, grid, pts)
h = hashlib.sha1()
for a in (pts.x, pts.velocity, pts.stress, pts.log_strain, pts.state):
    h.update(np.ascontiguousarray(a).tobytes())
print(rec.steps, h.hexdigest())
"""


def child_run(cache: Path, scene: Path, changes: dict, t_end: float, threads: int,
              slp: bool, cpu: str | None = None) -> tuple:
    """(steps, sha1) of one run of ``scene`` (with ``changes``, dotted keys) in a fresh
    interpreter using numba cache ``cache``; ``cpu``: an LLVM CPU name to compile for
    (its own instruction set, not the host's), None: the host."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(ROOT))
    for k in ("NUMBA_SLP_VECTORIZE", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES"):
        env.pop(k, None)
    if slp:
        env["NUMBA_SLP_VECTORIZE"] = "1"
    if cpu:
        env.update(NUMBA_CPU_NAME=cpu, NUMBA_CPU_FEATURES="")
    out = subprocess.run([sys.executable, "-c", _CHILD, str(scene), repr(t_end), str(threads),
                          json.dumps(changes)],
                         env=env, cwd=ROOT, check=True, capture_output=True, text=True)
    steps, digest = out.stdout.split()[-2:]
    return int(steps), digest


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", type=Path, default=SCENE, help="scene file (TOML)")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE",
                    help="as fem-rmpm run --set, e.g. solver.shape=gimp (repeatable)")
    ap.add_argument("--t-end", type=float, default=2.0, help="simulated seconds per run")
    ap.add_argument("--slp", action="store_true",
                    help="with numba's SLP vectorizer on (see the module docstring)")
    ap.add_argument("--cpu", metavar="NAME",
                    help="compile for this LLVM CPU (e.g. znver1: AVX2, no AVX-512) instead "
                         "of the host")
    a = ap.parse_args(argv)
    try:
        changes = parse_settings(a.set, str(a.scene))
    except InputError as exc:
        print(f"load_order: {exc}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="fem-rmpm-load-order-") as tmp:
        cache = Path(tmp)
        try:
            runs = {name: child_run(cache, a.scene, changes, a.t_end, th, a.slp, a.cpu)
                    for name, th in (("compiled, 1 thread", 1), ("cached, 1 thread", 1),
                                     ("compiled, 2 threads", 2), ("cached, 2 threads", 2))}
        except subprocess.CalledProcessError as exc:
            last = (exc.stderr or "").strip().splitlines()[-1:] or ["(no message)"]
            print(f"load_order: the run failed: {last[0]}", file=sys.stderr)
            return 2
    for name, (steps, digest) in runs.items():
        print(f"{name:21s} {steps:6d} steps  {digest}")
    same = len(set(runs.values())) == 1
    what = " ".join([a.scene.name, *(a.set or [])])
    print(f"load order {'does not change' if same else 'CHANGES'} the run of {what} "
          f"(t = {a.t_end:g} s{', SLP on' if a.slp else ''}"
          f"{', compiled for ' + a.cpu if a.cpu else ''})")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
