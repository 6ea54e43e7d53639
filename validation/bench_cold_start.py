"""Cold and warm start of ``fem-rmpm run``: what numba compiles before the first step, and
how long the first step takes with an empty and with a filled on-disk cache.

Plain script (no pytest), about 1-2 CPU-minutes per round and thread count::

    python validation/bench_cold_start.py                 # cold and warm, 1 and 2 threads
    python validation/bench_cold_start.py --list          # + every function numba compiles
    python validation/bench_cold_start.py --rounds 3 --other /path/to/other/checkout

Each measurement is a fresh process ``python -m fem_rmpm.cli run`` of the embedded
reference slope (no scene file: the scene a fresh install runs first) to ``t_end = 0.05``
s with ``[solver] threads`` = 1 or 2 and ``NUMBA_CACHE_DIR`` set to a fresh directory
(cold: numba compiles every kernel the run calls), then once more with that directory
filled (warm: the kernels are loaded).  Printed per run: the user's wait, from the start
of the process to the end of the first step (``first_step_after_start`` of its
``summary.json``: the interpreter, the imports, the scene's set-up and the compiles),
``first_step_time`` (wall seconds from the start of the time loop's set-up to the end of
the first step: compile or load included, imports and the scene's set-up before the loop
excluded), the process's wall and CPU seconds (user + system, all threads, and the helper
process that compiles aside on two cores: the figure that survives a loaded
machine), the functions numba compiled in the run's own process and their wall seconds
(``solver.numba_compiles``; not the helper's), and the 1-minute load average.
``--other PATH`` runs the same measurements with the package of another checkout (its
``PYTHONPATH``) in turn with this one (A B A B ...), so that the ratio of the two holds
while the machine's load drifts.

``--list``: one more cold process per thread count, in which numba's event API times
every compile (:func:`_compile_listing`): function, argument types, inclusive and
exclusive (callees compiled while typing it taken out) CPU seconds.  The kernels of the
explicit scheme are compiled lazily, only what the run's step driver calls
(:func:`fem_rmpm.schemes.explicit.kernels.advance.step_drivers`): the drivers and the
stress pass are specialised on the model of the points, F-bar, the basis and the model
path (block or point update), so a Q4 run without F-bar compiles no F-bar pass, no uGIMP
basis and, with von Mises' block update, no per-point model update.  The listing is of
the run's process only: on two cores a helper process compiles the stress pass, and on
two threads then the two-thread driver, while the run steps on the serial driver
(:mod:`fem_rmpm.schemes.explicit.cold_start`); ``--one-process`` lists a run pinned to one
core, where no helper starts (every compile in the run's process).
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
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
T_END = 0.05


def first_step(tree: Path, cache: str, threads: int) -> dict:
    """One fresh ``fem-rmpm run`` of the embedded reference slope with the package of
    ``tree`` and numba's cache in ``cache``: first step (s), process wall and CPU (s),
    numba's compiles and the load average."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=str(tree))
    with tempfile.TemporaryDirectory() as out:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "fem_rmpm.cli", "run", "--set",
                        f"solver.threads={threads}", "--set", f"solver.t_end={T_END}",
                        "--out", out], env=env, capture_output=True, text=True, check=True,
                       cwd=out)         # (not the caller's directory: its package would win)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        solver = json.loads((Path(out) / "summary.json").read_text())["solver"]
    compiles = solver.get("numba_compiles") or {}
    return {"after_start_s": solver.get("first_step_after_start"),
            "first_step_s": solver["first_step_time"], "wall_s": wall,
            "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
            "functions": compiles.get("functions"), "compile_s": compiles.get("seconds"),
            "load": os.getloadavg()[0]}


def cold_and_warm(tree: Path, threads: int) -> dict:
    """:func:`first_step` with a fresh cache directory, then again with it filled."""
    with tempfile.TemporaryDirectory() as cache:
        return {"cold": first_step(tree, cache, threads), "warm": first_step(tree, cache, threads)}


