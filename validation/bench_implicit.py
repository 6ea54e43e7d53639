"""Time per Newton iteration of the implicit MPM, split into its parts.

The elastic reference slope (meshes/slope_elastic.toml: 4575 Q4 soil elements of
0.25 m, 18 300 points) and the same slope at 1/13 m cells (48 300 elements, 193 000
points), gravity applied in one quasi-static large-deformation load step (4 full Newton
iterations), with SuperLU (MMD_AT_PLUS_A) and with pyamg (smoothed aggregation with the
rigid-body modes as near-null space, CG).  Per iteration:

* setup     -- basis at the points, DOF numbering, sparsity pattern (once per step,
               shown per iteration);
* material  -- stress update and consistent tangent at every point (complex step);
* assembly  -- kinematics, internal force and the tangent matrix (vectorised numpy);
* solve     -- factorisation + solve (SuperLU) or AMG setup + CG (pyamg).

Also times scikit-fem's ``asm`` of the same tangent (material points as quadrature,
``implicit.skfem_assemble``), the reference the vectorised path is tested against.
Writes ``validation/out/bench_implicit.json``.  Each case is run ``--repeat`` times and
the fastest time of each part is reported (the machine is shared; all runs are in the
JSON).  Run:
``nice python validation/bench_implicit.py`` (a few minutes; ``--small`` for 4600 only).

``--case-i``: the Newton iteration of case (i) (meshes/slope_reference.toml, 4565
elements, 18 260 points), implicit dynamics with the default settings over its first
``--t-end`` seconds (1 s: about 20 steps, 75 iterations), measured in CPU time
(``time.process_time`` in place of the wall clock, so the parts are CPU seconds even on a
loaded machine) after a short warm-up run that loads numba's cache.  It prints one line
per repeat and appends it to ``validation/out/bench_implicit_case_i.jsonl``.  It uses only
``run_implicit`` and the run record, so the same file measures another checkout:
``PYTHONPATH=/path/to/other nice python validation/bench_implicit.py --case-i --label other``
interleaved with ``--label this``.

``--whole-run``: case (i) to rest, implicit dynamics (default settings) against the
explicit run of the same scene, both through :func:`fem_rmpm.api.run` without output on
``--threads`` numba threads (1 by default; the implicit Newton step is serial) and one
BLAS thread, each in a fresh process (``--one explicit|implicit``: a 0.1 s warm-up run
that loads numba's cache, then the timed run), in interleaved pairs (explicit, implicit,
explicit, implicit, ...; ``--repeat`` pairs).  Per run: wall (``perf_counter``) and CPU
(``process_time``) seconds, the steps, and for the implicit run the Newton iterations,
the factorized ones among them (the others are BFGS iterations) and the CPU ms per step
with its parts (setup: the grid reset; predictor; material, assembly and solve inside the
Newton iterations; commit: the kinematic limits, the point update, the step's record and
the point check; other: the rest of the Newton iterations and the driver); per pair the implicit / explicit ratios of wall and CPU, and the
load average before and after.  Appends each pair to
``validation/out/bench_implicit_whole_run.jsonl``.  ``--t-end``: stop both runs at that
simulated time instead of at rest (default 40 s, the scene's: they stop at rest).

``--fs N``: the factor of safety of realizations 0..N-1 of the risk slope (xi = 12)
against the MPM run of the same realization stopped once decided, both in CPU seconds on
one numba thread (:mod:`fs_cost`, ``--risk``), and the median ratio; with ``--other
PATH`` interleaved with another checkout's FS, printed as a table (``fs_cost.py --risk N
--other PATH``).
"""
from __future__ import annotations

import os

# One BLAS thread: on a shared 2-core machine threaded BLAS oversubscribes and makes the
# dense kernels of SuperLU and of pyamg's coarse solve several times slower.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from fem_rmpm.discretise.grid import make_grid  # noqa: E402
from fem_rmpm.discretise.points import seed_particles, soil_cells  # noqa: E402
from fem_rmpm.runtime.machine import describe  # noqa: E402
from fem_rmpm.scene import load_scene  # noqa: E402
from fem_rmpm.schemes.implicit import (  # noqa: E402
    StepSystem,
    finite_strain_tangent,
    run_implicit,
    skfem_assemble,
)

HERE = Path(__file__).parent
OUT = HERE / "out"


def scene_at(cell: float, solver: str):
    scene = load_scene(HERE.parent / "meshes" / "slope_elastic.toml")
    return dataclasses.replace(
        scene, grid=dataclasses.replace(scene.grid, cell=(cell, cell)),
        solver=dataclasses.replace(scene.solver, scheme="implicit", dynamic=False,
                                   gravity_phase="dynamic", load_steps=1, linear_solver=solver))


