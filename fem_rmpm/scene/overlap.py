"""Do two simple polygons share area?  (Touching along an edge or at a point is fine.)

Two simple polygons P and Q share area exactly when a point of the boundary of one lies
inside the other, or when they are the same region.  The boundaries are compared edge
against edge, but only for pairs of edges that share a bucket of a uniform grid (each
edge cut into pieces about a bucket long), so the work grows about as n log n in the
number of vertices, not as n^2:

- two edges that cross at interior points of both: the polygons overlap there (near a
  proper crossing each polygon holds a half-plane, and two half-planes with crossing
  edges share a wedge);
- otherwise the boundaries meet only where a vertex of one lies on the other ("touch
  points").  Every piece of the boundary of Q off the boundary of P runs from touch point
  to touch point and lies wholly inside or wholly outside P, so the direction in which
  it leaves a touch point, compared with the wedge of P there, decides it exactly.  The
  same holds with P and Q swapped.  When no piece leaves the other boundary, the two
  boundaries coincide (the same region: overlap); when the boundaries never meet, one
  vertex of each tested against the other polygon decides nesting.

Distances within ``1e-9`` of the larger polygon's size count as zero (a vertex on an
edge, two edges along one line).  The point returned lies inside both polygons (the
middle of the overlap along a vertical line near where the overlap was found).
"""
from __future__ import annotations

import numpy as np

__all__ = ["overlap_point"]

_REL_TOL = 1e-9
#: Up to this many pairs of edges, every pair is compared (cheaper than bucketing them).
ALL_PAIRS = 4096


