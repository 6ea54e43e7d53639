"""The nodal contact with frictional bedrock, compiled: one node's velocity corrected.

The rule of :func:`fem_rmpm.schemes.contact.contact_velocities` (the numpy reference and
its description: Bardenhagen et al. 2000, 2001, with a rigid surface at rest) for one node
``a`` of the grid group ``M`` (:class:`.arrays.Mesh`: ``contact_on``, ``contact_n``,
``contact_mu``, ``contact_c``), called by the solve on the mesh and the MUSL nodal
velocities (:mod:`.transfer`) where ``M.has_contact`` and the node is a contact node; the
rough path never enters it.
"""
from __future__ import annotations

import math

from fem_rmpm.runtime.compiled import inline
from fem_rmpm.schemes.explicit.kernels.common import xy

__all__ = ["contact_velocity"]


@inline
def contact_velocity(M, a, m, v0, v1, dt, u0, u1):
    """Contact node ``a`` (uint64) of mass ``m`` (t/m) with trial velocity (``v0``, ``v1``)
    and velocity at the start of the step (``u0``, ``u1``) (m/s), step ``dt`` (s): the
    corrected velocity and the work the friction took (kJ/m), ``(w0, w1, dissipated)``.
    Approaching (v.n < 0, n out of the rock): the normal component removed, the tangential
    one reduced by at most ``mu |v.n| + c_a dt / m`` (Coulomb plus adhesion; to zero:
    stick); else unchanged (separation).  The work is the friction impulse times the mean
    tangential velocity over the step (start and corrected end): zero at a node that stays
    stuck."""
    ax, ay = xy(a)
    n0 = M.contact_n[ax]
    n1 = M.contact_n[ay]
    vn = v0 * n0 + v1 * n1
    if not vn < 0.0:
        return v0, v1, 0.0
    t0 = v0 - vn * n0
    t1 = v1 - vn * n1
    un = u0 * n0 + u1 * n1
    vt2 = t0 * t0 + t1 * t1
    limit = M.contact_mu[a] * (-vn) + M.contact_c[a] * dt / m
    s = 0.0 if vt2 <= limit * limit else 1.0 - limit / math.sqrt(vt2)
    w0 = s * t0
    w1 = s * t1
    mean0 = 0.5 * ((u0 - un * n0) + w0)
    mean1 = 0.5 * ((u1 - un * n1) + w1)
    return w0, w1, m * ((t0 - w0) * mean0 + (t1 - w1) * mean1)
