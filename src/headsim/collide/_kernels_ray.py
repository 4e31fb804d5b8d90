"""Numba kernels: Möller–Trumbore ray–triangle test and BVH ray traversal (first hit, all hits).

Tie rule (watertight in practice): a hit is accepted when its barycentric coordinates satisfy
``u >= -EDGE_EPS``, ``v >= -EDGE_EPS``, ``u + v <= 1 + EDGE_EPS``; edges and vertices therefore
belong to every triangle that shares them, so a ray through a shared edge or vertex never slips
between two triangles. The first-hit query then keeps the smallest distance and, on an exact tie,
the smallest triangle id; the all-hits query reports each triangle that was hit (a ray through a
shared edge lists both triangles at the same distance).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from headsim.collide._kernels_closest import CHUNK

EDGE_EPS = 1e-9
"""Barycentric tolerance (dimensionless) of the inclusive edge test."""
PARALLEL_EPS = 1e-12
"""A ray is parallel to a triangle when |cos(angle between normal and direction)| <= this."""


@njit(cache=True, inline="always")
def moller_trumbore(o0, o1, o2, d0, d1, d2, a, b, c):
    """Ray o + t d against triangle abc (Möller & Trumbore 1997; Heinze §3.3.3).

    Parallel test via the normal: det = -(n · d) with n = (b - a) × (c - a); a ray whose direction
    makes |cos| <= PARALLEL_EPS with the normal misses. Otherwise Cramer's rule gives (t, u, v).
    Returns (t, u, v), t = -1 for a miss; d need not be normalised (t is in units of |d|).
    """
    e1x = b[0] - a[0]
    e1y = b[1] - a[1]
    e1z = b[2] - a[2]
    e2x = c[0] - a[0]
    e2y = c[1] - a[1]
    e2z = c[2] - a[2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    det = -(nx * d0 + ny * d1 + nz * d2)
    nn = (nx * nx + ny * ny + nz * nz) * (d0 * d0 + d1 * d1 + d2 * d2)
    if not det * det > PARALLEL_EPS * PARALLEL_EPS * nn:
        return -1.0, 0.0, 0.0
    inv = 1.0 / det
    # pvec = d × e2
    px = d1 * e2z - d2 * e2y
    py = d2 * e2x - d0 * e2z
    pz = d0 * e2y - d1 * e2x
    sx = o0 - a[0]
    sy = o1 - a[1]
    sz = o2 - a[2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -EDGE_EPS or u > 1.0 + EDGE_EPS:
        return -1.0, 0.0, 0.0
    # qvec = s × e1
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (d0 * qx + d1 * qy + d2 * qz) * inv
    if v < -EDGE_EPS or u + v > 1.0 + EDGE_EPS:
        return -1.0, 0.0, 0.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return t, u, v


@njit(cache=True, inline="always")
def _ray_box_entry(o0, o1, o2, d0, d1, d2, i0, i1, i2, lo, hi, tmax):
    """Entry parameter of the ray into box [lo, hi] within [0, tmax], inf when it misses."""
    t0 = 0.0
    t1 = tmax
    if d0 == 0.0:
        if o0 < lo[0] or o0 > hi[0]:
            return np.inf
    else:
        ta = (lo[0] - o0) * i0
        tb = (hi[0] - o0) * i0
        t0 = max(t0, min(ta, tb))
        t1 = min(t1, max(ta, tb))
    if d1 == 0.0:
        if o1 < lo[1] or o1 > hi[1]:
            return np.inf
    else:
        ta = (lo[1] - o1) * i1
        tb = (hi[1] - o1) * i1
        t0 = max(t0, min(ta, tb))
        t1 = min(t1, max(ta, tb))
    if d2 == 0.0:
        if o2 < lo[2] or o2 > hi[2]:
            return np.inf
    else:
        ta = (lo[2] - o2) * i2
        tb = (hi[2] - o2) * i2
        t0 = max(t0, min(ta, tb))
        t1 = min(t1, max(ta, tb))
    if t0 > t1:
        return np.inf
    return t0


@njit(cache=True, inline="always")
def first_hit_ray(o0, o1, o2, d0, d1, d2, tmin, tmax, tri_coords, order, node_child, node_start, node_count,
                  node_lo, node_hi, stack, stack_t):
    """Nearest hit t ∈ [tmin, tmax] of one ray o + t d (front-to-back, pruned traversal; the tie rule of the
    module). stack, stack_t: work arrays of the tree's stack size. Returns (t, triangle id, u, v): (inf, −1, 0, 0)
    on a miss; u, v the barycentric weights of the triangle's vertices 1 and 2."""
    i0 = 1.0 / d0 if d0 != 0.0 else 0.0
    i1 = 1.0 / d1 if d1 != 0.0 else 0.0
    i2 = 1.0 / d2 if d2 != 0.0 else 0.0
    best = np.inf
    best_tri = -1
    bu = 0.0
    bv = 0.0
    top = 0
    t_root = _ray_box_entry(o0, o1, o2, d0, d1, d2, i0, i1, i2, node_lo[0], node_hi[0], tmax)
    if t_root < np.inf:
        stack[0] = 0
        stack_t[0] = t_root
        top = 1
    while top > 0:
        top -= 1
        if stack_t[top] > best:
            continue
        node = stack[top]
        c = node_child[node]
        if c < 0:
            for k in range(node_start[node], node_start[node] + node_count[node]):
                t, u, v = moller_trumbore(o0, o1, o2, d0, d1, d2, tri_coords[k, 0], tri_coords[k, 1], tri_coords[k, 2])
                if t >= tmin and t <= tmax:
                    if t < best or (t == best and order[k] < best_tri):
                        best = t
                        best_tri = order[k]
                        bu = u
                        bv = v
        else:
            lim = min(tmax, best)
            tl = _ray_box_entry(o0, o1, o2, d0, d1, d2, i0, i1, i2, node_lo[c], node_hi[c], lim)
            tr = _ray_box_entry(o0, o1, o2, d0, d1, d2, i0, i1, i2, node_lo[c + 1], node_hi[c + 1], lim)
            if tl <= tr:
                if tr < np.inf:
                    stack[top] = c + 1
                    stack_t[top] = tr
                    top += 1
                if tl < np.inf:
                    stack[top] = c
                    stack_t[top] = tl
                    top += 1
            else:
                if tl < np.inf:
                    stack[top] = c
                    stack_t[top] = tl
                    top += 1
                if tr < np.inf:
                    stack[top] = c + 1
                    stack_t[top] = tr
                    top += 1
    return best, best_tri, bu, bv


