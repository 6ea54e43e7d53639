"""Re-measure a run directory from its VTK with the deposit measures (fem_rmpm.measures.deposit).

    python validation/remeasure_vtk.py RUN_DIR [RUN_DIR ...]

Reads ``particles.pvd`` (first and last entry) and ``summary.json`` (scene: frame angle,
grid, failure threshold) and prints the measures on the deposit beside the ones the
summary holds (which may come from another version of a measure's definition).  Point
data used: coordinates, ``displacement`` (x0 = x - displacement), ``volume``, ``active``.
"""
from __future__ import annotations

import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from types import SimpleNamespace

import meshio
import numpy as np

from fem_rmpm.measures.deposit import compute_measures


def remeasure(run: Path) -> tuple[dict, dict]:
    summary = json.loads((run / "summary.json").read_text())
    sc = summary["scene"]
    files = [d.get("file") for d in ET.parse(run / "particles.pvd").getroot().iter("DataSet")]
    first, last = meshio.read(run / files[0]), meshio.read(run / files[-1])
    x = np.asarray(last.points[:, :2])
    pts = SimpleNamespace(x=x, x0=x - np.asarray(last.point_data["displacement"][:, :2]),
                          volume=np.asarray(last.point_data["volume"]),
                          volume0=np.asarray(first.point_data["volume"]),
                          active=np.asarray(last.point_data["active"]).astype(bool))
    grid = SimpleNamespace(origin=np.array(sc["grid"]["origin"], float),
                           cell=np.array(sc["grid"]["cell"], float))
    m = compute_measures(pts, sc["scene"]["frame_angle_deg"],
                         sc["montecarlo"]["failure_displacement"], grid.cell, None, grid=None)
    return m, summary["measures"]


def main(argv: list[str]) -> int:
    keys = ("runout_distance", "retrogression_distance", "sliding_area", "max_displacement",
            "excluded_frozen_points", "excluded_stray_points", "excluded_stray_volume")
    for d in argv:
        m, old = remeasure(Path(d))
        print(d)
        for k in keys:
            print(f"  {k:24s} deposit {m[k]:10.3f}   summary {old.get(k, float('nan'))}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
