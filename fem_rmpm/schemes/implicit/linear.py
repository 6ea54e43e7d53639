"""Linear solvers of the implicit Newton iteration.

``"cholmod"``: sparse Cholesky (SuiteSparse CHOLMOD through cvxopt) of a symmetric
positive-definite tangent -- the usual case of a dynamic step, whose mass term
``m / (beta dt^2)`` dominates the diagonal; the symbolic analysis (fill-reducing
ordering, elimination tree, supernodes) is done once per sparsity pattern and reused by
every factorization while the pattern stays, the numeric factorization alone is
repeated.  A tangent that is not symmetric (F-bar coupling, non-associated flow: checked
entry by entry against its transpose, 1e-12 of the largest) or not positive definite
(softening under large steps), or a missing cvxopt, goes to SuperLU for that solve;
``factorizations_by`` counts which solver did each.
``"superlu"`` (default): sparse LU of the free-DOF tangent with ``permc_spec =
"MMD_AT_PLUS_A"`` (about 2x the default ordering on these 2-D meshes).  ``"pyamg"``:
conjugate gradients preconditioned by pyamg smoothed aggregation whose near-null space is
the three 2-D rigid-body modes (the default constant vectors fail to converge on
elasticity) and a sparse-LU coarse solve; the hierarchy is built once per step and
reused by its Newton iterations; GMRES takes over if CG fails (softening makes the
tangent indefinite).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit
from scipy.sparse.linalg import cg, gmres, splu

try:                                   # SuiteSparse's CHOLMOD (cvxopt ships it in its wheels)
    import cvxopt
    from cvxopt import cholmod
except ImportError:                    # pragma: no cover - a core dependency
    cvxopt = cholmod = None

__all__ = ["LinearSolver", "LinearSolveError", "LowerTangent"]


class LinearSolveError(RuntimeError):
    pass


class LowerTangent:
    """A symmetric free-DOF tangent given by the data of its lower triangle in CHOLMOD's
    order (CSR row ``j`` from the diagonal on: column ``j`` of the lower triangle), on the
    CSR pattern ``indptr``, ``indices`` (the step's, :class:`.assembly.StepSystem`);
    symmetric to round-off (checked where it was assembled).  ``full()`` assembles the
    whole matrix (CSR) for a solver that needs it: SuperLU, pyamg, or CHOLMOD's fallback
    to SuperLU when the tangent is not positive definite."""

    def __init__(self, lower_data: np.ndarray, indptr: np.ndarray, indices: np.ndarray,
                 full):
        self.lower_data, self.indptr, self.indices = lower_data, indptr, indices
        self._full = full
        self.shape = (len(indptr) - 1, len(indptr) - 1)

    def full(self) -> sp.csr_matrix:
        """The whole matrix (CSR), assembled on first call."""
        if not isinstance(self._full, sp.csr_matrix):
            self._full = self._full()
        return self._full


class LinearSolver:
    """``"superlu"``: LU with MMD_AT_PLUS_A ordering; ``"pyamg"``: CG (GMRES fallback)
    preconditioned by smoothed aggregation with rigid-body modes, hierarchy kept per step."""

    def __init__(self, kind: str = "superlu"):
        self.kind = kind
        self._ml = None
        self._order = None        # fill-reducing ordering of the last sparsity pattern
        self._chol = None         # CHOLMOD's symbolic factor of the last sparsity pattern
        self.factorizations = 0
        self.factorizations_by = {"cholmod": 0, "superlu": 0}
        self.symbolic_analyses = 0
        self._system = None       # the step's StepSystem (its pattern's transpose gather)
        self._last = None         # solve with the last factorization (quasi-Newton)

    def new_step(self, system=None) -> None:
        """A new step: the pyamg hierarchy is rebuilt (the LU ordering and CHOLMOD's
        symbolic factor of a sparsity pattern are kept while the pattern stays).
        ``system``: the step's :class:`~fem_rmpm.schemes.implicit.assembly.StepSystem`,
        whose tangents share its CSR index arrays; CHOLMOD then takes the transpose
        gather of the pattern from it instead of searching for it."""
        self._ml = None
        self._system = system
        self._last = None

    def can_resolve(self) -> bool:
        """Whether :meth:`resolve` has a factorization of this step to use."""
        return self._last is not None

    def resolve(self, b: np.ndarray) -> np.ndarray:
        """``K0^-1 b`` with the last factorization ``K0`` of this step (CHOLMOD or
        SuperLU; one forward and back substitution, no factorization)."""
        if self._last is None:
            raise LinearSolveError("no factorization to reuse in this step")
        x = self._last(b)
        if not np.all(np.isfinite(x)):
            raise LinearSolveError("the reused factorization returned a non-finite solution")
        return x

    def solve(self, K, b: np.ndarray, modes=None, rtol: float = 1e-10) -> np.ndarray:
        """``K^-1 b``; ``K`` a CSR matrix or a :class:`LowerTangent`."""
        self._last = None
        if self.kind == "cholmod":
            return self._cholmod(K, b)
        if isinstance(K, LowerTangent):
            K = K.full()
        if self.kind == "superlu":
            return self._superlu(K, b)
        return self._pyamg(K, b, modes, rtol)

    def _cholmod(self, K: sp.csr_matrix, b: np.ndarray) -> np.ndarray:
        """Sparse Cholesky with the symbolic factor of the pattern reused (see the module
        docstring); SuperLU where the tangent is not symmetric positive definite."""
        given = isinstance(K, LowerTangent)
        if cholmod is None:
            return self._superlu(K.full() if given else K, b)
        c = self._chol
        if c is None or not (_same(c["indptr"], K.indptr) and _same(c["indices"], K.indices)):
            S = self._system
            ours = S is not None and _same(K.indptr, S._indptr) \
                and _same(K.indices, S._indices)
            pattern = sp.csr_matrix((np.zeros(len(K.indices)), K.indices, K.indptr),
                                    shape=K.shape) if given else K
            c = self._chol = _cholmod_pattern(pattern, S.transpose if ours else None)
            self.symbolic_analyses += 1
        if c["transpose"] is None:
            return self._superlu(K.full() if given else K, b)
        if given:                            # the lower triangle, checked symmetric
            lower = K.lower_data
        else:
            lower = symmetric_lower(K.data, c["transpose"], c["lower"], 1e-12)
            if lower is None:
                return self._superlu(K, b)
        c["A"].V = cvxopt.matrix(lower)
        try:
            if c["F"] is None:
                c["F"] = cholmod.symbolic(c["A"], uplo="L")
            cholmod.numeric(c["A"], c["F"])
        except ArithmeticError:              # not positive definite
            return self._superlu(K.full() if given else K, b)
        x = _cholmod_solve(c["F"], b)
        if not np.all(np.isfinite(x)):
            return self._superlu(K.full() if given else K, b)
        self._last = lambda r, F=c["F"]: _cholmod_solve(F, r)
        self.factorizations += 1
        self.factorizations_by["cholmod"] += 1
        return x

    def _superlu(self, K: sp.csr_matrix, b: np.ndarray) -> np.ndarray:
        """Sparse LU.

        A factorization reuses the fill-reducing ordering (MMD_AT_PLUS_A) of its
        pattern: the matrix is permuted by a precomputed gather and factorized in its
        natural order (same fill, no ordering work: 15 instead of 20 ms CPU at 9159 DOFs,
        case (i)).  The pattern stays through the Newton iterations of a step and often
        from step to step (in 11 of 20 steps of case (i)'s first second).  (Tried and
        dropped: the step's last factors as a GMRES preconditioner for the next Newton
        iterations -- half the solves needed more than 8 iterations, no gain overall.)
        """
        o = self._order
        same = o is not None and np.array_equal(o["indptr"], K.indptr) \
            and np.array_equal(o["indices"], K.indices)
        try:
            if same:
                ip = o["ip"]
                lu = splu(sp.csc_matrix((K.data[o["gather"]], o["p_indices"], o["p_indptr"]),
                                        shape=K.shape), permc_spec="NATURAL")

                def apply(r, lu=lu, ip=ip):
                    y = np.empty_like(r)
                    y[ip] = lu.solve(r[ip])
                    return y
            else:
                lu = splu(K.tocsc(), permc_spec="MMD_AT_PLUS_A")
                self._order = _ordering(K, np.argsort(lu.perm_c))
                apply = lu.solve
        except RuntimeError as exc:           # "Factor is exactly singular"
            raise LinearSolveError(f"SuperLU: {exc}") from None
        self.factorizations += 1
        self.factorizations_by["superlu"] += 1
        x = apply(b)
        if not np.all(np.isfinite(x)):
            raise LinearSolveError("SuperLU returned a non-finite solution (singular tangent)")
        self._last = apply
        return x

    def _pyamg(self, K, b, modes, rtol):
        import pyamg  # lazy: only when chosen; its import costs ~0.3 s a run would not need
        if self._ml is None:
            B = modes() if callable(modes) else modes
            self._ml = pyamg.smoothed_aggregation_solver(K, B=B, max_coarse=500,
                                                         coarse_solver="splu")
        M = self._ml.aspreconditioner(cycle="V")
        x, info = cg(K, b, rtol=rtol, atol=0.0, maxiter=500, M=M)
        if info != 0 or not np.all(np.isfinite(x)):
            x, info = gmres(K, b, rtol=rtol, atol=0.0, restart=60, maxiter=20, M=M)
            if info != 0 or not np.all(np.isfinite(x)):
                raise LinearSolveError(f"pyamg-preconditioned CG and GMRES did not reach "
                                       f"rtol {rtol:.1e} (info {info})")
        return x



def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two index arrays are equal (the same array object: at once)."""
    return a is b or np.array_equal(a, b)


def _ordering(K: sp.csr_matrix, ip: np.ndarray) -> dict:
    """The pattern of ``K`` and, for the symmetric permutation ``K[ip][:, ip]`` in CSC,
    its index arrays and the gather of ``K.data`` that fills it."""
    marker = sp.csr_matrix((np.arange(1, K.nnz + 1, dtype=float), K.indices, K.indptr),
                           shape=K.shape)
    Kp = marker[ip][:, ip].tocsc()
    Kp.sort_indices()
    return {"indptr": K.indptr.copy(), "indices": K.indices.copy(), "ip": ip,
            "gather": Kp.data.astype(np.int64) - 1, "p_indices": Kp.indices,
            "p_indptr": Kp.indptr}


def _cholmod_solve(F, b: np.ndarray) -> np.ndarray:
    x = cvxopt.matrix(np.array(b, dtype=float))
    cholmod.solve(F, x)
    return np.array(x).ravel()


def symmetric_lower(data: np.ndarray, transpose: np.ndarray, lower: np.ndarray,
                    rtol: float) -> np.ndarray | None:
    """``data[lower]`` if the matrix is symmetric to ``rtol`` of its largest entry
    (``|data - data[transpose]| <= rtol max|data|``), else None (one compiled pass)."""
    out = np.empty(len(lower))
    return out if _symmetric_lower(data, transpose, lower, rtol, out) else None


@njit(cache=True)
def _symmetric_lower(data, transpose, lower, rtol, out):
    big = 0.0
    diff = 0.0
    for q in range(len(data)):
        a = abs(data[q])
        if a > big:
            big = a
        d = abs(data[q] - data[transpose[q]])
        if d > diff:
            diff = d
    for j in range(len(lower)):
        out[j] = data[lower[j]]
    return diff <= rtol * big


def _cholmod_pattern(K: sp.csr_matrix, transpose: np.ndarray | None = None) -> dict:
    """For a CSR pattern: the entries of its lower triangle in
    CHOLMOD's column order (CSR row ``j`` from the diagonal on is column ``j`` of the lower
    triangle of a symmetric matrix), the gather ``transpose`` with ``data[transpose]`` the
    data of ``K^T`` in ``K``'s pattern (None for a pattern that is not symmetric, e.g.
    with the F-bar coupling), and cvxopt's matrix of that triangle (its values are
    replaced per factorization).  ``transpose``: that gather if known (a symmetric
    pattern built with it, :func:`.point_kernels.block_pattern`)."""
    n = K.shape[0]
    row = np.repeat(np.arange(n, dtype=np.int64), np.diff(K.indptr))
    col = K.indices.astype(np.int64)
    base = {"indptr": K.indptr.copy(), "indices": K.indices.copy(), "transpose": None}
    if transpose is None:
        key = row * n + col                                   # sorted: CSR order
        transpose = np.searchsorted(key, col * n + row)
        if len(key) and not np.array_equal(key[np.minimum(transpose, len(key) - 1)],
                                           col * n + row):
            return base
    lower = np.nonzero(col >= row)[0]
    A = cvxopt.spmatrix(K.data[lower], cvxopt.matrix(col[lower]), cvxopt.matrix(row[lower]),
                        (n, n))
    return {**base, "transpose": transpose, "lower": lower, "A": A, "F": None}
