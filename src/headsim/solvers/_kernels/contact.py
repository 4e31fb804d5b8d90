"""Numba kernels of the seed's consistent collision directions (Heinze eqs. 3.9-3.13)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def bfs_propagate(positions, vertex_ids, colliding, assigned, depth, direction, adj_ptr, adj_idx):
    """Breadth-first propagation of depth and direction (Heinze eqs. 3.12-3.13, variant 1).

    positions (n, 3) m; vertex_ids (k,) global ids of the slave vertices; colliding (k,) bool;
    assigned (k,) bool, True for the border points that seed the traversal (eqs. 3.9-3.11), updated;
    depth (k,) m and direction (k, 3) unit, filled in for the newly reached points;
    adj_ptr (k + 1,), adj_idx: CSR adjacency over local ids (springs).

    Level-synchronous: the points of level l + 1 (unassigned colliding neighbours of level l) take
    weighted means, w = 1 / |p_i - p|, over their neighbours assigned in levels <= l. All border
    points seed one traversal (variant 1).
    """
    k = vertex_ids.shape[0]
    frontier = np.empty(k, np.int64)
    nf = 0
    for i in range(k):
        if assigned[i]:
            frontier[nf] = i
            nf += 1
    queued = assigned.copy()
    nxt = np.empty(k, np.int64)
    while nf > 0:
        nn = 0
        for f in range(nf):
            a = frontier[f]
            for e in range(adj_ptr[a], adj_ptr[a + 1]):
                b = adj_idx[e]
                if colliding[b] and not queued[b]:
                    queued[b] = True
                    nxt[nn] = b
                    nn += 1
        for f in range(nn):
            p = nxt[f]
            vp = vertex_ids[p]
            wsum = 0.0
            dsum = 0.0
            r0 = 0.0
            r1 = 0.0
            r2 = 0.0
            for e in range(adj_ptr[p], adj_ptr[p + 1]):
                q = adj_idx[e]
                if not assigned[q]:
                    continue
                vq = vertex_ids[q]
                d0 = positions[vq, 0] - positions[vp, 0]
                d1 = positions[vq, 1] - positions[vp, 1]
                d2 = positions[vq, 2] - positions[vp, 2]
                dist = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                w = 1.0 / max(dist, 1e-300)  # eq. 3.10
                dsum += w * (d0 * direction[q, 0] + d1 * direction[q, 1] + d2 * direction[q, 2] + depth[q])  # 3.12
                r0 += w * direction[q, 0]  # eq. 3.13
                r1 += w * direction[q, 1]
                r2 += w * direction[q, 2]
                wsum += w
            depth[p] = dsum / wsum
            norm = np.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
            if norm > 0:
                direction[p, 0] = r0 / norm
                direction[p, 1] = r1 / norm
                direction[p, 2] = r2 / norm
        for f in range(nn):
            assigned[nxt[f]] = True
            frontier[f] = nxt[f]
        nf = nn
