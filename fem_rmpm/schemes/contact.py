"""Nodal contact with a rigid, motionless surface (frictional bedrock), in numpy.

The contact algorithm of Bardenhagen et al. (2000, 2001) for one deformable body (the
soil) and a rigid one at rest (the bedrock; its contact nodes and outward normals:
:mod:`fem_rmpm.discretise.contact`).  After the momentum balance on the mesh, each
contact node ``I`` with mass ``m_I`` and trial velocity ``v_I`` (the soil's velocity at
the node, the rock's being zero) is checked:

* ``v_I . n_I >= 0``: the soil leaves the rock or slides along it without pressing on it:
  nothing changes (separation is free; no tension is carried);
* ``v_I . n_I < 0``: the soil approaches the rock.  The normal impulse that stops it,
  ``m_I |v_I . n_I|``, is applied; the tangential velocity ``v_t`` is reduced by the
  Coulomb impulse ``mu m_I |v_I . n_I|`` plus the adhesion's ``c_a L_I dt`` (``c_a`` kPa,
  ``L_I`` the node's tributary length), at most to zero (stick):
  ``v_I <- v_t max(0, 1 - (mu |v . n| + c_a L_I dt / m_I) / |v_t|)``.

The node keeps the rest of its momentum; its acceleration becomes the corrected velocity
change over ``dt``, so the points' FLIP update sees the contact force.  The work of the
friction over the step, the friction impulse ``m_I (v_t - v_I)`` times the mean tangential
velocity (from the step's start to its corrected end, midpoint rule; zero at a node that
stays stuck), is summed into the run's frictional dissipation.  The MUSL nodal velocities
(from the re-mapped point momenta) are corrected the same way, and a node that stuck in the
solve is held at rest there (as a fixed node is).

The compiled path is :mod:`fem_rmpm.schemes.explicit.kernels.contact` (one node at a time,
called from the solve of :mod:`fem_rmpm.schemes.explicit.kernels.transfer`); the two agree
to round-off (``tests/test_contact.py``).
"""
from __future__ import annotations

import numpy as np

from fem_rmpm.discretise.contact import ContactNodes

__all__ = ["contact_velocities"]


def contact_velocities(contact: ContactNodes, m: np.ndarray, v: np.ndarray, dt: float,
                       v_start: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The nodal velocities ``v`` (nn, 2) m/s with the contact rule (module docstring)
    applied at the contact nodes that carry mass ``m`` (nn,) t/m, over the step ``dt``
    (s); returns (corrected copy, work the friction took, kJ/m: the friction impulse times
    the mean tangential velocity over the step, from ``v_start`` (nn, 2), the velocities at
    its start (None: zero), to the corrected one)."""
    out = v.copy()
    node = contact.node
    mk = m[node]
    has = mk > 1e-14
    node, mk, n = node[has], mk[has], contact.normal[has]
    vk = v[node]
    vn = (vk * n).sum(axis=1)
    push = vn < 0
    node, mk, n, vk, vn = node[push], mk[push], n[push], vk[push], vn[push]
    vt = vk - vn[:, None] * n
    vt2 = (vt * vt).sum(axis=1)
    limit = contact.friction[has][push] * (-vn) + contact.adhesion[has][push] * dt / mk
    stick = vt2 <= limit * limit
    s = np.where(stick, 0.0, 1.0 - limit / np.sqrt(np.where(stick, 1.0, vt2)))
    w = s[:, None] * vt
    out[node] = w
    u = np.zeros_like(vk) if v_start is None else v_start[node]
    ut = u - (u * n).sum(axis=1)[:, None] * n
    return out, float(np.sum(mk * ((vt - w) * (0.5 * (ut + w))).sum(axis=1)))