def one_run(cell: float, solver: str) -> dict:
    scene = scene_at(cell, solver)
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    t0 = time.perf_counter()
    rec = run_implicit(scene, grid, pts)
    wall = time.perf_counter() - t0
    s = rec.solver
    ms = s["ms_per_iteration"]
    total = sum(ms.values())
    return {"cell_m": cell, "elements": int((soil_cells(scene, grid) >= 0).sum()),
            "points": pts.n, "solver": solver,
            "iterations": s["iterations_total"], "residuals": s["steps"][0]["residuals"],
            "ms_per_iteration": ms, "ms_total_per_iteration": total,
            "assembly_share": ms["assembly"] / total,
            "material_plus_assembly_share": (ms["assembly"] + ms["material"]) / total,
            "wall_s": wall, "max_displacement_m": float(np.abs(pts.displacement).max())}


def skfem_vs_fast(cell: float) -> dict:
    """One tangent + internal force by skfem.asm and by the vectorised path (same state)."""
    scene = scene_at(cell, "superlu")
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    rng = np.random.default_rng(0)
    dF = np.eye(2) + 1e-3 * rng.normal(size=(pts.n, 2, 2))
    tau, A = finite_strain_tangent(dF, pts.log_strain, pts.plastic_shear_strain, pts.soil)
    t0 = time.perf_counter()
    S = StepSystem(grid, pts.x)
    t1 = time.perf_counter()
    g = np.matmul(S.dN, np.linalg.inv(dF))
    K = S.tangent(pts.volume0, g, A)
    f = S.internal_force(pts.volume0, tau, g)
    t2 = time.perf_counter()
    Ks, fs = skfem_assemble(grid, pts.x, pts.volume0, dF, tau, A)
    t3 = time.perf_counter()
    Ks = Ks[S.free_dofs][:, S.free_dofs]
    return {"cell_m": cell, "points": pts.n, "fast_setup_ms": 1e3 * (t1 - t0),
            "fast_tangent_and_force_ms": 1e3 * (t2 - t1), "skfem_asm_ms": 1e3 * (t3 - t2),
            "max_rel_difference": float(abs(K - Ks).max() / abs(Ks).max()),
            "force_rel_difference": float(np.abs(f - fs[S.free_dofs]).max() / np.abs(fs).max())}


def case_i(t_end: float, label: str, linear_solver: str | None) -> dict:
    """CPU ms per Newton iteration of case (i), implicit dynamics to ``t_end`` (see the
    module docstring); the parts are the run record's, timed by ``process_time``."""
    import fem_rmpm
    time.perf_counter = time.process_time     # the record's clocks become CPU clocks
    scene = load_scene(HERE.parent / "meshes" / "slope_reference.toml")

    def run(t):
        sv = dataclasses.replace(scene.solver, scheme="implicit", dynamic=True, t_end=t)
        if linear_solver:
            sv = dataclasses.replace(sv, linear_solver=linear_solver)
        sc = dataclasses.replace(scene, solver=sv)
        grid = make_grid(sc)
        pts = seed_particles(sc, grid)
        c0 = time.process_time()
        rec = run_implicit(sc, grid, pts)
        return rec, time.process_time() - c0

    run(0.1)                                  # warm-up: numba's cache, imports
    rec, cpu = run(t_end)
    s = rec.solver
    ms = s["ms_per_iteration"]
    its = s["iterations_total"]
    return {"label": label, "code": str(Path(fem_rmpm.__file__).parent), "t_end_s": t_end,
            "steps": s["n_steps"], "iterations": its, "ms_per_iteration": ms,
            "factorizations": s.get("factorizations_total", its),
            "ms_per_step": s.get("ms_per_step"),
            "run_cpu_ms_per_step": 1e3 * cpu / max(s["n_steps"], 1),
            "ms_total_per_iteration": sum(ms.values()),
            "run_cpu_ms_per_iteration": 1e3 * cpu / max(its, 1), "run_cpu_s": cpu,
            "linear_solver": rec.solver.get("linear_solver", linear_solver or "default"),
            "load_average": os.getloadavg()}