def _line(label: str, threads: int, r: dict) -> str:
    def one(d):
        start = d.get("after_start_s")
        since = f"{start:.2f} s after the start, " if start is not None else ""
        return (f"first step {since}{d['first_step_s']:.2f} s after the loop's set-up, "
                f"process wall {d['wall_s']:.1f} s, CPU {d['cpu_s']:.1f} s, {d['functions']} functions compiled "
                f"({d['compile_s'] or 0:.1f} s), load {d['load']:.1f}")
    return (f"{label} threads={threads}: cold: {one(r['cold'])}\n"
            f"{' ' * len(label)} threads={threads}: warm: {one(r['warm'])}")


_LISTING = r"""
import json, sys, time
from numba.core import event
rows, stack = [], []
class Timer(event.Listener):
    def on_start(self, ev):
        stack.append([time.process_time(), 0.0])
    def on_end(self, ev):
        c0, inner = stack.pop()
        d = ev.data["dispatcher"]
        cpu = time.process_time() - c0
        if stack:
            stack[-1][1] += cpu
        rows.append([f"{d.py_func.__module__}.{d.py_func.__qualname__}",
                     str(ev.data["args"])[:90], cpu, cpu - inner])
event.register("numba:compile", Timer())
from fem_rmpm import cli
cli.main(["run", "--set", "solver.threads=" + sys.argv[1], "--set", "solver.t_end=%g",
          "--out", sys.argv[2]])
print("ROWS" + json.dumps(rows))
"""


def _compile_listing(tree: Path, threads: int, one_core: bool = False) -> list:
    """Every numba compile of a cold ``fem-rmpm run`` (fresh process and cache) in the
    run's process (``one_core``: pinned to one core, so all of them):
    ``[function, argument types, inclusive CPU s, exclusive CPU s]``."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    with tempfile.TemporaryDirectory() as tmp:
        env["NUMBA_CACHE_DIR"] = str(Path(tmp) / "cache")
        out = subprocess.run([sys.executable, "-c", _LISTING % T_END, str(threads),
                              str(Path(tmp) / "out")], env=env, capture_output=True,
                             text=True, check=True, cwd=tmp,
                             preexec_fn=_one_core if one_core else None).stdout
    return json.loads(out[out.index("ROWS") + 4:])


def _one_core() -> None:
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=1, help="cold + warm pairs per thread count")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--other", type=Path, help="another checkout, measured in turn with this one")
    ap.add_argument("--list", action="store_true", help="list every function numba compiles")
    ap.add_argument("--one-process", action="store_true",
                    help="--list with the run pinned to one core (no helper process)")
    ap.add_argument("--out", type=Path, help="JSON file of the figures")
    args = ap.parse_args(argv)
    trees = [("this", ROOT)] + ([("other", args.other.resolve())] if args.other else [])
    res: dict = {"t_end": T_END, "rounds": []}
    print(f"load average at start {os.getloadavg()[0]:.2f}; cores {os.cpu_count()}", flush=True)
    for _ in range(args.rounds):
        for threads in args.threads:
            for label, tree in trees:          # A B A B: the ratio survives a drifting load
                r = cold_and_warm(tree, threads)
                res["rounds"].append({"tree": label, "threads": threads, **r})
                print(_line(label, threads, r), flush=True)
    if args.list:
        res["compiles"] = {}
        for threads in args.threads:
            rows = _compile_listing(ROOT, threads, args.one_process)
            res["compiles"][threads] = rows
            total = sum(r[3] for r in rows)
            print(f"numba compiles of a cold run on {threads} thread(s): {len(rows)} "
                  f"functions, {total:.1f} s CPU (exclusive of callees, largest first):")
            for name, sig, incl, excl in sorted(rows, key=lambda r: -r[3]):
                if excl >= 0.05:
                    print(f"  {excl:6.2f} {incl:6.2f}  {name}")
    print(f"load average at end {os.getloadavg()[0]:.2f}", flush=True)
    if args.out:
        args.out.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
