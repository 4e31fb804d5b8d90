"""Numba kernel: contact records (points, normal, depth) of colliding capsule pairs.

Same arithmetic, in the same order, as the NumPy reference ``_reference_fibres.capsule_contacts_numpy``
(the tests compare them bit for bit).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True)
def contact_records(nodes, seg_start, radius, pairs, params, point_a, point_b, normal, depth):
    """Fill (n, 3) point_a / point_b / normal and (n,) depth for pairs (n, 2) with params (n, 2) (s, t).

    Axis points c_a = p_a + s d_a, c_b = p_b + t d_b; normal = (c_a − c_b)/|c_a − c_b|, or for crossing
    axes (distance ≤ 1e-300 m) the unit d_a × d_b (if parallel: d_a × x̂, or d_a × ŷ when |d_a,x| ≥ 0.9);
    point_a = c_a − r_a n, point_b = c_b + r_b n, depth = r_a + r_b − |c_a − c_b| (m).
    """
    for k in prange(pairs.shape[0]):
        a = pairs[k, 0]
        b = pairs[k, 1]
        ia = seg_start[a]
        ib = seg_start[b]
        s = params[k, 0]
        t = params[k, 1]
        dax = nodes[ia + 1, 0] - nodes[ia, 0]
        day = nodes[ia + 1, 1] - nodes[ia, 1]
        daz = nodes[ia + 1, 2] - nodes[ia, 2]
        dbx = nodes[ib + 1, 0] - nodes[ib, 0]
        dby = nodes[ib + 1, 1] - nodes[ib, 1]
        dbz = nodes[ib + 1, 2] - nodes[ib, 2]
        cax = nodes[ia, 0] + s * dax
        cay = nodes[ia, 1] + s * day
        caz = nodes[ia, 2] + s * daz
        cbx = nodes[ib, 0] + t * dbx
        cby = nodes[ib, 1] + t * dby
        cbz = nodes[ib, 2] + t * dbz
        dx, dy, dz = cax - cbx, cay - cby, caz - cbz
        dist = np.sqrt(dx * dx + dy * dy + dz * dz)
        if dist > 1e-300:
            nx, ny, nz = dx / dist, dy / dist, dz / dist
        else:
            cx = day * dbz - daz * dby
            cy = daz * dbx - dax * dbz
            cz = dax * dby - day * dbx
            if np.sqrt(cx * cx + cy * cy + cz * cz) <= 1e-300:
                if abs(dax) < 0.9:  # d_a × x̂
                    cx, cy, cz = day * 0.0 - daz * 0.0, daz * 1.0 - dax * 0.0, dax * 0.0 - day * 1.0
                else:  # d_a × ŷ
                    cx, cy, cz = day * 0.0 - daz * 1.0, daz * 0.0 - dax * 0.0, dax * 1.0 - day * 0.0
            cn = np.sqrt(cx * cx + cy * cy + cz * cz)
            nx, ny, nz = cx / cn, cy / cn, cz / cn
        ra = radius[a]
        rb = radius[b]
        normal[k, 0], normal[k, 1], normal[k, 2] = nx, ny, nz
        point_a[k, 0] = cax - ra * nx
        point_a[k, 1] = cay - ra * ny
        point_a[k, 2] = caz - ra * nz
        point_b[k, 0] = cbx + rb * nx
        point_b[k, 1] = cby + rb * ny
        point_b[k, 2] = cbz + rb * nz
        depth[k] = ra + rb - dist
