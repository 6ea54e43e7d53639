"""Compiled per-step work of the implicit scheme around its Newton iterations (numba).

One loop over the points each, in place of chains of numpy passes and of the full-grid
nodal arrays they allocated (the reference slope's grid has 89 000 nodes for 9 600 free
DOFs):

* :func:`q4_step_basis` -- the grid reset of a Q4 step: host cell, F-bar cell, nodes,
  shape values and gradients at the points, and the nodes their basis touches (the
  arithmetic of :func:`fem_rmpm.discretise.basis.q4_at_points` and
  :func:`fem_rmpm.schemes.locking.host_cells`, so the same values to the last bit);
* :func:`dense_rank` -- the host cells numbered by rank;
* :func:`kept_groups` -- the node sets of a kept pattern at the points' host cells;
* :func:`free_body_force`, :func:`newmark_start` -- the body force and the Newmark
  step-start nodal mass, velocity and acceleration on the free DOFs;
* :func:`interpolate_free`, :func:`newmark_commit`, :func:`step_limits` -- free-DOF
  vectors at the points, the FLIP/PIC point velocity and acceleration update, and the
  kinematic figures of a step;
* :func:`points_fine` -- the point check of a step (finite state, inside the grid);
* :func:`rows`, :func:`set_rows` -- the active points' rows of a per-point array, read and
  written by compiled loops.

Every sum runs in the order of the numpy code it replaces, so a run is bitwise the same
(``tests/test_implicit_step_kernels.py``).  Compiled on first use and cached on disk.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["q4_step_basis", "dense_rank", "kept_groups", "free_body_force", "newmark_start",
           "interpolate_free", "newmark_commit", "step_limits", "points_fine", "gather_rows",
           "scatter_rows", "rows", "set_rows"]


@njit(cache=True, error_model="numpy")
def q4_step_basis(x, origin, h, ih, nx, ny, t, host, nodes, N, dN, used):
    """Q4 basis of the points ``x`` (n, 2), m, on a structured grid (``origin`` (2,),
    cell ``h`` (2,) and ``ih = 1 / h``, ``nx x ny`` cells, ``t`` (4, n_cells) the
    cells' nodes, scikit-fem's ``mesh.t``).  Fills ``host`` (n,) the F-bar cell
    (``floor((x - origin) ih)``, :func:`fem_rmpm.schemes.locking.host_cells`), ``nodes``
    (n, 4) the nodes of the basis cell (``floor((x - origin) / h)``, clipped into the grid,
    :func:`fem_rmpm.discretise.grid.locate`), ``N`` (n, 4) the values, ``dN`` (n, 4, 2)
    the gradients (1/m) and ``used`` (n_nodes,) True at every node whose value or
    gradient is non-zero at some point (``used`` zeroed by the caller)."""
    n = x.shape[0]
    for p in range(n):
        d0, d1 = x[p, 0] - origin[0], x[p, 1] - origin[1]
        i = min(max(np.int64(math.floor(d0 * ih[0])), 0), nx - 1)
        j = min(max(np.int64(math.floor(d1 * ih[1])), 0), ny - 1)
        host[p] = j * nx + i
        s, r = d0 / h[0], d1 / h[1]
        i = min(max(np.int64(math.floor(s)), 0), nx - 1)
        j = min(max(np.int64(math.floor(r)), 0), ny - 1)
        c = j * nx + i
        s -= i
        r -= j
        fs0, fs1, ft0, ft1 = 1.0 + -1.0 * s, s, 1.0 + -1.0 * r, r
        # corners counter-clockwise from the lower left: (fs, ft) = (0,0) (1,0) (1,1) (0,1)
        fss = (fs0, fs1, fs1, fs0)
        fts = (ft0, ft0, ft1, ft1)
        cs0 = (-1.0, 1.0, 1.0, -1.0)
        cs1 = (-1.0, -1.0, 1.0, 1.0)
        for a in range(4):
            q = t[a, c]
            nodes[p, a] = q
            fa, ta = fss[a], fts[a]
            N[p, a] = fa * ta
            g0 = cs0[a] * ta / h[0]
            g1 = fa * cs1[a] / h[1]
            dN[p, a, 0] = g0
            dN[p, a, 1] = g1
            if fa * ta != 0.0 or g0 != 0.0 or g1 != 0.0:
                used[q] = True


@njit(cache=True)
def dense_rank(values, size, out):
    """The rank of each value among the distinct ``values`` (``0 <= values < size``) in
    ``out``; returns the number of distinct values."""
    mark = np.zeros(size, dtype=np.int64)
    for v in values:
        mark[v] = 1
    k = 0
    for c in range(size):
        if mark[c]:
            mark[c] = k
            k += 1
    for p in range(len(values)):
        out[p] = mark[values[p]]
    return k


@njit(cache=True)
def kept_groups(group_of, nodes, out):
    """``out[p] = group_of[nodes[p, 0]]``, the node set of each point in a kept pattern;
    returns False as soon as a point's cell is not in the pattern (``-1``)."""
    for p in range(nodes.shape[0]):
        g = group_of[nodes[p, 0]]
        if g < 0:
            return False
        out[p] = g
    return True


