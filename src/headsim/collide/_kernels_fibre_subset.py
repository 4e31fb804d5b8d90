"""Numba kernels: the capsule pairs of a fibre set that involve a chosen subset of its segments (a sweep
along one axis; :func:`headsim.collide.fibre_bvh.subset_contact_pairs`)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from headsim.collide._kernels_fibre_traverse import segment_segment_closest


@njit(cache=True, inline="always")
def _touch(nodes, start, radius, a, b):
    """(hit, s, t): capsules a, b (segments start[a] → start[a] + 1) within r_a + r_b; s, t ∈ [0, 1]."""
    i, j = start[a], start[b]
    s, t, d2 = segment_segment_closest(nodes[i, 0], nodes[i, 1], nodes[i, 2], nodes[i + 1, 0], nodes[i + 1, 1],
                                       nodes[i + 1, 2], nodes[j, 0], nodes[j, 1], nodes[j, 2], nodes[j + 1, 0],
                                       nodes[j + 1, 1], nodes[j + 1, 2])
    rr = radius[a] + radius[b]
    return d2 < rr * rr, s, t


@njit(cache=True, parallel=True)
def subset_pairs(nodes, start, fibre, radius, box, order, lo_sorted, width, query, is_query, counts,
                 out_pairs, out_par, write):
    """For every query segment q (``query``): the segments b whose boxes (``box`` (S, 6), min then max, grown
    by the radii) overlap q's, found among the segments ``order`` sorted by their box minimum along axis 0 of
    ``box`` (``lo_sorted``; ``width`` the largest box extent along it), except same-fibre neighbours and a
    query b < q (that pair is q's partner's); capsule test as the BVH's. ``write`` False: counts[k] = hits of
    query k; True: the hits written at the offsets ``counts`` (exclusive prefix sums) as (min, max) pairs
    with their closest-point parameters."""
    for k in prange(len(query)):
        q = query[k]
        lo_q = box[q, 0]
        hi_q = box[q, 3]
        first = np.searchsorted(lo_sorted, lo_q - width, side="left")
        n = 0
        o = counts[k] if write else 0
        for m in range(first, len(order)):
            if lo_sorted[m] > hi_q:
                break
            b = order[m]
            if b == q or (is_query[b] and b < q):
                continue
            if fibre[b] == fibre[q] and abs(b - q) <= 1:
                continue
            if (box[b, 3] < lo_q or box[b, 1] > box[q, 4] or box[b, 4] < box[q, 1] or box[b, 2] > box[q, 5]
                    or box[b, 5] < box[q, 2]):
                continue
            hit, s, t = _touch(nodes, start, radius, q, b)
            if hit:
                if write:
                    if q < b:
                        out_pairs[o + n, 0], out_pairs[o + n, 1] = q, b
                        out_par[o + n, 0], out_par[o + n, 1] = s, t
                    else:
                        out_pairs[o + n, 0], out_pairs[o + n, 1] = b, q
                        out_par[o + n, 0], out_par[o + n, 1] = t, s
                n += 1
        if not write:
            counts[k] = n
