"""Numba kernels: building and updating bounding-volume hierarchies over capsule segments.

A tree over S leaves is stored in arrays (n_nodes = 2S − 1) in pre-order: node u's subtree is the
id range ``[u, u + 2 (hi[u] − lo[u]) − 1)``, its left child is u + 1:
``left, right`` (n_nodes,) int64 (−1 at leaves), ``lo, hi`` (n_nodes,) int64 — the node covers leaf
slots ``perm[lo:hi]``; ``perm`` (S,) int64 maps leaf slots to global segment ids; ``bv`` (n_nodes, w)
float64 BV rows (layout in ``bounding_volumes``). Segments: ``nodes`` (N, 3) m, ``seg_start`` (S,)
first node of each segment (the second is +1), ``radius`` (S,) m.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from headsim.collide._kernels_fibre_bv import (
    enclosing_ball,
    obb_from_capsule,
    obb_from_points,
    obb_merge,
    slab_from_capsule,
    sphere_from_capsule,
    sphere_merge,
)


@njit(cache=True)
def segment_slabs(nodes, seg_start, radius, dirs, out):
    """Slab rows (S, 2m) of all segments in global order (eq. 7.9)."""
    for s in range(seg_start.shape[0]):
        i = seg_start[s]
        slab_from_capsule(nodes[i, 0], nodes[i, 1], nodes[i, 2], nodes[i + 1, 0], nodes[i + 1, 1],
                          nodes[i + 1, 2], radius[s], dirs, out, s)


@njit(cache=True)
def build_topological(n_leaves, left, right, lo, hi):
    """Balanced tree over leaf slots 0..S−1 by recursive halving (H_TD/H_TI shape, §7.3.3).

    A node over ``[lo, hi)`` gets children ``[lo, mid)`` and ``[mid, hi)`` with
    ``mid = lo + ceil((hi − lo)/2)``. Returns the node count (2S − 1).
    """
    lo[0], hi[0] = 0, n_leaves
    count = 1
    stack = np.empty(128, np.int64)
    sp = 0
    stack[sp] = 0
    sp += 1
    while sp > 0:
        sp -= 1
        u = stack[sp]
        n = hi[u] - lo[u]
        if n == 1:
            left[u] = -1
            right[u] = -1
            continue
        mid = lo[u] + (n + 1) // 2
        a, b = u + 1, u + 2 * (mid - lo[u])  # pre-order: every subtree is a contiguous id range
        count += 2
        left[u], right[u] = a, b
        lo[a], hi[a] = lo[u], mid
        lo[b], hi[b] = mid, hi[u]
        stack[sp] = b
        stack[sp + 1] = a
        sp += 2
    return count


@njit(cache=True)
def build_spatial(leaf_slabs, perm, left, right, lo, hi, node_slabs):
    """Top-down spatial split (H_R, Sobottka §7.3.3 and §7.3.7.2.2).

    leaf_slabs (S, 2m): slab rows of the segments (global ids); ``perm`` (S,) is reordered in place.
    Each node's MEV (slab row, exact) goes to ``node_slabs``; the node is split at the mid-plane of
    its thickest slab (AABB: the longest axis), a segment going by its midpoint. Fallbacks: the next
    thickest slabs, then the projected centroid on the 1st, 2nd, 3rd thickest slab, then an index split.
    Returns the node count (2S − 1).
    """
    m = leaf_slabs.shape[1] // 2
    n_leaves = perm.shape[0]
    lo[0], hi[0] = 0, n_leaves
    count = 1
    cap = 1024
    stack = np.empty(cap, np.int64)
    sp = 0
    stack[sp] = 0
    sp += 1
    order = np.empty(3, np.int64)
    while sp > 0:
        sp -= 1
        u = stack[sp]
        a0, b0 = lo[u], hi[u]
        # node MEV = min/max over the leaf rows
        for i in range(m):
            node_slabs[u, i] = np.inf
            node_slabs[u, m + i] = -np.inf
        for k in range(a0, b0):
            s = perm[k]
            for i in range(m):
                if leaf_slabs[s, i] < node_slabs[u, i]:
                    node_slabs[u, i] = leaf_slabs[s, i]
                if leaf_slabs[s, m + i] > node_slabs[u, m + i]:
                    node_slabs[u, m + i] = leaf_slabs[s, m + i]
        n = b0 - a0
        if n == 1:
            left[u] = -1
            right[u] = -1
            continue
        # the three thickest slabs, thickest first (no allocation)
        o0, o1, o2 = -1, -1, -1
        w0, w1, w2 = -1.0, -1.0, -1.0
        for i in range(m):
            wi = node_slabs[u, m + i] - node_slabs[u, i]
            if wi > w0:
                o2, w2 = o1, w1
                o1, w1 = o0, w0
                o0, w0 = i, wi
            elif wi > w1:
                o2, w2 = o1, w1
                o1, w1 = i, wi
            elif wi > w2:
                o2, w2 = i, wi
        order[0], order[1], order[2] = o0, o1, o2
        mid = -1
        n_try = min(3, m)
        for attempt in range(2 * n_try):
            axis = order[attempt % n_try]
            if attempt < n_try:
                split = node_slabs[u, axis] + node_slabs[u, m + axis]  # 2 × mid-plane
            else:
                split = 0.0
                for k in range(a0, b0):
                    s = perm[k]
                    split += leaf_slabs[s, axis] + leaf_slabs[s, m + axis]
                split /= n
            # partition: midpoint (lo+hi)/2 < split/2
            i, j = a0, b0 - 1
            while i <= j:
                s = perm[i]
                if leaf_slabs[s, axis] + leaf_slabs[s, m + axis] < split:
                    i += 1
                else:
                    perm[i], perm[j] = perm[j], perm[i]
                    j -= 1
            if a0 < i < b0:
                mid = i
                break
        if mid < 0:
            mid = a0 + (n + 1) // 2  # index split: guarantees termination
        a, b = u + 1, u + 2 * (mid - a0)  # pre-order: every subtree is a contiguous id range
        count += 2
        left[u], right[u] = a, b
        lo[a], hi[a] = a0, mid
        lo[b], hi[b] = mid, b0
        if sp + 2 > cap:
            cap *= 2
            new = np.empty(cap, np.int64)
            new[:sp] = stack[:sp]
            stack = new
        stack[sp] = b
        stack[sp + 1] = a
        sp += 2
    return count


@njit(cache=True)
def refit_leaves(kind, dirs, nodes, seg_start, radius, perm, leaf_node, bv):
    """Fit every leaf BV to its segment (Alg. 5 line 5); ``leaf_node`` (S,) is the node of each leaf slot."""
    for k in range(perm.shape[0]):
        u = leaf_node[k]
        s = perm[k]
        i = seg_start[s]
        ax, ay, az = nodes[i, 0], nodes[i, 1], nodes[i, 2]
        bx, by, bz = nodes[i + 1, 0], nodes[i + 1, 1], nodes[i + 1, 2]
        if kind == 0:
            slab_from_capsule(ax, ay, az, bx, by, bz, radius[s], dirs, bv, u)
        elif kind == 1:
            sphere_from_capsule(ax, ay, az, bx, by, bz, radius[s], bv, u)
        else:
            obb_from_capsule(ax, ay, az, bx, by, bz, radius[s], bv, u)


@njit(cache=True, parallel=True)
def refit_inner_wrapped(kind, dirs, nodes, seg_start, radius, perm, left, lo, hi, bv):
    """Wrapped BVs: each inner node gets the MEV of ALL capsules of its range (H_TD, §7.3.3).

    Slabs: exact min/max over the capsules (eq. 7.9). Sphere: near-minimal ball of the segments'
    endpoint balls. OBB: PCA box over the endpoints, each inflated by its segment's radius.
    O(S log S) for balanced trees.
    """
    n_nodes = left.shape[0]
    m = dirs.shape[0]
    for u in prange(n_nodes):
        if left[u] < 0:
            continue
        a0, b0 = lo[u], hi[u]
        n = b0 - a0
        if kind == 0:
            for i in range(m):
                bv[u, i] = np.inf
                bv[u, m + i] = -np.inf
            for k in range(a0, b0):
                s = perm[k]
                j = seg_start[s]
                r = radius[s]
                for i in range(m):
                    pa = dirs[i, 0] * nodes[j, 0] + dirs[i, 1] * nodes[j, 1] + dirs[i, 2] * nodes[j, 2]
                    pb = (dirs[i, 0] * nodes[j + 1, 0] + dirs[i, 1] * nodes[j + 1, 1]
                          + dirs[i, 2] * nodes[j + 1, 2])
                    lo_i = (pa if pa < pb else pb) - r
                    hi_i = (pa if pa > pb else pb) + r
                    if lo_i < bv[u, i]:
                        bv[u, i] = lo_i
                    if hi_i > bv[u, m + i]:
                        bv[u, m + i] = hi_i
        else:
            pts = np.empty((2 * n, 3))
            pad = np.empty(2 * n)
            for k in range(n):
                s = perm[a0 + k]
                j = seg_start[s]
                for c in range(3):
                    pts[2 * k, c] = nodes[j, c]
                    pts[2 * k + 1, c] = nodes[j + 1, c]
                pad[2 * k] = radius[s]
                pad[2 * k + 1] = radius[s]
            if kind == 1:
                out = np.empty(4)
                enclosing_ball(pts, pad, out)
                for c in range(4):
                    bv[u, c] = out[c]
            else:
                obb_from_points(pts, pad, bv, u)



def subtree_partition(left, right, lo, hi, n_parts):
    """Split the tree into ≤ ``n_parts`` disjoint subtrees (largest first) plus their ancestors.

    Returns (roots (k,) int64, top (t,) int64 ancestors in decreasing id order) for
    :func:`refit_layered`. Plain Python: touches O(n_parts) nodes.
    """
    roots = [0]
    top = []
    while len(roots) < n_parts:
        sizes = [hi[r] - lo[r] for r in roots]
        j = int(np.argmax(sizes))
        r = roots[j]
        if left[r] < 0:
            break
        roots.pop(j)
        top.append(r)
        roots += [int(left[r]), int(right[r])]
    return np.array(roots, np.int64), np.array(sorted(top, reverse=True), np.int64)


@njit(cache=True, inline="always")
def _merge_children(kind, m, a, b, u, bv):
    """MERGE (Alg. 5): bv[u] = the bounding volume of children a and b (slabs: m directions; 1 sphere;
    otherwise OBB)."""
    if kind == 0:
        for k in range(m):
            x = bv[a, k]
            y = bv[b, k]
            bv[u, k] = x if x < y else y
            x = bv[a, m + k]
            y = bv[b, m + k]
            bv[u, m + k] = x if x > y else y
    elif kind == 1:
        sphere_merge(bv, a, b, bv, u)
    else:
        obb_merge(bv, a, b, bv, u)


@njit(cache=True, parallel=True)
def refit_layered(kind, dirs, nodes, seg_start, radius, perm, left, right, lo, hi, roots, top, bv):
    """Layered refit (Alg. 5): leaf BVs from the capsules, inner BVs = MERGE of the children.

    Each subtree in ``roots`` is swept in reverse pre-order (children before parents) by one thread;
    then the ancestors ``top`` are merged. Linear in the number of segments.
    """
    m = dirs.shape[0]
    for q in prange(roots.shape[0]):
        r = roots[q]
        end = r + 2 * (hi[r] - lo[r]) - 1
        for u in range(end - 1, r - 1, -1):
            a = left[u]
            if a < 0:
                s = perm[lo[u]]
                i = seg_start[s]
                ax, ay, az = nodes[i, 0], nodes[i, 1], nodes[i, 2]
                bx, by, bz = nodes[i + 1, 0], nodes[i + 1, 1], nodes[i + 1, 2]
                if kind == 0:
                    slab_from_capsule(ax, ay, az, bx, by, bz, radius[s], dirs, bv, u)
                elif kind == 1:
                    sphere_from_capsule(ax, ay, az, bx, by, bz, radius[s], bv, u)
                else:
                    obb_from_capsule(ax, ay, az, bx, by, bz, radius[s], bv, u)
                continue
            b = right[u]
            _merge_children(kind, m, a, b, u, bv)
    for q in range(top.shape[0]):
        u = top[q]
        a = left[u]
        b = right[u]
        _merge_children(kind, m, a, b, u, bv)
