"""scikit-fem forms of the implicit tangent and internal force (the reference path).

The material points are the quadrature points: a ``CellBasis`` with one "element" per
point (:func:`fem_rmpm.discretise.basis.skfem_point_basis`).  :func:`skfem_assemble` is what the
vectorised assembly of :class:`fem_rmpm.schemes.implicit.assembly.StepSystem` is tested against.
"""
from __future__ import annotations

import numpy as np
from skfem import BilinearForm, LinearForm, asm

from fem_rmpm.discretise.basis import skfem_point_basis
from fem_rmpm.discretise.grid import Grid
from fem_rmpm.schemes.implicit.tangent import inv2, tensor

__all__ = ["skfem_tangent_form", "skfem_force_form", "skfem_assemble"]


def _skfem_forms():
    @BilinearForm
    def tangent(u, v, w):
        """``V0/dx g(v)_ij A_ijlm g(u)_lm`` with ``g = grad . dF^-1``: K_ai,bl."""
        Finv, A = np.asarray(w["Finv"]), np.asarray(w["A"])
        gu = np.einsum("lk...,km...->lm...", u.grad, Finv)
        gv = np.einsum("ik...,kj...->ij...", v.grad, Finv)
        return np.einsum("ij...,ijlm...,lm...->...", gv, A, gu) * np.asarray(w["scale"])

    @LinearForm
    def force(v, w):
        """``V0/dx tau_ij g(v)_ij`` (internal force) and ``m/dx g_i v_i`` (body force)."""
        Finv, T = np.asarray(w["Finv"]), np.asarray(w["tau"])
        gv = np.einsum("ik...,kj...->ij...", v.grad, Finv)
        return (np.einsum("ij...,ij...->...", T, gv) * np.asarray(w["scale"]))

    return tangent, force


def skfem_tangent_form():
    """The scikit-fem BilinearForm of the consistent tangent (material points as quadrature)."""
    return _skfem_forms()[0]


def skfem_force_form():
    """The scikit-fem LinearForm of the internal force (material points as quadrature)."""
    return _skfem_forms()[1]


def skfem_assemble(grid: Grid, x: np.ndarray, V0: np.ndarray, dF: np.ndarray,
                   tau4: np.ndarray, A: np.ndarray):
    """Tangent (full DOF numbering, csr) and internal force assembled by ``skfem.asm``.

    The points ``x`` are the quadrature points (one element per point, weight 1,
    so ``dx`` is the host cell's Jacobian and the forms are scaled by ``V0 / dx``).
    Used to verify :meth:`StepSystem.tangent` / :meth:`StepSystem.internal_force`
    and in ``validation/bench_implicit.py``.
    """
    tangent, force = _skfem_forms()
    basis = skfem_point_basis(grid, x)
    scale = V0[:, None] / basis.dx
    Finv, _ = inv2(dF)
    FinvT = np.moveaxis(Finv, 0, -1)[..., None]               # (2, 2, n, 1)
    AT = np.moveaxis(A, 0, -1)[..., None]                      # (2, 2, 2, 2, n, 1)
    TT = np.moveaxis(tensor(tau4), 0, -1)[..., None]
    K = asm(tangent, basis, Finv=FinvT, A=AT, scale=scale)
    f = asm(force, basis, Finv=FinvT, tau=TT, scale=scale)
    return K.tocsr(), f