@njit(cache=True, parallel=True)
def first_hits_bvh(origins, directions, max_distance, tri_coords, order, node_child,
                   node_start, node_count, node_lo, node_hi, stack_size,
                   out_distance, out_triangle, out_u, out_v):
    """Nearest hit of every ray within [0, max_distance[i]] (:func:`first_hit_ray`).

    origins, directions (q, 3) float64 (m; directions unit length); max_distance (q,) m.
    Outputs: out_distance (q,) m (inf on a miss), out_triangle (q,) int64 (-1 on a miss),
    out_u, out_v (q,) barycentric weights of the triangle's vertices 1 and 2.
    """
    q = origins.shape[0]
    n_chunks = (q + CHUNK - 1) // CHUNK
    for chunk in prange(n_chunks):
        stack = np.empty(stack_size, np.int64)
        stack_t = np.empty(stack_size)
        for i in range(chunk * CHUNK, min(q, (chunk + 1) * CHUNK)):
            t, tri, u, v = first_hit_ray(origins[i, 0], origins[i, 1], origins[i, 2], directions[i, 0],
                                         directions[i, 1], directions[i, 2], 0.0, max_distance[i], tri_coords,
                                         order, node_child, node_start, node_count, node_lo, node_hi, stack,
                                         stack_t)
            out_distance[i] = t
            out_triangle[i] = tri
            out_u[i] = u
            out_v[i] = v


@njit(cache=True, parallel=True)
def all_hits_bvh(origins, directions, max_distance, tri_coords, order, node_child,
                 node_start, node_count, node_lo, node_hi, stack_size, offsets, fill,
                 out_count, out_distance, out_triangle, out_u, out_v):
    """Every hit of every ray within [0, max_distance[i]], in two passes.

    With ``fill`` False only out_count (q,) int64 is written. With ``fill`` True, ``offsets``
    (q + 1,) int64 (prefix sums of the counts) say where ray i's hits go in out_distance (k,) m,
    out_triangle (k,) int64, out_u, out_v (k,); each ray's hits are sorted by distance (ties by
    triangle id).
    """
    q = origins.shape[0]
    n_chunks = (q + CHUNK - 1) // CHUNK
    for chunk in prange(n_chunks):
        stack = np.empty(stack_size, np.int64)
        for i in range(chunk * CHUNK, min(q, (chunk + 1) * CHUNK)):
            o0 = origins[i, 0]
            o1 = origins[i, 1]
            o2 = origins[i, 2]
            d0 = directions[i, 0]
            d1 = directions[i, 1]
            d2 = directions[i, 2]
            i0 = 1.0 / d0 if d0 != 0.0 else 0.0
            i1 = 1.0 / d1 if d1 != 0.0 else 0.0
            i2 = 1.0 / d2 if d2 != 0.0 else 0.0
            tmax = max_distance[i]
            n_hit = 0
            base = offsets[i] if fill else 0
            top = 0
            if _ray_box_entry(o0, o1, o2, d0, d1, d2, i0, i1, i2, node_lo[0], node_hi[0], tmax) < np.inf:
                stack[0] = 0
                top = 1
            while top > 0:
                top -= 1
                node = stack[top]
                c = node_child[node]
                if c < 0:
                    for k in range(node_start[node], node_start[node] + node_count[node]):
                        t, u, v = moller_trumbore(o0, o1, o2, d0, d1, d2,
                                                  tri_coords[k, 0], tri_coords[k, 1], tri_coords[k, 2])
                        if t >= 0.0 and t <= tmax:
                            if fill:
                                j = base + n_hit
                                tri = order[k]
                                # insertion into the sorted run base .. j
                                while j > base and (out_distance[j - 1] > t or (
                                        out_distance[j - 1] == t and out_triangle[j - 1] > tri)):
                                    out_distance[j] = out_distance[j - 1]
                                    out_triangle[j] = out_triangle[j - 1]
                                    out_u[j] = out_u[j - 1]
                                    out_v[j] = out_v[j - 1]
                                    j -= 1
                                out_distance[j] = t
                                out_triangle[j] = tri
                                out_u[j] = u
                                out_v[j] = v
                            n_hit += 1
                else:
                    if _ray_box_entry(o0, o1, o2, d0, d1, d2, i0, i1, i2, node_lo[c], node_hi[c], tmax) < np.inf:
                        stack[top] = c
                        top += 1
                    if _ray_box_entry(o0, o1, o2, d0, d1, d2, i0, i1, i2, node_lo[c + 1], node_hi[c + 1], tmax) < np.inf:
                        stack[top] = c + 1
                        top += 1
            out_count[i] = n_hit
