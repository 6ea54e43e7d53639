"""Biaxial compression of a softening specimen on three meshes, local against non-local
softening, and Newton's iterations with the regularisation on: mesh objectivity of the
post-peak response, and the error of the staggered non-local update.

meshes/biaxial_softening.toml (1 x 2 m unconfined plane strain, c 10 -> 5 kPa, weak seed
cell at the bottom-left corner, implicit small-strain load steps to 0.12 m) on cells of
0.1, 0.05 and 0.025 m, with local softening and with non-local softening (l = 0.2 m).
A second implicit check: the soft column (meshes/soft_column.toml, large deformation,
quasi-static gravity steps) made of von Mises clay that yields and softens at its base
(c 40 -> 20 kPa), local and non-local (l = 0.5 m): Newton iterations per step.

Writes validation/out/biaxial_softening.png (force against displacement) and .json;
prints the post-peak differences between meshes and the iterations per step.
Run: ``nice python validation/biaxial_softening.py`` (a few minutes on a shared machine).
``--staggered``: the staggered update's error - the non-local biaxial at
0.05 m with 20 / 40 / 80 / 160 load steps, and case (i) (0.25 m, non-local) to 4 s
implicit dynamic against explicit - written to validation/out/staggered_error.json.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from fem_rmpm import api
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.common import SimulationError

HERE = Path(__file__).parent
ROOT = HERE.parent
OUT = HERE / "out"
CELLS = (0.1, 0.05, 0.025)
LENGTH = 0.2          # m


def biaxial(h: float, mode: str, extra: dict | None = None, tag: str = "") -> dict:
    scene = load_scene(ROOT / "meshes" / "biaxial_softening.toml")
    ch = {"grid.cell": h, **(extra or {})}
    if mode == "nonlocal":
        ch.update({"soil.regularisation": "nonlocal", "soil.internal_length": LENGTH})
    out = OUT / "biaxial_runs" / f"{mode}_{h}{tag}"
    try:
        api.run(with_values(scene, ch), out=out, force=True)
        error = None
    except SimulationError as exc:
        error = str(exc).split(":")[0] + ": Newton did not converge"
    steps = json.loads((out / "summary.json").read_text())["solver"]["steps"]
    return {"cell": h, "mode": mode, "error": error,
            "u": [0.0] + [0.12 * s["load_factor"] for s in steps],
            "force": [0.0] + [-s["reactions"]["platen"][1] for s in steps],
            "iterations": [s["iterations"] for s in steps]}


def soft_column(mode: str) -> dict:
    scene = load_scene(ROOT / "meshes" / "soft_column.toml")
    ch = {"soil.model": "von_mises_softening", "soil.cohesion_peak": 40.0,
          "soil.cohesion_residual": 20.0, "soil.softening_strain": 0.5}
    if mode == "nonlocal":
        ch.update({"soil.regularisation": "nonlocal", "soil.internal_length": 0.5})
    out = OUT / "biaxial_runs" / f"column_{mode}"
    res = api.run(with_values(scene, ch), out=out, force=True)
    steps = json.loads((out / "summary.json").read_text())["solver"]["steps"]
    gp = res.particles.plastic_shear_strain
    return {"mode": mode, "iterations": [s["iterations"] for s in steps],
            "max_plastic_shear_strain": float(gp.max()),
            "settlement": float(res.measures["max_displacement"]),
            "stop": res.record.stop_reason}


def load_step_error(h: float = 0.05, steps=(20, 40, 80, 160)) -> list[dict]:
    """The staggering error in the implicit scheme alone: the non-local biaxial at
    ``h`` with 20 ... 160 load steps (the softening lags one load step, so the error of
    the lag falls with the step; 160 steps is the reference)."""
    runs = []
    for n in steps:
        r = biaxial(h, "nonlocal", {"solver.load_steps": n}, tag=f"_{n}")
        runs.append({**r, "load_steps": n})
    for r in runs:
        r["post_peak_vs_finest"] = _post_peak(r, runs[-1])
    return runs


def explicit_vs_implicit(t_end: float = 4.0) -> dict:
    """The staggered non-local update in both schemes against each other: case (i)
    (meshes/slope_reference.toml, 0.25 m, regularisation = "nonlocal") to ``t_end``
    explicit (the update after every step, ~3.6e-3 s) and implicit dynamic (after every
    converged step, up to 0.1 s): measures, softened area and Newton iterations."""
    base = with_values(load_scene(ROOT / "meshes" / "slope_reference.toml"),
                       {"soil.regularisation": "nonlocal", "solver.t_end": t_end,
                        "output.vtk": False, "output.png": False})
    out = {}
    for scheme in ("explicit", "implicit"):
        ch = {"solver.scheme": scheme, "solver.dynamic": True} if scheme == "implicit" else {}
        d = OUT / "biaxial_runs" / f"slope_{scheme}"
        t0 = time.process_time()
        res = api.run(with_values(base, ch) if ch else base, out=d, force=True)
        cpu = time.process_time() - t0
        p = res.particles
        soft = p.cohesion < 0.5 * (p.soil.cohesion_peak + p.soil.cohesion_residual)
        steps = json.loads((d / "summary.json").read_text())["solver"].get("steps") or []
        it = [s["iterations"] for s in steps if "iterations" in s]
        out[scheme] = {"cpu_s": cpu, "steps": res.record.steps, "t": res.record.time,
                       "softened_area": float(np.sum(p.volume0[soft])),
                       "iterations_per_step": float(np.mean(it)) if it else None,
                       "max_iterations": max(it) if it else None,
                       **{m: res.measures.get(m) for m in ("sliding_area", "retrogression_distance",
                                                          "runout_distance", "slip_surface_height")}}
    return out


def _post_peak(a: dict, b: dict) -> float:
    """Max relative difference of two curves between u = 0.05 and 0.12 m (post-peak)."""
    g = np.linspace(0.05, min(a["u"][-1], b["u"][-1]), 15)
    fa, fb = np.interp(g, a["u"], a["force"]), np.interp(g, b["u"], b["force"])
    return float(np.max(np.abs(fa - fb) / np.abs(fb)))


def staggered() -> None:
    """The staggered scheme's error (``--staggered``)."""
    OUT.mkdir(exist_ok=True)
    runs = load_step_error()
    for r in runs:
        it = r["iterations"]
        print(f"biaxial non-local 0.05 m, {r['load_steps']} load steps: post-peak difference "
              f"to 160 steps {r['post_peak_vs_finest']:.4f}, {np.mean(it):.1f} iterations/step "
              f"(max {max(it)}); {r['error'] or 'load applied'}", flush=True)
    ei = explicit_vs_implicit()
    for k, v in ei.items():
        print(k, v, flush=True)
    (OUT / "staggered_error.json").write_text(json.dumps({"load_steps": runs, "slope": ei}))


