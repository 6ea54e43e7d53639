"""Cost of the strength-reduction factor of safety beside the MPM run.

For one scene (default: the reference slope, case (i)), interleaved in one process and
repeated: the FS with strength continuation (the default search), the FS with gravity
applied anew at every trial (``continuation = False``, the plain search) and the
explicit MPM run of the same realization (no output files).  CPU time is
``time.process_time`` of this process (one numba thread, as a campaign worker), so the
figures compare on a loaded machine; wall times are printed with the load average.

    nice python validation/fs_cost.py [--scene meshes/slope_reference.toml] [--repeats 2]

Writes ``validation/out/fs_cost.json``.

``--risk N``: realizations 0..N-1 of a case of the risk slope (meshes/slope_risk.toml,
``--case xi=12``, seeds from the campaign seed as a campaign draws them), each: the FS
(default search) and the MPM run stopped once decided (as a campaign's realization with
index >= runs_to_rest), both in CPU seconds of this process on one numba thread.  One
JSON line per realization is printed and appended to
``validation/out/fs_cost_risk_<label>.jsonl``; ``--compare OTHER.jsonl`` prints, per seed,
the relative FS difference to another checkout's lines and the largest one.  It uses only
``api``, the campaign's seeds and ``factor_of_safety``, so another checkout runs it too:
``PYTHONPATH=/path/to/other python validation/fs_cost.py --risk 10 --label other``.

``--risk N --other PATH``: the same realizations with the FS of another checkout (at
PATH, e.g. an unpacked older commit) computed in a second process, one realization at a
time and in alternating order (other, this, this, other, ...) after one warm-up solve in
each process, so both see the same machine load; each FS's CPU time is that process's
own.  Prints the table: FS of both, their difference, both CPU times, the decided MPM
run's CPU and the ratio of this FS's CPU to it.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
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


def risk_rows(case: str, n: int, label: str) -> list[dict]:
    """FS and decided MPM run of realizations 0..n-1 of ``case`` of the risk slope."""
    from fem_rmpm.campaign.cases import parse_case, realization_seed
    from fem_rmpm.campaign.decide import FailureWatch, failure_threshold
    base = api.load_scene(str(ROOT / "meshes" / "slope_risk.toml"))
    scene = parse_case(case, base).scene
    rows = []
    dest = ROOT / "validation" / "out"
    dest.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        seed = realization_seed(scene.montecarlo.seed, i)
        res, cpu_fs, wall_fs = timed(lambda: _fs_seed(scene, seed))
        watch = FailureWatch(scene.montecarlo.failure_displacement,
                             failure_threshold(scene), stop=True)
        run, cpu_mpm, wall_mpm = timed(lambda: api.run(
            scene, out=None, seed=seed, progress=False, vtk=False, figures=False,
            stop_when=watch))
        row = {"label": label, "case": case, "index": i, "seed": seed, "fs": res.fs,
               "text": res.text, "bracket": list(res.bracket),
               "static_solves": res.static_solves,
               "newton_iterations": sum(t.iterations for t in res.trials),
               "cpu_fs": cpu_fs, "wall_fs": wall_fs, "cpu_mpm_decided": cpu_mpm,
               "wall_mpm_decided": wall_mpm, "mpm_stop": run.summary["stop_reason"],
               "load": os.getloadavg()[0]}
        rows.append(row)
        print(json.dumps(row), flush=True)
        with open(dest / f"fs_cost_risk_{label}.jsonl", "a") as fh:
            fh.write(json.dumps(row) + "\n")
    return rows


#: the other checkout's FS, one realization per line of stdin (only api, the campaign's
#: seeds and factor_of_safety: any checkout since the risk slope runs it)
_OTHER = r"""
import json, sys, time
import numba
numba.set_num_threads(1)
from fem_rmpm import api
from fem_rmpm.campaign.cases import parse_case, realization_seed
from fem_rmpm.schemes.implicit.strength_reduction import FSOptions, factor_of_safety
scene = parse_case(sys.argv[2], api.load_scene(sys.argv[1])).scene
for line in sys.stdin:
    i = int(line)
    seed = realization_seed(scene.montecarlo.seed, i)
    c0 = time.process_time()
    grid, pts = api.prepare(scene, seed)
    res = factor_of_safety(scene, seed=seed, options=FSOptions(), grid=grid, pts=pts)
    print(json.dumps({"index": i, "fs": res.fs, "cpu_fs": time.process_time() - c0,
                      "newton_iterations": sum(t.iterations for t in res.trials)}), flush=True)
