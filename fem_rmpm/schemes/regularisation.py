"""Mesh-objective softening: non-local averaging of the plastic shear strain, and the
displacement-scaled softening rate.

A softening model that declares its regularisable state (``REGULARISABLE``,
:class:`fem_rmpm.materials.Regularisable`: the state columns of the local plastic shear
strain, of the softening variable and of the strain at the last averaging, and its
softening-strain parameter, by name) and the keys below as parameters lets each
``[[soil]]`` choose with ``regularisation``:

``"local"`` (default)
    the strength falls with the point's own plastic shear strain ``gamma_p``.  The
    shear band is one cell wide and the energy dissipated in it scales with the
    cell: the mechanism depends on the mesh.
``"nonlocal"``
    the strength falls with the *softening variable* ``gamma*``, whose increment at
    point i combines the weighted mean of the plastic shear strain increments of the
    points around it (Galavi & Schweiger 2010, Int. J. Geomech. 10(1) 30-44; in MPM:
    González Acosta et al. 2024, Comput. Geotech. 172, 106424) with its own increment
    (the over-non-local form of Vermeer & Brinkgreve 1994, in Chambon et al. (eds.),
    Localisation and Bifurcation Theory for Soils and Rocks, 89-100)::

        mean_i = sum_j w(r_ij) V_j d gamma_p,j / sum_j w(r_ij) V_j,
        d gamma*_i = max(m mean_i + (1 - m) d gamma_p,i, 0),
        w(r) = r / l^2 exp(-(r / l)^2),   r_ij < 2 l

    with ``l = internal_length`` (m), ``m = nonlocal_factor`` (default 2) and V the
    current point volumes.  The weight is zero at the point itself, peaks at
    ``r = l / sqrt(2)`` and is truncated at ``2 l`` (the part beyond holds 4.6 % of the
    full weight in 2D; the sum is normalised over the points present, so free surfaces
    and the truncation need no correction).  Why m = 2: with the plain mean (m = 1) the
    regularisation is only partial - the dissipated energy and the softened zone follow
    ``l``, but the plastic strain inside that zone still concentrates into a band that
    narrows with the cell (Rolshoven & Jirásek 2001, in de Borst et al. (eds.), Fracture
    Mechanics of Concrete Structures; Jirásek & Rolshoven 2003, Int. J. Eng. Sci. 41,
    1553-1602:
    the m = 1 consistency condition is a Fredholm equation of the first kind, whose
    solution localises).  With m > 1 a point that deforms more than its neighbourhood
    softens less than it, which spreads the plastic flow over a width set by ``l``.
    On the reference slope the band at its formation narrows with the cell for m = 1
    and keeps about the same width, set by l, for m = 2 (the validation pages of the
    documentation give the measured widths).  The increment is kept >= 0: softening is
    irreversible (the total form ``m gamma_bar + (1 - m) gamma_p`` would let a point that
    outruns its neighbours regain strength).  The default ``l = 0.5 m`` is the vertical
    scale of fluctuation of the reference random fields (theta_v = 0.5 m: strength varies
    on that scale, so a band cannot be thinner) and two 0.25 m cells, the least that
    resolves the averaging; ``l`` below one cell is refused (the average would see no
    neighbour).
``"displacement"``
    the softening strain is ``softening_displacement / h`` (h = cell size, m): the
    displacement across the band at which the strength reaches the residual is fixed,
    so the dissipated energy no longer falls with the cell (the fMPMM family,
    H_p = H h); the band stays one cell wide.

Staggered update (both schemes): within a step the return mapping of a non-local point
is perfectly plastic at the strength ``c(gamma*)`` of the step's start (so an implicit
step is a well-posed perfectly plastic problem: Newton needs no softening tangent);
:func:`average_softening`, called once after each explicit step and each converged
implicit step, then adds the step's increment ``d gamma*`` to ``gamma*``.  The softening
lags one step (explicit steps are ~1e-3 s).  The state columns (``REGULARISABLE``):
the local plastic shear strain (for outputs too), the softening variable ``gamma*`` and
the local value at the last averaging.

Neighbour search: the points are sorted into the cells of the structured background
grid (counting sort, O(n)); a point looks only at the cells within ``2 l`` and only
when one of them holds a plastic increment; fully softened points (linear law past
``softening_strain``) are skipped.  The cost per point-step is linear in the number
of points, times the number of neighbours (about 13 (l/h)^2 per point at 4 points per
cell).
"""
from __future__ import annotations

