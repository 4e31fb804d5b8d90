"""Numba kernels: exact point–triangle distance (Ericson's region method) and BVH closest point."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

# Points are processed in chunks; each chunk owns one traversal stack.
CHUNK = 256


@njit(cache=True, inline="always")
def _segment_barycentric(p0, p1, p2, a, b):
    """Parameter s in [0, 1] of the point of segment a→b closest to p, and its squared distance."""
    abx = b[0] - a[0]
    aby = b[1] - a[1]
    abz = b[2] - a[2]
    denom = abx * abx + aby * aby + abz * abz
    s = 0.0
    if denom > 0.0:
        s = ((p0 - a[0]) * abx + (p1 - a[1]) * aby + (p2 - a[2]) * abz) / denom
        s = min(1.0, max(0.0, s))
    dx = a[0] + s * abx - p0
    dy = a[1] + s * aby - p1
    dz = a[2] + s * abz - p2
    return s, dx * dx + dy * dy + dz * dz


@njit(cache=True)
def closest_point_triangle(p0, p1, p2, a, b, c):
    """Barycentric coordinates (u, v, w) of the point of triangle abc closest to p = (p0, p1, p2).

    Ericson, *Real-Time Collision Detection* (2005), §5.1.5: classify p against the Voronoi regions
    of the vertices, edges and face. a, b, c: (3,) float64, m. Degenerate (zero-area) triangles fall
    back to the closest of their three edges.
    """
    abx = b[0] - a[0]
    aby = b[1] - a[1]
    abz = b[2] - a[2]
    acx = c[0] - a[0]
    acy = c[1] - a[1]
    acz = c[2] - a[2]
    apx = p0 - a[0]
    apy = p1 - a[1]
    apz = p2 - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return 1.0, 0.0, 0.0  # vertex region a
    bpx = p0 - b[0]
    bpy = p1 - b[1]
    bpz = p2 - b[2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return 0.0, 1.0, 0.0  # vertex region b
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0 and d1 - d3 > 0.0:
        v = d1 / (d1 - d3)
        return 1.0 - v, v, 0.0  # edge region ab
    cpx = p0 - c[0]
    cpy = p1 - c[1]
    cpz = p2 - c[2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return 0.0, 0.0, 1.0  # vertex region c
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0 and d2 - d6 > 0.0:
        w = d2 / (d2 - d6)
        return 1.0 - w, 0.0, w  # edge region ac
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0 and (d4 - d3) + (d5 - d6) > 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return 0.0, 1.0 - w, w  # edge region bc
    total = va + vb + vc
    if total > 0.0:
        v = vb / total
        w = vc / total
        return 1.0 - v - w, v, w  # face region
    # degenerate triangle: best of the three edges
    s_ab, d_ab = _segment_barycentric(p0, p1, p2, a, b)
    s_bc, d_bc = _segment_barycentric(p0, p1, p2, b, c)
    s_ca, d_ca = _segment_barycentric(p0, p1, p2, c, a)
    if d_ab <= d_bc and d_ab <= d_ca:
        return 1.0 - s_ab, s_ab, 0.0
    if d_bc <= d_ca:
        return 0.0, 1.0 - s_bc, s_bc
    return s_ca, 0.0, 1.0 - s_ca


@njit(cache=True, inline="always")
def _box_distance2(p0, p1, p2, lo, hi):
    d = 0.0
    x = max(lo[0] - p0, 0.0, p0 - hi[0])
    d += x * x
    x = max(lo[1] - p1, 0.0, p1 - hi[1])
    d += x * x
    x = max(lo[2] - p2, 0.0, p2 - hi[2])
    d += x * x
    return d


@njit(cache=True, parallel=True)
def closest_points_bvh(points, tri_coords, order, node_child, node_start, node_count,
                       node_lo, node_hi, stack_size, max_distance2,
                       out_distance2, out_point, out_triangle, out_barycentric):
    """Closest point on the mesh for every query point (depth-first, nearer child first, pruned).

    points (q, 3) float64, m; tri_coords (m, 3, 3) float64, m, triangle corners in leaf order;
    order (m,) leaf position → triangle id; node_* the BVH; max_distance2 float, m^2 (only closer
    triangles are searched). Outputs: out_distance2 (q,) m^2 (inf when none within the limit),
    out_point (q, 3) m, out_triangle (q,) int64 (-1 when none), out_barycentric (q, 3) weights of
    the triangle's vertices 0, 1, 2.
    """
    q = points.shape[0]
    n_chunks = (q + CHUNK - 1) // CHUNK
    for chunk in prange(n_chunks):
        stack = np.empty(stack_size, np.int64)
        for i in range(chunk * CHUNK, min(q, (chunk + 1) * CHUNK)):
            p0 = points[i, 0]
            p1 = points[i, 1]
            p2 = points[i, 2]
            best = max_distance2
            best_t = -1
            best_k = -1
            bu = 0.0
            bv = 0.0
            bw = 0.0
            top = 0
            if _box_distance2(p0, p1, p2, node_lo[0], node_hi[0]) <= best:
                stack[0] = 0
                top = 1
            while top > 0:
                top -= 1
                node = stack[top]
                c = node_child[node]
                if c < 0:
                    for k in range(node_start[node], node_start[node] + node_count[node]):
                        a = tri_coords[k, 0]
                        b = tri_coords[k, 1]
                        cc = tri_coords[k, 2]
                        u, v, w = closest_point_triangle(p0, p1, p2, a, b, cc)
                        x0 = u * a[0] + v * b[0] + w * cc[0] - p0
                        x1 = u * a[1] + v * b[1] + w * cc[1] - p1
                        x2 = u * a[2] + v * b[2] + w * cc[2] - p2
                        d2 = x0 * x0 + x1 * x1 + x2 * x2
                        if d2 < best or (d2 == best and best_t >= 0 and order[k] < best_t):
                            best = d2
                            best_t = order[k]
                            best_k = k
                            bu = u
                            bv = v
                            bw = w
                else:
                    dl = _box_distance2(p0, p1, p2, node_lo[c], node_hi[c])
                    dr = _box_distance2(p0, p1, p2, node_lo[c + 1], node_hi[c + 1])
                    if dl <= dr:
                        if dr <= best:
                            stack[top] = c + 1
                            top += 1
                        if dl <= best:
                            stack[top] = c
                            top += 1
                    else:
                        if dl <= best:
                            stack[top] = c
                            top += 1
                        if dr <= best:
                            stack[top] = c + 1
                            top += 1
            out_triangle[i] = best_t
            if best_t >= 0:
                out_distance2[i] = best
                out_barycentric[i, 0] = bu
                out_barycentric[i, 1] = bv
                out_barycentric[i, 2] = bw
                for k in range(3):
                    out_point[i, k] = (bu * tri_coords[best_k, 0, k] + bv * tri_coords[best_k, 1, k]
                                       + bw * tri_coords[best_k, 2, k])
            else:
                out_distance2[i] = np.inf
                out_barycentric[i, :] = np.nan
                out_point[i, :] = np.nan
