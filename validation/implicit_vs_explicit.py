"""Implicit against explicit on the reference slope: case (i) and two xi = 12 realizations.

For each case the explicit run (the scene as shipped) and the implicit dynamic run
(``solver.scheme = "implicit"``, ``solver.dynamic = true``, every other setting the
default) are made back to back in this process, and the measures of the outputs
(:mod:`fem_rmpm.measures.deposit`, on the deposit) are compared: run-out, retrogression,
sliding area and slip-surface height, within a tolerance of 10 % (a measure whose
explicit value is below one cell, such as a slip surface at the base, is compared
absolutely: within one cell, 0.25 m).  Wall time (``perf_counter``) and CPU time
(``process_time``) of each run and their implicit / explicit ratios are printed; on a
shared machine only the CPU ratio means much.

The random realizations are those of the campaign's ``xi=12`` case: seeds
``realization_seed(montecarlo.seed, k)`` for ``k = 0, 1`` (``fem-rmpm run
meshes/slope_reference.toml --set random_field... --seed S`` reproduces one alone).

Writes ``validation/out/implicit_vs_explicit.json`` (measures, times, solver figures),
the final states ``implicit_vs_explicit_states.npz`` and the figure
``implicit_vs_explicit.png`` (one row per case, explicit left, implicit right; plastic
shear strain on a log scale).  Run (about an hour on one loaded core; minutes idle)::

    nice python validation/implicit_vs_explicit.py            # all three cases
    nice python validation/implicit_vs_explicit.py --cases homogeneous
    python validation/implicit_vs_explicit.py --plot-only     # redraw from the npz
"""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # one BLAS thread on a shared machine

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from fem_rmpm import api  # noqa: E402
from fem_rmpm.campaign.cases import parse_case, realization_seed  # noqa: E402
from fem_rmpm.io.output import to_true_frame  # noqa: E402
from fem_rmpm.io.plots import draw_ground, plot_field, strain_norm  # noqa: E402
from fem_rmpm.scene import load_scene, with_value  # noqa: E402

HERE = Path(__file__).parent
OUT = HERE / "out"
MEASURES = ("runout_distance", "retrogression_distance", "sliding_area", "slip_surface_height")
TOLERANCE = 0.10


def cases(spec: str, scene) -> list[tuple[str, object, int | None]]:
    """``[(name, scene, seed)]`` from ``homogeneous,xi=12:0,xi=12:1`` (``:k`` = the
    campaign's realization k)."""
    out = []
    for item in spec.split(","):
        case, _, k = item.partition(":")
        c = parse_case(case, scene)
        seed = realization_seed(scene.montecarlo.seed, int(k)) if k else None
        out.append((c.name + (f"_r{k}" if k else ""), c.scene, seed))
    return out


def implicit_scene(scene):
    s = with_value(scene, "solver.scheme", "implicit")
    return with_value(s, "solver.dynamic", True)


def one_run(scene, seed) -> dict:
    w0, c0 = time.perf_counter(), time.process_time()
    res = api.run(scene, out=None, seed=seed)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    rec, m = res.record, res.measures
    row = {"wall_s": wall, "cpu_s": cpu, "stop_reason": rec.stop_reason, "time_s": rec.time,
           "steps": rec.steps, **{k: m[k] for k in MEASURES}}
    if rec.solver:
        s = rec.solver
        row["solver"] = {k: s.get(k) for k in ("n_steps", "iterations_total",
                                               "iterations_per_step", "cuts_total",
                                               "rejected_total", "limited_by",
                                               "ms_per_iteration", "factorizations_by",
                                               "linear_solver")}
    state = {"x": res.particles.x.copy(), "gamma": res.particles.plastic_shear_strain.copy()}
    return row, state


def agree(m: str, exp: float, imp: float, cell: float) -> tuple[float, bool]:
    """(difference, within the tolerance): relative to the explicit value, or absolute
    (m) where that is below one cell."""
    if abs(exp) < cell:
        return imp - exp, abs(imp - exp) <= cell
    d = (imp - exp) / exp
    return d, abs(d) <= TOLERANCE


