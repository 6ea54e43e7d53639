"""Run-out of case (i) on a frictional floor against the rough floor, and the cost of contact.

Case (i) (``meshes/slope_reference.toml``, homogeneous) is run with its run-out floor as it is
(``interface = "rough"``: the floor's nodes fixed, no slip) and with a frictional floor
(``meshes/slope_reference_frictional.toml``) at the Coulomb coefficients ``--friction``
(default 0.2, 0.4, 0.6: interface friction angles of 11, 22 and 31 degrees, from a smooth,
wet clay-on-rock contact to one as rough as the clay's own drained friction).  All on one
thread.  Prints one table row per floor from each run's ``summary.json``: run-out,
retrogression, sliding area, time to rest, the frictional dissipation, steps and the CPU
cost per point-step (and its ratio to the rough floor's)::

    python validation/contact_runout.py --out /tmp/contact_runout      # 4 runs, ~5 min
    python validation/contact_runout.py --friction 0.4 --out /tmp/x     # one floor

A run already in ``--out`` (its summary.json complete) is read, not run again.  The cost
ratio is meaningful only on an idle machine (CPU time per point-step is less sensitive to
load than wall time, but not immune: shared caches and frequency).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fem_rmpm import api  # noqa: E402

MEASURES = ("runout_distance", "retrogression_distance", "sliding_area", "time_to_rest")


def scene_for(friction: float | None):
    """Case (i) on one thread: the rough floor (``friction`` None) or the frictional one."""
    name = "slope_reference" if friction is None else "slope_reference_frictional"
    scene = api.load_scene(str(ROOT / "meshes" / f"{name}.toml"))
    scene = api.with_value(scene, "solver.threads", 1)
    if friction is not None:
        scene = api.with_value(scene, "bedrock[0].friction", float(friction))
    return scene


def run_or_read(friction: float | None, out: Path) -> dict:
    """The summary of the run of :func:`scene_for` in ``out`` (run if not there)."""
    path = out / "summary.json"
    if path.exists():
        summary = json.loads(path.read_text())
        if summary.get("status") == "ok":
            return summary
    api.run(scene_for(friction), out, force=True, vtk=False)
    return json.loads(path.read_text())


def row(label: str, s: dict, cost0: float | None) -> str:
    m = s["measures"]
    fd = s.get("friction_dissipation")
    diss = f"{fd[-1][1]:9.1f}" if fd else "        -"
    cost = s["ns_per_particle_step_cpu"]
    ratio = f"{cost / cost0:5.2f}" if cost0 else "    -"
    return (f"{label:>8} | " + " | ".join(f"{m[k]:7.2f}" if m.get(k) is not None else "      -"
                                          for k in MEASURES)
            + f" | {diss} | {s['steps']:6d} | {cost:6.1f} | {ratio}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--friction", type=float, nargs="+", default=[0.2, 0.4, 0.6])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--no-rough", action="store_true", help="skip the rough floor's run")
    args = ap.parse_args(argv)
    runs = ([] if args.no_rough else [("rough", None)]) + [(f"mu={f:g}", f)
                                                           for f in args.friction]
    print("   floor | run-out m | retrog. m | sliding m2 | rest s | friction kJ/m | steps "
          "| ns/pt-step CPU | x rough")
    cost0 = None
    for label, mu in runs:
        s = run_or_read(mu, args.out / label.replace("=", ""))
        if mu is None:
            cost0 = s["ns_per_particle_step_cpu"]
        print(row(label, s, cost0), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