def one_whole_run(scheme: str, threads: int, t_end: float) -> dict:
    """One run of case (i) in this process (see ``--whole-run``): a 0.1 s warm-up, then
    the timed run to rest (or ``t_end``); returns its figures."""
    from fem_rmpm import api
    from fem_rmpm.scene import with_value
    scene = load_scene(HERE.parent / "meshes" / "slope_reference.toml")
    scene = with_value(scene, "solver.threads", threads)
    if scheme == "implicit":
        scene = with_value(with_value(scene, "solver.scheme", "implicit"),
                           "solver.dynamic", True)
    api.run(with_value(scene, "solver.t_end", 0.1))            # warm-up: numba's cache
    scene = with_value(scene, "solver.t_end", t_end)
    w0, c0 = time.perf_counter(), time.process_time()
    res = api.run(scene)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    rec = res.record
    row = {"scheme": scheme, "threads": threads, "wall_s": wall, "cpu_s": cpu,
           "stop_reason": rec.stop_reason, "time_s": rec.time, "steps": rec.steps,
           "runout_m": res.measures["runout_distance"]}
    if scheme == "implicit":
        s = rec.solver
        row.update(iterations=s["iterations_total"], factorizations=s["factorizations_total"],
                   ms_per_step=s["ms_per_step"], cpu_ms_per_step=1e3 * cpu / max(rec.steps, 1),
                   cuts=s["cuts_total"],
                   rejected=s["rejected_total"], limited_by=s["limited_by"],
                   ms_per_iteration=s["ms_per_iteration"],
                   factorizations_by=s["factorizations_by"],
                   symbolic_analyses=s["symbolic_analyses"])
    return row


def whole_run(pairs: int, threads: int, t_end: float, label: str) -> None:
    """Interleaved pairs of whole runs, each in a fresh process (``--whole-run``)."""
    import subprocess
    import sys
    env = dict(os.environ, NUMBA_NUM_THREADS=str(max(threads, 1)))

    def one(scheme):
        out = subprocess.run([sys.executable, __file__, "--one", scheme, "--threads",
                              str(threads), "--t-end", str(t_end)], env=env, check=True,
                             capture_output=True, text=True).stdout
        return json.loads(out.strip().splitlines()[-1])

    for k in range(pairs):
        load0 = os.getloadavg()
        exp, imp = one("explicit"), one("implicit")
        load1 = os.getloadavg()
        pair = {"label": label, "threads": threads, "explicit": exp, "implicit": imp,
                "ratio_wall": imp["wall_s"] / exp["wall_s"],
                "ratio_cpu": imp["cpu_s"] / exp["cpu_s"], "load_before": load0,
                "load_after": load1}
        m = imp["ms_per_step"]
        print(f"pair {k + 1}, {threads} thread(s): explicit {exp['stop_reason']} at "
              f"{exp['time_s']:.1f} s, {exp['steps']} steps, wall {exp['wall_s']:.1f} s, CPU "
              f"{exp['cpu_s']:.1f} s; implicit {imp['stop_reason']} at {imp['time_s']:.1f} s, "
              f"{imp['steps']} steps, {imp['iterations']} iterations of which "
              f"{imp['factorizations']} factorized, wall {imp['wall_s']:.1f} s, CPU "
              f"{imp['cpu_s']:.1f} s ({imp['cpu_ms_per_step']:.1f} ms per step: "
              + ", ".join(f"{p} {v:.1f}" for p, v in m.items())
              + f", other {imp['cpu_ms_per_step'] - sum(m.values()):.1f}"
              + f"); implicit / explicit: wall {pair['ratio_wall']:.2f}x, "
              f"CPU {pair['ratio_cpu']:.2f}x; load {load0[0]:.2f} -> {load1[0]:.2f}",
              flush=True)
        with open(OUT / "bench_implicit_whole_run.jsonl", "a") as f:
            f.write(json.dumps(pair) + "\n")


