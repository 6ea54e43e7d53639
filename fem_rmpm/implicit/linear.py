"""Linear solvers of the implicit Newton iteration.

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
from scipy.sparse.linalg import cg, gmres, splu

__all__ = ["LinearSolver", "LinearSolveError"]


class LinearSolveError(RuntimeError):
    pass


class LinearSolver:
    """``"superlu"``: LU with MMD_AT_PLUS_A ordering; ``"pyamg"``: CG (GMRES fallback)
    preconditioned by smoothed aggregation with rigid-body modes, hierarchy kept per step."""

    def __init__(self, kind: str = "superlu"):
        self.kind = kind
        self._ml = None

    def new_step(self) -> None:
        self._ml = None

    def solve(self, K: sp.csr_matrix, b: np.ndarray, modes=None, rtol: float = 1e-10) -> np.ndarray:
        if self.kind == "superlu":
            try:
                lu = splu(K.tocsc(), permc_spec="MMD_AT_PLUS_A")
            except RuntimeError as exc:           # "Factor is exactly singular"
                raise LinearSolveError(f"SuperLU: {exc}") from None
            x = lu.solve(b)
            if not np.all(np.isfinite(x)):
                raise LinearSolveError("SuperLU returned a non-finite solution (singular tangent)")
            return x
        import pyamg  # only when chosen: its import costs ~0.3 s a run would not need
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

