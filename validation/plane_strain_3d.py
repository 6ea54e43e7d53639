"""Plane-strain limit of the three-dimensional scheme: the reference slope extruded 2 m
with rollers on both strike faces (``meshes/slope_extruded_3d.toml``, von Mises softening,
0.5 m hexahedra) against the plane-strain case (i) (``meshes/slope_reference.toml``) on the
same 0.5 m cells.  Plain script:

    nice python validation/plane_strain_3d.py            # both runs to rest (~10 CPU-min)
    python validation/plane_strain_3d.py --t-end 10      # shorter

Both runs stop at rest (the scenes' at-rest test) or at ``--t-end`` (default 80 s, past
the rest of both: the plane-strain run rests at ~35 s, the slab later).  The measures of
both exclude frozen and stray points by the same rule
(:mod:`fem_rmpm.measures.deposit`, :mod:`fem_rmpm.measures.deposit3d`).

Compared: run-out, retrogression (3-D: the largest over the strike slices, and the mean)
and the sliding area (3-D: sliding volume / strike length, m2/m); the criterion is 5 %
relative difference.  Prints the table (Markdown) and writes
``validation/out/plane_strain_3d.json``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from fem_rmpm import api
from fem_rmpm.scene import with_values

ROOT = Path(__file__).resolve().parents[1]
TOLERANCE = 0.05


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--t-end", type=float, default=80.0, help="simulated time, s")
    a = ap.parse_args(argv)
    two = with_values(api.load_scene(ROOT / "meshes" / "slope_reference.toml"),
                          {"grid.cell": 0.5, "solver.threads": 1, "solver.t_end": a.t_end})
    three = with_values(api.load_scene(ROOT / "meshes" / "slope_extruded_3d.toml"),
                            {"solver.t_end": a.t_end})
    rows, runs = [], {}
    for name, scene in (("2-D", two), ("3-D", three)):
        c0 = time.process_time()
        res = api.run(scene)
        runs[name] = {"measures": {k: v for k, v in res.measures.items()
                                   if isinstance(v, (int, float, bool)) or v is None},
                      "steps": res.record.steps, "points": res.particles.n,
                      "time": res.record.time, "stop_reason": res.record.stop_reason,
                      "cpu_s": time.process_time() - c0}
        m = res.measures
        print(f"{name}: {res.particles.n} points, {res.record.steps} steps to "
              f"t = {res.record.time:.2f} s ({res.record.stop_reason}), "
              f"CPU {runs[name]['cpu_s']:.1f} s; excluded: {m['excluded_frozen_points']} "
              f"frozen, {m['excluded_stray_points']} stray points", flush=True)
    m2, m3 = runs["2-D"]["measures"], runs["3-D"]["measures"]
    ok = True
    print("\n| measure | 2-D (0.5 m) | 3-D max over strike | 3-D mean | difference |")
    print("|---|---|---|---|---|")
    for key, unit in (("runout_distance", "m"), ("retrogression_distance", "m"),
                      ("sliding_area", "m2/m")):
        ref, got = m2[key], m3[key]
        mean = m3.get(f"{key}_mean", got)
        diff = abs(got - ref) / max(abs(ref), 1e-12)
        ok &= diff <= TOLERANCE
        rows.append({"measure": key, "2d": ref, "3d": got, "3d_mean": mean, "rel_diff": diff})
        print(f"| {key} ({unit}) | {ref:.3f} | {got:.3f} | {mean:.3f} | {100 * diff:.2f} % |")
    print(f"\nwithin {100 * TOLERANCE:g} %: {'yes' if ok else 'NO'}")
    out = ROOT / "validation" / "out"
    out.mkdir(exist_ok=True)
    (out / "plane_strain_3d.json").write_text(json.dumps({"rows": rows, "runs": runs,
                                                          "within": ok}, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
