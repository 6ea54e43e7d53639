"""Rigid strip footing on von Mises soil: limit load against Prandtl, with and without F-bar.

Reference: Prandtl 1920 (and Hill 1950 for the rough footing): the limit pressure of a
strip footing on weightless phi = 0 soil is (2 + pi) c = 5.14 c, rough or smooth.  The
scene is meshes/footing.toml (half model, B = 2 m, c = 10 kPa, E = 3000 kPa, nu = 0.49,
perfectly plastic, rough, displacement controlled; the pressure is the reaction of the
prescribed nodes over B/2).

Prints and charts:

* small-strain load steps (the scene's own setting), cell size B/8 ... B/64, with the
  F-bar remedy (de Souza Neto et al. 1996) and without it: q / c at 3 % of B, whether the
  curve has levelled off, Newton iterations, wall time; the Richardson extrapolation of
  the F-bar sequence to h -> 0;
* a smooth footing and a larger domain (4 m x 2.5 m) at B/32 (should not matter);
* large-deformation (updated Lagrangian) load steps at B/16 and B/32 up to a settlement
  of 0.7 of a cell (the prescribed nodes stay on the grid while the soil moves below
  them, so the footing keeps contact only that far; points heaving into the empty row
  beside the footing are a known hazard of implicit MPM).

Writes ``validation/out/footing.png`` and ``footing.json``.
Run: ``nice python validation/footing.py`` (about a minute; ``--quick`` skips B/64).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.implicit import run_implicit

HERE = Path(__file__).parent
OUT = HERE / "out"
PRANDTL = 2.0 + math.pi
B, C = 2.0, 10.0


def run(h: float, fbar: bool = True, kind: str = "geostatic", components: str = "xy",
        W: float = 3.0, D: float = 2.0, settlement: float = 0.06, steps: int = 12) -> dict:
    """One footing run; returns the load-settlement curve (q / c against settlement / B)."""
    scene = with_values(load_scene(HERE.parent / "meshes" / "footing.toml"), {
        "grid.cell": h, "grid.size": [W, D + h], "soil.polygon": [[0, 0], [W, 0], [W, D], [0, D]],
        "prescribed.polygon": [[-0.01, D - 0.01], [B / 2 + 0.01, D - 0.01],
                               [B / 2 + 0.01, D + 0.01], [-0.01, D + 0.01]],
        "prescribed.displacement": [0.0, -settlement], "prescribed.components": components,
        "solver.gravity_phase": kind, "solver.fbar": fbar, "solver.load_steps": steps})
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    t0 = time.perf_counter()
    status = "ok"
    try:
        rec = run_implicit(scene, grid, pts)
    except SimulationError as exc:
        rec = exc.record
        status = "failed: " + str(exc).split(";")[0][:90]
    st = rec.solver["steps"]
    q = np.array([-s["reactions"]["footing"][1] / (B / 2) / C for s in st])
    d = np.array([s["load_factor"] * settlement / B for s in st])
    return {"h": h, "h_over_B": h / B, "fbar": fbar, "kind": kind, "components": components,
            "domain": [W, D], "points": pts.n, "settlement_over_B": d.tolist(),
            "q_over_c": q.tolist(), "q_end": float(q[-1]) if len(q) else float("nan"),
            "q_max": float(q.max()) if len(q) else float("nan"),
            "levelled": bool(len(q) > 1 and abs(q[-1] / q[-2] - 1) < 2e-3),
            "iterations": int(sum(s["iterations"] for s in st)), "status": status,
            "wall_s": time.perf_counter() - t0}


def main(argv=None):
    global OUT
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="skip B/64")
    ap.add_argument("--out", default=str(OUT), help="output directory (default validation/out)")
    args = ap.parse_args(argv)
    OUT = Path(args.out)
    OUT.mkdir(parents=True, exist_ok=True)
    rows = []

    def show(r, label):
        print(f"{label:<34} {r['h_over_B']:7.4f} {r['points']:7d} {r['q_end']:7.3f} "
              f"{r['q_end'] / PRANDTL - 1:+8.2%} {r['q_max']:7.3f} "
              f"{'yes' if r['levelled'] else 'no':>5} {r['iterations']:5d} {r['wall_s']:7.1f}  "
              f"{r['status']}", flush=True)
    print(f"Strip footing, Prandtl q_u / c = 2 + pi = {PRANDTL:.4f}")
    print(f"{'case':<34} {'h / B':>7} {'points':>7} {'q/c end':>7} {'vs 5.14':>8} "
          f"{'q/c max':>7} {'level':>5} {'its':>5} {'wall s':>7}")
    hs = (0.25, 0.125, 0.0625) if args.quick else (0.25, 0.125, 0.0625, 0.03125)
    for fbar in (True, False):
        for h in hs:
            r = run(h, fbar)
            rows.append(r)
            show(r, f"small strain, {'F-bar' if fbar else 'standard Q4'}")
    r = run(0.0625, True, components="y")
    rows.append(r)
    show(r, "small strain, F-bar, smooth")
    r = run(0.0625, True, W=4.0, D=2.5)
    rows.append(r)
    show(r, "small strain, F-bar, 4 m x 2.5 m")
    for h in (0.125, 0.0625):
        for fbar in (True, False):
            r = run(h, fbar, kind="dynamic", settlement=0.7 * h, steps=14)
            rows.append(r)
            show(r, f"large deformation, {'F-bar' if fbar else 'standard Q4'}")
    fb = [r for r in rows if r["fbar"] and r["kind"] == "geostatic" and r["components"] == "xy"
          and r["domain"] == [3.0, 2.0]]
    q3 = [r["q_end"] for r in fb[-3:]]
    ratio = (q3[1] - q3[2]) / (q3[0] - q3[1])
    extrap = q3[2] - (q3[1] - q3[2]) * ratio / (1 - ratio)
    order = -math.log(ratio) / math.log(2)
    print(f"F-bar, Richardson from the three finest meshes: q_u / c -> {extrap:.3f} "
          f"({extrap / PRANDTL - 1:+.2%} from Prandtl), observed order {order:.2f}")
    (OUT / "footing.json").write_text(json.dumps(
        {"prandtl": PRANDTL, "runs": rows, "richardson": {"q_over_c": extrap, "order": order}},
        indent=1))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.3))
    cmap = plt.get_cmap("viridis")
    for i, h in enumerate(hs):
        for r in rows:
            if r["h"] == h and r["kind"] == "geostatic" and r["components"] == "xy" \
                    and r["domain"] == [3.0, 2.0]:
                a1.plot(100 * np.array(r["settlement_over_B"]), r["q_over_c"],
                        "-" if r["fbar"] else "--", color=cmap(i / len(hs)),
                        label=f"h = B/{B / h:.0f}, {'F-bar' if r['fbar'] else 'standard'}")
    a1.axhline(PRANDTL, color="k", lw=1.5, label="Prandtl 2 + pi")
    a1.set_xlabel("settlement / B (%)")
    a1.set_ylabel("q / c")
    a1.set_title("rough strip footing, small-strain steps")
    a1.legend(fontsize=7, ncol=2)
    a1.grid(True, alpha=0.3)
    for fbar, mk in ((True, "s-"), (False, "o--")):
        r = [x for x in rows if x["fbar"] == fbar and x["kind"] == "geostatic"
             and x["components"] == "xy" and x["domain"] == [3.0, 2.0]]
        a2.semilogx([x["h_over_B"] for x in r], [x["q_end"] for x in r], mk,
                    label=f"{'F-bar' if fbar else 'standard Q4'}, at 3 % of B")
        r = [x for x in rows if x["fbar"] == fbar and x["kind"] == "dynamic"]
        a2.semilogx([x["h_over_B"] for x in r], [x["q_max"] for x in r], mk[0],
                    mfc="none", label=f"{'F-bar' if fbar else 'standard Q4'}, large "
                    "deformation (max)")
    a2.axhline(PRANDTL, color="k", lw=1.5)
    a2.axhspan(0.95 * PRANDTL, 1.05 * PRANDTL, color="k", alpha=0.08, label="Prandtl ± 5 %")
    a2.set_xlabel("h / B")
    a2.set_ylabel("q / c")
    a2.set_title("limit pressure under refinement")
    a2.legend(fontsize=7)
    a2.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(OUT / "footing.png", dpi=130)
    print(f"wrote {OUT / 'footing.png'} and {OUT / 'footing.json'}")


if __name__ == "__main__":
    main()