@njit(cache=True, error_model="numpy")
def free_body_force(nodes, N, mass, gx, gy, fnum, out):
    """``out[fnum[2 q + i]] += (N[p, a] m_p) g_i`` over the points and their nodes ``q``
    (free DOFs only, ``out`` (n_free,) zeroed by the caller): the nodal body force (kN/m)
    summed in point order (as a ``bincount`` over the points)."""
    n, k = nodes.shape
    for p in range(n):
        for a in range(k):
            w = N[p, a] * mass[p]
            q = nodes[p, a]
            d = fnum[2 * q]
            if d >= 0:
                out[d] += w * gx
            d = fnum[2 * q + 1]
            if d >= 0:
                out[d] += w * gy
    return out


@njit(cache=True, error_model="numpy")
def newmark_start(nodes, N, mass, v, a, fnum, free_dofs, used_nodes, m_min, tol, m_node,
                  mv, ma, v_n, a_n, m_free):
    """The step-start nodal state of a Newmark step on the free DOFs: lumped mass
    ``m_b = sum_p m_p N_b`` (t/m), velocity ``sum_p m_p N_b v_p / m_b`` and acceleration
    (zero where ``m_b <= tol``) in ``v_n``, ``a_n``, and the mass with its floor
    ``max(m_b, m_min)`` in ``m_free``.  ``m_node`` (n_nodes,), ``mv``, ``ma`` (n_free,)
    are work arrays zeroed by the caller; ``m_node`` is zeroed again on return.  Returns
    the number of ``used_nodes`` lighter than ``m_min``."""
    n, k = nodes.shape
    for p in range(n):
        for b in range(k):
            q = nodes[p, b]
            w = N[p, b] * mass[p]
            m_node[q] += w
            d = fnum[2 * q]
            if d >= 0:
                mv[d] += w * v[p, 0]
                ma[d] += w * a[p, 0]
            d = fnum[2 * q + 1]
            if d >= 0:
                mv[d] += w * v[p, 1]
                ma[d] += w * a[p, 1]
    for d in range(len(free_dofs)):
        m = m_node[free_dofs[d] // 2]
        inv = 1.0 / m if m > tol else 0.0
        v_n[d] = mv[d] * inv
        a_n[d] = ma[d] * inv
        m_free[d] = max(m, m_min)
    light = 0
    for q in used_nodes:
        if m_node[q] < m_min:
            light += 1
    for p in range(n):
        for b in range(k):
            m_node[nodes[p, b]] = 0.0
    return light


@njit(cache=True, error_model="numpy")
def interpolate_free(vec, fnum, nodes, N, out):
    """``out[p, i] = sum_a N[p, a] vec[fnum[2 nodes[p, a] + i]]`` (n, 2): a free-DOF
    vector at the points (zero at the other DOFs)."""
    n, k = nodes.shape
    for p in range(n):
        s0 = s1 = 0.0
        for a in range(k):
            q = nodes[p, a]
            d0, d1 = fnum[2 * q], fnum[2 * q + 1]
            w = N[p, a]
            s0 += w * (vec[d0] if d0 >= 0 else 0.0)
            s1 += w * (vec[d1] if d1 >= 0 else 0.0)
        out[p, 0], out[p, 1] = s0, s1
    return out


@njit(cache=True, error_model="numpy")
def newmark_commit(act, v_new, dv, a_new, fnum, nodes, N, flip, velocity, acc):
    """The point velocity and acceleration after a Newmark step: per active point
    ``p = act[j]``, ``velocity[p] = flip (velocity[p] + N dv) + (1 - flip) N v_new`` (FLIP
    blended with PIC) and ``acc[p] = N a_new``, the free-DOF vectors interpolated at the
    point (m/s, m/s2).  Returns the largest PIC speed ``|N v_new|`` (m/s)."""
    n, k = nodes.shape
    vmax2 = 0.0
    for j in range(n):
        pv0 = pv1 = dv0 = dv1 = pa0 = pa1 = 0.0
        for a in range(k):
            q = nodes[j, a]
            d0, d1 = fnum[2 * q], fnum[2 * q + 1]
            w = N[j, a]
            pv0 += w * (v_new[d0] if d0 >= 0 else 0.0)
            pv1 += w * (v_new[d1] if d1 >= 0 else 0.0)
            dv0 += w * (dv[d0] if d0 >= 0 else 0.0)
            dv1 += w * (dv[d1] if d1 >= 0 else 0.0)
            pa0 += w * (a_new[d0] if d0 >= 0 else 0.0)
            pa1 += w * (a_new[d1] if d1 >= 0 else 0.0)
        p = act[j]
        velocity[p, 0] = flip * (velocity[p, 0] + dv0) + (1 - flip) * pv0
        velocity[p, 1] = flip * (velocity[p, 1] + dv1) + (1 - flip) * pv1
        acc[p, 0], acc[p, 1] = pa0, pa1
        s = pv0 * pv0 + pv1 * pv1
        if s > vmax2:
            vmax2 = s
    return math.sqrt(vmax2)


@njit(cache=True, error_model="numpy")
def step_limits(u, dF):
    """The kinematic figures of a step: the largest ``|u_p|`` (m), the smallest and largest
    ``det dF_p`` and the point of the largest ``|log det dF_p|`` (its first)."""
    n = u.shape[0]
    umax2 = 0.0
    jmin, jmax, worst, lmax = 1.0, 1.0, 0, -1.0
    for p in range(n):
        s = u[p, 0] * u[p, 0] + u[p, 1] * u[p, 1]
        if s > umax2:
            umax2 = s
        J = dF[p, 0, 0] * dF[p, 1, 1] - dF[p, 0, 1] * dF[p, 1, 0]
        if J < jmin:
            jmin = J
        if J > jmax:
            jmax = J
        lj = abs(math.log(J))
        if lj > lmax or lj != lj and lmax == lmax:
            lmax, worst = lj, p
    return math.sqrt(umax2), jmin, jmax, worst


@njit(cache=True)
def points_fine(active, x, velocity, stress, lo0, lo1, hi0, hi1):
    """True when every active point (``active`` (n,) bool) has a finite position, velocity
    and stress and lies inside the grid rectangle ``[lo, hi]`` (m): the point check of a
    step (:func:`fem_rmpm.schemes.common.check_points`) would find nothing."""
    for p in range(len(active)):
        if not active[p]:
            continue
        if not (lo0 <= x[p, 0] <= hi0 and lo1 <= x[p, 1] <= hi1):
            return False
        if not (math.isfinite(velocity[p, 0]) and math.isfinite(velocity[p, 1])):
            return False
        for c in range(stress.shape[1]):
            if not math.isfinite(stress[p, c]):
                return False
    return True


@njit(cache=True)
def gather_rows(src, act, out):
    """``out[j] = src[act[j]]`` for a 2-D ``src`` (the rows of the active points)."""
    for j in range(len(act)):
        p = act[j]
        for c in range(src.shape[1]):
            out[j, c] = src[p, c]
    return out


@njit(cache=True)
def scatter_rows(dst, act, src):
    """``dst[act[j]] = src[j]`` for a 2-D ``dst`` (the rows of the active points)."""
    for j in range(len(act)):
        p = act[j]
        for c in range(dst.shape[1]):
            dst[p, c] = src[j, c]


def rows(a: np.ndarray, act: np.ndarray) -> np.ndarray:
    """``a[act]`` for a per-point array, in C order (compiled for 2-D float arrays)."""
    if a.ndim != 2 or a.dtype != np.float64:
        return a[act]
    return gather_rows(a, act, np.empty((len(act), a.shape[1])))


def set_rows(a: np.ndarray, act: np.ndarray, values: np.ndarray) -> None:
    """``a[act] = values`` for a per-point array (compiled for 2-D float arrays)."""
    if a.ndim == 2 and values.ndim == 2 and a.dtype == values.dtype == np.float64 \
            and values.shape == (len(act), a.shape[1]):
        scatter_rows(a, act, values)
    else:
        a[act] = values
