"""The closed-form symmetric 3x3 eigen-decomposition of the 3-D step
(:func:`fem_rmpm.schemes.explicit3d.elastic.sym_eig3`) against ``numpy.linalg.eigh``
(LAPACK): eigenvalues, the tensor rebuilt from the eigenpairs and the orthonormality of the
eigenvectors, on random, nearly degenerate, exactly degenerate and near-identity matrices
(the elastic stretch of a soil point is the identity plus strains of 1e-12 to 1e-1)."""
from __future__ import annotations

import numpy as np
import pytest

from fem_rmpm.schemes.explicit3d.elastic import eig_blocks, spectral_3d

#: Achieved: 2.2e-15 of the largest |eigenvalue| over 4000 matrices of each kind.
TOL = 1e-14


def _six(A):
    return A[[0, 1, 2, 0, 1, 0], [0, 1, 2, 1, 2, 2]]


def _eigenvalues(kind, rng):
    if kind == "random":
        return rng.normal(size=3) * 10.0 ** rng.uniform(-3, 3)
    if kind == "near-degenerate":
        lam = rng.normal()
        return np.array([lam, lam * (1 + 10.0 ** rng.uniform(-16, -4)), rng.normal()])
    if kind == "double":
        lam = rng.normal()
        return np.array([lam, lam, rng.normal()])
    if kind == "triple":
        return np.full(3, rng.normal())
    lam = 1 + rng.normal(size=3) * 10.0 ** rng.uniform(-12, -1)     # near the identity
    lam[1] = lam[0] + 1e-14 * rng.normal()
    return lam


@pytest.mark.parametrize("kind", ["random", "near-degenerate", "double", "triple",
                                  "near-identity"])
def test_eigen_decomposition_matches_lapack(kind):
    """Eigenvalues within 1e-14 |A| of LAPACK's, A rebuilt from the eigenpairs within 1e-14
    |A|, eigenvectors orthonormal within 1e-14, whatever the multiplicity."""
    rng = np.random.default_rng(["random", "near-degenerate", "double", "triple",
                                 "near-identity"].index(kind))
    err_w = err_a = err_q = 0.0
    for _ in range(4000):
        R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        A = R @ np.diag(_eigenvalues(kind, rng)) @ R.T
        A = 0.5 * (A + A.T)
        scale = np.abs(np.linalg.eigvalsh(A)).max()
        w = spectral_3d(_six(A), 0)
        Q = spectral_3d(_six(A), 3).reshape(3, 3)           # rows: the eigenvectors
        err_w = max(err_w, np.abs(np.sort(w) - np.linalg.eigvalsh(A)).max() / scale)
        err_a = max(err_a, np.abs(Q.T @ np.diag(w) @ Q - A).max() / scale)
        err_q = max(err_q, np.abs(Q @ Q.T - np.eye(3)).max())
    assert err_w < TOL and err_a < TOL and err_q < TOL, (err_w, err_a, err_q)


def test_eigen_decomposition_of_diagonal_and_zero_matrices():
    """Diagonal matrices give their diagonal and the unit vectors; the zero matrix zeros."""
    for d in ([3.0, -1.0, 2.0], [1.0, 1.0, -2.0], [0.0, 0.0, 0.0], [5.0, 5.0, 5.0]):
        v = np.array([*d, 0.0, 0.0, 0.0])
        assert np.allclose(np.sort(spectral_3d(v, 0)), np.sort(d), rtol=0, atol=1e-15)
        Q = np.abs(spectral_3d(v, 3).reshape(3, 3))
        assert np.allclose(np.sort(Q, axis=None), [0] * 6 + [1] * 3, atol=1e-15)


def test_vectorized_blocks_give_the_one_point_results_bitwise():
    """The stress pass's blocked eigen-decomposition (:func:`~fem_rmpm.schemes.explicit3d.
    elastic.sym_eig3_block`, vectorized by LLVM) performs the IEEE operations of
    :func:`~fem_rmpm.schemes.explicit3d.elastic.sym_eig3` on each point, so eigenvalues
    and eigenvectors are the same bits as one point at a time, over random, degenerate,
    near-identity, zero and NaN tensors in blocks with a partial last block."""
    rng = np.random.default_rng(11)
    kinds = ["random", "near-degenerate", "double", "triple", "near-identity"]
    rows = []
    for k in range(1000):
        R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        A = R @ np.diag(_eigenvalues(kinds[k % 5], rng)) @ R.T
        rows.append(_six(0.5 * (A + A.T)))
    rows += [np.zeros(6), np.array([2.0, 2.0, 2.0, 0, 0, 0]), np.full(6, np.nan)]
    a6 = np.array(rows)
    got = eig_blocks(a6)
    one = np.array([np.concatenate([spectral_3d(r, 0), spectral_3d(r, 3)]) for r in a6])
    assert np.array_equal(got, one, equal_nan=True)