"""


def interleaved_rows(case: str, n: int, label: str, other: Path) -> list[dict]:
    """FS of realizations 0..n-1 by this checkout and by ``other`` (a second process, one
    realization at a time, in alternating order), and this checkout's decided MPM run."""
    from fem_rmpm.campaign.cases import parse_case, realization_seed
    path = str(ROOT / "meshes" / "slope_risk.toml")
    scene = parse_case(case, api.load_scene(path)).scene
    env = dict(os.environ, PYTHONPATH=str(other))
    child = subprocess.Popen([sys.executable, "-c", _OTHER, path, case], env=env, text=True,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, cwd=str(other))

    def theirs(i):
        child.stdin.write(f"{i}\n")
        child.stdin.flush()
        return json.loads(child.stdout.readline())

    theirs(0)                                     # warm-up: numba's cache, the first solve
    _fs_seed(scene, realization_seed(scene.montecarlo.seed, 0))
    _decided_run(scene, realization_seed(scene.montecarlo.seed, 0))   # and the MPM's
    rows, dest = [], ROOT / "validation" / "out"
    dest.mkdir(parents=True, exist_ok=True)
    try:
        for i in range(n):
            seed = realization_seed(scene.montecarlo.seed, i)
            if i % 2 == 0:
                o = theirs(i)
            res, cpu_fs, _ = timed(lambda: _fs_seed(scene, seed))
            if i % 2 == 1:
                o = theirs(i)
            _, cpu_mpm, _ = timed(lambda: _decided_run(scene, seed))
            row = {"label": label, "case": case, "index": i, "seed": seed, "fs": res.fs,
                   "fs_other": o["fs"], "cpu_fs": cpu_fs, "cpu_fs_other": o["cpu_fs"],
                   "newton_iterations": sum(t.iterations for t in res.trials),
                   "newton_iterations_other": o["newton_iterations"],
                   "cpu_mpm_decided": cpu_mpm, "load": os.getloadavg()[0]}
            rows.append(row)
            print(json.dumps(row), flush=True)
            with open(dest / f"fs_cost_interleaved_{label}.jsonl", "a") as fh:
                fh.write(json.dumps(row) + "\n")
    finally:
        child.stdin.close()
        child.wait()
    return rows


def print_table(rows: list[dict]) -> None:
    """Markdown table of :func:`interleaved_rows` and its summary line."""
    print("| realization | FS other | FS this | difference | CPU FS other (s) | CPU FS this (s) "
          "| CPU decided MPM run (s) | FS this / MPM |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        d = r["fs"] / r["fs_other"] - 1.0
        print(f"| {r['index']} | {r['fs_other']:.4f} | {r['fs']:.4f} | {100 * d:+.2f} % "
              f"| {r['cpu_fs_other']:.2f} | {r['cpu_fs']:.2f} | {r['cpu_mpm_decided']:.2f} "
              f"| {r['cpu_fs'] / r['cpu_mpm_decided']:.2f} |")
    worst = max(abs(r["fs"] / r["fs_other"] - 1.0) for r in rows)
    ratios = sorted(r["cpu_fs"] / r["cpu_mpm_decided"] for r in rows)
    met = sum(x <= 1.0 for x in ratios)
    loads = [r["load"] for r in rows]
    cpu = sum(r["cpu_fs"] for r in rows)
    print(f"largest |FS difference| {100 * worst:.2f} %; FS CPU {cpu:.1f}"
          f" s (other {sum(r['cpu_fs_other'] for r in rows):.1f} s), decided MPM runs "
          f"{sum(r['cpu_mpm_decided'] for r in rows):.1f} s; FS / MPM median "
          f"{ratios[len(ratios) // 2]:.2f} (range {ratios[0]:.2f}-{ratios[-1]:.2f}), at most 1 "
          f"on {met} of {len(rows)}; load average {min(loads):.1f}-{max(loads):.1f}")


def _decided_run(scene, seed):
    """The MPM run of realization ``seed`` stopped once decided (no output files)."""
    from fem_rmpm.campaign.decide import FailureWatch, failure_threshold
    watch = FailureWatch(scene.montecarlo.failure_displacement, failure_threshold(scene),
                         stop=True)
    return api.run(scene, out=None, seed=seed, progress=False, vtk=False, figures=False,
                   stop_when=watch)


def _fs_seed(scene, seed):
    grid, pts = api.prepare(scene, seed)
    return factor_of_safety(scene, seed=seed, options=FSOptions(), grid=grid, pts=pts)


def compare(rows: list[dict], other: Path) -> None:
    """Relative FS difference per seed against another checkout's JSON lines."""
    ref = {}
    for line in other.read_text().splitlines():
        r = json.loads(line)
        ref[r["seed"]] = r
    worst = 0.0
    for r in rows:
        o = ref.get(r["seed"])
        if o is None:
            continue
        d = r["fs"] / o["fs"] - 1.0
        worst = max(worst, abs(d))
        print(f"realization {r['index']}: FS {r['fs']:.4f} vs {o['fs']:.4f} ({100 * d:+.2f} %); "
              f"CPU FS {r['cpu_fs']:.1f} s (was {o['cpu_fs']:.1f} s), decided MPM run "
              f"{r['cpu_mpm_decided']:.1f} s, ratio {r['cpu_fs'] / r['cpu_mpm_decided']:.2f}")
    print(f"largest |FS difference| {100 * worst:.2f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "meshes" / "slope_reference.toml"))
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--no-classic", action="store_true",
                    help="skip the plain search (gravity anew at every trial)")
    ap.add_argument("--risk", type=int, default=0, metavar="N",
                    help="realizations 0..N-1 of the risk slope: FS and decided MPM run")
    ap.add_argument("--case", default="xi=12")
    ap.add_argument("--label", default="this")
    ap.add_argument("--compare", type=Path, default=None)
    ap.add_argument("--other", type=Path, default=None, metavar="PATH",
                    help="--risk: interleave with the FS of the checkout at PATH")
    a = ap.parse_args()
    numba.set_num_threads(1)
    if a.risk and a.other:
        print_table(interleaved_rows(a.case, a.risk, a.label, a.other.resolve()))
        return
    if a.risk:
        rows = risk_rows(a.case, a.risk, a.label)
        if a.compare:
            compare(rows, a.compare)
        return
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