import math
import weakref

import numpy as np
from numba import njit

from fem_rmpm import materials
from fem_rmpm.materials import registry
from fem_rmpm.scene import SceneError

__all__ = ["DEFAULT_INTERNAL_LENGTH", "DEFAULT_FACTOR", "CUTOFF", "MODES", "average_softening",
           "has_nonlocal",
           "prepare_softening", "nonlocal_average", "cell_average", "stencil", "galavi_weight"]

DEFAULT_INTERNAL_LENGTH = 0.5      # m (theta_v of the reference fields; 2 cells of 0.25 m)
DEFAULT_FACTOR = 2.0               # over-non-local m (Vermeer & Brinkgreve 1994)
CUTOFF = 2.0                       # the weight is truncated at CUTOFF * l
MODES = ("local", "nonlocal", "displacement")
_PLANS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_BUFFERS: dict = {}                # id(grid) -> (weakref to the grid, work arrays)


def galavi_weight(r: np.ndarray, length: float) -> np.ndarray:
    """Galavi & Schweiger (2010) weight ``r / l^2 exp(-(r/l)^2)`` (1/m), truncated at
    ``CUTOFF * l``."""
    r = np.asarray(r, dtype=float)
    w = r / length**2 * np.exp(-(r / length) ** 2)
    return np.where(r < CUTOFF * length, w, 0.0)


def _columns(model_id: int):
    """(regularisation, internal_length, nonlocal_factor) parameter columns of a model,
    or None if the model has no regularisation parameter or declares no regularisable
    state."""
    if getattr(registry.model(model_id), "REGULARISABLE", None) is None:
        return None
    cols = [registry.column(model_id, n) for n in
            ("regularisation", "internal_length", "nonlocal_factor")]
    return None if cols[0] is None else cols


def state_columns(model_id: int) -> tuple[int, int, int]:
    """The state columns (strain, softening variable, strain at the last averaging) of a
    model that declares ``REGULARISABLE``."""
    m = registry.model(model_id)
    reg = m.REGULARISABLE
    return (m.STATE.index(reg.strain), m.STATE.index(reg.variable),
            m.STATE.index(reg.averaged))


def _plan(soil):
    """Indices of the non-local points, their internal length (m), the softening
    variable past which they are fully softened, their factor m and the state columns
    (strain, softening variable, averaged strain) of their models; cached per
    :class:`MaterialPoints` object (a changed material is a new object: ``replace``
    copies)."""
    key = soil
    if key in _PLANS:           # also a cached None (no non-local soil): one look-up a step
        return _PLANS[key]
    sel, length, full, factor, columns = [], [], [], [], set()
    nonlocal_code = float(MODES.index("nonlocal"))
    for k in np.unique(soil.model):
        cols = _columns(int(k))
        if cols is None:
            continue
        idx = np.nonzero((soil.model == k) & (soil.params[:, cols[0]] == nonlocal_code))[0]
        if len(idx) == 0:
            continue
        p = soil.params[idx]
        ell = p[:, cols[1]]
        sel.append(idx)
        length.append(np.where(np.isfinite(ell), ell, DEFAULT_INTERNAL_LENGTH))
        full.append(registry.model(int(k)).fully_softened(p))
        fac = p[:, cols[2]] if cols[2] is not None else np.full(len(idx), np.nan)
        factor.append(np.where(np.isfinite(fac), fac, DEFAULT_FACTOR))
        columns.add(state_columns(int(k)))
    if len(columns) > 1:
        raise ValueError("non-local soils of models with different regularisable state "
                         f"columns {sorted(columns)}: one average needs one layout")
    if sel:
        plan = (np.concatenate(sel).astype(np.int64), np.concatenate(length),
                np.concatenate(full), np.concatenate(factor), columns.pop())
    else:
        plan = None
    _PLANS[key] = plan
    return plan


