"""Cost of the pore water in the explicit scheme: CPU ns per point-step of the wet
infinite slope (tests/test_water.py's submerged case, 1536 points, 10 s) with its water,
with the phreatic surface below the grid (the water path, every point dry), and without
a [water] section (the dry path), on one thread.

    python validation/water_cost.py
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))

from fem_rmpm import api  # noqa: E402
from fem_rmpm.scene import with_values  # noqa: E402
from fem_rmpm.schemes.explicit.loop import run_explicit  # noqa: E402
from test_water import _wet_infinite_slope  # noqa: E402


def main() -> None:
    wet = with_values(_wet_infinite_slope(1.1, "submerged"),
                      {"solver.threads": 1, "solver.t_end": 10.0})
    L = wet.grid.size[0]
    cases = {"water (all points below the surface)": wet,
             "water section, surface below the grid": with_values(
                 wet, {"water.phreatic_surface": [[0.0, -10.0], [L, -10.0]]}),
             "no water section (dry path)": dataclasses.replace(wet, water=None)}
    api.run(wet)                                      # compile / load the kernels once
    print("| case | steps | CPU s (time loop) | ns per point-step (CPU, best of 5) |")
    print("|---|---|---|---|")
    for name, scene in cases.items():
        best = None
        for _ in range(5):
            grid, pts = api.prepare(scene)
            t0 = time.process_time()
            rec = run_explicit(scene, grid, pts)
            cpu = time.process_time() - t0
            ns = 1e9 * cpu / (rec.steps * pts.n)
            best = ns if best is None else min(best, ns)
        print(f"| {name} | {rec.steps} | {cpu:.2f} | {best:.0f} |", flush=True)


if __name__ == "__main__":
    main()
