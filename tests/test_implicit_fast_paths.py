"""The fast paths of the implicit scheme and of strength reduction against their
references: the compiled sparsity pattern against the sorted block keys, the compiled
B-bar tangent against the sparse products of
:func:`fem_rmpm.schemes.locking.bbar_tangent_correction`, the StepSystem reused on a fixed
geometry, and the search that skips continuation solves already known to fail against
the search that runs them again (the same decisions, the same FS)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.scene import with_values
from fem_rmpm.schemes.implicit import LinearSolver, strength_reduction
from fem_rmpm.schemes.implicit.assembly import StepSystem
from fem_rmpm.schemes.implicit.steps import ImplicitSystem
from fem_rmpm.schemes.implicit.strength_reduction import (
    FSOptions,
    KnownFailures,
    factor_of_safety,
)


def infinite_slope(meshes, c, rows=8, hx=1.0, z=5.0, beta=30.0, length=12.0):
    sc = api.load_scene(meshes / "infinite_slope.toml")
    t = z * math.cos(math.radians(beta))
    L = length * t
    return with_values(sc, {"scene.frame_angle_deg": beta, "grid.size": [L, t],
                            "grid.cell": [hx * t, t / rows],
                            "soil.polygon": [[0, 0], [L, 0], [L, t], [0, t]],
                            "soil.cohesion_peak": c, "soil.cohesion_residual": c})


def _pattern_by_sorting(gd: np.ndarray, nf: int):
    """The reference of :func:`point_kernels.block_pattern`: the sorted unique keys
    ``row * nf + col`` of every block entry ``[a, i, l, b]`` of every node set."""
    ng, m = gd.shape
    k = m // 2
    g3 = gd.reshape(ng, k, 2)
    rows = np.broadcast_to(g3[:, :, :, None, None], (ng, k, 2, 2, k)).ravel()
    cols = np.broadcast_to(np.swapaxes(g3, 1, 2)[:, None, None, :, :], (ng, k, 2, 2, k)).ravel()
    keep = (rows >= 0) & (cols >= 0)
    ukey, pos = np.unique(rows[keep] * nf + cols[keep], return_inverse=True)
    positions = np.full(ng * m * m, -1, dtype=np.int64)
    positions[keep] = pos.ravel()
    indptr = np.searchsorted(ukey, np.arange(nf + 1) * nf)
    return indptr, ukey % nf, positions.reshape(ng, m * m), ukey


@pytest.mark.parametrize("shape", ["standard", "gimp"])
def test_block_pattern_equals_sorted_keys(meshes, shape):
    """The one-pass pattern of the grid reset (the reference slope's points moved at
    random, prescribed DOFs at the base and sides; Q4 and uGIMP node sets) equals the
    sorted unique block keys: the same row pointer, columns and block positions; the
    diagonal and transpose gathers point at the entries (r, r) and (c, r)."""
    from fem_rmpm.schemes.implicit import point_kernels as pk
    sc = with_values(api.load_scene(meshes / "slope_reference.toml"), {"solver.shape": shape})
    grid, pts = api.prepare(sc)
    x = pts.x + np.random.default_rng(3).normal(scale=0.06, size=pts.x.shape)
    S = StepSystem(grid, x, shape, pts.half_width)
    first = np.zeros(S.n_groups, dtype=np.int64)
    first[S._group] = np.arange(S.n)
    gd = np.ascontiguousarray(S.fnum[S.point_dofs[first]])
    assert (gd < 0).any()                            # prescribed DOFs are in the sets
    indptr, indices, positions, diag, transpose = pk.block_pattern(gd, S.n_free)
    r_indptr, r_indices, r_positions, key = _pattern_by_sorting(gd, S.n_free)
    assert np.array_equal(indptr, r_indptr) and np.array_equal(indices, r_indices)
    assert np.array_equal(positions, r_positions)
    row = np.repeat(np.arange(S.n_free), np.diff(indptr))
    assert np.array_equal(key[diag], np.arange(S.n_free) * (S.n_free + 1))
    assert np.array_equal(key[transpose], indices.astype(np.int64) * S.n_free + row)


def test_compiled_bbar_tangent_equals_sparse_products(meshes):
    """Random symmetric point tangents D on the reference slope's points: the one-pass
    compiled B-bar tangent equals the standard tangent plus the sparse-product B-bar
    correction to round-off (1e-14 of the largest entry; seen: 5e-16), and is symmetric."""
    sc = api.load_scene(meshes / "slope_reference.toml")
    grid, pts = api.prepare(sc)
    S = StepSystem(grid, pts.x, "standard")
    assert S.groups_are_cells
    rng = np.random.default_rng(1)
    n = S.n
    D = rng.normal(size=(n, 2, 2, 2, 2))
    D = D + D.transpose(0, 3, 4, 1, 2)
    w = rng.uniform(0.2, 1.0, n)
    w = w / np.bincount(S.cell, w)[S.cell]
    V0 = rng.uniform(0.01, 0.1, n)
    ref = S.tangent(V0, S.dN, D) + S.bbar_tangent(V0, S.dN, D, w)
    K = S.tangent_with_bbar(V0, S.dN, D, w)
    scale = abs(ref).max()
    assert abs(K - ref).max() <= 1e-14 * scale
    assert abs(K - K.T).max() <= 1e-14 * scale


def test_step_system_reused_while_points_stay(meshes):
    """Same active points at the same positions: the cached StepSystem; a moved point or
    another active set: a new one."""
    sc = api.load_scene(meshes / "slope_elastic.toml")
    grid, pts = api.prepare(sc)
    sys_ = ImplicitSystem(sc, grid, pts, LinearSolver("cholmod"))
    act = np.nonzero(pts.active)[0]
    S1 = sys_._step_system(act)
    assert sys_._step_system(act) is S1
    pts.x[0, 0] += 1e-9
    assert sys_._step_system(act) is not S1
    assert sys_._step_system(act[1:]) is not sys_._step_system(act)


def test_known_failures_skip_without_changing_the_search(meshes, monkeypatch):
    """Infinite slope (c = 60 kPa: FS 1.48 on this mesh) searched twice: with the
    continuation solves known to fail skipped, and with every solve run again.  Same
    trials (F, converged, reached), same FS; no more iterations (the search aims below
    the lowest failed solve, so it rarely asks for a known one)."""
    sc = infinite_slope(meshes, c=60.0)
    grid, pts = api.prepare(sc)
    fast = factor_of_safety(sc, options=FSOptions(), grid=grid, pts=pts)
    monkeypatch.setattr(KnownFailures, "get", lambda self, state_id, target: None)
    grid, pts = api.prepare(sc)
    plain = factor_of_safety(sc, options=FSOptions(), grid=grid, pts=pts)
    assert fast.bound == plain.bound == "="
    assert fast.fs == pytest.approx(plain.fs, rel=1e-12)
    assert [t.converged for t in fast.trials] == [t.converged for t in plain.trials]
    for a, b in zip(fast.trials, plain.trials, strict=True):
        assert (a.F, a.reached) == pytest.approx((b.F, b.reached), rel=1e-12)
    its = sum(t.iterations for t in fast.trials)
    assert its <= sum(t.iterations for t in plain.trials)


def test_search_uses_one_solver_policy():
    """Strength reduction factorizes as the implicit scheme does (CHOLMOD by default)."""
    assert FSOptions().linear_solver == "cholmod"
    assert strength_reduction.FSOptions.__dataclass_fields__["linear_solver"].default == \
        "cholmod"


def test_halo_pattern_solves_as_the_exact_one(meshes):
    """A dynamic step's system on the occupied cells plus a halo of empty cells (free
    DOFs with only the mass-floor diagonal) gives the same nodal solution of
    ``(K + diag(d)) u = f`` as the system on the occupied cells alone, to round-off
    (1e-12 of the largest); a later step whose points stay in those cells keeps the
    numbering and pattern, one whose point leaves them gets new ones."""
    import scipy.sparse.linalg as spla
    sc = api.load_scene(meshes / "slope_reference.toml")
    grid, pts = api.prepare(sc)
    rng = np.random.default_rng(5)
    exact = StepSystem(grid, pts.x)
    halo = StepSystem(grid, pts.x, halo=True)
    assert halo.n_free > exact.n_free and halo.halo_cells is not None
    n = exact.n
    A = rng.normal(size=(n, 2, 2, 2, 2))
    A = 0.5 * (A + A.transpose(0, 3, 4, 1, 2)) + 4.0 * np.einsum(
        "ik,jl->ijkl", np.eye(2), np.eye(2))[None]
    V0 = pts.volume0

    def nodal_solution(S):
        d = np.full(S.n_free, 50.0)                  # the Newmark mass term
        K = S.tangent(V0, S.dN, A, diagonal=d)
        f = S.body_force(pts.mass, [0.3, -9.81])
        return S.to_nodes(spla.spsolve(K.tocsc(), f))

    u_exact, u_halo = nodal_solution(exact), nodal_solution(halo)
    assert np.abs(u_halo - u_exact).max() <= 1e-12 * np.abs(u_exact).max()
    nudged = pts.x + rng.uniform(-1e-3, 1e-3, pts.x.shape)
    kept = StepSystem(grid, nudged, keep=halo, halo=True)
    assert kept._indices is halo._indices and kept.n_free == halo.n_free
    far = pts.x.copy()
    far[0] += [30.0, 20.0]                              # into an empty cell far away
    moved = StepSystem(grid, far, keep=halo, halo=True)
    assert moved._indices is not halo._indices
    assert moved._group_of[moved.nodes[0, 0]] >= 0


def test_compiled_point_sums_equal_the_numpy_sums_bitwise(meshes):
    """The step system's compiled point loops against numpy's sums in point order
    (``bincount``, ``einsum``) on the reference slope's points, moved a little: nodal
    mass and momenta, the body force on the free DOFs and a nodal vector at the points,
    equal to the last bit (measured: 0 difference)."""
    sc = api.load_scene(meshes / "slope_reference.toml")
    grid, pts = api.prepare(sc)
    rng = np.random.default_rng(3)
    S = StepSystem(grid, pts.x + rng.uniform(-0.05, 0.05, pts.x.shape))
    nn, m = grid.n_nodes, pts.mass
    v, a = rng.normal(size=(S.n, 2)), rng.normal(size=(S.n, 2))
    w = S.N * m[:, None]

    def nodal(per_point):                                # (n, k) -> (n_nodes,)
        return np.bincount(S.nodes.ravel(), per_point.ravel(), minlength=nn)
    M, MV, MA = S.mass_and_momenta(m, v, a)
    assert np.array_equal(M, nodal(w))
    for got, vec in ((MV, v), (MA, a)):
        assert np.array_equal(got, np.stack([nodal(w * vec[:, k:k + 1]) for k in range(2)], 1))
    g = np.array([0.3, -9.81])
    force = np.bincount(S.point_dofs.ravel(), (S.N[:, :, None] * m[:, None, None] * g).ravel(),
                        minlength=2 * nn)[S.free_dofs]
    assert np.array_equal(S.body_force(m, g), force)
    u = rng.normal(size=(nn, 2))
    assert np.array_equal(S.interpolate(u), np.einsum("pa,pai->pi", S.N, u[S.nodes]))
