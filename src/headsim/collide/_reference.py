"""Brute-force O(points × triangles) versions of every collide query, in NumPy, for tests only.

They use formulations independent of the fast kernels (projection + edge segments for the closest
point, plane intersection + signed sub-areas for rays, the exact solid-angle sum for the winding
number), so a shared mistake is unlikely.
"""

from __future__ import annotations

import numpy as np

from headsim.collide._kernels_ray import EDGE_EPS, PARALLEL_EPS
from headsim.collide.bvh import ClosestPoints, RayHits

_BLOCK = 64  # query rows per vectorised block


def icosphere(subdivisions: int = 1, radius: float = 1.0):
    """Closed, outward-wound icosphere: vertices (n, 3) float64, triangles (m, 3) int64."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def random_star_shape(seed: int, subdivisions: int = 1):
    """A closed, non-self-intersecting test surface: an icosphere with random radii in [0.6, 1.4],
    rotated and shifted at random (star-shaped about its centre, so the winding stays outward)."""
    rng = np.random.default_rng(seed)
    v, t = icosphere(subdivisions)
    v = v * rng.uniform(0.6, 1.4, size=(len(v), 1))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return v @ q.T + rng.uniform(-1, 1, 3), t


def _segment_closest(p, a, b):
    """Closest points on segments a→b to p; p (q, 1, 3), a, b (1, m, 3) → (q, m, 3), param (q, m)."""
    ab = b - a
    denom = np.einsum("...k,...k->...", ab, ab)
    s = np.einsum("...k,...k->...", p - a, ab) / np.where(denom > 0, denom, 1.0)
    s = np.clip(np.where(denom > 0, s, 0.0), 0.0, 1.0)
    return a + s[..., None] * ab, s


def closest_points_bruteforce(points, vertices, triangles) -> ClosestPoints:
    """Closest point on the mesh: projection onto each triangle's plane when it falls inside the
    triangle, otherwise the best of the three edge segments; minimum over all triangles."""
    points = np.asarray(points, float)
    V = np.asarray(vertices, float)
    T = np.asarray(triangles, np.int64)
    a, b, c = V[T[:, 0]][None], V[T[:, 1]][None], V[T[:, 2]][None]
    n = np.cross(b - a, c - a)
    nn = np.einsum("...k,...k->...", n, n)
    out_d = np.empty(len(points))
    out_p = np.empty((len(points), 3))
    out_t = np.empty(len(points), np.int64)
    out_b = np.empty((len(points), 3))
    for s0 in range(0, len(points), _BLOCK):
        p = points[s0:s0 + _BLOCK, None, :]
        # projection and its barycentric coordinates from signed sub-areas
        h = np.einsum("...k,...k->...", p - a, n) / np.where(nn > 0, nn, 1.0)
        x = p - h[..., None] * n
        la = np.einsum("...k,...k->...", np.cross(b - x, c - x), n) / np.where(nn > 0, nn, 1.0)
        lb = np.einsum("...k,...k->...", np.cross(c - x, a - x), n) / np.where(nn > 0, nn, 1.0)
        lc = 1.0 - la - lb
        inside = (nn > 0) & (la >= 0) & (lb >= 0) & (lc >= 0)
        cands = [x]
        bary = [np.stack([la, lb, lc], axis=-1)]
        for (u, v, iu, iv) in ((a, b, 0, 1), (b, c, 1, 2), (c, a, 2, 0)):
            q, s = _segment_closest(p, u, v)
            w = np.zeros(q.shape)
            w[..., iu] = 1.0 - s
            w[..., iv] = s
            cands.append(q)
            bary.append(w)
        dist = [np.linalg.norm(cands[0] - p, axis=-1)]
        dist[0] = np.where(inside, dist[0], np.inf)
        dist += [np.linalg.norm(q - p, axis=-1) for q in cands[1:]]
        dist = np.stack(dist)  # (4, q, m)
        which = np.argmin(dist, axis=0)
        dmin = np.take_along_axis(dist, which[None], 0)[0]
        tri = np.argmin(dmin, axis=1)
        rows = np.arange(len(tri))
        w = which[rows, tri]
        out_d[s0:s0 + len(tri)] = dmin[rows, tri]
        out_p[s0:s0 + len(tri)] = np.stack(cands)[w, rows, tri]
        out_b[s0:s0 + len(tri)] = np.stack(bary)[w, rows, tri]
        out_t[s0:s0 + len(tri)] = tri
    return ClosestPoints(out_d, out_p, out_t, out_b)


def _ray_plane_hits(origins, directions, vertices, triangles, max_distance):
    """(q, m) distances of every ray–triangle hit (inf where none), by plane intersection."""
    o = np.asarray(origins, float)
    d = np.asarray(directions, float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    md = np.broadcast_to(np.asarray(max_distance, float), (len(o),))
    V = np.asarray(vertices, float)
    T = np.asarray(triangles, np.int64)
    a, b, c = V[T[:, 0]][None], V[T[:, 1]][None], V[T[:, 2]][None]
    n = np.cross(b - a, c - a)
    nn = np.einsum("...k,...k->...", n, n)
    dn = np.einsum("qk,mk->qm", d, n[0])
    ok = dn * dn > PARALLEL_EPS**2 * nn
    t = np.einsum("...k,...k->...", a - o[:, None], n) / np.where(ok, dn, 1.0)
    x = o[:, None] + t[..., None] * d[:, None]
    la = np.einsum("...k,...k->...", np.cross(b - x, c - x), n) / np.where(nn > 0, nn, 1.0)
    lb = np.einsum("...k,...k->...", np.cross(c - x, a - x), n) / np.where(nn > 0, nn, 1.0)
    lc = 1.0 - la - lb
    hit = ok & (t >= 0) & (t <= md[:, None]) & (la >= -EDGE_EPS) & (lb >= -EDGE_EPS) & (lc >= -EDGE_EPS)
    return np.where(hit, t, np.inf), np.stack([la, lb, lc], axis=-1), n, o, d


def intersect_rays_bruteforce(origins, directions, vertices, triangles, max_distance=np.inf) -> RayHits:
    """First hit of each ray against every triangle (ties: smallest triangle id)."""
    dist, bary, n, o, d = _ray_plane_hits(origins, directions, vertices, triangles, max_distance)
    tri = np.argmin(dist, axis=1)  # first minimum = smallest id on ties
    rows = np.arange(len(o))
    best = dist[rows, tri]
    hit = np.isfinite(best)
    tri = np.where(hit, tri, -1)
    point = np.where(hit[:, None], o + np.where(hit, best, 0.0)[:, None] * d, np.nan)
    normal = n[0][np.maximum(tri, 0)]
    norm = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(hit[:, None], normal / np.where(norm > 0, norm, 1.0), np.nan)
    b = np.where(hit[:, None], bary[rows, np.maximum(tri, 0)], np.nan)
    return RayHits(hit, best, point, tri, normal, b)


def intersect_rays_all_bruteforce(origins, directions, vertices, triangles, max_distance=np.inf):
    """List (one per ray) of (distances sorted, triangle ids) of every hit."""
    dist, _, _, o, _ = _ray_plane_hits(origins, directions, vertices, triangles, max_distance)
    out = []
    for row in dist:
        ids = np.nonzero(np.isfinite(row))[0]
        k = np.lexsort((ids, row[ids]))
        out.append((row[ids][k], ids[k]))
    return out


def winding_number_exact(points, vertices, triangles) -> np.ndarray:
    """(q,) exact generalized winding number: sum of signed solid angles / 4π (Van Oosterom &
    Strackee 1983, tan(Ω/2) = a·(b×c) / (|a||b||c| + (a·b)|c| + (a·c)|b| + (b·c)|a|))."""
    P = np.asarray(points, float)
    V = np.asarray(vertices, float)
    T = np.asarray(triangles, np.int64)
    out = np.empty(len(P))
    for s0 in range(0, len(P), _BLOCK):
        p = P[s0:s0 + _BLOCK, None, :]
        a = V[T[:, 0]][None] - p
        b = V[T[:, 1]][None] - p
        c = V[T[:, 2]][None] - p
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("...k,...k->...", a, np.cross(b, c))
        dot = lambda x, y: np.einsum("...k,...k->...", x, y)  # noqa: E731
        denom = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la
        out[s0:s0 + len(p)] = (2.0 * np.arctan2(det, denom)).sum(axis=1) / (4.0 * np.pi)
    return out


def contains_bruteforce(points, vertices, triangles, surface_tolerance: float) -> np.ndarray:
    """(q,) bool: on the surface (closest distance <= tolerance, m) or exact winding number > 0.5."""
    on = closest_points_bruteforce(points, vertices, triangles).distance <= surface_tolerance
    return on | (winding_number_exact(points, vertices, triangles) > 0.5)


def signed_distance_bruteforce(points, vertices, triangles, surface_tolerance: float) -> np.ndarray:
    """(q,) m, negative inside (see :func:`contains_bruteforce`)."""
    d = closest_points_bruteforce(points, vertices, triangles).distance
    inside = (d <= surface_tolerance) | (winding_number_exact(points, vertices, triangles) > 0.5)
    return np.where(inside, -d, d)


def heightmap_bruteforce(u, v, axis: int, from_above: bool, vertices, triangles) -> np.ndarray:
    """Height of the surface seen along ``axis`` at in-plane coordinates (u, v), NaN where no hit:
    one brute-force ray per sample, cast from beyond the mesh's bounding box."""
    V = np.asarray(vertices, float)
    other = [k for k in range(3) if k != axis]
    lo, hi = V[:, axis].min(), V[:, axis].max()
    span = hi - lo + 1.0
    o = np.zeros((len(u), 3))
    o[:, other[0]] = u
    o[:, other[1]] = v
    o[:, axis] = hi + span if from_above else lo - span
    d = np.zeros((len(u), 3))
    d[:, axis] = -1.0 if from_above else 1.0
    hits = intersect_rays_bruteforce(o, d, V, triangles)
    return np.where(hits.hit, hits.point[:, axis], np.nan)