def has_nonlocal(soil) -> bool:
    """True when some points of ``soil`` soften non-locally (:func:`average_softening`
    then has work to do after every step)."""
    return _plan(soil) is not None


def forget_plan(soil) -> None:
    """Drop the cached plan of ``soil`` (its points were reordered in place)."""
    _PLANS.pop(soil, None)


def average_softening(grid, pts, method: str = "cells") -> None:
    """The non-local step of the staggered update (in place, once per step): the
    softening variable of every non-local point grows by the weighted mean of the
    plastic shear strain increments since the last call.  Does nothing
    (and costs nothing) when no soil is non-local.

    ``method``: ``"cells"`` (default) evaluates the mean on the background cells
    (:func:`cell_average`: linear in the points, a fixed stencil per cell);
    ``"points"`` sums over the point pairs (:func:`nonlocal_average`, the reference:
    about 13 (l/h)^2 pairs per point at 4 points per cell, 10-30x the cost of a step).
    """
    plan = _plan(pts.soil)
    if plan is None:
        return
    sel, length, full, factor, columns = plan
    origin = np.asarray(grid.origin, dtype=float)
    nx, ny = int(grid.shape[0]), int(grid.shape[1])
    if method == "points":
        nonlocal_average(pts.x, pts.volume, pts.active, pts.state, sel, length, full,
                         factor, origin, float(np.max(grid.cell)), nx, ny, columns)
        return
    hx, hy = float(grid.cell[0]), float(grid.cell[1])
    for ell in np.unique(length):          # one stencil per internal length (usually one)
        rec = length == ell
        da, db, w = stencil(float(ell), hx, hy)
        cell_average(pts.x, pts.volume, pts.active, pts.state, sel, rec, full, factor, origin,
                     hx, hy, nx, ny, da, db, w, columns, _buffers_of(grid, nx * ny))
    strain, _, averaged = columns
    pts.state[sel, averaged] = pts.state[sel, strain]


def _buffers_of(grid, nc: int) -> tuple:
    """The zeroed work arrays of :func:`cell_average` for ``grid``, made once per grid
    (a run's grid lives for the run) and reused every step; entries of grids that no
    longer exist are dropped."""
    ref_buf = _BUFFERS.get(id(grid))
    if ref_buf is not None and ref_buf[0]() is grid and len(ref_buf[1][0]) == nc:
        return ref_buf[1]
    for key in [k for k, (ref, _) in _BUFFERS.items() if ref() is None]:
        _BUFFERS.pop(key, None)
    buf = _cell_buffers(nc)
    try:
        _BUFFERS[id(grid)] = (weakref.ref(grid), buf)
    except TypeError:                       # not weak-referenceable: not kept
        pass
    return buf


def stencil(length: float, hx: float, hy: float):
    """Cell offsets (da, db) within ``CUTOFF * length`` of a cell centre and their
    Galavi weights (1/m) between cell centres."""
    ra, rb = int(math.ceil(CUTOFF * length / hx)), int(math.ceil(CUTOFF * length / hy))
    a, b = np.meshgrid(np.arange(-ra, ra + 1), np.arange(-rb, rb + 1), indexing="ij")
    w = galavi_weight(np.hypot(a * hx, b * hy), length)
    keep = w > 0
    return a[keep].astype(np.int64), b[keep].astype(np.int64), w[keep]


