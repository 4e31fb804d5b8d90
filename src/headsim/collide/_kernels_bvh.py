"""Numba kernels that build and refit the triangle BVH (flat arrays, no Python objects).

Layout of a tree with ``n_nodes`` nodes (root = node 0):

- ``node_child`` (n_nodes,) int64: index of the first child (the second is ``node_child + 1``), or -1
  for a leaf. Children always have larger indices than their parent, so one reverse loop refits.
- ``node_start``, ``node_count`` (n_nodes,) int64: a leaf's range in the triangle ``order``.
- ``node_lo``, ``node_hi`` (n_nodes, 3) float64, m: axis-aligned boxes.
- ``order`` (m,) int64: triangle ids in leaf order.

Inputs first, outputs last (headsim style).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_N_BINS = 16
# Boxes are padded by this fraction of their largest side (plus the same fraction of the root's
# largest side) so that a hit accepted by the tolerant triangle tests always lies inside its box.
BOX_PAD = 1e-7


@njit(cache=True)
def _sah_split(order, start, end, centroids, tri_lo, tri_hi, clo, chi):
    """Best binned-SAH split of ``order[start:end]``: (axis, bin boundary index, cost) or axis -1."""
    best_axis = -1
    best_k = -1
    best_cost = np.inf
    bin_count = np.zeros(_N_BINS, np.int64)
    bin_lo = np.empty((_N_BINS, 3))
    bin_hi = np.empty((_N_BINS, 3))
    right_area = np.empty(_N_BINS)
    right_count = np.empty(_N_BINS, np.int64)
    for axis in range(3):
        extent = chi[axis] - clo[axis]
        if not extent > 0.0:
            continue
        scale = _N_BINS / extent
        bin_count[:] = 0
        bin_lo[:, :] = np.inf
        bin_hi[:, :] = -np.inf
        for i in range(start, end):
            t = order[i]
            b = int((centroids[t, axis] - clo[axis]) * scale)
            if b >= _N_BINS:
                b = _N_BINS - 1
            bin_count[b] += 1
            for k in range(3):
                if tri_lo[t, k] < bin_lo[b, k]:
                    bin_lo[b, k] = tri_lo[t, k]
                if tri_hi[t, k] > bin_hi[b, k]:
                    bin_hi[b, k] = tri_hi[t, k]
        # sweep from the right: area and count of bins k..N-1
        lo0 = np.inf
        lo1 = np.inf
        lo2 = np.inf
        hi0 = -np.inf
        hi1 = -np.inf
        hi2 = -np.inf
        cnt = 0
        for b in range(_N_BINS - 1, 0, -1):
            if bin_count[b] > 0:
                lo0 = min(lo0, bin_lo[b, 0])
                lo1 = min(lo1, bin_lo[b, 1])
                lo2 = min(lo2, bin_lo[b, 2])
                hi0 = max(hi0, bin_hi[b, 0])
                hi1 = max(hi1, bin_hi[b, 1])
                hi2 = max(hi2, bin_hi[b, 2])
                cnt += bin_count[b]
            right_count[b] = cnt
            if cnt > 0:
                dx = hi0 - lo0
                dy = hi1 - lo1
                dz = hi2 - lo2
                right_area[b] = dx * dy + dy * dz + dz * dx
            else:
                right_area[b] = 0.0
        lo0 = np.inf
        lo1 = np.inf
        lo2 = np.inf
        hi0 = -np.inf
        hi1 = -np.inf
        hi2 = -np.inf
        cnt = 0
        for b in range(0, _N_BINS - 1):
            if bin_count[b] > 0:
                lo0 = min(lo0, bin_lo[b, 0])
                lo1 = min(lo1, bin_lo[b, 1])
                lo2 = min(lo2, bin_lo[b, 2])
                hi0 = max(hi0, bin_hi[b, 0])
                hi1 = max(hi1, bin_hi[b, 1])
                hi2 = max(hi2, bin_hi[b, 2])
                cnt += bin_count[b]
            if cnt == 0 or right_count[b + 1] == 0:
                continue
            dx = hi0 - lo0
            dy = hi1 - lo1
            dz = hi2 - lo2
            cost = (dx * dy + dy * dz + dz * dx) * cnt + right_area[b + 1] * right_count[b + 1]
            if cost < best_cost:
                best_cost = cost
                best_axis = axis
                best_k = b + 1
    return best_axis, best_k, best_cost


@njit(cache=True)
def build_bvh(vertices, triangles, leaf_size):
    """Top-down binned-SAH build (16 bins on each axis, split when a node holds > ``leaf_size``).

    vertices (n, 3) float64, m; triangles (m, 3) int64; leaf_size int >= 1.
    Returns (order, node_child, node_start, node_count, n_nodes, depth); boxes come from
    :func:`refit_bvh`. Arrays are sized 2m - 1 (an upper bound); use the first ``n_nodes``.
    """
    m = triangles.shape[0]
    tri_lo = np.empty((m, 3))
    tri_hi = np.empty((m, 3))
    centroids = np.empty((m, 3))
    for t in range(m):
        for k in range(3):
            a = vertices[triangles[t, 0], k]
            b = vertices[triangles[t, 1], k]
            c = vertices[triangles[t, 2], k]
            tri_lo[t, k] = min(a, min(b, c))
            tri_hi[t, k] = max(a, max(b, c))
            centroids[t, k] = (a + b + c) / 3.0
    max_nodes = max(2 * m - 1, 1)
    order = np.arange(m)
    node_child = np.full(max_nodes, -1, np.int64)
    node_start = np.zeros(max_nodes, np.int64)
    node_count = np.zeros(max_nodes, np.int64)
    stack_node = np.empty(max_nodes, np.int64)
    stack_start = np.empty(max_nodes, np.int64)
    stack_end = np.empty(max_nodes, np.int64)
    stack_depth = np.empty(max_nodes, np.int64)
    clo = np.empty(3)
    chi = np.empty(3)
    top = 0
    stack_node[0] = 0
    stack_start[0] = 0
    stack_end[0] = m
    stack_depth[0] = 0
    top = 1
    n_nodes = 1
    depth = 0
    while top > 0:
        top -= 1
        node = stack_node[top]
        start = stack_start[top]
        end = stack_end[top]
        d = stack_depth[top]
        if d > depth:
            depth = d
        node_start[node] = start
        node_count[node] = end - start
        if end - start <= leaf_size:
            continue
        clo[:] = np.inf
        chi[:] = -np.inf
        for i in range(start, end):
            t = order[i]
            for k in range(3):
                if centroids[t, k] < clo[k]:
                    clo[k] = centroids[t, k]
                if centroids[t, k] > chi[k]:
                    chi[k] = centroids[t, k]
        axis, kbin, _ = _sah_split(order, start, end, centroids, tri_lo, tri_hi, clo, chi)
        mid = start
        if axis >= 0:
            scale = _N_BINS / (chi[axis] - clo[axis])
            i = start
            j = end - 1
            while i <= j:
                b = int((centroids[order[i], axis] - clo[axis]) * scale)
                if b >= _N_BINS:
                    b = _N_BINS - 1
                if b < kbin:
                    i += 1
                else:
                    tmp = order[i]
                    order[i] = order[j]
                    order[j] = tmp
                    j -= 1
            mid = i
        if mid <= start or mid >= end:  # all centroids coincide: split the range in half
            mid = (start + end) // 2
        child = n_nodes
        n_nodes += 2
        node_child[node] = child
        stack_node[top] = child + 1
        stack_start[top] = mid
        stack_end[top] = end
        stack_depth[top] = d + 1
        top += 1
        stack_node[top] = child
        stack_start[top] = start
        stack_end[top] = mid
        stack_depth[top] = d + 1
        top += 1
    return order, node_child, node_start, node_count, n_nodes, depth


@njit(cache=True)
def refit_bvh(vertices, sorted_triangles, node_child, node_start, node_count, tri_coords, node_lo, node_hi):
    """Recompute every node box bottom-up in O(nodes) after the vertices moved.

    vertices (n, 3) float64, m; sorted_triangles (m, 3) int64 in leaf order; node_* as built.
    Outputs: tri_coords (m, 3, 3) float64, m, corner coordinates in leaf order (what the queries
    read, contiguous per leaf); node_lo, node_hi (n_nodes, 3) float64, m, boxes padded by
    ``BOX_PAD`` times (node's largest side + root's largest side).
    """
    for i in range(sorted_triangles.shape[0]):
        for j in range(3):
            for k in range(3):
                tri_coords[i, j, k] = vertices[sorted_triangles[i, j], k]
    n_nodes = node_child.shape[0]
    # root size from the vertex cloud (only used for the absolute part of the padding)
    vlo = np.full(3, np.inf)
    vhi = np.full(3, -np.inf)
    for i in range(vertices.shape[0]):
        for k in range(3):
            x = vertices[i, k]
            if x < vlo[k]:
                vlo[k] = x
            if x > vhi[k]:
                vhi[k] = x
    root_pad = BOX_PAD * max(vhi[0] - vlo[0], max(vhi[1] - vlo[1], vhi[2] - vlo[2]))
    for node in range(n_nodes - 1, -1, -1):
        c = node_child[node]
        if c < 0:
            for k in range(3):
                lo = np.inf
                hi = -np.inf
                for i in range(node_start[node], node_start[node] + node_count[node]):
                    for j in range(3):
                        x = tri_coords[i, j, k]
                        if x < lo:
                            lo = x
                        if x > hi:
                            hi = x
                node_lo[node, k] = lo
                node_hi[node, k] = hi
            side = max(node_hi[node, 0] - node_lo[node, 0],
                       max(node_hi[node, 1] - node_lo[node, 1], node_hi[node, 2] - node_lo[node, 2]))
            pad = BOX_PAD * side + root_pad
            for k in range(3):
                node_lo[node, k] -= pad
                node_hi[node, k] += pad
        else:
            for k in range(3):
                node_lo[node, k] = min(node_lo[c, k], node_lo[c + 1, k])
                node_hi[node, k] = max(node_hi[c, k], node_hi[c + 1, k])


@njit(cache=True)
def refit_winding_moments(vertices, sorted_triangles, node_child, node_start, node_count, node_lo,
                          node_hi, node_center, node_radius, node_normal, node_moment, node_tensor):
    """Far-field expansion data of every node for the fast winding number (Barill et al. 2018).

    Outputs, per node: node_center (n_nodes, 3) area-weighted centroid, m; node_radius (n_nodes,)
    radius of a sphere about the centre holding all the node's triangles, m (exact for leaves, the
    smaller of the box-corner and children's-spheres bounds above); node_normal (n_nodes, 3) sum of area
    vectors N = sum A_t n_t, m^2; node_moment (n_nodes, 3, 3) M_ij = sum A_t n_t,i (x_t - c)_j, m^3;
    node_tensor (n_nodes, 3, 3, 3) T_ijk = sum_t A_t n_t,i (mean over triangle t of (x - c)_j (x - c)_k), m^4,
    with the triangle's own second moment (1/12) sum_v (v - x_t)(v - x_t)^T included (x_t its centroid).
    Bottom-up in O(nodes); boxes must be current (:func:`refit_bvh`).
    """
    n_nodes = node_child.shape[0]
    node_area = np.zeros(n_nodes)
    for node in range(n_nodes - 1, -1, -1):
        c = node_child[node]
        if c < 0:
            area_sum = 0.0
            cx = 0.0
            cy = 0.0
            cz = 0.0
            nx = 0.0
            ny = 0.0
            nz = 0.0
            for i in range(node_start[node], node_start[node] + node_count[node]):
                a = vertices[sorted_triangles[i, 0]]
                b = vertices[sorted_triangles[i, 1]]
                cc = vertices[sorted_triangles[i, 2]]
                e1x = b[0] - a[0]
                e1y = b[1] - a[1]
                e1z = b[2] - a[2]
                e2x = cc[0] - a[0]
                e2y = cc[1] - a[1]
                e2z = cc[2] - a[2]
                ax = 0.5 * (e1y * e2z - e1z * e2y)
                ay = 0.5 * (e1z * e2x - e1x * e2z)
                az = 0.5 * (e1x * e2y - e1y * e2x)
                area = np.sqrt(ax * ax + ay * ay + az * az)
                area_sum += area
                cx += area * (a[0] + b[0] + cc[0]) / 3.0
                cy += area * (a[1] + b[1] + cc[1]) / 3.0
                cz += area * (a[2] + b[2] + cc[2]) / 3.0
                nx += ax
                ny += ay
                nz += az
            if area_sum > 0.0:
                cx /= area_sum
                cy /= area_sum
                cz /= area_sum
            else:
                cx = 0.5 * (node_lo[node, 0] + node_hi[node, 0])
                cy = 0.5 * (node_lo[node, 1] + node_hi[node, 1])
                cz = 0.5 * (node_lo[node, 2] + node_hi[node, 2])
            node_center[node, 0] = cx
            node_center[node, 1] = cy
            node_center[node, 2] = cz
            node_area[node] = area_sum
            node_normal[node, 0] = nx
            node_normal[node, 1] = ny
            node_normal[node, 2] = nz
            node_moment[node, :, :] = 0.0
            node_tensor[node, :, :, :] = 0.0
            av = np.empty(3)
            delta = np.empty(3)
            cov = np.empty((3, 3))
            for i in range(node_start[node], node_start[node] + node_count[node]):
                a = vertices[sorted_triangles[i, 0]]
                b = vertices[sorted_triangles[i, 1]]
                cc = vertices[sorted_triangles[i, 2]]
                av[0] = 0.5 * ((b[1] - a[1]) * (cc[2] - a[2]) - (b[2] - a[2]) * (cc[1] - a[1]))
                av[1] = 0.5 * ((b[2] - a[2]) * (cc[0] - a[0]) - (b[0] - a[0]) * (cc[2] - a[2]))
                av[2] = 0.5 * ((b[0] - a[0]) * (cc[1] - a[1]) - (b[1] - a[1]) * (cc[0] - a[0]))
                for q in range(3):
                    delta[q] = (a[q] + b[q] + cc[q]) / 3.0 - node_center[node, q]
                for q in range(3):
                    xq = (a[q] + b[q] + cc[q]) / 3.0
                    for r in range(3):
                        xr = (a[r] + b[r] + cc[r]) / 3.0
                        cov[q, r] = ((a[q] - xq) * (a[r] - xr) + (b[q] - xq) * (b[r] - xr)
                                     + (cc[q] - xq) * (cc[r] - xr)) / 12.0
                for p in range(3):
                    for q in range(3):
                        node_moment[node, p, q] += av[p] * delta[q]
                        for r in range(3):
                            node_tensor[node, p, q, r] += av[p] * (delta[q] * delta[r] + cov[q, r])
        else:
            l = c
            r = c + 1
            node_tensor[node, :, :, :] = 0.0
            area_sum = node_area[l] + node_area[r]
            node_area[node] = area_sum
            for k in range(3):
                if area_sum > 0.0:
                    node_center[node, k] = (node_area[l] * node_center[l, k] + node_area[r] * node_center[r, k]) / area_sum
                else:
                    node_center[node, k] = 0.5 * (node_lo[node, k] + node_hi[node, k])
                node_normal[node, k] = node_normal[l, k] + node_normal[r, k]
            for p in range(3):
                for q in range(3):
                    node_moment[node, p, q] = (
                        node_moment[l, p, q] + node_normal[l, p] * (node_center[l, q] - node_center[node, q])
                        + node_moment[r, p, q] + node_normal[r, p] * (node_center[r, q] - node_center[node, q])
                    )
            # T about the new centre: delta' = delta + s, s = c_child - c
            for child in (l, r):
                s0 = node_center[child, 0] - node_center[node, 0]
                s1 = node_center[child, 1] - node_center[node, 1]
                s2 = node_center[child, 2] - node_center[node, 2]
                sv = (s0, s1, s2)
                for p in range(3):
                    for q in range(3):
                        for k in range(3):
                            node_tensor[node, p, q, k] += (
                                node_tensor[child, p, q, k] + node_moment[child, p, q] * sv[k]
                                + node_moment[child, p, k] * sv[q] + node_normal[child, p] * sv[q] * sv[k])
        # radius: the smaller of the box-corner bound and the children's spheres (a leaf: exact)
        r2 = 0.0
        for k in range(3):
            d = max(abs(node_hi[node, k] - node_center[node, k]), abs(node_center[node, k] - node_lo[node, k]))
            r2 += d * d
        radius = np.sqrt(r2)
        if c < 0:
            exact2 = 0.0
            for i in range(node_start[node], node_start[node] + node_count[node]):
                for j in range(3):
                    x = vertices[sorted_triangles[i, j]]
                    dx = x[0] - node_center[node, 0]
                    dy = x[1] - node_center[node, 1]
                    dz = x[2] - node_center[node, 2]
                    exact2 = max(exact2, dx * dx + dy * dy + dz * dz)
            radius = min(radius, np.sqrt(exact2))
        else:
            bound = 0.0
            for child in (c, c + 1):
                dx = node_center[child, 0] - node_center[node, 0]
                dy = node_center[child, 1] - node_center[node, 1]
                dz = node_center[child, 2] - node_center[node, 2]
                bound = max(bound, np.sqrt(dx * dx + dy * dy + dz * dz) + node_radius[child])
            radius = min(radius, bound)
        node_radius[node] = radius
