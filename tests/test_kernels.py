"""The compiled explicit kernels (fem_rmpm.schemes.explicit.kernels) against their references.

* shape functions: scikit-fem's own ``ElementQuad1`` basis at the points
  (:func:`fem_rmpm.discretise.basis.skfem_point_basis`) and the numpy uGIMP basis
  (:func:`fem_rmpm.discretise.basis.gimp_at_points`);
* material update: :func:`fem_rmpm.materials.stress_update` and
  :func:`fem_rmpm.materials.small_strain_update` (elastic, linear and
  exponential softening, plastic points);
* whole steps and runs: the numpy reference step
  :func:`fem_rmpm.schemes.explicit.reference.explicit_step_numpy` /
  ``run_explicit(kernel="numpy")``.

Equality is to round-off: 1e-12 relative to the largest value of each field.
No timing here (speed lives in validation/bench_explicit.py).
"""
from __future__ import annotations

import numpy as np
import pytest
from soil_points import vm_points

from fem_rmpm.discretise.basis import gimp_at_points, skfem_point_basis
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.materials import small_strain_update, stress_update
from fem_rmpm.scene import load_scene, with_value, with_values
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.explicit import kernels as K
from fem_rmpm.schemes.explicit.loop import Workspace, explicit_step, run_explicit, stable_time_step

RTOL = 1e-12
FIELDS = ("x", "velocity", "stress", "log_strain", "plastic_shear_strain", "volume", "F",
          "u_geostatic")


def _rel(a, b):
    scale = max(float(np.max(np.abs(b))), 1e-300)
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) / scale


def _random_points(grid, n, rng, margin=0.0):
    lo = grid.origin + margin
    hi = grid.upper - margin
    return lo + rng.random((n, 2)) * (hi - lo)


def test_cell_index_is_the_clamped_floor():
    """:func:`fem_rmpm.schemes.explicit.kernels.basis.cell_index` truncates instead of taking the floor; the
    two clamped to the grid's cells are the same number (a formula: they differ only for
    negative non-integers, which clamp to 0).  Checked on the integers and halves around
    both grid edges, on negative zero, far outside, and on 20 000 random coordinates."""
    from numba import njit

    from fem_rmpm.schemes.explicit.kernels.basis import cell_index
    n = 7
    index = njit(lambda s: cell_index(s, n))
    edges = np.array([-1e15, -3.0, -1.5, -1.0, -0.5, -1e-300, -0.0, 0.0, 1e-300, 0.5, 1.0,
                      n - 1.5, n - 1.0, n - 0.5, n - 1e-12, float(n), n + 0.5, n + 2.0, 1e15])
    s = np.concatenate([edges, np.random.default_rng(3).uniform(-3 * n, 4 * n, 20_000)])
    expected = np.clip(np.floor(s), 0, n - 1).astype(np.int64)
    assert [index(v) for v in s] == expected.tolist()


def test_q4_kernel_equals_scikit_fem_basis(meshes):
    """Reference: scikit-fem ElementQuad1 evaluated at the points (skfem_point_basis)."""
    grid = make_grid(load_scene(meshes / "slope_elastic.toml"))
    x = _random_points(grid, 500, np.random.default_rng(1))
    nodes, N, dN = K.q4_shape(x, grid.origin, grid.cell, *grid.shape)
    basis = skfem_point_basis(grid, x, vector=False)
    cell = basis.tind
    assert np.array_equal(nodes, grid.cells[cell])          # local DOF a = mesh.t[a]
    for a in range(4):
        phi = basis.basis[a][0]
        assert np.allclose(N[:, a], np.asarray(phi)[:, 0], rtol=0, atol=1e-13)
        assert np.allclose(dN[:, a, 0], phi.grad[0][:, 0], rtol=0, atol=1e-12)
        assert np.allclose(dN[:, a, 1], phi.grad[1][:, 0], rtol=0, atol=1e-12)