def cell_average(x, volume, active, state, sel, rec, full, factor, origin, hx, hy, nx, ny,
                 da, db, w, columns, buffers=None) -> None:
    """The non-local mean on the background cells: each cell sums the volume and the
    volume-weighted plastic increment of its points; at every cell centre a receiver
    needs, numerator and denominator of the mean are the stencil sums ``sum w I`` and
    ``sum w V`` over the cells within ``CUTOFF * l``; a receiver point (``rec``, not
    fully softened) adds the ratio of their bilinear interpolations to its softening
    variable (its own increment if no neighbour is within reach).  ``columns``: the
    state columns (strain, softening variable, strain at the last averaging); the last is
    left to the caller.  ``buffers`` (:func:`_cell_buffers`, zero on entry and left zero):
    work arrays over the grid's cells, kept between steps, so a step costs
    O(points + needed cells x stencil) whatever the size of the grid (allocating and
    clearing arrays over every cell of a long run-out floor cost more than the step).
    """
    if buffers is None:
        buffers = _cell_buffers(nx * ny)
    strain, variable, averaged = columns
    _cell_average(x, volume, active, state, sel, rec, full, factor, origin, hx, hy, nx, ny,
                  da, db, w, strain, variable, averaged, *buffers)


def _cell_buffers(nc: int) -> tuple:
    """Zeroed work arrays of :func:`cell_average` over ``nc`` cells."""
    return (np.zeros(nc), np.zeros(nc), np.zeros(nc), np.zeros(nc), np.zeros(nc, dtype=np.bool_))


@njit(cache=True)
def _cell_average(x, volume, active, state, sel, rec, full, factor, origin, hx, hy, nx, ny,
                  da, db, w, strain, variable, averaged, inc_sum, vol_sum, num, den, need):
    """Kernel of :func:`cell_average`; the five work arrays are zero on entry and on exit
    (only the entries touched are cleared)."""
    m = len(sel)
    home = np.full(m, -1, dtype=np.int64)
    for k in range(m):
        i = sel[k]
        if not active[i]:
            continue
        cx = min(max(int((x[i, 0] - origin[0]) / hx), 0), nx - 1)
        cy = min(max(int((x[i, 1] - origin[1]) / hy), 0), ny - 1)
        home[k] = cy * nx + cx
        inc_sum[home[k]] += volume[i] * (state[i, strain] - state[i, averaged])
        vol_sum[home[k]] += volume[i]
    needed = np.empty(4 * m, dtype=np.int64)
    nn = 0
    for k in range(m):
        i = sel[k]
        if not (rec[k] and active[i]) or state[i, variable] >= full[k]:
            continue
        ax, ay, _, _ = _corner(x[i, 0], x[i, 1], origin, hx, hy, nx, ny)
        for c in (ay * nx + ax, ay * nx + ax + 1, (ay + 1) * nx + ax, (ay + 1) * nx + ax + 1):
            if not need[c]:
                need[c] = True
                needed[nn] = c
                nn += 1
    for q in range(nn):
        c = needed[q]
        ca, cb = c % nx, c // nx
        sn, sd = 0.0, 0.0
        for e in range(len(w)):
            a, b = ca + da[e], cb + db[e]
            if a < 0 or a >= nx or b < 0 or b >= ny:
                continue
            sn += w[e] * inc_sum[b * nx + a]
            sd += w[e] * vol_sum[b * nx + a]
        num[c], den[c] = sn, sd
    for k in range(m):
        i = sel[k]
        if not (rec[k] and active[i]) or state[i, variable] >= full[k]:
            continue
        ax, ay, tx, ty = _corner(x[i, 0], x[i, 1], origin, hx, hy, nx, ny)
        c00, c10 = ay * nx + ax, ay * nx + ax + 1
        c01, c11 = c00 + nx, c10 + nx
        n_i = ((1 - tx) * (1 - ty) * num[c00] + tx * (1 - ty) * num[c10]
               + (1 - tx) * ty * num[c01] + tx * ty * num[c11])
        d_i = ((1 - tx) * (1 - ty) * den[c00] + tx * (1 - ty) * den[c10]
               + (1 - tx) * ty * den[c01] + tx * ty * den[c11])
        own = state[i, strain] - state[i, averaged]
        state[i, variable] += _increment(n_i / d_i if d_i > 0.0 else own, own, factor[k])
    for k in range(m):                    # leave the work arrays zero for the next call
        if home[k] >= 0:
            inc_sum[home[k]] = 0.0
            vol_sum[home[k]] = 0.0
    for q in range(nn):
        c = needed[q]
        num[c] = den[c] = 0.0
        need[c] = False