def fs_against_mpm(n: int, label: str, other=None) -> None:
    """One line per realization and the summary: CPU of the FS over CPU of the decided
    MPM run (one numba thread, as a campaign worker); ``other``: a checkout whose FS is
    interleaved with this one's (the table of :func:`fs_cost.print_table`)."""
    import sys
    from pathlib import Path
    import numba
    sys.path.insert(0, str(HERE))
    from fs_cost import interleaved_rows, print_table, risk_rows
    numba.set_num_threads(1)
    if other:
        print_table(interleaved_rows("xi=12", n, label, Path(other).resolve()))
        return
    rows = risk_rows("xi=12", n, label)
    ratios = sorted(r["cpu_fs"] / r["cpu_mpm_decided"] for r in rows)
    print(f"FS against the decided MPM run, {n} realizations of xi = 12: CPU ratio median "
          f"{ratios[len(ratios) // 2]:.2f} (range {ratios[0]:.2f}-{ratios[-1]:.2f}); FS CPU "
          f"{sum(r['cpu_fs'] for r in rows):.1f} s, MPM CPU "
          f"{sum(r['cpu_mpm_decided'] for r in rows):.1f} s in all", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="only the 4600-element slope")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--case-i", action="store_true",
                    help="CPU ms per Newton iteration of case (i) implicit dynamics")
    ap.add_argument("--t-end", type=float, default=None,
                    help="simulated time (s): --case-i 1 by default, --whole-run 40")
    ap.add_argument("--label", default="", help="--case-i: a name for this code version")
    ap.add_argument("--linear-solver", default=None, help="--case-i: override the scene's")
    ap.add_argument("--whole-run", action="store_true",
                    help="case (i) to rest, implicit against explicit, interleaved pairs")
    ap.add_argument("--one", choices=("explicit", "implicit"), default=None,
                    help="--whole-run: one timed run in this process (prints JSON)")
    ap.add_argument("--threads", type=int, default=1, help="--whole-run: numba threads")
    ap.add_argument("--fs", type=int, default=0, metavar="N",
                    help="the FS of realizations 0..N-1 of the risk slope (xi = 12) against "
                         "their MPM runs stopped once decided, CPU (validation/fs_cost.py)")
    ap.add_argument("--other", default=None, metavar="PATH",
                    help="--fs: interleave with the FS of the checkout at PATH")
    a = ap.parse_args()
    OUT.mkdir(exist_ok=True)
    if a.one:
        print(json.dumps(one_whole_run(a.one, a.threads, a.t_end or 40.0)))
        return
    if a.whole_run:
        whole_run(a.repeat, a.threads, a.t_end or 40.0, a.label)
        return
    if a.fs:
        fs_against_mpm(a.fs, a.label or "this", a.other)
        return
    if a.case_i:
        for _ in range(a.repeat):
            r = case_i(a.t_end or 1.0, a.label, a.linear_solver)
            m = r["ms_per_iteration"]
            print(f"{r['label'] or r['code']}: {r['steps']} steps, {r['iterations']} its "
                  f"({r['factorizations']} factorized); "
                  + ", ".join(f"{k} {v:.1f}" for k, v in m.items())
                  + f"; total {r['ms_total_per_iteration']:.1f} ms, whole run "
                  f"{r['run_cpu_ms_per_iteration']:.1f} ms CPU per iteration "
                  f"(load {r['load_average'][0]:.1f})", flush=True)
            with open(OUT / "bench_implicit_case_i.jsonl", "a") as f:
                f.write(json.dumps(r) + "\n")
        return
    cells = [0.25] if a.small else [0.25, 1 / 13]
    rows = []
    print(f"{'elements':>8} {'points':>7} {'solver':>8} {'its':>3} {'setup':>7} {'material':>8} "
          f"{'assembly':>8} {'solve':>8} {'total':>8}  ms per Newton iteration (asm share)")
    for cell in cells:
        for solver in ("superlu", "pyamg"):
            runs = [one_run(cell, solver) for _ in range(a.repeat)]
            r = dict(runs[0])
            r["ms_per_iteration"] = {k: min(x["ms_per_iteration"][k] for x in runs)
                                     for k in runs[0]["ms_per_iteration"]}
            m = r["ms_per_iteration"]
            r["ms_total_per_iteration"] = total = sum(m.values())
            r["assembly_share"] = m["assembly"] / total
            r["material_plus_assembly_share"] = (m["assembly"] + m["material"]) / total
            r["repeats"] = [x["ms_per_iteration"] for x in runs]
            rows.append(r)
            m = r["ms_per_iteration"]
            print(f"{r['elements']:8d} {r['points']:7d} {solver:>8} {r['iterations']:3d} "
                  f"{m['setup']:7.1f} {m['material']:8.1f} {m['assembly']:8.1f} "
                  f"{m['solve']:8.1f} {r['ms_total_per_iteration']:8.1f}  "
                  f"({100 * r['assembly_share']:.0f} % assembly, "
                  f"{100 * r['material_plus_assembly_share']:.0f} % with material)", flush=True)
    comp = skfem_vs_fast(0.25)
    print(f"tangent + internal force at {comp['points']} points: vectorised "
          f"{comp['fast_tangent_and_force_ms']:.1f} ms (+ {comp['fast_setup_ms']:.1f} ms setup "
          f"per step), skfem.asm {comp['skfem_asm_ms']:.1f} ms; max relative difference "
          f"{comp['max_rel_difference']:.1e} (K), {comp['force_rel_difference']:.1e} (f)")
    result = {"cases": rows, "skfem_vs_vectorised": comp,
              "machine": {**describe(),
                          "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS")}}
    (OUT / "bench_implicit.json").write_text(json.dumps(result, indent=2))
    print(f"wrote {OUT / 'bench_implicit.json'}")


if __name__ == "__main__":
    main()
