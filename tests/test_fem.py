"""Static FEM reference (against the column's closed form) and the material points as
quadrature (against scikit-fem's own Gauss-point assembly)."""
from __future__ import annotations

import numpy as np

from fem_rmpm.discretise.basis import skfem_point_basis
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles, soil_cells
from fem_rmpm.scene import load_scene
from fem_rmpm.schemes.fem import _lame, elastic_stiffness, gravity_load, solve_static


def _column_closed_form(y, H=5.0, gamma=20.0, E=1000.0, nu=0.33):
    M = E * (1 - nu) / ((1 + nu) * (1 - 2 * nu))
    return -(gamma / M) * (H * y - y * y / 2), M


def test_column_fem_matches_closed_form(meshes):
    """Closed form: u_y(y) = -(gamma/M)(H y - y^2/2), M = E(1-nu)/((1+nu)(1-2nu)) =
    1481.6 kPa, top -0.1687 m; Q4 elements reproduce it at the nodes (relative < 1e-8)."""
    res = solve_static(load_scene(meshes / "column.toml"))
    used = np.unique(res.grid.cells[res.cells])
    y = res.grid.nodes[used, 1]
    ua, M = _column_closed_form(y)
    assert abs(M - 1481.6) < 0.1
    err = np.max(np.abs(res.displacement[used, 1] - ua)) / np.max(np.abs(ua))
    assert err < 1e-8
    assert np.allclose(res.displacement[used, 0], 0.0, atol=1e-14)
    assert abs(res.displacement[:, 1].min() - (-0.1687)) < 5e-5
    # K0 state at the Gauss points: sigma_xx = sigma_zz = nu/(1-nu) sigma_yy
    k0 = 0.33 / 0.67
    assert np.allclose(res.stress[:, 0], k0 * res.stress[:, 1], rtol=1e-10)


def test_points_as_quadrature_equal_fem_assembly(meshes):
    """With points at the 2x2 Gauss points and volume area/4 (0.25 detJ
    on [-1, 1]^2), stiffness and gravity load assembled by scikit-fem with the points as
    quadrature equal scikit-fem's FEM ones to relative 1e-10 (column and reference slope)."""
    for name in ("column.toml", "slope_elastic.toml"):
        scene = load_scene(meshes / name)
        grid = make_grid(scene)
        pts = seed_particles(scene, grid)
        res = solve_static(scene, grid)
        basis = skfem_point_basis(grid, pts.x)
        scale = pts.volume[:, None] / basis.dx                 # point volume / cell Jacobian
        lam, mu, rho = _lame(scene, pts.soil_id)
        K = elastic_stiffness(basis, lam * scale, mu * scale)
        f = gravity_load(basis, rho * scale, scene.gravity_vector)
        dK = abs(K - res.K).max() / abs(res.K).max()
        df = np.abs(f - res.f).max() / np.abs(res.f).max()
        assert dK < 1e-10, (name, dK)
        assert df < 1e-10, (name, df)


def test_soil_cells_cover_reference_slope(meshes):
    """The reference slope (Wang, Vardon & Hicks 2017): about 4600 Q4 elements of 0.25 m,
    4 material points each."""
    scene = load_scene(meshes / "slope_elastic.toml")
    grid = make_grid(scene)
    n_cells = int((soil_cells(scene, grid) >= 0).sum())
    assert 4400 <= n_cells <= 4800
    assert seed_particles(scene, grid).n == 4 * n_cells