@njit(inline="always")
def _increment(mean, own, m):
    """Softening increment of a receiver from the non-local mean of the plastic
    increments and its own: ``m mean + (1 - m) own``, kept >= 0 (the softening variable
    never decreases: the strength lost does not come back)."""
    return max(m * mean + (1.0 - m) * own, 0.0)


@njit(inline="always")
def _corner(px, py, origin, hx, hy, nx, ny):
    """Lower-left cell of the 2 x 2 cell centres around a point and its bilinear
    coordinates (clamped at the grid edge)."""
    fx = (px - origin[0]) / hx - 0.5
    fy = (py - origin[1]) / hy - 0.5
    ax = min(max(int(math.floor(fx)), 0), max(nx - 2, 0))
    ay = min(max(int(math.floor(fy)), 0), max(ny - 2, 0))
    tx = min(max(fx - ax, 0.0), 1.0)
    ty = min(max(fy - ay, 0.0), 1.0)
    return ax, ay, tx, ty


@njit(cache=True)
def _bins(x, active, sel, origin, h, nx, ny):
    """Counting sort of the active selected points into the grid cells: (start (nc+1,),
    order (m,) positions into ``sel``, cell of each selected point (-1: inactive))."""
    m = len(sel)
    cell = np.empty(m, dtype=np.int64)
    count = np.zeros(nx * ny + 1, dtype=np.int64)
    for k in range(m):
        i = sel[k]
        if not active[i]:
            cell[k] = -1
            continue
        cx = min(max(int((x[i, 0] - origin[0]) / h), 0), nx - 1)
        cy = min(max(int((x[i, 1] - origin[1]) / h), 0), ny - 1)
        cell[k] = cy * nx + cx
        count[cell[k] + 1] += 1
    for c in range(nx * ny):
        count[c + 1] += count[c]
    fill = count[:-1].copy()
    order = np.empty(m, dtype=np.int64)
    for k in range(m):
        if cell[k] >= 0:
            order[fill[cell[k]]] = k
            fill[cell[k]] += 1
    return count, order, cell


def nonlocal_average(x, volume, active, state, sel, length, full, factor, origin, h, nx, ny,
                     columns) -> int:
    """Add to the softening variable of the points ``sel`` the Galavi-weighted mean of
    the plastic increments of the selected points within ``CUTOFF * length`` (``columns``:
    the state columns of the plastic shear strain, the softening variable and the strain
    at the last call).  Returns the number of point pairs evaluated (for the cost
    figures)."""
    strain, variable, averaged = columns
    return _nonlocal_average(x, volume, active, state, sel, length, full, factor, origin, h,
                             nx, ny, strain, variable, averaged)


