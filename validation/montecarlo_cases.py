"""The four literature cases of the reference slope, side by side.

Wang, Vardon & Hicks (2017) ran the reference slope (meshes/slope_reference.toml) homogeneous and
with a lognormal random field of the undrained strength (COV 0.25, theta_v = 0.5 m) of
anisotropy xi = theta_h / theta_v = 1, 12 and 48, and found the intermediate anisotropy
gave the most disturbed failures (widest spread of run-out and retrogression).  This
script runs those four cases as one campaign (homogeneous: 1 realization, it is
deterministic; each random case: N realizations with the same seeds, i.e. common random
numbers) and writes to ``validation/out/montecarlo_cases/``:

* ``results.csv``, ``summary.json``, ``records/`` — the campaign (resumable: re-running
  the script computes only what is missing);
* ``cases.png`` — final plastic shear strain of one realization per case (the first
  kept one: VTK is kept for realization 0 of each case, ``vtk/<case>/...``);
* ``exceedance.png``, ``histograms.png``, ``convergence.png`` — their distributions.

Documented N: **N = 6 per random case** (19 realizations).  A reference-slope
realization costs ~30-60 s of one core (18 300 points, 20-40 s simulated), so the run
takes ~10-15 min on 2 cores.  With N = 6 the standard error of a probability is at
most sqrt(0.25 / 6) = 0.20 and that of a mean run-out about s / 2.4: enough to see
whether the cases differ by much, not to rank close ones; the literature used
hundreds of realizations per case (raise ``-n`` on a cluster: ``--scheduler``).

Usage::

    python validation/montecarlo_cases.py                    # documented N, 2 local workers
    python validation/montecarlo_cases.py -n 50 --scheduler tcp://host:8786
    python validation/montecarlo_cases.py --scene tests/data/mc_tiny.toml -n 2 --out /tmp/x
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
N_DOCUMENTED = 6


def main(argv=None) -> int:
    from fem_rmpm import api
    from fem_rmpm.campaign import LITERATURE_CASES, run_campaign
    from fem_rmpm.cli import default_scene_path, summary_text
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=str(default_scene_path()),
                   help="scene (default: the embedded reference slope)")
    p.add_argument("-n", type=int, default=N_DOCUMENTED,
                   help=f"realizations per random case (default {N_DOCUMENTED})")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--scheduler", default=None)
    p.add_argument("--keep-vtk", default="1", help="VTK of the first K per case (default 1)")
    p.add_argument("--out", default=str(HERE / "out" / "montecarlo_cases"))
    p.add_argument("--force", action="store_true", help="recompute finished realizations")
    p.add_argument("--quiet", action="store_true")
    a = p.parse_args(argv)
    scene = api.load_scene(a.scene)
    res = run_campaign(scene, a.out, a.n, cases=LITERATURE_CASES, workers=a.workers,
                       scheduler=a.scheduler, keep_vtk=a.keep_vtk, force=a.force,
                       progress=not a.quiet)
    print(summary_text(res))
    print("Figures: " + ", ".join(str(f) for f in res.figures))
    return 3 if res.lost else 0


if __name__ == "__main__":     # required: local Dask workers are spawned processes
    sys.exit(main())
