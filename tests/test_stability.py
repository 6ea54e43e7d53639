"""Where MPM fails: the explicit stability limit and cell crossing.

References: the central-difference bound (explicit time step dt <= C h / (c_p + |v|max), C =
1, c_p = sqrt(M / rho)); the compaction column and its error norm; Bardenhagen & Kober 2004
(GIMP: cell-crossing noise and its cure); Charlton, Coombs & Augarde 2017 (AMPLE, the
compaction benchmark); Sulsky, Zhou & Schreyer 1995 / Nairn 2003 (MUSL).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.explicit.loop import run_explicit
from fem_rmpm.schemes.explicit.stability import cfl_limit, spectral_cfl_limit
from fem_rmpm.schemes.implicit import run_implicit

MESHES = Path(__file__).resolve().parents[1] / "meshes"


# ------------------------------------------------------------------ CFL
def _column(phase, damping):
    """meshes/column.toml (seed clay, 5 m, 0.25 m cells, rollers): gravity ramped over 0.5 s,
    either on the fixed in-situ geometry (geostatic: linear elastodynamics) or on the
    large-deformation model (dynamic), with the given local damping."""
    return with_values(load_scene(MESHES / "column.toml"), {
        "solver.gravity_phase": phase, "solver.damping": damping})


def test_cfl_limit_against_theory_and_default():
    """Bisection on cfl (a run is unstable when the run guard raises
    SimulationError or the stress leaves 10 gamma H), 3 s of simulated time each:

    * large deformation, undamped: the limit is within 20 % of the textbook
      estimate dt = h / (c_p + |v|max), i.e. cfl = 1;
    * linear elastodynamics (geostatic phase), undamped: MUSL re-maps the velocities before
      the stress update and is stable well beyond cfl = 1; the measured limit agrees within
      3 % with the theory of the scheme itself, the cfl where the spectral radius of the
      linearised step (fem_rmpm.schemes.explicit.stability.spectral_cfl_limit) exceeds 1, and the textbook
      estimate stays on the safe side;
    * the default cfl = 0.5 is at most half of every limit, damped (0.7, the default) or not.
    """
    bound = 10 * 20.0 * 5.0
    limits = {}
    for phase in ("dynamic", "geostatic"):
        for damping in (0.0, 0.7):
            lo, hi, _ = cfl_limit(_column(phase, damping), 3.0, bound, lo=0.5, hi=3.0, tol=0.01)
            limits[(phase, damping)] = lo
    print({f"{p}, damping {d}": round(v, 3) for (p, d), v in limits.items()})
    assert abs(limits[("dynamic", 0.0)] - 1.0) < 0.2
    short = with_values(_column("geostatic", 0.0), {"grid.size": [0.25, 1.75],
                                                     "soil.polygon": [[0, 0], [0.25, 0],
                                                                      [0.25, 1.25], [0, 1.25]]})
    s_lo, s_hi = spectral_cfl_limit(short, lo=1.0, hi=2.0, tol=0.01)
    print("spectral limit of the linearised MUSL step:", s_lo, s_hi)
    assert abs(limits[("geostatic", 0.0)] / (0.5 * (s_lo + s_hi)) - 1) < 0.03
    assert min(limits.values()) >= 1.0
    default = load_scene(MESHES / "column.toml").solver.cfl
    assert default == 0.5 and default <= 0.5 * min(limits.values())


# ------------------------------------------------------------------ cell crossing
def _compaction(cells, shape, scheme):
    """The compaction column of Charlton et al. 2017 (meshes/compaction.toml: l0 = 50 m,
    E = 10 kPa, nu = 0, rho0 g = 0.8 kN/m3) with ``cells`` cells over the height, one cell wide.
    Returns the error norm sum_p |sigma_p - sigma_a| V_p / (rho0 g l0 V0), sigma_a =
    -rho0 g (l0 - Y).  Implicit: 50 quasi-static load steps; explicit: gravity ramped over
    20 s with local damping 0.7 until at rest (or 400 s)."""
    h = 50.0 / cells
    scene = with_values(load_scene(MESHES / "compaction.toml"), {
        "grid.size": [h, 50.0], "grid.cell": h, "soil.polygon": [[0, 0], [h, 0], [h, 50], [0, 50]],
        "solver.shape": shape, "solver.scheme": scheme, "solver.damping": 0.7,
        "solver.gravity_ramp_time": 20.0, "solver.t_end": 400.0, "solver.rest_velocity": 1e-4,
        "solver.rest_energy_ratio": 1e-8})
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    (run_implicit if scheme == "implicit" else run_explicit)(scene, grid, pts)
    sigma_a = -0.8 * (50.0 - pts.x0[:, 1])
    return float(np.sum(np.abs(pts.stress[:, 1] - sigma_a) * pts.volume)
                 / (0.8 * 50.0 * pts.volume0.sum()))


@pytest.mark.parametrize("scheme,cells", [("implicit", (4, 8, 16, 32)),
                                          ("explicit", (8, 16, 32, 64))])
def test_cell_crossing_gimp_converges_standard_stalls(scheme, cells):
    """Compaction column (Bardenhagen & Kober 2004): under 4
    refinements the uGIMP stress error norm decreases monotonically (and by at least 2x
    overall); standard MPM does not: its error does not fall monotonically and the finest
    mesh is no better than half the coarsest (cell-crossing noise: points jump between
    cells with a discontinuous basis gradient)."""
    gimp = [_compaction(c, "gimp", scheme) for c in cells]
    std = [_compaction(c, "standard", scheme) for c in cells]
    print(scheme, "cells", cells, "gimp", [f"{e:.2e}" for e in gimp],
          "standard", [f"{e:.2e}" for e in std])
    assert all(b < a for a, b in zip(gimp, gimp[1:])) and gimp[-1] < 0.5 * gimp[0]
    assert not all(b < a for a, b in zip(std, std[1:]))
    assert std[-1] > 0.5 * std[0]
    assert gimp[-1] < std[-1]


@pytest.mark.slow
def test_validation_scripts_write_their_figures(tmp_path):
    """validation/stability_map.py (--quick) and validation/footing.py (--quick) run to the end
    and write one fresh PNG per study into a temporary directory (CFL, cell
    crossing, locking, points per cell, footing), with the JSON of numbers beside them.  The
    documented figures from them (docs/guide/choosing.md, docs/validation/footing.md):
    tests/test_readme_figures.py."""
    import json
    import subprocess
    import sys
    root = MESHES.parent
    for script in ("stability_map.py", "footing.py"):
        subprocess.run([sys.executable, str(root / "validation" / script), "--quick", "--out",
                        str(tmp_path)], check=True, cwd=root, capture_output=True)
    for name in ("stability_cfl", "stability_cell_crossing", "stability_locking",
                 "stability_ppc", "footing"):
        data = (tmp_path / f"{name}.png").read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    res = json.loads((tmp_path / "stability_map.json").read_text())
    assert set(res) == {"cfl", "crossing", "locking", "ppc"}
    assert json.loads((tmp_path / "footing.json").read_text())["runs"]
