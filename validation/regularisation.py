"""Mesh convergence of the failure mechanism with local, displacement-scaled and non-local
softening: does the failure mechanism converge as the cells shrink?

Two slopes: case (i) (meshes/slope_reference.toml, c 20 -> 4 kPa) and one fixed random
realization of it (lognormal c_peak, COV 0.25, theta_v 0.5 m, xi = 12, field cells 0.25 m,
seed 12), both on an open run-out floor instead of the reference's valley: the floor is
horizontal in the true frame and 200 m long beyond the toe (grid 261 x 150 m, bedrock
triangle [[61, 0], [261, 0], [261, 72.79]]; the deposits rest about 100 m out), so neither
a valley side nor the grid edge bounds the deposit; the grid is tall so that points thrown
off land again instead of freezing at its top (the script reports the frozen points).
Only cells with points cost time (the non-local average keeps its work arrays per grid
and touches only the cells near points).
Each at 0.5, 0.25 and 0.125 m cells with

* local softening (softening_strain 0.5),
* displacement-scaled softening (softening_displacement 0.125 m = 0.5 x 0.25 m: the same
  as the local law at 0.25 m),
* non-local softening (internal_length 0.5 m and nonlocal_factor 2, the defaults;
  ``nonlocal_m1`` is the plain mean, nonlocal_factor 1, for comparison).

The runs go to rest (the reference's rest test: no point faster than 0.02 m/s, kinetic
energy below 1e-4 of its peak) or stop at ``--t-end`` (default 150 s; the table's ``t``
column and ``stop`` say which): the run-out is the front where the deposit stopped.
Stray points (debris separated from the deposit, excluded from every measure) count in
the rest test, so a point sliding on alone along the floor delays it.  Outputs in
validation/out/: regularisation_<slope>.json (every run as it finishes; rerunning skips
the runs already there; ``--slopes`` runs one slope per process),
regularisation_<slope>.png (plastic shear strain at the
mechanism time, one row per mesh, one column per softening), regularisation_width.png
(main shear band width against the cell) and the tables printed at the end.

Main shear band width, measures of the basal band (case (i) fails at the base), in
1 m wide columns of the initial mid-slope (x0 from 15 to 45 m), median over the columns:

* ``band_width``: the effective width of the plastic shear strain
  ``(sum V gamma_p)^2 / (b sum V gamma_p^2)`` (b = 1 m; a band of uniform strain and
  thickness t gives t) at t = 1.5 s, when the band forms (gravity is fully on at 1 s and
  the base has just softened to the residual);
* ``band_width_3s``: the same at the mechanism time (3 s).  By then the slope has slid
  metres at residual strength, which is perfectly plastic (no length scale): under a
  shear stress that grows with depth that slip gathers in the cell at the no-slip base,
  whatever the softening law, so this later measure drifts towards the cell;
* ``softened_width``: the thickness of the softened zone, the material that has lost
  more than half of its strength drop (c < (c_peak + c_residual) / 2), at the mechanism
  time (3 s): the band the softening law makes (``softened_width_end``: at the end, by
  when the whole sliding layer may have softened).

Intact blocks at the mechanism time (3 s): ``intact_blocks`` is the measure (least block
1 m2 on every mesh), ``intact_blocks_4cells`` the count with a least block of 4 cells
(1 m2 at 0.5 m, 0.06 m2 at 0.125 m).  The run's own measure is exact; the other
count is recounted from the run's saved snapshot at the mechanism time (positions rounded
to 1 mm, which moves a few points across cell edges: a recount of the run's own 4-cell
measure differs from it by at most 1 block, 12 against 11 and 9 against 8).  The
slip-surface height is that of the deposit at rest.

Cost: ``--cost N`` runs case (i) as it is (0.25 m, to rest) N times local
and non-local, interleaved, and prints the CPU times.

Run: ``nice python validation/regularisation.py [--t-end 150] [--cells 0.5 0.25 0.125]
[--softenings nonlocal local]`` (the 0.125 m runs hold 73 000 points: about 3 min CPU
each to rest, idle); ``--report`` redraws.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from pathlib import Path

import numpy as np

from fem_rmpm import api
from fem_rmpm.measures.deposit import intact_blocks
from fem_rmpm.scene import load_scene, with_values

HERE = Path(__file__).parent
OUT = HERE / "out"
ROOT = HERE.parent
FLOOR_LENGTH = 200.0  # m beyond the toe (x = 61 m): the deposits rest about 100 m out
_RISE = FLOOR_LENGTH * math.tan(math.radians(20.0))    # the floor in the bedrock frame
GRID_HEIGHT = 150.0   # m: room above the floor for points thrown off (none reaches the top)
FLOOR = {"grid.size": [61.0 + FLOOR_LENGTH, GRID_HEIGHT],
         "bedrock.polygon": [[61.0, 0.0], [61.0 + FLOOR_LENGTH, 0.0],
                             [61.0 + FLOOR_LENGTH, round(_RISE, 4)]]}
SOFTENING = {
    "local": {},
    "displacement": {"soil.regularisation": "displacement", "soil.softening_displacement": 0.125},
    "nonlocal": {"soil.regularisation": "nonlocal", "soil.internal_length": 0.5},
    "nonlocal_m1": {"soil.regularisation": "nonlocal", "soil.internal_length": 0.5,
                    "soil.nonlocal_factor": 1.0},
}
BAND_TIME = 1.5       # s: the band has formed (gravity on at 1 s), before metres of slip
SLOPES = {"case_i": {}, "xi12": {"random_field.anisotropy": 12.0, "random_field.cov": 0.25,
                                 "random_field.theta_v": 0.5, "random_field.cell_size": 0.25}}
SEED = 12
MEASURES = ("sliding_area", "retrogression_distance", "runout_distance", "slip_surface_height",
            "intact_blocks", "intact_blocks_4cells", "band_width", "band_width_3s",
            "softened_width")


def band_width(x0, vol0, gamma, lo=15.0, hi=45.0, b=1.0) -> float:
    """Median effective thickness (m) of the plastic strain across the layer in columns
    of width ``b`` of the initial configuration between x0 = ``lo`` and ``hi``."""
    out = []
    for a in np.arange(lo, hi, b):
        m = (x0[:, 0] >= a) & (x0[:, 0] < a + b)
        s1, s2 = float(np.sum(vol0[m] * gamma[m])), float(np.sum(vol0[m] * gamma[m] ** 2))
        if s2 > 0:
            out.append(s1 * s1 / (b * s2))
    return float(np.median(out)) if out else float("nan")


def softened_width(x0, vol0, softened, lo=15.0, hi=45.0, b=1.0) -> float:
    """Median thickness (m) of the softened material (``softened`` mask) in columns of
    width ``b`` of the initial configuration between x0 = ``lo`` and ``hi``."""
    out = [float(np.sum(vol0[(x0[:, 0] >= a) & (x0[:, 0] < a + b) & softened])) / b
           for a in np.arange(lo, hi, b)]
    return float(np.median(out))


def scene_for(slope: str, soft: str, cell: float, t_end: float):
    base = load_scene(ROOT / "meshes" / "slope_reference.toml")
    ch = {**FLOOR, "grid.cell": cell, "solver.t_end": t_end, "solver.output_interval": 0.5,
          **SLOPES[slope], **SOFTENING[soft]}
    return with_values(base, ch)


def _softened_at(when: float, into: list):
    """``api._run_scheme`` that also keeps the softened mask (:func:`_softened`) of the
    output nearest ``when`` (s) in ``into`` (the run's snapshots hold only the plastic
    strain, not the softening variable)."""
    run_scheme = api._run_scheme

    def hooked(scene, grid, pts, on_output, progress):
        def both(t, p):
            on_output(t, p)
            if not into or abs(t - when) < abs(into[0][0] - when):
                into[:] = [(t, _softened(p))]
        return run_scheme(scene, grid, pts, both, progress)
    return hooked


def one_run(slope, soft, cell, t_end):
    s = scene_for(slope, soft, cell, t_end)
    kept: list = []
    plain, api._run_scheme = api._run_scheme, _softened_at(3.0, kept)
    t0 = time.process_time()
    try:
        res = api.run(s, seed=SEED if slope != "case_i" else None, vtk=False, figures=False)
    finally:
        api._run_scheme = plain
    cpu = time.process_time() - t0
    m = res.measures
    times = np.array([t for t, *_ in res.snapshots])
    k = int(np.argmin(np.abs(times - m["mechanism_time"])))
    t_m, x_m, g_m = res.snapshots[k]
    g_b = res.snapshots[int(np.argmin(np.abs(times - BAND_TIME)))][2]
    p = res.particles
    return {"slope": slope, "softening": soft, "cell": cell, "points": int(p.n),
            "steps": res.record.steps, "t": res.record.time, "cpu_s": cpu,
            "stop": res.record.stop_reason, "frozen_points": int((~p.active).sum()),
            **{k2: m[k2] for k2 in MEASURES + ("intact_block_area",) if k2 in m},
            "band_width": band_width(p.x0, p.volume0, g_b),
            "band_width_3s": band_width(p.x0, p.volume0, g_m), "mechanism_time": t_m,
            "softened_width": softened_width(p.x0, p.volume0, kept[0][1]),
            "softened_width_end": softened_width(p.x0, p.volume0, _softened(p)),
            "snapshot": {"x": x_m[::max(1, len(x_m) // 40000)].round(3).tolist(),
                         "g": g_m[::max(1, len(x_m) // 40000)].round(4).tolist()}}


def _softened(p) -> np.ndarray:
    """Points that lost more than half of their strength drop (at the end of the run)."""
    cp, cr = p.soil.cohesion_peak, p.soil.cohesion_residual
    return p.cohesion < 0.5 * (cp + cr)


def table(runs, slope, soft) -> str:
    rows = sorted((r for r in runs if r["slope"] == slope and r["softening"] == soft),
                  key=lambda r: -r["cell"])
    if not rows:
        return ""
    fine = rows[-1]
    lines = [f"{slope}, {soft} softening (relative to the finest mesh {fine['cell']} m)",
             "| cell (m) | " + " | ".join(MEASURES) + " | end (s) | frozen | CPU (s) |",
             "|---" * (len(MEASURES) + 4) + "|"]
    for r in rows:
        cells = []
        for k in MEASURES:
            v, f = r.get(k), fine.get(k)
            rel = "" if r is fine or not f else f" ({(v - f) / f:+.0%})"
            cells.append(f"{v:.3g}{rel}" if isinstance(v, (int, float)) else str(v))
        end = f"{r['t']:.1f}" + ("" if r.get("stop", "at rest") == "at rest" else f" ({r.get('stop')})")
        lines.append(f"| {r['cell']} | " + " | ".join(cells) + f" | {end} | {r['frozen_points']} | "
                     f"{r['cpu_s']:.0f} |")
    return "\n".join(lines)


def blocks_at_mechanism_time(r: dict, **rule) -> int:
    """Intact blocks at the mechanism time as the ``intact_blocks`` measure counts them
    (least block ``[montecarlo] intact_block_area``, 1 m2), or with ``rule`` (e.g.
    ``min_cells=4``: a least block of 4 cells, 0.06 m2 at 0.125 m), from the
    run's saved snapshot (every point at 0.125 m and up) and the seeded initial positions
    (the run keeps the points' order); -1 if the snapshot was thinned."""
    s = scene_for(r["slope"], r["softening"], r["cell"], 3.0)
    grid, pts = api.prepare(s, SEED if r["slope"] != "case_i" else None)
    x = np.array(r["snapshot"]["x"])
    if len(x) != pts.n:
        return -1
    g = np.array(r["snapshot"]["g"])
    return intact_blocks(x, pts.x0, g, s.montecarlo.failure_displacement, grid.origin,
                         grid.cell, grid.shape, **rule)


def compact_table(runs) -> str:
    """One row per slope and softening, entries coarse / medium / fine mesh and the
    medium mesh against the finest in per cent (the table of the regularisation page)."""
    cols = ("sliding_area", "retrogression_distance", "runout_distance", "slip_surface_height",
            "intact_blocks", "intact_blocks_4cells", "band_width", "band_width_3s",
            "softened_width", "t", "frozen_points")
    lines = ["| slope, softening | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for slope in SLOPES:
        for soft in SOFTENING:
            rr = sorted((r for r in runs if r["slope"] == slope and r["softening"] == soft),
                        key=lambda r: -r["cell"])
            if not rr:
                continue
            cells = []
            for k in cols:
                v = [r.get(k) for r in rr]
                txt = " / ".join("-" if x is None else f"{x:.3g}" for x in v)
                if len(v) > 1 and v[-1] and v[-2] is not None:
                    txt += f" ({(v[-2] - v[-1]) / v[-1]:+.0%})"
                cells.append(txt)
            lines.append(f"| {slope}, {soft} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figures(runs):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    for slope in SLOPES:
        rows = sorted((r for r in runs if r["slope"] == slope),
                      key=lambda r: (list(SOFTENING).index(r["softening"]), -r["cell"]))
        if not rows:
            continue
        fig, axes = plt.subplots(len(rows), 1, figsize=(14, 1.25 * len(rows) + 0.8),
                                 layout="constrained", squeeze=False, sharex=True, sharey=True)
        for ax, r in zip(axes[:, 0], rows):
            x, g = np.array(r["snapshot"]["x"]), np.array(r["snapshot"]["g"])
            sc = ax.scatter(x[:, 0], x[:, 1], c=np.clip(g, 0, 2), s=0.5 * (r["cell"] / 0.125) ** 2,
                            cmap="viridis", vmin=0, vmax=2, rasterized=True, linewidths=0)
            ax.set_title(f"{r['softening']}, {r['cell']} m cells: softened zone "
                         f"{r['softened_width']:.2f} m, strain width {r['band_width']:.2f} m "
                         f"(1.5 s) / {r['band_width_3s']:.2f} m (3 s), {r['intact_blocks']} "
                         "blocks", fontsize=9, loc="left")
            ax.set_xlim(0, 75)
            ax.set_ylim(-0.5, 6.5)
            ax.set_aspect("equal")
        fig.colorbar(sc, ax=axes, shrink=0.5, pad=0.01, label="plastic shear strain (-), clipped at 2")
        fig.suptitle(f"{slope}: plastic shear strain at the mechanism time t = 3 s "
                     "(bedrock frame, m)")
        fig.savefig(OUT / f"regularisation_{slope}.png", dpi=110)
        plt.close(fig)
    fig, ax = plt.subplots(figsize=(9.5, 4.5))
    for slope, mk in zip(SLOPES, "os"):
        for soft, col in zip(SOFTENING, ("C0", "C1", "C2", "C3")):
            rr = sorted((r for r in runs if r["slope"] == slope and r["softening"] == soft),
                        key=lambda r: r["cell"])
            if rr:
                ax.plot([r["cell"] for r in rr], [r["softened_width"] for r in rr], mk + "-",
                        color=col, label=f"{slope}, {soft}: softened zone")
                ax.plot([r["cell"] for r in rr], [r["band_width"] for r in rr], mk + ":",
                        color=col, alpha=0.8, label=f"{slope}, {soft}: strain width, 1.5 s")
                ax.plot([r["cell"] for r in rr], [r["band_width_3s"] for r in rr], mk + "-.",
                        color=col, alpha=0.4, label=f"{slope}, {soft}: strain width, 3 s")
    ax.set_xlabel("cell (m)")
    ax.set_ylabel("main shear band width (m)")
    ax.plot([0.125, 0.5], [0.125, 0.5], "k--", lw=0.8, label="one cell")
    ax.set_xscale("log", base=2)
    ax.set_xticks([0.125, 0.25, 0.5], ["0.125", "0.25", "0.5"])
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5))
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(OUT / "regularisation_width.png", dpi=110)
    plt.close(fig)


def cost(repeats: int) -> None:
    """Whole runs of case (i) (meshes/slope_reference.toml as it is, 0.25 m,
    to rest), local and non-local interleaved, CPU time (time.process_time) of each;
    written to validation/out/regularisation_cost.json."""
    base = load_scene(ROOT / "meshes" / "slope_reference.toml")
    rows = []
    for k in range(repeats):
        for soft in ("local", "nonlocal"):
            s = with_values(base, SOFTENING[soft]) if SOFTENING[soft] else base
            t0 = time.process_time()
            res = api.run(s, vtk=False, figures=False)
            cpu = time.process_time() - t0
            rows.append({"softening": soft, "repeat": k, "cpu_s": cpu, "steps": res.record.steps,
                         "t": res.record.time, "stop": res.record.stop_reason,
                         "ns_per_point_step": 1e9 * cpu / (res.record.steps * res.particles.n),
                         **{m: res.measures.get(m) for m in MEASURES}})
            print(rows[-1], flush=True)
            (OUT / "regularisation_cost.json").write_text(json.dumps(rows))
    loc = [r["cpu_s"] for r in rows if r["softening"] == "local"]
    nl = [r["cpu_s"] for r in rows if r["softening"] == "nonlocal"]
    print(f"CPU local {loc}, non-local {nl}: ratio {np.mean(nl) / np.mean(loc):.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=150.0)
    ap.add_argument("--softenings", nargs="+", choices=list(SOFTENING),
                    default=["nonlocal", "local", "nonlocal_m1", "displacement"])
    ap.add_argument("--cells", type=float, nargs="+", default=[0.5, 0.25, 0.125])
    ap.add_argument("--slopes", nargs="+", default=list(SLOPES), choices=list(SLOPES))
    ap.add_argument("--report", action="store_true", help="only tables and figures")
    ap.add_argument("--cost", type=int, default=0, metavar="N",
                    help="only the cost check: N interleaved local / non-local whole runs")
    a = ap.parse_args(argv)
    OUT.mkdir(exist_ok=True)
    if a.cost:
        cost(a.cost)
        return
    runs = []
    for slope in SLOPES:
        path = OUT / f"regularisation_{slope}.json"
        runs += json.loads(path.read_text()) if path.exists() else []
    if not a.report:
        for soft, cell, slope in itertools.product(a.softenings, a.cells, a.slopes):
            if any(r["slope"] == slope and r["softening"] == soft and r["cell"] == cell
                   for r in runs):
                continue                     # resumable: each run is saved as it ends
            r = one_run(slope, soft, cell, a.t_end)
            runs.append(r)
            path = OUT / f"regularisation_{slope}.json"
            path.write_text(json.dumps([q for q in runs if q["slope"] == slope]))
            print(slope, soft, cell, {k: r.get(k) for k in MEASURES},
                  f"cpu {r['cpu_s']:.0f} s, {r['stop']} at {r['t']:.1f} s", flush=True)
    for r in runs:        # the run's own count is exact; the other is recounted
        if "intact_block_area" in r:
            r["intact_blocks_4cells"] = blocks_at_mechanism_time(r, min_cells=4)
        else:             # records without intact_block_area hold the 4-cell count
            r["intact_blocks_4cells"] = r["intact_blocks"]
            r["intact_blocks"] = blocks_at_mechanism_time(r)
    for slope in SLOPES:
        for soft in SOFTENING:
            print(table(runs, slope, soft), "\n")
    print(compact_table(runs))
    figures(runs)


if __name__ == "__main__":
    main()