@njit(cache=True)
def _nonlocal_average(x, volume, active, state, sel, length, full, factor, origin, h, nx, ny,
                      strain, variable, averaged):
    """Kernel of :func:`nonlocal_average`."""
    m = len(sel)
    start, order, cell = _bins(x, active, sel, origin, h, nx, ny)
    inc = np.zeros(m)
    plastic = np.zeros(nx * ny, dtype=np.bool_)
    for k in range(m):
        i = sel[k]
        inc[k] = state[i, strain] - state[i, averaged]
        if cell[k] >= 0 and inc[k] > 0.0:
            plastic[cell[k]] = True
    pairs = 0
    for k in range(m):
        i = sel[k]
        if cell[k] < 0 or state[i, variable] >= full[k]:
            continue
        ell = length[k]
        rc = CUTOFF * ell
        reach = int(math.ceil(rc / h))
        cx, cy = cell[k] % nx, cell[k] // nx
        x0, x1 = max(cx - reach, 0), min(cx + reach, nx - 1)
        y0, y1 = max(cy - reach, 0), min(cy + reach, ny - 1)
        near = False
        for by in range(y0, y1 + 1):
            for bx in range(x0, x1 + 1):
                if plastic[by * nx + bx]:
                    near = True
        if not near:
            continue
        num, den = 0.0, 0.0
        inv2 = 1.0 / (ell * ell)
        xi, yi = x[i, 0], x[i, 1]
        for by in range(y0, y1 + 1):
            for bx in range(x0, x1 + 1):
                b = by * nx + bx
                for q in range(start[b], start[b + 1]):
                    kj = order[q]
                    j = sel[kj]
                    dx, dy = x[j, 0] - xi, x[j, 1] - yi
                    r2 = (dx * dx + dy * dy) * inv2
                    if r2 >= CUTOFF * CUTOFF:
                        continue
                    w = math.sqrt(r2) * math.exp(-r2) * volume[j]
                    num += w * inc[kj]
                    den += w
                    pairs += 1
        # no neighbour within reach: its own increment
        state[i, variable] += _increment(num / den if den > 0.0 else inc[k], inc[k],
                                         factor[k])
    for k in range(m):
        i = sel[k]
        state[i, averaged] = state[i, strain]
    return pairs


def prepare_softening(scene, grid, soil, soil_id: np.ndarray):
    """Check the regularisation keys against the grid and resolve the displacement-scaled
    softening (``softening_strain = softening_displacement / h``, h the cell size in m).
    ``soil_id`` (n,): the ``[[soil]]`` index of each point.  Returns the (possibly new)
    :class:`MaterialPoints`; raises ``SceneError`` naming the ``[[soil]]`` key for an
    internal length below one cell or a displacement-scaled softening modulus not below
    the shear modulus."""
    h_max = float(np.max(grid.cell))
    h = math.sqrt(float(grid.cell[0]) * float(grid.cell[1]))
    params = None
    for k, so in enumerate(scene.soils):
        mode = so.value("regularisation", "local")
        if mode == "nonlocal":
            ell = so.value("internal_length", math.nan)
            ell = DEFAULT_INTERNAL_LENGTH if not math.isfinite(ell) else ell
            if ell < h_max:
                raise SceneError(
                    f"{scene.source}: [soil[{k}].internal_length] {ell:g} m is smaller than "
                    f"the cell ({h_max:g} m): the non-local average would see no neighbour "
                    f"and not regularise; allowed: internal_length >= {h_max:g} m (at least "
                    f"2 cells, {2 * h_max:g} m, recommended), or a finer grid")
        elif mode == "displacement":
            ur = so.value("softening_displacement")
            gs = ur / h
            model = registry.model(so.model)
            name = model.REGULARISABLE.softening_strain
            values = {**materials.soil_values(so), name: gs}
            modulus, G = model.softening_modulus(values), values["shear_modulus"]
            if modulus >= G:
                raise SceneError(
                    f"{scene.source}: [soil[{k}].softening_displacement] {ur:g} m over a "
                    f"{h:g} m cell gives the softening strain {gs:g} and a softening modulus "
                    f"{modulus:g} kPa >= shear modulus {G:g} kPa (the local "
                    f"return mapping snaps back); allowed: softening_displacement > "
                    f"{ur * modulus / G:g} m")
            if params is None:
                params = soil.params.copy()
            params[soil_id == k, registry.column(so.model, name)] = gs
    if params is None:
        return soil
    return materials.MaterialPoints(soil.model, params)

