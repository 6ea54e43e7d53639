"""Strip footing on weightless Mohr-Coulomb soil: q / c against Prandtl's N_c under refinement.

Reference: Prandtl 1920, Reissner 1924: the limit pressure of a strip footing on weightless
c-phi soil with associated flow is ``q_u = c N_c``, ``N_c = (N_q - 1) cot(phi)``,
``N_q = exp(pi tan(phi)) tan^2(45 + phi / 2)``; phi = 20 deg: N_c = 14.835, rough or smooth.
The scene is meshes/bearing_capacity.toml (half model 8 m x 4 m, B = 2 m, c = 10 kPa,
phi = psi = 20 deg, E = 100 MPa, nu = 0.3, perfectly plastic, rough, displacement
controlled to 2.5 % of B in 20 small-strain load steps, F-bar); the pressure is the
reaction of the prescribed nodes over B/2.

Two volumetric constraints per cell (``[solver] locking_constraint``): ``pressure`` (the
scene's: one in-plane mean stress per cell, each point its own volume change) and
``volume`` (B-bar: one volume change per cell; its curves flatten with refinement but do
not level off on a mesh, because dilatant flow ties each point's volume change to its
own plastic shear).  Prints and charts, per constraint and cell size B/8, B/16, B/32
(``--fine``: and B/64, B-bar about 16 min CPU): q / c at the end of loading, its rise
over the last quarter of the settlement, Newton iterations, CPU time; the Richardson
extrapolation of the three finest meshes (observed order from the same three).

Each run is written to ``validation/out/bearing_capacity_<constraint>_<B/h>.json`` as soon
as it is done and re-used by a rerun (resume after a kill; ``--fresh`` recomputes).
Writes ``validation/out/bearing_capacity.json`` and ``bearing_capacity.png``.
Run: ``nice python validation/bearing_capacity.py`` (about 5 min CPU; ``--constraint
pressure`` about 3 min).
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
SCENE = HERE.parent / "meshes" / "bearing_capacity.toml"
B, C, PHI = 2.0, 10.0, 20.0


def prandtl_nc(phi_deg: float) -> float:
    """Prandtl's N_c = (N_q - 1) cot(phi), N_q = exp(pi tan phi) tan^2(45 + phi/2)."""
    t = math.tan(math.radians(phi_deg))
    nq = math.exp(math.pi * t) * math.tan(math.radians(45.0 + phi_deg / 2.0)) ** 2
    return (nq - 1.0) / t


