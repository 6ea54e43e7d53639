"""The pore water's force on a point as the compiled kernels compute it (inlined into the
map to the nodes, :mod:`.transfer`): the compiled twin of
:func:`fem_rmpm.schemes.pore_pressure.water_forces`, reading the phreatic surface's
segment table and frame that :class:`fem_rmpm.schemes.pore_pressure.WaterTable` holds
(:class:`.arrays.Mesh` ``water`` and ``frame``)."""
from __future__ import annotations

from fem_rmpm.runtime.compiled import inline

__all__ = ["water_force", "water_ramp"]


@inline
def water_force(x0, x1, vol, seg, frame, ramp):
    """Compiled :func:`fem_rmpm.schemes.pore_pressure.water_forces` of one point at
    (x0, x1) of volume ``vol``, times ``ramp``: (fx, fy) kN per m (zero above the
    surface)."""
    c = frame[0]
    s = frame[1]
    X = x0 * c + x1 * s
    Y = -x0 * s + x1 * c
    lo, hi = 0, seg.shape[0] - 1          # the last segment start <= X (else the first)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if seg[mid, 0] <= X:
            lo = mid
        else:
            hi = mid - 1
    if seg[lo, 1] + seg[lo, 2] * (X - seg[lo, 0]) - Y <= 0.0:
        return 0.0, 0.0
    f = -ramp * vol
    return f * seg[lo, 4], f * seg[lo, 5]


@inline
def water_ramp(M, o):
    """(whether the mesh ``M`` carries pore water, the gravity ramp of step ``o``): the
    water force grows with gravity (ramped gravity over full gravity)."""
    fr = M.frame
    if M.water.shape[0] == 0:
        return False, 0.0
    g2 = fr[2] * fr[2] + fr[3] * fr[3]
    return True, ((o.gx * fr[2] + o.gy * fr[3]) / g2 if g2 > 0.0 else 1.0)
