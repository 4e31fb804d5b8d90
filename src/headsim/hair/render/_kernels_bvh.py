"""Numba kernels of the ray–capsule BVH over fibre segments (render subpackage).

Primitives are capsules (segment a→b swept by a sphere of radius r) in Morton order; the tree is a
binary LBVH (split at the highest differing Morton bit) with leaves of ≤ ``leaf_size`` capsules. Node
arrays: ``left``/``right`` children (−1 for leaves), ``start``/``count`` primitive ranges, ``bmin``/``bmax``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_STACK = 128


@njit(cache=True)
def build_lbvh(codes, leaf_size, left, right, start, count):
    """Top-down split of sorted Morton ``codes`` (n,) uint64; fills node arrays; returns the node count."""
    n = codes.shape[0]
    stack_s = np.empty(128, np.int64)
    stack_e = np.empty(128, np.int64)
    stack_node = np.empty(128, np.int64)
    n_nodes = 1
    top = 0
    stack_s[0] = 0
    stack_e[0] = n
    stack_node[0] = 0
    top = 1
    while top > 0:
        top -= 1
        s = stack_s[top]
        e = stack_e[top]
        node = stack_node[top]
        if e - s <= leaf_size:
            left[node] = -1
            right[node] = -1
            start[node] = s
            count[node] = e - s
            continue
        cs = codes[s]
        ce = codes[e - 1]
        if cs == ce:
            mid = (s + e) // 2
        else:
            x = cs ^ ce
            bit = np.uint64(1)
            while (x >> bit) != np.uint64(0):
                bit += np.uint64(1)
            mask = np.uint64(1) << (bit - np.uint64(1))
            lo = s
            hi = e - 1
            while lo < hi:  # first index with the bit set
                m = (lo + hi) // 2
                if codes[m] & mask:
                    hi = m
                else:
                    lo = m + 1
            mid = lo
            if mid <= s or mid >= e:
                mid = (s + e) // 2
        l = n_nodes
        r = n_nodes + 1
        n_nodes += 2
        left[node] = l
        right[node] = r
        start[node] = s
        count[node] = e - s
        stack_s[top] = mid
        stack_e[top] = e
        stack_node[top] = r
        top += 1
        stack_s[top] = s
        stack_e[top] = mid
        stack_node[top] = l
        top += 1
    return n_nodes


@njit(cache=True)
def fit_bounds(a, b, radius, left, right, start, count, n_nodes, bmin, bmax):
    """Node boxes bottom-up (children have larger indices than parents)."""
    for node in range(n_nodes - 1, -1, -1):
        if left[node] < 0:
            for k in range(3):
                bmin[node, k] = np.inf
                bmax[node, k] = -np.inf
            for i in range(start[node], start[node] + count[node]):
                for k in range(3):
                    lo = min(a[i, k], b[i, k]) - radius[i]
                    hi = max(a[i, k], b[i, k]) + radius[i]
                    if lo < bmin[node, k]:
                        bmin[node, k] = lo
                    if hi > bmax[node, k]:
                        bmax[node, k] = hi
        else:
            l = left[node]
            r = right[node]
            for k in range(3):
                bmin[node, k] = min(bmin[l, k], bmin[r, k])
                bmax[node, k] = max(bmax[l, k], bmax[r, k])


@njit(cache=True, inline="always")
def ray_capsule(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, r):
    """Entering distance of a ray (unit direction) into a capsule, or −1 (I. Quilez's closed form)."""
    bax = bx - ax
    bay = by - ay
    baz = bz - az
    oax = ox - ax
    oay = oy - ay
    oaz = oz - az
    baba = bax * bax + bay * bay + baz * baz
    bard = bax * dx + bay * dy + baz * dz
    baoa = bax * oax + bay * oay + baz * oaz
    rdoa = dx * oax + dy * oay + dz * oaz
    oaoa = oax * oax + oay * oay + oaz * oaz
    A = baba - bard * bard
    B = baba * rdoa - baoa * bard
    C = baba * oaoa - baoa * baoa - r * r * baba
    h = B * B - A * C
    if h >= 0.0:
        if A > 1e-30:
            t = (-B - math.sqrt(h)) / A
            y = baoa + t * bard
            if y > 0.0 and y < baba:
                return t
        else:
            y = baoa
        # end caps
        if y <= 0.0:
            cx, cy, cz = oax, oay, oaz
        else:
            cx, cy, cz = ox - bx, oy - by, oz - bz
        B2 = dx * cx + dy * cy + dz * cz
        C2 = cx * cx + cy * cy + cz * cz - r * r
        h2 = B2 * B2 - C2
        if h2 > 0.0:
            return -B2 - math.sqrt(h2)
    return -1.0


@njit(cache=True, inline="always")
def _slab(ox, oy, oz, ix, iy, iz, bmin, bmax, node, tmax):
    t0 = (bmin[node, 0] - ox) * ix
    t1 = (bmax[node, 0] - ox) * ix
    tn = min(t0, t1)
    tf = max(t0, t1)
    t0 = (bmin[node, 1] - oy) * iy
    t1 = (bmax[node, 1] - oy) * iy
    tn = max(tn, min(t0, t1))
    tf = min(tf, max(t0, t1))
    t0 = (bmin[node, 2] - oz) * iz
    t1 = (bmax[node, 2] - oz) * iz
    tn = max(tn, min(t0, t1))
    tf = min(tf, max(t0, t1))
    if tn <= tf and tf >= 0.0 and tn < tmax:
        return max(tn, 0.0)
    return np.inf


@njit(cache=True)
def intersect(ox, oy, oz, dx, dy, dz, tmin, tmax, skip, any_hit, a, b, radius, left, right, bmin, bmax,
              start, count, stack):
    """Closest (or any, for shadow rays) capsule hit with tmin < t < tmax, ignoring primitive ``skip``.

    ``stack``: scratch (≥ 128,) int64. Returns (t, primitive index) or (inf, −1)."""
    ix = 1.0 / dx if dx != 0.0 else 1e300
    iy = 1.0 / dy if dy != 0.0 else 1e300
    iz = 1.0 / dz if dz != 0.0 else 1e300
    top = 0
    best_t = tmax
    best_i = -1
    if _slab(ox, oy, oz, ix, iy, iz, bmin, bmax, 0, best_t) == np.inf:
        return np.inf, -1
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if left[node] < 0:
            for i in range(start[node], start[node] + count[node]):
                if i == skip:
                    continue
                t = ray_capsule(ox, oy, oz, dx, dy, dz, a[i, 0], a[i, 1], a[i, 2], b[i, 0], b[i, 1], b[i, 2],
                                radius[i])
                if t > tmin and t < best_t:
                    best_t = t
                    best_i = i
                    if any_hit:
                        return best_t, best_i
            continue
        l = left[node]
        r = right[node]
        tl = _slab(ox, oy, oz, ix, iy, iz, bmin, bmax, l, best_t)
        tr = _slab(ox, oy, oz, ix, iy, iz, bmin, bmax, r, best_t)
        if tl < tr:
            if tr != np.inf:
                stack[top] = r
                top += 1
            stack[top] = l
            top += 1
        else:
            if tl != np.inf:
                stack[top] = l
                top += 1
            if tr != np.inf:
                stack[top] = r
                top += 1
    if best_i < 0:
        return np.inf, -1
    return best_t, best_i
