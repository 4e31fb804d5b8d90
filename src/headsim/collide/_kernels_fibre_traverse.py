"""Numba kernels: simultaneous BVH traversal (Sobottka Algorithm 3) and the capsule–capsule test.

Counters (int64 array, added to): 0 BV overlap tests, 1 overlapping BV pairs, 2 BV tests between two
leaves (the lowest level), 3 primitive (capsule–capsule) tests, 4 contacts found.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from headsim.collide._kernels_fibre_bv import bv_overlap, bv_size

N_COUNTERS = 5


@njit(cache=True)
def _clamp01(x):
    if x < 0.0:
        return 0.0
    if x > 1.0:
        return 1.0
    return x


@njit(cache=True)
def segment_segment_closest(p1x, p1y, p1z, q1x, q1y, q1z, p2x, p2y, p2z, q2x, q2y, q2z):
    """Closest points of segments p1q1 and p2q2: returns (s, t, squared distance).

    Points are ``p1 + s (q1 − p1)`` and ``p2 + t (q2 − p2)``, s, t ∈ [0, 1]
    (Ericson 2005, §5.1.9; the capsule leaf test of Sobottka Alg. 3 line 6).
    """
    d1x, d1y, d1z = q1x - p1x, q1y - p1y, q1z - p1z
    d2x, d2y, d2z = q2x - p2x, q2y - p2y, q2z - p2z
    rx, ry, rz = p1x - p2x, p1y - p2y, p1z - p2z
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    tiny = 1e-300
    if a <= tiny and e <= tiny:
        s, t = 0.0, 0.0
    elif a <= tiny:
        s = 0.0
        t = _clamp01(f / e)
    else:
        c = d1x * rx + d1y * ry + d1z * rz
        if e <= tiny:
            t = 0.0
            s = _clamp01(-c / a)
        else:
            b = d1x * d2x + d1y * d2y + d1z * d2z
            denom = a * e - b * b
            if denom > 0.0:
                s = _clamp01((b * f - c * e) / denom)
            else:
                s = 0.0
            t = (b * s + f) / e
            if t < 0.0:
                t = 0.0
                s = _clamp01(-c / a)
            elif t > 1.0:
                t = 1.0
                s = _clamp01((b - c) / a)
    dx = (p1x + s * d1x) - (p2x + t * d2x)
    dy = (p1y + s * d1y) - (p2y + t * d2y)
    dz = (p1z + s * d1z) - (p2z + t * d2z)
    return s, t, dx * dx + dy * dy + dz * dz


@njit(cache=True)
def _capsule_test(sa, sb, nodes, seg_start, radius):
    i = seg_start[sa]
    j = seg_start[sb]
    s, t, d2 = segment_segment_closest(
        nodes[i, 0], nodes[i, 1], nodes[i, 2], nodes[i + 1, 0], nodes[i + 1, 1], nodes[i + 1, 2],
        nodes[j, 0], nodes[j, 1], nodes[j, 2], nodes[j + 1, 0], nodes[j + 1, 1], nodes[j + 1, 2],
    )
    rr = radius[sa] + radius[sb]
    return d2 < rr * rr, s, t


@njit(cache=True)
def _grow_i(a, n):
    b = np.empty(n, a.dtype)
    b[: a.shape[0]] = a
    return b


@njit(cache=True)
def _grow2(a, n):
    b = np.empty((n, 2), a.dtype)
    b[: a.shape[0]] = a
    return b


@njit(cache=True, nogil=True)
def traverse_pairs(tasks, left, right, lo, hi, perm, bv, kind, m, nodes, seg_start, radius,
                   seg_fibre, split_rule, first_only, counters):
    """Depth-first simultaneous descent from every node pair in ``tasks`` (T, 2) (Sobottka Alg. 3).

    A self pair (u, u) expands to (l, l), (r, r), (l, r) without a BV test, so every unordered leaf
    pair is visited once. Two overlapping inner BVs: descend the node with more leaves
    (``split_rule`` 0) or the larger BV (``split_rule`` 1). Two leaves: skip the pair if the segments
    are the same or neighbours on one fibre (``adj``), else the exact capsule test.
    Returns (pairs (n, 2) int64 with pairs[:, 0] < pairs[:, 1], params (n, 2) float64: s, t).
    """
    cap = 256
    out_pairs = np.empty((cap, 2), np.int64)
    out_par = np.empty((cap, 2), np.float64)
    n_out = 0
    scap = 256
    stack = np.empty((scap, 2), np.int64)
    n_bv = 0
    n_ovl = 0
    n_leafbv = 0
    n_prim = 0
    done = False
    for task in range(tasks.shape[0]):
        if done:
            break
        sp = 0
        stack[0, 0] = tasks[task, 0]
        stack[0, 1] = tasks[task, 1]
        sp = 1
        while sp > 0:
            sp -= 1
            u = stack[sp, 0]
            v = stack[sp, 1]
            if sp + 3 > scap:
                scap *= 2
                stack = _grow2(stack, scap)
            if u == v:
                lu = left[u]
                if lu < 0:
                    continue
                ru = right[u]
                stack[sp, 0], stack[sp, 1] = lu, ru
                stack[sp + 1, 0], stack[sp + 1, 1] = ru, ru
                stack[sp + 2, 0], stack[sp + 2, 1] = lu, lu
                sp += 3
                continue
            n_bv += 1
            lu = left[u]
            lv = left[v]
            if lu < 0 and lv < 0:
                n_leafbv += 1
            if not bv_overlap(bv, u, v, kind, m):
                continue
            n_ovl += 1
            if lu < 0 and lv < 0:
                sa = perm[lo[u]]
                sb = perm[lo[v]]
                if sa > sb:
                    sa, sb = sb, sa
                if seg_fibre[sa] == seg_fibre[sb] and sb - sa <= 1:
                    continue
                n_prim += 1
                hit, s, t = _capsule_test(sa, sb, nodes, seg_start, radius)
                if hit:
                    if n_out == cap:
                        cap *= 2
                        out_pairs = _grow2(out_pairs, cap)
                        out_par = _grow2(out_par, cap)
                    out_pairs[n_out, 0] = sa
                    out_pairs[n_out, 1] = sb
                    out_par[n_out, 0] = s
                    out_par[n_out, 1] = t
                    n_out += 1
                    if first_only:
                        done = True
                        break
                continue
            # choose which node to descend
            descend_v = False
            if lu < 0:
                descend_v = True
            elif lv >= 0:
                if split_rule == 0:
                    nu = hi[u] - lo[u]
                    nv = hi[v] - lo[v]
                    if nv > nu:
                        descend_v = True
                    elif nv == nu and bv_size(bv, v, kind, m) > bv_size(bv, u, kind, m):
                        descend_v = True
                else:
                    if bv_size(bv, v, kind, m) > bv_size(bv, u, kind, m):
                        descend_v = True
            if descend_v:
                stack[sp, 0], stack[sp, 1] = u, right[v]
                stack[sp + 1, 0], stack[sp + 1, 1] = u, lv
            else:
                stack[sp, 0], stack[sp, 1] = right[u], v
                stack[sp + 1, 0], stack[sp + 1, 1] = lu, v
            sp += 2
    counters[0] += n_bv
    counters[1] += n_ovl
    counters[2] += n_leafbv
    counters[3] += n_prim
    counters[4] += n_out
    return out_pairs[:n_out].copy(), out_par[:n_out].copy()


@njit(cache=True)
def expand_tasks(root_a, root_b, left, right, lo, hi, bv, kind, m, n_target, split_rule, counters):
    """Breadth-first expansion of the pair (root_a, root_b) into ≥ ``n_target`` independent pairs.

    Uses the same rules as :func:`traverse_pairs` (BV tests counted); pairs that cannot be expanded
    further (two leaves) are kept as tasks untested. Returns (T, 2) int64.
    """
    cap = 4 * n_target + 16
    q = np.empty((cap, 2), np.int64)
    head, tail = 0, 0
    q[0, 0], q[0, 1] = root_a, root_b
    tail = 1
    final = np.empty((cap, 2), np.int64)
    n_final = 0
    while head < tail and (tail - head) + n_final < n_target:
        u, v = q[head, 0], q[head, 1]
        head += 1
        if tail + 3 > cap or n_final + 1 > final.shape[0]:
            # compact and grow
            live = q[head:tail].copy()
            cap *= 2
            q = np.empty((cap, 2), np.int64)
            q[: live.shape[0]] = live
            tail = live.shape[0]
            head = 0
            final = _grow2(final, cap)
        lu, lv = left[u], left[v]
        if u == v:
            if lu < 0:
                continue
            ru = right[u]
            q[tail, 0], q[tail, 1] = lu, lu
            q[tail + 1, 0], q[tail + 1, 1] = ru, ru
            q[tail + 2, 0], q[tail + 2, 1] = lu, ru
            tail += 3
            continue
        if lu < 0 and lv < 0:
            final[n_final, 0], final[n_final, 1] = u, v
            n_final += 1
            continue
        counters[0] += 1
        if not bv_overlap(bv, u, v, kind, m):
            continue
        counters[1] += 1
        descend_v = False
        if lu < 0:
            descend_v = True
        elif lv >= 0:
            if split_rule == 0:
                nu = hi[u] - lo[u]
                nv = hi[v] - lo[v]
                descend_v = nv > nu or (nv == nu and bv_size(bv, v, kind, m) > bv_size(bv, u, kind, m))
            else:
                descend_v = bv_size(bv, v, kind, m) > bv_size(bv, u, kind, m)
        if descend_v:
            q[tail, 0], q[tail, 1] = u, lv
            q[tail + 1, 0], q[tail + 1, 1] = u, right[v]
        else:
            q[tail, 0], q[tail, 1] = lu, v
            q[tail + 1, 0], q[tail + 1, 1] = right[u], v
        tail += 2
    out = np.empty((n_final + tail - head, 2), np.int64)
    out[:n_final] = final[:n_final]
    out[n_final:] = q[head:tail]
    return out


@njit(cache=True, parallel=False)
def capsule_pairs_test(pairs, nodes, seg_start, radius, seg_fibre):
    """Exact capsule test of candidate segment pairs (n, 2): returns (hit (n,) bool, s (n,), t (n,))."""
    n = pairs.shape[0]
    hit = np.zeros(n, np.bool_)
    ss = np.zeros(n)
    tt = np.zeros(n)
    for k in range(n):
        a, b = pairs[k, 0], pairs[k, 1]
        if a == b or (seg_fibre[a] == seg_fibre[b] and abs(a - b) <= 1):
            continue
        h, s, t = _capsule_test(a, b, nodes, seg_start, radius)
        hit[k] = h
        ss[k] = s
        tt[k] = t
    return hit, ss, tt