def run(h: float, changes: dict | None = None) -> dict:
    """One footing run at cell size ``h`` (m); the load-settlement curve (q / c against
    settlement / B), Newton iterations and CPU time."""
    scene = load_scene(SCENE)
    W, D = scene.grid.size[0], scene.grid.size[1] - scene.grid.cell[1]
    scene = with_values(scene, {"grid.cell": h, "grid.size": [W, D + h], **(changes or {})})
    settlement = -scene.prescribed[0].displacement[1]
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    t0 = time.process_time()
    status = "ok"
    try:
        rec = run_implicit(scene, grid, pts)
    except SimulationError as exc:
        rec = exc.record
        status = "failed: " + str(exc).split(";")[0][:120]
    st = rec.solver["steps"]
    q = [-s["reactions"]["footing"][1] / (B / 2) / C for s in st]
    d = [s["load_factor"] * settlement / B for s in st]
    n = len(q)
    rise = q[-1] / q[(3 * n) // 4 - 1] - 1 if n >= 4 else float("nan")
    return {"h": h, "B_over_h": B / h, "points": int(pts.n), "settlement_over_B": d,
            "q_over_c": q, "q_end": q[-1] if q else float("nan"), "rise_last_quarter": rise,
            "iterations": int(sum(s["iterations"] for s in st)), "status": status,
            "cpu_s": time.process_time() - t0}


def richardson(q3: list[float], ratio_h: float = 2.0) -> tuple[float, float]:
    """Extrapolation to h -> 0 of three values on meshes refined by ``ratio_h``, and the
    observed order."""
    r = (q3[1] - q3[2]) / (q3[0] - q3[1])
    return q3[2] - (q3[1] - q3[2]) * r / (1 - r), -math.log(r) / math.log(ratio_h)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fine", action="store_true", help="add B/64")
    ap.add_argument("--constraint", choices=("pressure", "volume", "both"), default="both",
                    help="locking_constraint of the runs (default both)")
    ap.add_argument("--fresh", action="store_true", help="recompute every mesh")
    ap.add_argument("--out", default=str(HERE / "out"), help="output directory")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    nc = prandtl_nc(PHI)
    print(f"Rough strip footing, weightless soil, phi = psi = {PHI:g} deg: Prandtl N_c = {nc:.3f}")
    kinds = ("pressure", "volume") if args.constraint == "both" else (args.constraint,)
    series = {}
    for kind in kinds:
        print(f"locking_constraint = {kind}")
        print(f"{'h':>7} {'points':>7} {'q/c':>8} {'vs N_c':>8} {'rise':>7} {'its':>5} {'cpu s':>7}")
        rows = []
        for k in ((8, 16, 32, 64) if args.fine else (8, 16, 32)):
            path = out / f"bearing_capacity_{kind}_{k}.json"
            if path.exists() and not args.fresh:
                r = json.loads(path.read_text())
            else:
                r = run(B / k, {"solver.locking_constraint": kind})
                path.write_text(json.dumps(r, indent=1))
            rows.append(r)
            print(f"{'B/' + str(k):>7} {r['points']:7d} {r['q_end']:8.3f} "
                  f"{r['q_end'] / nc - 1:+8.2%} {r['rise_last_quarter']:+7.2%} "
                  f"{r['iterations']:5d} {r['cpu_s']:7.1f}  {r['status']}", flush=True)
        q_inf, order = richardson([r["q_end"] for r in rows[-3:]])
        print(f"Richardson from the three finest meshes: q / c -> {q_inf:.3f} "
              f"({q_inf / nc - 1:+.2%} from N_c), observed order {order:.2f}")
        series[kind] = {"runs": rows, "richardson": {"q_over_c": q_inf, "order": order}}
    (out / "bearing_capacity.json").write_text(json.dumps({"N_c": nc, **series}, indent=1))
    _figure(series, nc, out / "bearing_capacity.png")


def _figure(series, nc, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.3))
    style = {"pressure": ("-", "s-", "one pressure per cell"),
             "volume": ("--", "o--", "B-bar: one volume change per cell")}
    cmap = plt.get_cmap("viridis")
    for kind, ser in series.items():
        ls, mk, label = style[kind]
        rows = ser["runs"]
        for i, r in enumerate(rows):
            a1.plot(100 * np.array(r["settlement_over_B"]), r["q_over_c"], ls,
                    color=cmap(i / len(rows)),
                    label=f"{kind}, h = B/{r['B_over_h']:.0f} ({r['points']} points)")
        hb = [1 / r["B_over_h"] for r in rows]
        q_inf = ser["richardson"]["q_over_c"]
        a2.plot(hb, [r["q_end"] for r in rows], mk, label=f"{label} (Richardson {q_inf:.2f})")
    a1.axhline(nc, color="k", lw=1.5, label=f"Prandtl N_c = {nc:.2f}")
    a1.set_xlabel("settlement / B (%)")
    a1.set_ylabel("q / c")
    a1.set_title("rough strip footing, phi = psi = 20 deg, weightless")
    a1.legend(fontsize=7)
    a1.grid(True, alpha=0.3)
    a2.axhline(nc, color="k", lw=1.5, label="Prandtl")
    a2.axhspan(0.95 * nc, 1.05 * nc, color="0.85", label="+-5 %")
    a2.set_xlim(left=-0.005)
    a2.set_xlabel("h / B")
    a2.set_ylabel("q / c at 2.5 % of B")
    a2.set_title("under refinement (Q4, 2 x 2 points per cell, F-bar)")
    a2.legend(fontsize=8)
    a2.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
