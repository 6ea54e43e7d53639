"""Drained infinite slope with water: strength-reduction FS against the closed forms.

Cases on ``meshes/infinite_slope_water.toml`` (b = 30 deg, H = 5 m, c' = 8 kPa,
phi' = 26 deg, gamma = 18, gamma_sat = 20, gamma_w = 9.81 kN/m3): a water table parallel
to the slope at m = 0.5 and 1 with ``"hydrostatic"`` and ``"parallel_seepage"`` pore
pressure, dry (m = 0), and the slope fully submerged below a horizontal free water level.
Closed forms: the scene's header.  Prints a markdown table (FS, closed form, error, CPU s; FS bracketed to 0.5 %)
and writes it as JSON to ``--out``.

    python validation/water_infinite_slope.py [--cases a,b] [--out water_fs.json]
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from fem_rmpm import api
from fem_rmpm.scene import load_scene, with_values

SCENE = Path(__file__).parents[1] / "meshes" / "infinite_slope_water.toml"
B, H, C, PHI, G, GSAT, GW = 30.0, 5.0, 8.0, 26.0, 18.0, 20.0, 9.81


def closed_form(m: float | None, mode: str) -> float:
    """FS of the infinite slope; ``m`` None: fully submerged."""
    b, tphi = math.radians(B), math.tan(math.radians(PHI))
    if m is None:
        return C / ((GSAT - GW) * H * math.sin(b) * math.cos(b)) + tphi / math.tan(b)
    W = ((1 - m) * G + m * GSAT) * H
    if mode == "hydrostatic":
        num = C + (W * math.cos(b) ** 2 - GW * m * H) * tphi
    else:
        num = C + (W - GW * m * H) * math.cos(b) ** 2 * tphi
    return num / (W * math.sin(b) * math.cos(b))


def case_scene(m: float | None, mode: str):
    """The scene of one case: the water table at m H cos(b) in the frame, or (None) a
    horizontal free water level 1 m above the slope's highest point."""
    s = load_scene(SCENE)
    L, t = s.grid.size[0], H * math.cos(math.radians(B))
    b = math.radians(B)
    if m is None:       # true-horizontal level Y = t cos(b) + 1 m (the top corner x = 0
        Y = t * math.cos(b) + 1.0       # is highest): in the frame y = (Y + x sin b) / cos b
        line = [[0.0, Y / math.cos(b)], [L, (Y + L * math.sin(b)) / math.cos(b)]]
    elif m == 0:
        return with_values(s, {"water.phreatic_surface": [[0.0, -1.0], [L, -1.0]]})
    else:
        line = [[0.0, m * t], [L, m * t]]
    return with_values(s, {"water.phreatic_surface": line, "water.pore_pressure": mode})


CASES = {"dry": (0.0, "hydrostatic"), "h0.5": (0.5, "hydrostatic"), "h1": (1.0, "hydrostatic"),
         "p0.5": (0.5, "parallel_seepage"), "p1": (1.0, "parallel_seepage"),
         "submerged": (None, "hydrostatic")}


def run_case(name: str, tolerance: float = 0.005) -> dict:
    m, mode = CASES[name]
    scene = case_scene(m, mode)
    t0 = time.process_time()
    res = api.factor_of_safety(scene, tolerance=tolerance)
    ref = closed_form(m, mode)
    return {"case": name, "m": m, "pore_pressure": mode, "fs": res.fs, "closed_form": ref,
            "error": res.fs / ref - 1, "cpu_s": time.process_time() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--out", default=None)
    ap.add_argument("--tolerance", type=float, default=0.005, help="FS bracket width")
    args = ap.parse_args()
    rows = []
    print("| case | m | pore pressure | FS | closed form | error | CPU s |")
    print("|---|---|---|---|---|---|---|")
    for name in args.cases.split(","):
        r = run_case(name, args.tolerance)
        rows.append(r)
        print(f"| {r['case']} | {r['m']} | {r['pore_pressure']} | {r['fs']:.4f} | "
              f"{r['closed_form']:.4f} | {100 * r['error']:+.2f} % | {r['cpu_s']:.0f} |",
              flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