def test_gimp_kernel_equals_numpy_gimp_including_grid_edges(meshes):
    """Reference: fem_rmpm.discretise.basis.gimp_at_points (uGIMP, Bardenhagen & Kober 2004)."""
    grid = make_grid(load_scene(meshes / "slope_elastic.toml"))
    rng = np.random.default_rng(2)
    x = np.vstack([_random_points(grid, 400, rng),
                   grid.origin + rng.random((50, 2)) * grid.cell,        # lower-left corner cells
                   grid.upper - rng.random((50, 2)) * grid.cell])        # upper-right corner cells
    lp = np.tile(grid.cell / 4, (len(x), 1)) * rng.uniform(0.5, 1.0, (len(x), 1))
    nodes, N, dN = K.gimp_shape(x, lp, grid.origin, grid.cell, *grid.shape)
    _, nodes_ref, N_ref, dN_ref, _ = gimp_at_points(grid, x, lp)
    assert np.array_equal(nodes, nodes_ref)
    assert _rel(N, N_ref) < RTOL and _rel(dN, dN_ref) < RTOL
    assert np.allclose(N.sum(axis=1), 1.0, atol=1e-14)


def _soil_mix(n, rng):
    """Elastic, linear and exponential softening points with a low strength (many yield)."""
    kind = np.arange(n) % 3
    G = rng.uniform(200, 600, n)
    Kb = G * rng.uniform(1.5, 4.0, n)
    cp = np.where(kind == 0, np.inf, rng.uniform(2.0, 8.0, n))
    cr = np.where(kind == 0, np.inf, cp * rng.uniform(0.2, 0.9, n))
    return vm_points(shear_modulus=G, bulk_modulus=Kb, cohesion_peak=cp, cohesion_residual=cr,
                      softening_strain=rng.uniform(0.05, 0.5, n), exponential=kind == 2)


def test_stress_update_kernel_equals_material_finite_strain():
    """Reference: fem_rmpm.materials.stress_update (Hencky + von Mises return, softening)."""
    rng = np.random.default_rng(3)
    n = 3000
    soil = _soil_mix(n, rng)
    th = rng.uniform(-np.pi, np.pi, n)                      # any rotation, small to large stretch
    R = np.stack([np.stack([np.cos(th), -np.sin(th)], 1), np.stack([np.sin(th), np.cos(th)], 1)], 1)
    scale = np.where(np.arange(n) % 2 == 0, 1e-4, 0.1)[:, None, None]
    dF = R @ (np.eye(2) + scale * rng.normal(size=(n, 2, 2)))
    eps = rng.normal(size=(n, 4)) * np.where(np.arange(n) % 5 == 0, 1e-5, 0.05)[:, None]
    gam = np.where(np.arange(n) % 4 == 0, 0.0, rng.uniform(0, 0.8, n))
    e_ref, g_ref, t_ref = stress_update(dF, eps, gam, soil)
    e, g, t = K.stress_update_points(dF, eps, gam, soil)
    plastic = g_ref > gam
    assert plastic.sum() > n // 4 and (plastic & (soil.softening == 1)).any()
    assert (plastic & (soil.softening == 0)).any()
    assert _rel(e, e_ref) < RTOL and _rel(g, g_ref) < RTOL and _rel(t, t_ref) < RTOL


def test_small_strain_update_kernel_equals_material():
    """Reference: fem_rmpm.materials.small_strain_update (geostatic phase)."""
    rng = np.random.default_rng(4)
    n = 2000
    soil = _soil_mix(n, rng)
    grad = rng.normal(size=(n, 2, 2)) * 0.01
    eps = rng.normal(size=(n, 4)) * 0.01
    gam = rng.uniform(0, 0.3, n)
    e_ref, g_ref, t_ref = small_strain_update(grad, eps, gam, soil)
    e, g, t = K.small_strain_update_points(grad, eps, gam, soil)
    assert (g_ref > gam).sum() > n // 4
    assert _rel(e, e_ref) < RTOL and _rel(g, g_ref) < RTOL and _rel(t, t_ref) < RTOL


