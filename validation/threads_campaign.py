"""A Monte Carlo campaign on 1 and on 2 threads per realization gives the same
``results.csv``: a realization is a pure function of the scene and its seed, whatever the
number of threads.

Runs ``fem-rmpm mc`` twice on the reference slope with one local worker, ``--set
solver.threads=1`` and ``=2`` (the worker process then has a numba pool of that many
threads), checks that every realization ran on that many threads (its record's
``worker.threads``) and compares the two ``results.csv`` byte for byte (they hold no
timings).

The whole campaign (the scene's 3 realizations of each of its four cases, whole
runs): ``python validation/threads_campaign.py`` (~10 realizations x ~20 s on one thread,
then again on two: ~10-15 CPU-min).  A small check: ``--case xi=12 --t-end 2`` (3
realizations to t = 2 s, ~1 CPU-min).  Exit status 0 when identical, 1 otherwise.
"""
from __future__ import annotations

import argparse
import filecmp
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def campaign(out: Path, threads: int, args) -> float:
    """Run the campaign into ``out``; returns its CPU seconds (the child processes')."""
    cmd = [sys.executable, "-m", "fem_rmpm.cli", "mc", str(ROOT / "meshes" / "slope_reference.toml"),
           "-n", str(args.realizations), "--out", str(out), "--workers", "1", "--quiet",
           "--keep-vtk", "0", "--force", "--set", f"solver.threads={threads}"]
    if args.t_end is not None:
        cmd += ["--set", f"solver.t_end={args.t_end}"]
    for c in args.case or []:
        cmd += ["--case", c]
    t0 = sum(os.times()[2:4])
    subprocess.run(cmd, check=True, cwd=ROOT)
    return sum(os.times()[2:4]) - t0


def threads_used(out: Path) -> list:
    """The numba thread count each realization of the campaign in ``out`` ran on."""
    return [json.loads(p.read_text())["worker"].get("threads")
            for p in sorted((out / "records").rglob("*.json"))]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("runs/threads_campaign"))
    ap.add_argument("-n", "--realizations", type=int, default=3)
    ap.add_argument("--case", action="append", help="as fem-rmpm mc --case (repeatable)")
    ap.add_argument("--t-end", type=float, default=None, help="simulated seconds per run")
    a = ap.parse_args(argv)
    cpu, used = {}, {}
    for th in (1, 2):
        cpu[th] = campaign(a.out / f"threads{th}", th, a)
        used[th] = threads_used(a.out / f"threads{th}")
        print(f"threads = {th}: the realizations ran on {used[th]} threads")
    f1, f2 = a.out / "threads1" / "results.csv", a.out / "threads2" / "results.csv"
    same = filecmp.cmp(f1, f2, shallow=False)
    rows = len(f1.read_text().splitlines()) - 1
    print(f"results.csv {'IDENTICAL' if same else 'DIFFERENT'} on 1 and 2 threads "
          f"({rows} realizations; CPU {cpu[1]:.1f} s / {cpu[2]:.1f} s): {f1} {f2}")
    ran_as_asked = all(u and u == [th] * len(u) for th, u in used.items())
    if not ran_as_asked:
        print("NOT a 1 / 2 thread comparison: a campaign did not run on the threads asked for")
    return 0 if same and ran_as_asked else 1


if __name__ == "__main__":
    raise SystemExit(main())
