"""A campaign through SLURM: scaling (1 vs 2 workers) and the --dry-run estimate against
the measured CPU time.

Needs a running SLURM (``bash .ci/slurm-start.sh`` as root starts a single-node one) and
runs ``fem-rmpm mc`` as a user would, in subprocesses, writing to ``--out``
(default ``validation/out/slurm_campaign/``):

``scaling``  the same campaign (``--case xi=12``, N realizations of the reference slope)
             through ``--cluster slurm`` with 1 and with 2 workers; prints the whole-command
             wall time and the realizations per hour from each run's own ``summary.json``
             and checks that the two ``results.csv`` are identical.
``estimate`` ``--dry-run`` of the reference slope main job (``fem-rmpm mc`` with the
             embedded default: 10 realizations of the four literature cases), then the
             campaign itself (local cluster, or ``--cluster slurm``); prints the estimated
             core-hours against the measured CPU time: the sum of the records' CPU time
             (the workers' realizations) and the whole command's CPU (client, scheduler,
             worker starts; its children's rusage), with the ratios.

The load average of the machine is printed before and after each run: on a shared
machine the CPU time per point-step grows with the load.

Usage::

    python validation/slurm_campaign.py scaling -n 6
    python validation/slurm_campaign.py estimate [--cluster slurm]
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
YAML = """jobqueue:
  slurm:
    interface: lo
    walltime: "02:00:00"
"""


def _env(out: Path) -> dict:
    cfg = out / "dask-config"
    cfg.mkdir(parents=True, exist_ok=True)
    (cfg / "jobqueue.yaml").write_text(YAML)
    env = dict(os.environ, DASK_CONFIG=str(cfg))
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def _mc(args: list[str], out: Path) -> tuple[float, float, str]:
    """(wall s, CPU s of the command and its children, stdout) of one ``fem-rmpm mc``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "fem_rmpm.cli", "mc", *args, "--quiet"],
                         env=_env(out), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode != 0:
        raise SystemExit(f"fem-rmpm mc {' '.join(args)} failed: {res.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, res.stdout


def _records_cpu(out: Path) -> float:
    return sum(json.loads(p.read_text())["cpu_time"] for p in (out / "records").rglob("*.json"))


def _slurm_cpu_note() -> str:
    """Worker jobs are children of slurmd, not of this script: their CPU is in the
    records only."""
    return "(with --cluster slurm the workers are slurmd's children: command CPU = client only)"


def scaling(args) -> int:
    out = Path(args.out) / "scaling"
    rows, tables = [], []
    for k in (1, 2):
        d = out / f"workers{k}"
        shutil.rmtree(d, ignore_errors=True)
        load0 = _load()
        wall, _, _ = _mc(["--case", "xi=12", "-n", str(args.n), "--out", str(d),
                          "--cluster", "slurm", "--workers", str(k), "--keep-vtk", "0"], out)
        s = json.loads((d / "summary.json").read_text())["this_run"]
        rows.append((k, wall, s["wall_time"], s["compute_wall_time"],
                     s["realizations_per_hour"], load0, _load()))
        tables.append((d / "results.csv").read_bytes())
    print(f"{args.n} realizations of the reference slope, xi = 12, through SLURM:")
    print("| workers | command wall (s) | campaign wall, summary.json (s) | compute (s) "
          "| realizations per hour | load before / after |")
    print("|---|---|---|---|---|---|")
    for k, wall, w, c, rph, l0, l1 in rows:
        print(f"| {k} | {wall:.1f} | {w:.1f} | {c:.1f} | {rph:.0f} | {l0} / {l1} |")
    print(f"speed-up {rows[0][2] / rows[1][2]:.2f} (campaign wall time); tables identical: "
          f"{tables[0] == tables[1]}")
    return 0


def estimate(args) -> int:
    out = Path(args.out) / "estimate"
    shutil.rmtree(out, ignore_errors=True)
    cluster = ["--cluster", args.cluster] if args.cluster != "local" else []
    base = ["--out", str(out / "main")] + cluster + (["--workers", "2"])
    load0 = _load()
    _, _, text = _mc(base + ["--dry-run"], out)
    print(text)
    assert not (out / "main").exists(), "--dry-run wrote the campaign directory"
    line = next(s for s in text.splitlines() if "core-hours:" in s)
    est = float(line.split("(")[1].split(" s CPU")[0])
    load1 = _load()
    wall, cpu, _ = _mc(base, out)
    rec = _records_cpu(out / "main")
    print(f"load before the dry run {load0}; before the campaign {load1}; after {_load()}")
    print(f"estimate {est:.0f} s CPU; measured: records {rec:.1f} s (ratio measured/estimate "
          f"{rec / est:.2f}); whole command {cpu:.1f} s (ratio {cpu / est:.2f})"
          + (f" {_slurm_cpu_note()}" if cluster else "") + f"; wall {wall:.0f} s")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default=str(HERE / "out" / "slurm_campaign"))
    sub = p.add_subparsers(dest="what", required=True)
    s = sub.add_parser("scaling")
    s.add_argument("-n", type=int, default=6)
    s.set_defaults(func=scaling)
    e = sub.add_parser("estimate")
    e.add_argument("--cluster", default="local")
    e.set_defaults(func=estimate)
    a = p.parse_args(argv)
    return a.func(a)


if __name__ == "__main__":
    sys.exit(main())