def table(rows: dict, cell: float) -> str:
    lines = ["| case | measure | explicit | implicit | difference | within |",
             "|---|---|---|---|---|---|"]
    for name, r in rows.items():
        for m in MEASURES:
            e, i = r["explicit"][m], r["implicit"][m]
            d, ok = agree(m, e, i, cell)
            ds = f"{100 * d:+.1f} %" if abs(e) >= cell else f"{d:+.2f} m"
            lines.append(f"| {name} | {m} | {e:.2f} | {i:.2f} | {ds} | {'yes' if ok else 'NO'} |")
        we, wi = r["explicit"]["wall_s"], r["implicit"]["wall_s"]
        ce, ci = r["explicit"]["cpu_s"], r["implicit"]["cpu_s"]
        lines.append(f"| {name} | wall / CPU (s) | {we:.0f} / {ce:.0f} | {wi:.0f} / {ci:.0f} | "
                     f"x{wi / we:.1f} / x{ci / ce:.1f} | |")
    return "\n".join(lines)


def plot(states: dict, scene, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = sorted({k.rsplit("/", 1)[0] for k in states}, key=lambda n: list(states).index(n + "/explicit"))
    fig, axes = plt.subplots(len(names), 2, figsize=(14, 2.4 * len(names)), squeeze=False,
                             constrained_layout=True)
    a = scene.scene.frame_angle_deg
    vmax = max(float(np.max(s["gamma"])) for s in states.values())
    norm = strain_norm(vmax)
    for r, name in enumerate(names):
        for c, scheme in enumerate(("explicit", "implicit")):
            ax = axes[r, c]
            s = states[f"{name}/{scheme}"]
            draw_ground(ax, scene)
            X = to_true_frame(s["x"], a)
            sc = plot_field(ax, X, np.maximum(s["gamma"], 1e-12), 0.125, cmap="viridis")
            sc.set_norm(norm)
            ax.set_aspect("equal")
            ax.set_xlim(-5, 125)
            ax.set_ylim(-26, 6)
            ax.set_title(f"{name}: {scheme}", fontsize=10)
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
    fig.colorbar(sc, ax=axes, shrink=0.8, label="plastic shear strain (-)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="homogeneous,xi=12:0,xi=12:1")
    ap.add_argument("--scene", default=str(HERE.parent / "meshes" / "slope_reference.toml"))
    ap.add_argument("--plot-only", action="store_true")
    a = ap.parse_args()
    OUT.mkdir(exist_ok=True)
    scene = load_scene(a.scene)
    npz = OUT / "implicit_vs_explicit_states.npz"
    js = OUT / "implicit_vs_explicit.json"
    if a.plot_only:
        data = np.load(npz)
        states = {}
        for k in data.files:
            key, field = k.rsplit("/", 1)
            states.setdefault(key, {})[field] = data[k]
        plot(states, scene, OUT / "implicit_vs_explicit.png")
        print(table(json.loads(js.read_text())["cases"], float(scene.grid.cell[0])))
        return
    rows, states = {}, {}
    for name, sc, seed in cases(a.cases, scene):
        rows[name] = {"seed": seed}
        for scheme, s in (("explicit", sc), ("implicit", implicit_scene(sc))):
            print(f"{name}: {scheme} run (seed {seed}) ...", flush=True)
            row, st = one_run(s, seed)
            rows[name][scheme] = row
            states[f"{name}/{scheme}"] = st
            print(f"  {row['stop_reason']} at {row['time_s']:.1f} s, wall {row['wall_s']:.0f} s, "
                  f"CPU {row['cpu_s']:.0f} s; " + ", ".join(f"{m} {row[m]:.2f}" for m in MEASURES),
                  flush=True)
        result = {"cases": rows, "machine": {"python": platform.python_version(),
                                             "cpus": os.cpu_count(),
                                             "load_average_end": os.getloadavg()}}
        js.write_text(json.dumps(result, indent=2))
        np.savez_compressed(npz, **{f"{k}/{f}": v for k, st in states.items()
                                    for f, v in st.items()})
    plot(states, scene, OUT / "implicit_vs_explicit.png")
    print(table(rows, float(scene.grid.cell[0])))


if __name__ == "__main__":
    main()