def _ring(poly) -> np.ndarray:
    """The polygon's distinct points (m), counter-clockwise, without repeated points."""
    p = np.asarray(poly, dtype=float).reshape(-1, 2)
    keep = np.any(p != np.roll(p, 1, axis=0), axis=1)
    p = p[keep] if keep.any() else p[:1]
    area2 = float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))
    return p[::-1].copy() if area2 < 0 else p


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _buckets(a: np.ndarray, b: np.ndarray, side: float, pad: float, origin: np.ndarray,
             width: int) -> tuple[np.ndarray, np.ndarray]:
    """(bucket, edge) entries, an edge once per bucket: edge k (``a[k] -> b[k]``) cut into
    pieces no longer than a bucket, each in the buckets of its bounding box widened by
    ``pad`` (m)."""
    extent = np.abs(b - a).max(axis=1)
    pieces = np.maximum(np.ceil(extent / side).astype(np.int64), 1)
    owner = np.repeat(np.arange(len(a)), pieces)
    t = (np.arange(len(owner)) - np.repeat(np.cumsum(pieces) - pieces, pieces))[:, None]
    m = pieces[owner][:, None]
    u = a[owner] + (b[owner] - a[owner]) * (t / m)
    v = a[owner] + (b[owner] - a[owner]) * ((t + 1) / m)
    k0 = np.floor((np.minimum(u, v) - pad - origin) / side).astype(np.int64)
    k1 = np.floor((np.maximum(u, v) + pad - origin) / side).astype(np.int64)
    span = k1 - k0 + 1
    cells = span[:, 0] * span[:, 1]
    piece = np.repeat(np.arange(len(owner)), cells)
    offset = np.arange(len(piece)) - np.repeat(np.cumsum(cells) - cells, cells)
    bucket = (k0[piece, 1] + offset // span[piece, 0]) * width + k0[piece, 0] \
        + offset % span[piece, 0]
    # buckets per axis <= ~4 x the edges (the doubling of ``side``): the key fits int64
    key = np.unique(bucket * len(a) + owner[piece])   # bucket-major, each pair once
    return np.stack([key // len(a), key % len(a)])


def _edge_pairs(p: np.ndarray, q: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j) of an edge i of ``p`` and an edge j of ``q`` (edge k from point k to
    point k + 1) that share a bucket: every pair closer than ``tol`` (m), a pair possibly
    repeated.  Only edges near the common bounding box take part."""
    pa, pb, qa, qb = p, np.roll(p, -1, axis=0), q, np.roll(q, -1, axis=0)
    lo = np.maximum(p.min(axis=0), q.min(axis=0)) - 2 * tol
    hi = np.minimum(p.max(axis=0), q.max(axis=0)) + 2 * tol

    def near(a, b):
        return np.all((np.maximum(a, b) >= lo) & (np.minimum(a, b) <= hi), axis=1)
    ip, jq = np.flatnonzero(near(pa, pb)), np.flatnonzero(near(qa, qb))
    if not len(ip) or not len(jq):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    if len(ip) * len(jq) <= ALL_PAIRS:            # few edges: every pair, no buckets
        return np.repeat(ip, len(jq)), np.tile(jq, len(ip))
    ext = np.concatenate([np.abs(pb[ip] - pa[ip]).max(axis=1),
                          np.abs(qb[jq] - qa[jq]).max(axis=1)])
    side = max(float(np.median(ext)), 4 * tol, 1e-300)
    while np.maximum(np.ceil(ext / side), 1).sum() > 4 * len(ext) + 64:
        side *= 2.0
    origin = lo - 4 * tol
    width = int(np.floor((hi[0] + 4 * tol - origin[0]) / side)) + 3
    bp = _buckets(pa[ip], pb[ip], side, 2 * tol, origin, width)
    bq = _buckets(qa[jq], qb[jq], side, 2 * tol, origin, width)
    # every entry of p against the entries of q in its bucket (both lists sorted by bucket)
    start = np.searchsorted(bq[0], bp[0], side="left")
    count = np.searchsorted(bq[0], bp[0], side="right") - start
    e = np.repeat(np.arange(bp.shape[1]), count)
    k = np.repeat(start, count) + np.arange(len(e)) - np.repeat(np.cumsum(count) - count, count)
    return ip[bp[1, e]], jq[bq[1, k]]


def _seg_dist(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (m) of points ``x`` from segments ``a -> b`` (row by row)."""
    d = b - a
    t = np.clip(np.sum((x - a) * d, axis=1) / np.maximum(np.sum(d * d, axis=1), 1e-300), 0, 1)
    return np.hypot(*(a + t[:, None] * d - x).T)


def _along(e: np.ndarray, d: np.ndarray, tol: float) -> np.ndarray:
    """Do directions ``d`` run along lines ``e``: the far end of the shorter of the two
    within ``tol`` (m) of the other's line?"""
    longer = np.maximum(np.hypot(*e.T), np.hypot(*d.T))
    return np.abs(_cross(e, d)) <= tol * longer


def _side_at_vertex(p: np.ndarray, k: np.ndarray, d: np.ndarray, tol: float) -> np.ndarray:
    """+1 where direction ``d`` leaves vertex ``k`` of ``p`` (counter-clockwise) into its
    interior, -1 into its exterior, 0 along one of its two edges there."""
    n = len(p)
    e_out, e_back = p[(k + 1) % n] - p[k], p[(k - 1) % n] - p[k]
    a0 = np.arctan2(e_out[:, 1], e_out[:, 0])
    width = np.mod(np.arctan2(e_back[:, 1], e_back[:, 0]) - a0, 2 * np.pi)
    r = np.mod(np.arctan2(d[:, 1], d[:, 0]) - a0, 2 * np.pi)
    on = (_along(e_out, d, tol) & (np.sum(e_out * d, axis=1) > 0)) | \
         (_along(e_back, d, tol) & (np.sum(e_back * d, axis=1) > 0))
    return np.where(on, 0, np.where((r > 0) & (r < width), 1, -1))


def _side_on_edge(p: np.ndarray, i: np.ndarray, d: np.ndarray, tol: float) -> np.ndarray:
    """As :func:`_side_at_vertex` for a point inside edge ``i`` of ``p``."""
    e = p[(i + 1) % len(p)] - p[i]
    return np.where(_along(e, d, tol), 0, np.sign(_cross(e, d))).astype(int)


def _leaving(p: np.ndarray, q: np.ndarray, i: np.ndarray, j: np.ndarray,
             tol: float) -> tuple[np.ndarray, np.ndarray]:
    """The touch points of the boundary of ``q`` on the boundary of ``p`` (for the edge
    pairs ``(i, j)``) and, for each direction the boundary of ``q`` leaves them in, its
    side of ``p`` (+1 inside, -1 outside, 0 along): ``(points (k, 2) m, sides (k,))``."""
    n, m = len(p), len(q)
    pts, sides = [np.zeros((0, 2))], [np.zeros(0, dtype=int)]
    # a vertex j of q on edge i of p: at a vertex of p, or inside the edge
    c, a, b = q[j], p[i], p[(i + 1) % n]
    hit = _seg_dist(c, a, b) <= tol
    jj, ii, c, a, b = j[hit], i[hit], c[hit], a[hit], b[hit]
    at_a = np.hypot(*(c - a).T) <= tol
    at_b = ~at_a & (np.hypot(*(c - b).T) <= tol)
    inside = ~at_a & ~at_b
    for d in (q[(jj + 1) % m] - c, q[(jj - 1) % m] - c):
        s = np.zeros(len(jj), dtype=int)
        if at_a.any():
            s[at_a] = _side_at_vertex(p, ii[at_a], d[at_a], tol)
        if at_b.any():
            s[at_b] = _side_at_vertex(p, (ii[at_b] + 1) % n, d[at_b], tol)
        if inside.any():
            s[inside] = _side_on_edge(p, ii[inside], d[inside], tol)
        pts.append(c)
        sides.append(s)
    # a vertex i of p inside edge j of q
    a, c, e = p[i], q[j], q[(j + 1) % m]
    hit = (_seg_dist(a, c, e) <= tol) & (np.hypot(*(a - c).T) > tol) & \
        (np.hypot(*(a - e).T) > tol)
    for sign in (1.0, -1.0):
        pts.append(a[hit])
        sides.append(_side_at_vertex(p, i[hit], sign * (e[hit] - c[hit]), tol))
    return np.concatenate(pts), np.concatenate(sides)


def _crossing(p: np.ndarray, q: np.ndarray, i: np.ndarray, j: np.ndarray,
              tol: float) -> np.ndarray | None:
    """A point (m) where an edge of ``p`` crosses an edge of ``q`` at interior points of
    both (each end of either edge farther than ``tol`` from the other's line), or None."""
    a, b, c, d = p[i], np.roll(p, -1, axis=0)[i], q[j], np.roll(q, -1, axis=0)[j]
    r, s = b - a, d - c
    lr, ls = np.maximum(np.hypot(*r.T), 1e-300), np.maximum(np.hypot(*s.T), 1e-300)
    sc, sd = _cross(r, c - a) / lr, _cross(r, d - a) / lr
    sa, sb = _cross(s, a - c) / ls, _cross(s, b - c) / ls
    hit = (sc * sd < 0) & (sa * sb < 0) & (np.minimum(np.abs(sc), np.abs(sd)) > tol) & \
        (np.minimum(np.abs(sa), np.abs(sb)) > tol)
    if not hit.any():
        return None
    k = int(np.flatnonzero(hit)[0])
    return a[k] + r[k] * (sa[k] / (sa[k] - sb[k]))


def _contains(p: np.ndarray, x: np.ndarray) -> bool:
    """Is point ``x`` (m, off the boundary) inside polygon ``p`` (crossing number)?"""
    a, b = p, np.roll(p, -1, axis=0)
    span = (a[:, 1] > x[1]) != (b[:, 1] > x[1])
    a, b = a[span], b[span]
    xs = a[:, 0] + (x[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return bool(np.count_nonzero(xs > x[0]) % 2)


def _intervals(poly: np.ndarray, x: float) -> np.ndarray:
    """The intervals ``[[y0, y1], ...]`` (m) of the vertical line at ``x`` inside ``poly``
    (``x`` is not a vertex's x-coordinate)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    span = (np.minimum(a[:, 0], b[:, 0]) < x) & (x < np.maximum(a[:, 0], b[:, 0]))
    a, b = a[span], b[span]
    y = np.sort(a[:, 1] + (x - a[:, 0]) * (b[:, 1] - a[:, 1]) / (b[:, 0] - a[:, 0]))
    return y.reshape(-1, 2)


def _witness(p: np.ndarray, q: np.ndarray, near: np.ndarray, tol: float,
             scale: float) -> tuple[float, float]:
    """A point (m) inside both polygons, on a vertical line close to ``near`` (a point
    next to their common area): the middle of the common interval nearest ``near``.
    Falls back to ``near`` itself."""
    xs = np.sort(np.concatenate([p[:, 0], q[:, 0]]))
    for h in scale * 10.0 ** -np.arange(2, 9):
        for x in (near[0] + h, near[0] - h):
            k = np.searchsorted(xs, x)
            if min(abs(x - xs[max(k - 1, 0)]), abs(x - xs[min(k, len(xs) - 1)])) <= 1e-3 * h:
                continue
            ip, iq = _intervals(p, x), _intervals(q, x)
            first = np.searchsorted(iq[:, 1], ip[:, 0], side="right")
            count = np.maximum(np.searchsorted(iq[:, 0], ip[:, 1], side="left") - first, 0)
            e = np.repeat(np.arange(len(ip)), count)
            f = np.repeat(first, count) + np.arange(len(e)) - np.repeat(np.cumsum(count)
                                                                       - count, count)
            y0, y1 = np.maximum(ip[e, 0], iq[f, 0]), np.minimum(ip[e, 1], iq[f, 1])
            good = y1 - y0 > tol
            if good.any():
                mid = 0.5 * (y0[good] + y1[good])
                return float(x), float(mid[np.argmin(np.abs(mid - near[1]))])
    return float(near[0]), float(near[1])


def overlap_point(p, q) -> tuple[float, float] | None:
    """A point (x, y) in m inside both simple polygons ``p`` and ``q`` (``[(x, y), ...]``,
    m) where they overlap with positive area, or None when they do not (disjoint, or
    touching along edges or at points only).  About n log n in the number of vertices."""
    p, q = _ring(p), _ring(q)
    scale = float(max(np.ptp(p, axis=0).max(), np.ptp(q, axis=0).max(), 1e-300))
    tol = _REL_TOL * scale
    lo, hi = np.maximum(p.min(axis=0), q.min(axis=0)), np.minimum(p.max(axis=0), q.max(axis=0))
    if np.any(hi - lo <= tol):                    # bounding boxes share no area
        return None
    i, j = _edge_pairs(p, q, tol)
    x = _crossing(p, q, i, j, tol)
    if x is not None:
        return _witness(p, q, x, tol, scale)
    pts_q, side_q = _leaving(p, q, i, j, tol)     # the boundary of q against p
    pts_p, side_p = _leaving(q, p, j, i, tol)     # the boundary of p against q
    for pts, side in ((pts_q, side_q), (pts_p, side_p)):
        if (side > 0).any():
            return _witness(p, q, pts[np.argmax(side > 0)], tol, scale)
    if len(side_q):                               # the boundaries meet
        if not (side_q != 0).any():               # ... and coincide: the same region
            return _witness(p, q, q[0], tol, scale)
        return None
    for a, b in ((p, q), (q, p)):                 # disjoint boundaries: nested or apart
        if _contains(a, b[0]):
            return _witness(p, q, b[0], tol, scale)
    return None