def _steps_both(scene, n_geo, n_dyn, gravity_factor, damping=0.7, flip=1.0):
    grid = make_grid(scene)
    a = seed_particles(scene, grid)
    b = a.copy()
    g = np.array(scene.gravity_vector) * gravity_factor
    work = Workspace.for_grid(grid, b.n)
    shape = scene.solver.shape
    for k in range(n_geo + n_dyn):
        dt = stable_time_step(a, grid.cell, 0.5)
        sa = explicit_step(grid, a, dt, g, damping, flip, shape, k < n_geo, kernel="numpy")
        sb = explicit_step(grid, b, dt, g, damping, flip, shape, k < n_geo, kernel="numba",
                           work=work)
        assert abs(sb.kinetic_energy - sa.kinetic_energy) <= RTOL * sa.kinetic_energy
        assert abs(sb.max_speed - sa.max_speed) <= RTOL * sa.max_speed
        assert sb.wave_speed + sb.point_speed == pytest.approx(
            0.5 * float(np.min(grid.cell)) / stable_time_step(b, grid.cell, 0.5), rel=1e-14)
    return a, b


def test_step_elastic_slope_equals_numpy_step(meshes):
    """Reference: explicit_step_numpy on the reference elastic slope (18 260 points),
    geostatic (small strain) then finite-strain steps under 30 g."""
    scene = load_scene(meshes / "slope_elastic.toml")
    a, b = _steps_both(scene, 3, 8, 30.0)
    assert np.abs(a.x - a.x0).max() > 1e-4                 # the points did move
    for f in FIELDS:
        assert _rel(getattr(b, f), getattr(a, f)) < RTOL, f


@pytest.mark.parametrize("shape,law,flip", [("standard", "linear", 1.0),
                                            ("gimp", "exponential", 0.9),
                                            ("gimp", "linear", 1.0)])
def test_step_softening_equals_numpy_step(meshes, shape, law, flip):
    """Reference: explicit_step_numpy on a coarse softening slope with many plastic points
    (Q4 and uGIMP, linear and exponential softening, FLIP/PIC blend)."""
    scene = load_scene(meshes / "slope_elastic.toml")
    scene = with_values(scene, {"grid.cell": [0.5, 0.5], "solver.shape": shape,
                                "soil.model": "von_mises_softening", "soil.cohesion_peak": 3.0,
                                "soil.cohesion_residual": 1.0, "soil.softening": law,
                                "soil.softening_strain": 0.05})
    a, b = _steps_both(scene, 3, 12, 20.0, flip=flip)
    assert (a.plastic_shear_strain > 0).sum() > 100         # the return mapping was exercised
    for f in FIELDS:
        assert _rel(getattr(b, f), getattr(a, f)) < RTOL, f


def test_run_explicit_numba_equals_numpy_run(meshes):
    """Reference: run_explicit(kernel="numpy") on the column under self-weight (the damped
    gravity phase, first 1.5 s): same steps, same stop, same state.

    Not to 4 s: this run amplifies round-off — the compiled run against itself with ONE
    point's x moved by one ulp differs in stress by 3e-16 at 0.5 s, 7.5e-14 at 1.5 s,
    1.6e-12 at 2 s, 3.4e-7 at 3 s and 2.6e-4 at 4 s — and the two steps round
    differently (operation order; the compiled Hencky exp / log are series of their own),
    so to 4 s they differ by about 2.6e-4 in stress.  To 1.5 s it achieves 4.5e-14 (stress; 5.7e-15
    u_geostatic, x and dt_min equal); asserts 1e-10."""
    scene = with_value(load_scene(meshes / "column.toml"), "solver.t_end", 1.5)
    grid = make_grid(scene)
    a = seed_particles(scene, grid)
    b = a.copy()
    ra = run_explicit(scene, grid, a, kernel="numpy")
    rb = run_explicit(scene, grid, b, kernel="numba")
    assert rb.steps == ra.steps > 100 and rb.stop_reason == ra.stop_reason
    assert rb.dt_min == pytest.approx(ra.dt_min, rel=1e-13, abs=0)
    for f in ("x", "stress", "log_strain", "u_geostatic"):
        assert _rel(getattr(b, f), getattr(a, f)) < 1e-10, f


def test_non_finite_state_stops_numba_run_like_numpy(meshes):
    """Reference: the guard of check_points (run.py) — a NaN stress stops both kernels."""
    scene = with_value(load_scene(meshes / "column.toml"), "solver.t_end", 0.1)
    for kernel in ("numpy", "numba"):
        grid = make_grid(scene)
        pts = seed_particles(scene, grid)
        pts.stress[5, 1] = np.nan
        with pytest.raises(SimulationError, match="non-finite state at material point"):
            run_explicit(scene, grid, pts, kernel=kernel)