def main() -> None:
    if "--staggered" in sys.argv:
        staggered()
        return
    OUT.mkdir(exist_ok=True)
    runs = [biaxial(h, m) for m in ("local", "nonlocal") for h in CELLS]
    cols = [soft_column(m) for m in ("local", "nonlocal")]
    for r in runs:
        it = r["iterations"]
        print(f"{r['mode']:8s} h = {r['cell']:<5} peak {max(r['force']):.2f} kN/m, force at "
              f"u = 0.048 m {np.interp(0.048, r['u'], r['force']):.2f}, end "
              f"{r['force'][-1]:.2f} at u = {r['u'][-1]:.4f} m; {len(it)} steps, "
              f"{np.mean(it):.1f} iterations/step (max {max(it)}); {r['error'] or 'load applied'}")
    for m in ("local", "nonlocal"):
        rr = [r for r in runs if r["mode"] == m and r["error"] is None]
        for a, b in zip(rr, rr[1:]):
            print(f"{m}: {a['cell']} vs {b['cell']} m: max post-peak difference "
                  f"{_post_peak(a, b):.3f}")
    for c in cols:
        print(f"soft column, {c['mode']}: {np.mean(c['iterations']):.1f} iterations/step "
              f"{c['iterations']}, max gamma_p {c['max_plastic_shear_strain']:.3f}, "
              f"max displacement {c['settlement']:.4f} m, {c['stop']}")
    (OUT / "biaxial_softening.json").write_text(json.dumps({"biaxial": runs, "column": cols}))
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, m in zip(axes, ("local", "nonlocal")):
        for r, col in zip([r for r in runs if r["mode"] == m], ("C0", "C1", "C2")):
            lab = f"{r['cell']} m cells" + (" (Newton failed)" if r["error"] else "")
            ax.plot(r["u"], r["force"], "-", color=col, label=lab)
        ax.set_title("local softening" if m == "local" else f"non-local softening, l = {LENGTH} m, m = 2")
        ax.set_xlabel("top displacement (m)")
        ax.grid(alpha=0.3)
        ax.legend()
    axes[0].set_ylabel("axial force (kN per m)")
    fig.suptitle("Biaxial compression of a softening specimen (1 x 2 m, weak seed cell)")
    fig.tight_layout()
    fig.savefig(OUT / "biaxial_softening.png", dpi=110)


if __name__ == "__main__":
    main()
