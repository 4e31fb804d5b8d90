"""Slow references for the fibre collision code, for tests and benchmarks only.

* :func:`segment_closest_points` — vectorised NumPy closest points of segment pairs (Ericson 2005,
  §5.1.9), independent of the Numba kernel.
* :func:`capsule_contacts_bruteforce` — all colliding capsule pairs by the O(S²) test of every pair.
* :func:`capsule_contacts_kdtree` — the "peer" method: a SciPy cKDTree on segment midpoints finds
  candidate pairs within ``max segment length + 2 max radius``, NumPy does the exact test.
* :func:`capsule_contacts_numpy` — the contact records of :func:`~headsim.collide.fibres.capsule_contacts`
  in plain NumPy.
* :func:`point_mesh_distance_bruteforce` — exact point-to-triangle-mesh distance by testing every
  triangle (Ericson 2005, §5.1.5).
"""

from __future__ import annotations

import numpy as np

from headsim.collide.fibres import FibreContacts, FibreSet


def segment_closest_points(p1, q1, p2, q2):
    """Closest points of segment pairs; all (n, 3). Returns s (n,), t (n,), squared distance (n,)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = (d1 * d1).sum(1)
    e = (d2 * d2).sum(1)
    f = (d2 * r).sum(1)
    c = (d1 * r).sum(1)
    b = (d1 * d2).sum(1)
    tiny = 1e-300
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 0, np.clip((b * f - c * e) / np.where(denom > 0, denom, 1), 0, 1), 0.0)
        t = (b * s + f) / np.where(e > tiny, e, 1.0)
        s_lo = np.clip(-c / np.where(a > tiny, a, 1.0), 0, 1)
        s_hi = np.clip((b - c) / np.where(a > tiny, a, 1.0), 0, 1)
    s = np.where(t < 0, s_lo, np.where(t > 1, s_hi, s))
    t = np.clip(t, 0, 1)
    # degenerate segments
    deg_e = e <= tiny
    s = np.where(deg_e, s_lo, s)
    t = np.where(deg_e, 0.0, t)
    deg_a = a <= tiny
    t = np.where(deg_a, np.clip(f / np.where(e > tiny, e, 1.0), 0, 1), t)
    s = np.where(deg_a, 0.0, s)
    t = np.where(deg_a & deg_e, 0.0, t)
    d = (p1 + s[:, None] * d1) - (p2 + t[:, None] * d2)
    return s, t, (d * d).sum(1)


def _test_pairs(fibres: FibreSet, nodes, a, b):
    ia, ib = fibres.segment_start[a], fibres.segment_start[b]
    s, t, d2 = segment_closest_points(nodes[ia], nodes[ia + 1], nodes[ib], nodes[ib + 1])
    rr = fibres.radius[a] + fibres.radius[b]
    hit = (d2 < rr * rr) & ~fibres.adjacent(a, b)
    return hit, s, t


def capsule_contacts_bruteforce(fibres: FibreSet, nodes=None, chunk: int = 2_000_000):
    """All colliding segment pairs by testing every pair: pairs (n, 2) sorted with a < b, params (n, 2)."""
    x = fibres.nodes if nodes is None else np.asarray(nodes, float)
    n = fibres.n_segments
    out_p, out_s = [], []
    rows = max(1, chunk // max(n, 1))
    for a0 in range(0, n, rows):
        a = np.arange(a0, min(n, a0 + rows))
        aa, bb = np.meshgrid(a, np.arange(n), indexing="ij")
        keep = bb > aa
        aa, bb = aa[keep], bb[keep]
        hit, s, t = _test_pairs(fibres, x, aa, bb)
        out_p.append(np.stack([aa[hit], bb[hit]], 1))
        out_s.append(np.stack([s[hit], t[hit]], 1))
    pairs = np.concatenate(out_p) if out_p else np.zeros((0, 2), np.int64)
    params = np.concatenate(out_s) if out_s else np.zeros((0, 2))
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order].astype(np.int64), params[order]


def capsule_contacts_kdtree(fibres: FibreSet, nodes=None, chunk: int = 50_000):
    """Peer method: cKDTree broad phase on segment midpoints + NumPy exact test.

    Two capsules can touch only if their midpoints are closer than ``(L_a + L_b)/2 + r_a + r_b``, so a
    ball query with ``max length + 2 max radius`` finds every candidate. The query runs ``chunk``
    segments at a time (a small tree of the chunk against the full tree,
    ``sparse_distance_matrix(..., output_type="ndarray")``), so memory stays bounded by the
    candidates of one chunk. Returns like :func:`capsule_contacts_bruteforce`.
    """
    from scipy.spatial import cKDTree

    x = fibres.nodes if nodes is None else np.asarray(nodes, float)
    p, q = fibres.segment_endpoints(x)
    mid = 0.5 * (p + q)
    length = np.linalg.norm(q - p, axis=1)
    reach = length.max() + 2.0 * fibres.radius.max()
    tree = cKDTree(mid)
    out_p, out_s = [], []
    for c0 in range(0, len(mid), chunk):
        near = cKDTree(mid[c0 : c0 + chunk]).sparse_distance_matrix(tree, reach, output_type="ndarray")
        a = near["i"].astype(np.int64) + c0
        b = near["j"].astype(np.int64)
        keep = b > a
        a, b = a[keep], b[keep]
        hit, s, t = _test_pairs(fibres, x, a, b)
        out_p.append(np.stack([a[hit], b[hit]], 1))
        out_s.append(np.stack([s[hit], t[hit]], 1))
    pairs = np.concatenate(out_p) if out_p else np.zeros((0, 2), np.int64)
    params = np.concatenate(out_s) if out_s else np.zeros((0, 2))
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order].astype(np.int64), params[order]


def closest_point_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p; all (n, 3) (Ericson 2005, §5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    out = np.empty_like(p)
    done = np.zeros(len(p), bool)

    def put(mask, val):
        m = mask & ~done
        out[m] = val[m]
        done[m] = True

    with np.errstate(divide="ignore", invalid="ignore"):
        put((d1 <= 0) & (d2 <= 0), a)
        put((d3 >= 0) & (d4 <= d3), b)
        v = d1 / (d1 - d3)
        put((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + v[:, None] * ab)
        put((d6 >= 0) & (d5 <= d6), c)
        w = d2 / (d2 - d6)
        put((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + w[:, None] * ac)
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        put((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + w[:, None] * (c - b))
        denom = 1.0 / (va + vb + vc)
        v, w = vb * denom, vc * denom
        put(np.ones(len(p), bool), a + v[:, None] * ab + w[:, None] * ac)
    return out


def point_mesh_distance_bruteforce(points, vertices, triangles):
    """Unsigned distance (n,) m and closest points (n, 3) of ``points`` to a triangle mesh, exactly."""
    pts = np.asarray(points, float)
    v = np.asarray(vertices, float)
    t = np.asarray(triangles, np.int64)
    best = np.full(len(pts), np.inf)
    closest = np.zeros_like(pts)
    for i, p in enumerate(pts):
        pp = np.broadcast_to(p, (len(t), 3))
        q = closest_point_on_triangles(pp, v[t[:, 0]], v[t[:, 1]], v[t[:, 2]])
        d = np.linalg.norm(q - p, axis=1)
        j = int(np.argmin(d))
        best[i], closest[i] = d[j], q[j]
    return best, closest


def capsule_contacts_numpy(fibres: FibreSet, pairs: np.ndarray, params: np.ndarray,
                           nodes: np.ndarray | None = None) -> FibreContacts:
    """NumPy reference of :func:`headsim.collide.fibres.capsule_contacts` (same arithmetic, vectorised).

    pairs : (n, 2) int64 segment ids (a < b); params : (n, 2) float64 closest-point parameters (s, t).
    A zero centre-line distance (crossing axes) takes the normal ``d_a × d_b`` (or any
    perpendicular of d_a if parallel).
    """
    x = fibres.nodes if nodes is None else nodes
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    params = np.asarray(params, np.float64).reshape(-1, 2)
    a, b = pairs[:, 0], pairs[:, 1]
    ia, ib = fibres.segment_start[a], fibres.segment_start[b]
    da = x[ia + 1] - x[ia]
    db = x[ib + 1] - x[ib]
    ca = x[ia] + params[:, :1] * da
    cb = x[ib] + params[:, 1:] * db
    d = ca - cb
    dist = np.linalg.norm(d, axis=1)
    normal = np.empty_like(d)
    ok = dist > 1e-300
    normal[ok] = d[ok] / dist[ok, None]
    if (~ok).any():
        c = np.cross(da[~ok], db[~ok])
        cn = np.linalg.norm(c, axis=1)
        para = cn <= 1e-300
        helper = np.where((np.abs(da[~ok][:, 0]) < 0.9)[:, None], [1.0, 0, 0], [0, 1.0, 0])
        c[para] = np.cross(da[~ok][para], helper[para])
        normal[~ok] = c / np.linalg.norm(c, axis=1, keepdims=True)
    ra, rb = fibres.radius[a], fibres.radius[b]
    return FibreContacts(
        body_a=fibres.segment_fibre[a],
        body_b=fibres.segment_fibre[b],
        segment_a=a.copy(),
        segment_b=b.copy(),
        s_a=params[:, 0].copy(),
        s_b=params[:, 1].copy(),
        point_a=ca - ra[:, None] * normal,
        point_b=cb + rb[:, None] * normal,
        normal=normal,
        depth=ra + rb - dist,
        obstacle=np.zeros(len(a), bool),
    )
