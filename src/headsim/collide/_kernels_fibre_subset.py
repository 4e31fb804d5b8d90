"""Numba kernels: the capsule pairs of a fibre set that involve a chosen subset of its segments (the query
segments' boxes binned in a uniform grid, every segment's box looked up in it;
:func:`headsim.collide.fibre_bvh.subset_contact_pairs`)."""

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


@njit(cache=True, inline="always")
def _cell(x, lo, cell, n):
    """Grid index (clamped to 0 … n − 1) of coordinate x (m) on an axis starting at lo with cells of size cell."""
    i = int(np.floor((x - lo) / cell))
    return min(max(i, 0), n - 1)


@njit(cache=True, inline="always")
def _cell_range(box, q, lo, cell, dims):
    """(i0, i1, j0, j1, k0, k1): the grid cells (clamped) that box q of ``box`` (S, 6) overlaps."""
    return (_cell(box[q, 0], lo[0], cell, dims[0]), _cell(box[q, 3], lo[0], cell, dims[0]),
            _cell(box[q, 1], lo[1], cell, dims[1]), _cell(box[q, 4], lo[1], cell, dims[1]),
            _cell(box[q, 2], lo[2], cell, dims[2]), _cell(box[q, 5], lo[2], cell, dims[2]))


@njit(cache=True)
def bin_query_boxes(box, query, lo, cell, dims, cell_start, members):
    """The query segments' boxes (``box`` (S, 6) rows ``query``) binned into a uniform grid (origin lo (3,),
    cell size ``cell`` m, ``dims`` (3,) cells): CSR ``cell_start`` (nx·ny·nz + 1) over ``members`` (the
    query segments of every cell they overlap). With ``members`` empty only ``cell_start`` is filled (the
    counts' prefix sums, so that the caller can size ``members``)."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    count = np.zeros(nx * ny * nz, np.int64)
    fill = members.shape[0] > 0
    if fill:
        for c in range(nx * ny * nz):
            count[c] = cell_start[c]
    for k in range(len(query)):
        q = query[k]
        i0, i1, j0, j1, k0, k1 = _cell_range(box, q, lo, cell, dims)
        for i in range(i0, i1 + 1):
            for j in range(j0, j1 + 1):
                for m in range(k0, k1 + 1):
                    c = (i * ny + j) * nz + m
                    if fill:
                        members[count[c]] = q
                    count[c] += 1
    if not fill:
        cell_start[0] = 0
        for c in range(nx * ny * nz):
            cell_start[c + 1] = cell_start[c] + count[c]


@njit(cache=True, parallel=True)
def subset_pairs(nodes, start, fibre, radius, box, lo, cell, dims, cell_start, members, is_query, counts,
                 out_pairs, out_par, write):
    """For every segment b: the query segments q found in the grid cells b's box (``box`` (S, 6), min then
    max, grown by the radii) overlaps (:func:`bin_query_boxes`) whose boxes overlap b's, except q = b,
    same-fibre neighbours and a query b < q (that pair is found from b = q's side); each pair once, from the
    cell that holds the lower corner of the two boxes' intersection. ``write`` False: counts[b] = the number
    of those box pairs of segment b; True: the ones that pass the capsule test (as the BVH's, with q's
    parameter first) written from the offsets ``counts`` (exclusive prefix sums of the box pairs) as
    (min, max) pairs with their closest-point parameters, and counts[b] set to their number."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    hx, hy, hz = lo[0] + nx * cell, lo[1] + ny * cell, lo[2] + nz * cell
    for b in prange(box.shape[0]):
        n = 0
        o = counts[b] if write else 0
        if not (box[b, 3] < lo[0] or box[b, 4] < lo[1] or box[b, 5] < lo[2] or box[b, 0] > hx or box[b, 1] > hy
                or box[b, 2] > hz):
            i0, i1, j0, j1, k0, k1 = _cell_range(box, b, lo, cell, dims)
            for i in range(i0, i1 + 1):
                for j in range(j0, j1 + 1):
                    for m in range(k0, k1 + 1):
                        c = (i * ny + j) * nz + m
                        for e in range(cell_start[c], cell_start[c + 1]):
                            q = members[e]
                            if q == b or (is_query[b] and b < q):
                                continue
                            if fibre[b] == fibre[q] and abs(b - q) <= 1:
                                continue
                            if (box[b, 3] < box[q, 0] or box[b, 0] > box[q, 3] or box[b, 4] < box[q, 1]
                                    or box[b, 1] > box[q, 4] or box[b, 5] < box[q, 2] or box[b, 2] > box[q, 5]):
                                continue
                            # the pair's owner cell: the one of the intersection's lower corner
                            if (_cell(max(box[b, 0], box[q, 0]), lo[0], cell, nx) != i
                                    or _cell(max(box[b, 1], box[q, 1]), lo[1], cell, ny) != j
                                    or _cell(max(box[b, 2], box[q, 2]), lo[2], cell, nz) != m):
                                continue
                            if not write:
                                n += 1
                                continue
                            hit, s, t = _touch(nodes, start, radius, q, b)
                            if hit:
                                if q < b:
                                    out_pairs[o + n, 0], out_pairs[o + n, 1] = q, b
                                    out_par[o + n, 0], out_par[o + n, 1] = s, t
                                else:
                                    out_pairs[o + n, 0], out_pairs[o + n, 1] = b, q
                                    out_par[o + n, 0], out_par[o + n, 1] = t, s
                                n += 1
        counts[b] = n


@njit(cache=True, parallel=True)
def compact_hits(offsets, hits, pairs, params, out_offsets, out_pairs, out_par):
    """The hits of every segment b (``hits[b]`` rows of ``pairs``/``params`` from ``offsets[b]``) moved to
    ``out_pairs``/``out_par`` from ``out_offsets[b]`` (exclusive prefix sums of ``hits``)."""
    for b in prange(offsets.shape[0]):
        for k in range(hits[b]):
            out_pairs[out_offsets[b] + k, 0] = pairs[offsets[b] + k, 0]
            out_pairs[out_offsets[b] + k, 1] = pairs[offsets[b] + k, 1]
            out_par[out_offsets[b] + k, 0] = params[offsets[b] + k, 0]
            out_par[out_offsets[b] + k, 1] = params[offsets[b] + k, 1]
