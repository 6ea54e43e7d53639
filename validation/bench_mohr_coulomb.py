"""Explicit cost per point-step of Mohr–Coulomb beside von Mises.

The reference geometry run explicitly for ``--t-end`` seconds, once as
meshes/slope_reference.toml (von Mises clay, case (i)) and once as meshes/slope_drained.toml
(the same geometry and mesh, 18 260 points, Mohr–Coulomb c' 5 -> 1 kPa, phi' 22 -> 18 deg),
interleaved ``--repeats`` times in one process, one numba thread; CPU time
(``time.process_time``) per point-step of the whole run (the model's return mapping plus
everything else in a step), after a warm-up run of each (compilation). A CPU-time A/B, valid
under load; say what the load was.

    nice python validation/bench_mohr_coulomb.py [--repeats 3] [--t-end 1.0]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numba

from fem_rmpm import api
from fem_rmpm.scene import load_scene, scene_from_dict, scene_to_dict
from fem_rmpm.schemes.explicit.loop import run_explicit

MESHES = Path(__file__).resolve().parents[1] / "meshes"
SOILS = ("von_mises_softening", "mohr_coulomb_softening")


def scene(model: str, t_end: float):
    name = {"von_mises_softening": "slope_reference", "mohr_coulomb_softening": "slope_drained"}
    data = scene_to_dict(load_scene(MESHES / f"{name[model]}.toml"))
    data.pop("random_field", None)
    data["solver"].update(t_end=t_end, output_interval=t_end)
    data["output"] = {"vtk": False, "png": False}
    return scene_from_dict(data, f"{model}.toml")


def one(sc) -> tuple[float, int, float]:
    grid, pts = api.prepare(sc)
    c0 = time.process_time()
    rec = run_explicit(sc, grid, pts, progress=False)
    cpu = time.process_time() - c0
    return cpu, rec.steps * pts.n, float((pts.plastic_shear_strain > 0).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=1.0)
    a = ap.parse_args()
    numba.set_num_threads(1)
    scenes = {m: scene(m, a.t_end) for m in SOILS}
    for m in SOILS:
        one(scene(m, 0.05))                      # warm-up: compile
    res = {m: [] for m in SOILS}
    for r in range(a.repeats):
        for m, sc in scenes.items():
            cpu, ps, gp = one(sc)
            res[m].append(cpu / ps * 1e9)
            print(f"repeat {r} {m}: {cpu:.2f} s CPU, {ps} point-steps, "
                  f"{cpu / ps * 1e9:.0f} ns per point-step, plastic fraction {gp:.2f}, "
                  f"load {os.getloadavg()[0]:.1f}", flush=True)
    for m, v in res.items():
        print(f"{m}: median {sorted(v)[len(v) // 2]:.0f} ns per point-step over {len(v)}")


if __name__ == "__main__":
    main()
