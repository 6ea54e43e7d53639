"""Case (i) with the compiled kernels against the numpy reference, and the chaos floor:
how close the compiled kernels come to the single-thread numpy reference on the measures
of case (i), against the target of 1e-10 relative.

The numpy path (``[solver] kernel = "numpy"``) takes about an hour for the whole run on
the shared 2-core machine, and case (i) is a collapsing slope: round-off differences
grow.  So this script measures two affordable things:

1. **prefix** — numba and numpy from the same initial state to ``--prefix`` seconds of
   simulated time (default 2 s, ~480 steps: ~3-5 CPU-min for numpy); every 0.25 s the
   largest relative difference of positions (divided by the largest displacement),
   stresses (divided by the largest |stress|) and point velocities, and the measures at
   the end of the prefix;
2. **chaos floor** — the whole run with numba twice: as given, and with one point's
   initial position moved by one ulp (``np.nextafter``); the measures of the two runs
   (relative differences).  If a 1-ulp change of the input moves the measures by more
   than 1e-10, no implementation can reproduce the reference to 1e-10 on the whole run.

3. ``--whole-numpy`` — the whole run with the numpy reference (~10-20 CPU-min on the
   shared machine, 50 ms per step) and its measures against the numba run's.

Usage: ``python validation/explicit_reference.py [--prefix 2.0] [--skip-floor]
[--skip-prefix] [--whole-numpy] [--out FILE.json]``.  Prints one JSON document.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fem_rmpm import api  # noqa: E402
from fem_rmpm.scene import load_scene, with_values  # noqa: E402

SCENE = ROOT / "meshes" / "slope_reference.toml"
MEASURES = ("runout_distance", "retrogression_distance", "sliding_area", "sliding_area_early",
            "max_displacement", "time_to_rest", "slip_surface_height", "intact_blocks")


def _scene(**values):
    return with_values(load_scene(SCENE), {"solver.threads": 1, **values})


def _run_with_snapshots(scene, pts=None):
    """One run (api.prepare + run_explicit); state copies every output interval."""
    from fem_rmpm.schemes.explicit.loop import run_explicit
    grid, p = api.prepare(scene)
    if pts is not None:
        pts(p)
    snaps = []
    c0 = time.process_time()
    rec = run_explicit(scene, grid, p, on_output=lambda t, q: snaps.append(
        (t, q.x.copy(), q.stress.copy(), q.velocity.copy())))
    return grid, p, rec, snaps, time.process_time() - c0


def _rel(a, b, scale):
    return float(np.max(np.abs(a - b)) / scale) if scale > 0 else 0.0


def prefix(t_end: float) -> dict:
    """numba vs numpy to ``t_end`` s; relative differences every 0.25 s."""
    out = {}
    runs = {k: _run_with_snapshots(_scene(**{"solver.t_end": t_end, "solver.kernel": k,
                                            "solver.output_interval": 0.25}))
            for k in ("numba", "numpy")}
    (_, pa, ra, sa, ca), (_, pb, rb, sb, cb) = runs["numba"], runs["numpy"]
    x0 = pa.x0
    rows = []
    for (ta, xa, qa, va), (tb, xb, qb, vb) in zip(sa, sb):
        disp = float(np.max(np.linalg.norm(xb - x0, axis=1)))
        rows.append({"t_numba": ta, "t_numpy": tb, "max_displacement_m": disp,
                     "x_rel_to_max_displacement": _rel(xa, xb, disp),
                     "stress_rel_to_max_stress": _rel(qa, qb, float(np.max(np.abs(qb)))),
                     "velocity_rel_to_max_speed": _rel(va, vb, float(np.max(np.abs(vb))))})
    out["snapshots"] = rows
    out["steps"] = {"numba": ra.steps, "numpy": rb.steps}
    out["cpu_s"] = {"numba": ca, "numpy": cb}
    from fem_rmpm.measures.deposit import compute_measures
    sc = _scene()
    ms = [compute_measures(p, sc.scene.frame_angle_deg, sc.montecarlo.failure_displacement,
                           g.cell, None) for g, p, *_ in (runs["numba"], runs["numpy"])]
    out["measures_at_prefix"] = {k: {"numba": ms[0].get(k), "numpy": ms[1].get(k)}
                                 for k in MEASURES if k in ms[0]}
    return out


def _whole(perturb: bool, kernel: str = "numba") -> dict:
    def nudge(p):
        p.x[0, 0] = np.nextafter(p.x[0, 0], np.inf)
    res = api.run(_scene(**{"solver.kernel": kernel})) if not perturb else None
    if perturb:
        import fem_rmpm.api as A
        orig = A.prepare

        def prepare(*a, **k):
            grid, p = orig(*a, **k)
            nudge(p)
            return grid, p
        A.prepare = prepare
        try:
            res = api.run(_scene())
        finally:
            A.prepare = orig
    m = res.measures
    return {"steps": res.record.steps, "cpu_s": res.record.cpu_time,
            **{k: m.get(k) for k in MEASURES}}


def _compare(a: dict, b: dict) -> dict:
    return {k: (abs(a[k] - b[k]) / abs(a[k]) if a[k] not in (None, 0) and b[k] is not None
                else None) for k in MEASURES}


def floor() -> dict:
    """The whole run twice, the second with point 0's initial x one ulp larger."""
    a, b = _whole(False), _whole(True)
    return {"as_given": a, "one_ulp": b, "relative_difference": _compare(a, b)}


def whole_numpy() -> dict:
    """The whole run with numba and with the numpy reference (~10-20 CPU-min): measures."""
    a, b = _whole(False), _whole(False, "numpy")
    return {"numba": a, "numpy": b, "relative_difference": _compare(a, b)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prefix", type=float, default=2.0, help="simulated seconds (default 2)")
    ap.add_argument("--skip-floor", action="store_true", help="prefix comparison only")
    ap.add_argument("--skip-prefix", action="store_true", help="chaos floor only")
    ap.add_argument("--whole-numpy", action="store_true",
                    help="also the whole run with the numpy reference (~10-20 CPU-min)")
    ap.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    a = ap.parse_args(argv)
    doc = {}
    if not a.skip_prefix:
        doc["prefix"] = prefix(a.prefix)
    if not a.skip_floor:
        doc["chaos_floor"] = floor()
    if a.whole_numpy:
        doc["whole_run_numpy"] = whole_numpy()
    text = json.dumps(doc, indent=1)
    print(text)
    if a.out:
        a.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
