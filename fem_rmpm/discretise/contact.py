"""Contact nodes of frictional bedrock: which grid nodes touch a rigid surface, its normal there.

A ``[[bedrock]]`` with ``interface = "frictional"`` is a rigid, motionless body the soil
may slide on and lift off (the nodal contact of Bardenhagen et al. 2000, 2001, with a
rigid surface; the rule itself is :mod:`fem_rmpm.schemes.contact`).  This module builds
its table from the scene and the grid:

* **Contact nodes**: every grid node inside or on a frictional polygon (within 1e-6 of a
  cell of an edge) that no grid edge condition fixes in any component (a boundary
  condition wins) and no rough bedrock fixes.  The soil's points map to the nodes of the
  cells they lie in, and no point is seeded in a cell whose centre is in the rock
  (:func:`fem_rmpm.discretise.points.seed_particles`), so the nodes the soil touches are
  those on the surface and, where the surface is inclined to the grid lines, the nodes
  of the rock's staircase cells just below it.  Nodes deeper in the rock are listed too:
  they carry mass only if soil penetrates, and are then pushed out along the same normal.
* **Normals** from the polygon's geometry, not from the staircase of cells: the unit
  outward normal (out of the rock, into the soil) of the *exposed* edge nearest to the
  node; where two edges are equally near (a node at or beyond a vertex, within 1e-6 of a
  cell) the normals are averaged and normalised.  An edge lying on a side of the grid
  rectangle is not exposed (the soil cannot reach it) and is skipped.
* **Adhesion force** (kN per m out of plane) of a node: ``adhesion x L``, the tributary
  length ``L`` of an exposed edge being its length over the number of contact nodes
  less than a cell below or on it (the nodes that carry it); a node takes the ``L`` of
  its nearest edge.

``work`` holds the run's frictional dissipation (kJ per m): one sum per half of the
points, written by the explicit step (:mod:`fem_rmpm.schemes.explicit.kernels.contact`
and the numpy reference).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fem_rmpm.scene import SceneError

__all__ = ["ContactNodes", "contact_nodes", "outward_edges", "refuse_frictional"]


def refuse_frictional(scene, what: str) -> None:
    """Raise :class:`SceneError` (one line) if ``scene`` has frictional bedrock: ``what``
    (e.g. "strength reduction") has no contact and would silently make it rough."""
    for k, rock in enumerate(scene.bedrock):
        if rock.interface == "frictional":
            raise SceneError(f"{scene.source}: [bedrock[{k}].interface] a frictional "
                             f"interface is supported by the explicit MPM run only, not by "
                             f"{what}; allowed: interface = \"rough\" for {what}")


@dataclass(frozen=True)
class ContactNodes:
    """The contact nodes of the frictional bedrock of one grid (module docstring)."""
    node: np.ndarray          # (k,) int64 node numbers
    normal: np.ndarray        # (k, 2) unit outward normals of the rock (into the soil)
    friction: np.ndarray      # (k,) Coulomb coefficient (-)
    adhesion: np.ndarray      # (k,) adhesion force = adhesion x tributary length, kN/m
    work: np.ndarray = field(default_factory=lambda: np.zeros(3))   # dissipation, last dt

    def dense(self, n_nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per-node arrays over all ``n_nodes``: flag (uint8), normal (2 nn,) interleaved
        x, y, friction and adhesion force (nn,); zero off the contact nodes."""
        on = np.zeros(n_nodes, np.uint8)
        nrm = np.zeros((n_nodes, 2))
        mu = np.zeros(n_nodes)
        ca = np.zeros(n_nodes)
        on[self.node] = 1
        nrm[self.node] = self.normal
        mu[self.node] = self.friction
        ca[self.node] = self.adhesion
        return on, nrm.reshape(-1), mu, ca


def outward_edges(polygon: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The exposed edges of ``polygon`` (k, 2) m in the grid rectangle ``lo``..``hi``:
    (start points (e, 2), end points (e, 2), unit outward normals (e, 2)); an edge with
    both ends on the same side of the rectangle (within ``tol``, m) is not exposed."""
    a = np.asarray(polygon, float)
    if len(a) > 3 and np.array_equal(a[0], a[-1]):
        a = a[:-1]
    b = np.roll(a, -1, axis=0)
    area = 0.5 * float(np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1]))
    d = b - a
    n = np.stack([d[:, 1], -d[:, 0]], axis=1) / np.linalg.norm(d, axis=1)[:, None]
    if area < 0:                                  # clockwise: the right-hand normal points in
        n = -n
    keep = np.ones(len(a), bool)
    for k in (0, 1):
        for edge in (lo[k], hi[k]):
            keep &= ~((np.abs(a[:, k] - edge) <= tol) & (np.abs(b[:, k] - edge) <= tol))
    return a[keep], b[keep], n[keep]


def _edge_distances(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, e) distances (m) of points ``p`` (n, 2) to the segments ``a``-``b`` (e, 2)."""
    ab = b - a
    t = np.clip((((p[:, None, :] - a[None]) * ab[None]).sum(-1))
                / np.maximum((ab * ab).sum(-1), 1e-300)[None], 0.0, 1.0)
    q = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - q, axis=-1)


def contact_nodes(scene, nodes: np.ndarray, cell: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                  in_or_on, fixed: np.ndarray) -> ContactNodes | None:
    """The :class:`ContactNodes` of the frictional ``[[bedrock]]`` of ``scene`` on the grid
    nodes ``nodes`` (nn, 2) m, cells ``cell`` (2,) m, rectangle ``lo``..``hi``;
    ``in_or_on(points, polygon, tol)`` the grid's inside-or-on test, ``fixed`` (nn, 2) the
    components the boundary and the rough bedrock fix.  None without frictional bedrock."""
    rocks = [r for r in scene.bedrock if r.interface == "frictional"]
    if not rocks:
        return None
    h = float(np.min(cell))
    tol = 1e-6 * h
    free = ~fixed.any(axis=1)
    best = np.full(len(nodes), np.inf)
    out_n, out_mu, out_ca = np.zeros((len(nodes), 2)), np.zeros(len(nodes)), np.zeros(len(nodes))
    for rock in rocks:
        hit = np.flatnonzero(in_or_on(nodes, np.array(rock.polygon), tol) & free)
        a, b, n = outward_edges(np.array(rock.polygon), lo, hi, 1e-9 * float(np.max(hi - lo)))
        if len(hit) == 0 or len(a) == 0:
            continue
        d = _edge_distances(nodes[hit], a, b)                     # (k, e)
        dmin = d.min(axis=1)
        near = d <= dmin[:, None] + tol                           # the nearest edge(s)
        nrm = (near[..., None] * n[None]).sum(axis=1)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
        nearest = np.argmin(d, axis=1)
        band = np.bincount(nearest[dmin < h - tol], minlength=len(a))
        trib = np.linalg.norm(b - a, axis=1) / np.maximum(band, 1)
        take = dmin < best[hit]
        sel = hit[take]
        best[sel] = dmin[take]
        out_n[sel] = nrm[take]
        out_mu[sel] = rock.friction
        out_ca[sel] = (rock.adhesion or 0.0) * trib[nearest[take]]
    node = np.flatnonzero(np.isfinite(best))
    return ContactNodes(node.astype(np.int64), out_n[node], out_mu[node], out_ca[node])
