"""Numba kernels of the Coulomb treecode (Barnes & Hut 1986 with Cartesian multipoles to order 2).

The charges are sorted along a Morton (Z-order) space-filling curve, an octree is built on the
sorted codes (cells with a single non-empty octant are collapsed, so every inner cell has >= 2
children and children are stored contiguously), and every cell stores, about its centre of |q|:
total charge, dipole p = sum q d, traceless quadrupole Q = sum q (3 d d^T - |d|^2 I) and the radius
max |d| of the sphere that encloses its charges (d = x - c). Moments are computed directly from the
charges of a cell (O(n depth)); a refit after deformation recomputes them with the same topology.

Evaluation (target groups, :func:`treecode_field_groups`): for every leaf (a group of targets that
are contiguous along the curve) the tree is traversed once; a source cell is accepted when
r_cell < theta (|c_cell - c_leaf| - r_leaf), i.e. it is well separated from EVERY target of the
leaf, and its expansion is evaluated at each of them; otherwise a leaf is summed directly (near
field), an inner cell is opened. Fields are returned without K = 1/(4 pi eps0), in C/m^2.

Expansion about c, with r = x - c, r = |r| (potential phi = K (q/r + p.r/r^3 + r^T Q r / (2 r^5))):
  E_mono = q r / r^3
  E_dip  = 3 (p.r) r / r^5 - p / r^3
  E_quad = 5/2 (r^T Q r) r / r^7 - Q r / r^5

Cell-to-leaf local expansions (:func:`treecode_field_groups_local`, the default): a cell with
r_cell + r_leaf < theta d is converted once per leaf into a second-order Taylor expansion of the field
about the leaf centre, E(L + delta) = E + J delta + H:delta delta / 2, with E from all multipoles,
J = dE/dx from the monopole and dipole and H from the monopole. The omitted terms (quadrupole J,
dipole H, third-order Taylor) are O(theta^3) relative to the cell's monopole field, like the
truncation of the multipoles; cells that only pass the per-target test keep the per-target evaluation.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

MAX_LEVEL = 20  # 21 bits per axis in a 63-bit Morton code


@njit(cache=True)
def _spread_bits(v):
    v = v & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


@njit(parallel=True, cache=True)
def morton_codes(points, lower, extent, out):
    """63-bit Morton codes of points (n, 3) in the cube [lower, lower + extent]^3; out (n,) uint64."""
    scale = (2.0**21 - 1.0) / extent
    for i in prange(points.shape[0]):
        ix = np.uint64(min(max((points[i, 0] - lower[0]) * scale, 0.0), 2.0**21 - 1.0))
        iy = np.uint64(min(max((points[i, 1] - lower[1]) * scale, 0.0), 2.0**21 - 1.0))
        iz = np.uint64(min(max((points[i, 2] - lower[2]) * scale, 0.0), 2.0**21 - 1.0))
        out[i] = _spread_bits(ix) | (_spread_bits(iy) << np.uint64(1)) | (_spread_bits(iz) << np.uint64(2))


@njit(cache=True)
def _lower_bound(codes, lo, hi, shift, key):
    """First index in [lo, hi) with (codes >> shift) >= key (codes sorted)."""
    while lo < hi:
        mid = (lo + hi) // 2
        if (codes[mid] >> shift) < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def build_octree(codes, leaf_size, start, end, first_child, n_child):
    """Octree over sorted Morton codes. Arrays (>= 2n + 1,) int64 are filled; returns the node count.

    Node 0 is the root; the children of node i are first_child[i] .. first_child[i] + n_child[i] - 1
    (n_child = 0 for a leaf); the charges of node i are the sorted indices start[i] .. end[i] - 1.
    """
    n = codes.shape[0]
    start[0] = 0
    end[0] = n
    n_nodes = 1
    stack_node = np.empty(64 * 8 + 16, np.int64)
    stack_level = np.empty(64 * 8 + 16, np.int64)
    sp = 0
    stack_node[0] = 0
    stack_level[0] = 0
    sp = 1
    bounds = np.empty(9, np.int64)
    while sp > 0:
        sp -= 1
        nd = stack_node[sp]
        level = stack_level[sp]
        s = start[nd]
        e = end[nd]
        first_child[nd] = -1
        n_child[nd] = 0
        if e - s <= leaf_size:
            continue
        while level <= MAX_LEVEL:
            shift = np.uint64(3 * (MAX_LEVEL - level))
            prefix = (codes[s] >> shift) & ~np.uint64(7)
            bounds[0] = s
            for o in range(1, 8):
                bounds[o] = _lower_bound(codes, bounds[o - 1], e, shift, prefix | np.uint64(o))
            bounds[8] = e
            nonempty = 0
            for o in range(8):
                if bounds[o + 1] > bounds[o]:
                    nonempty += 1
            if nonempty >= 2:
                break
            level += 1
        if level > MAX_LEVEL:
            continue  # identical codes: keep as a leaf
        first_child[nd] = n_nodes
        for o in range(8):
            if bounds[o + 1] > bounds[o]:
                c = n_nodes
                start[c] = bounds[o]
                end[c] = bounds[o + 1]
                n_nodes += 1
                n_child[nd] += 1
                stack_node[sp] = c
                stack_level[sp] = level + 1
                sp += 1
    return n_nodes


@njit(parallel=True, fastmath=True, cache=True)
def cell_moments(xs, ys, zs, q, start, end, centre, radius, mono, dipole, quad):
    """Moments of every node from its charges (see the module docstring).

    xs, ys, zs, q (n,) sorted by Morton code; start, end (m,); out: centre (m, 3) m, radius (m,) m,
    mono (m,) C, dipole (m, 3) C m, quad (m, 6) C m^2 as (xx, yy, zz, xy, xz, yz), traceless.
    """
    for nd in prange(start.shape[0]):
        s = start[nd]
        e = end[nd]
        a = 0.0
        cx = 0.0
        cy = 0.0
        cz = 0.0
        qt = 0.0
        for k in range(s, e):
            w = abs(q[k])
            a += w
            cx += w * xs[k]
            cy += w * ys[k]
            cz += w * zs[k]
            qt += q[k]
        if a > 0.0:
            cx /= a
            cy /= a
            cz /= a
        else:
            cx = 0.0
            cy = 0.0
            cz = 0.0
            for k in range(s, e):
                cx += xs[k]
                cy += ys[k]
                cz += zs[k]
            cx /= e - s
            cy /= e - s
            cz /= e - s
        px = 0.0
        py = 0.0
        pz = 0.0
        qxx = 0.0
        qyy = 0.0
        qzz = 0.0
        qxy = 0.0
        qxz = 0.0
        qyz = 0.0
        r2max = 0.0
        for k in range(s, e):
            dx = xs[k] - cx
            dy = ys[k] - cy
            dz = zs[k] - cz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > r2max:
                r2max = d2
            w = q[k]
            px += w * dx
            py += w * dy
            pz += w * dz
            qxx += w * (3.0 * dx * dx - d2)
            qyy += w * (3.0 * dy * dy - d2)
            qzz += w * (3.0 * dz * dz - d2)
            qxy += w * 3.0 * dx * dy
            qxz += w * 3.0 * dx * dz
            qyz += w * 3.0 * dy * dz
        centre[nd, 0] = cx
        centre[nd, 1] = cy
        centre[nd, 2] = cz
        radius[nd] = np.sqrt(r2max)
        mono[nd] = qt
        dipole[nd, 0] = px
        dipole[nd, 1] = py
        dipole[nd, 2] = pz
        quad[nd, 0] = qxx
        quad[nd, 1] = qyy
        quad[nd, 2] = qzz
        quad[nd, 3] = qxy
        quad[nd, 4] = qxz
        quad[nd, 5] = qyz


@njit(fastmath=True, inline="always")
def _far_field(nd, rx, ry, rz, order, mono, dipole, quad):
    r2 = rx * rx + ry * ry + rz * rz
    inv2 = 1.0 / r2
    inv1 = np.sqrt(inv2)
    inv3 = inv1 * inv2
    w = mono[nd] * inv3
    ex = w * rx
    ey = w * ry
    ez = w * rz
    if order >= 1:
        px = dipole[nd, 0]
        py = dipole[nd, 1]
        pz = dipole[nd, 2]
        pr = px * rx + py * ry + pz * rz
        inv5 = inv3 * inv2
        ex += 3.0 * pr * inv5 * rx - px * inv3
        ey += 3.0 * pr * inv5 * ry - py * inv3
        ez += 3.0 * pr * inv5 * rz - pz * inv3
        if order >= 2:
            qx = quad[nd, 0] * rx + quad[nd, 3] * ry + quad[nd, 4] * rz
            qy = quad[nd, 3] * rx + quad[nd, 1] * ry + quad[nd, 5] * rz
            qz = quad[nd, 4] * rx + quad[nd, 5] * ry + quad[nd, 2] * rz
            rqr = rx * qx + ry * qy + rz * qz
            inv7 = inv5 * inv2
            ex += 2.5 * rqr * inv7 * rx - qx * inv5
            ey += 2.5 * rqr * inv7 * ry - qy * inv5
            ez += 2.5 * rqr * inv7 * rz - qz * inv5
    return ex, ey, ez


@njit(fastmath=True, inline="always")
def _add_cell_far_field(nd, ls, le, xs, ys, zs, centre, order, mono, dipole, quad, out):
    """Add cell ``nd``'s multipole field at the sorted targets ls..le-1 into ``out`` (C/m^2)."""
    for t in range(ls, le):
        ex, ey, ez = _far_field(nd, xs[t] - centre[nd, 0], ys[t] - centre[nd, 1], zs[t] - centre[nd, 2],
                                order, mono, dipole, quad)
        out[t, 0] += ex
        out[t, 1] += ey
        out[t, 2] += ez


@njit(fastmath=True, inline="always")
def _add_direct_field(ls, le, s, e, xs, ys, zs, q, out):
    """Add the exact field of the sorted charges s..e-1 at targets ls..le-1 into ``out`` (C/m^2);
    coincident pairs (a charge and itself) are skipped."""
    for t in range(ls, le):
        xt = xs[t]
        yt = ys[t]
        zt = zs[t]
        ex = 0.0
        ey = 0.0
        ez = 0.0
        for j in range(s, e):
            rx = xt - xs[j]
            ry = yt - ys[j]
            rz = zt - zs[j]
            r2 = rx * rx + ry * ry + rz * rz
            if r2 > 0.0:
                w = q[j] / (r2 * np.sqrt(r2))
                ex += w * rx
                ey += w * ry
                ez += w * rz
        out[t, 0] += ex
        out[t, 1] += ey
        out[t, 2] += ez


@njit(parallel=True, fastmath=True, cache=True)
def treecode_field_groups(xs, ys, zs, q, start, end, first_child, n_child, centre, radius, mono, dipole,
                          quad, leaves, theta, order, out, counts):
    """Field at every (sorted) charge from all others, by leaf groups (module docstring).

    leaves (L,) int64 leaf node ids; theta opening angle (> 0); order 0, 1 or 2;
    out (n, 3) C/m^2 in sorted order; counts (L, 2) int64: far-cell and near-pair evaluations.
    """
    for li in prange(leaves.shape[0]):
        leaf = leaves[li]
        ls = start[leaf]
        le = end[leaf]
        for t in range(ls, le):
            out[t, 0] = 0.0
            out[t, 1] = 0.0
            out[t, 2] = 0.0
        lcx = centre[leaf, 0]
        lcy = centre[leaf, 1]
        lcz = centre[leaf, 2]
        lr = radius[leaf]
        stack = np.empty(8 * 64 + 16, np.int64)
        stack[0] = 0
        sp = 1
        n_far = 0
        n_near = 0
        while sp > 0:
            sp -= 1
            nd = stack[sp]
            dx = centre[nd, 0] - lcx
            dy = centre[nd, 1] - lcy
            dz = centre[nd, 2] - lcz
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if d - lr > 0.0 and radius[nd] < theta * (d - lr):
                n_far += le - ls
                _add_cell_far_field(nd, ls, le, xs, ys, zs, centre, order, mono, dipole, quad, out)
            elif n_child[nd] == 0:
                s = start[nd]
                e = end[nd]
                n_near += (le - ls) * (e - s)
                _add_direct_field(ls, le, s, e, xs, ys, zs, q, out)
            else:
                fc = first_child[nd]
                for c in range(n_child[nd]):
                    stack[sp] = fc + c
                    sp += 1
        counts[li, 0] = n_far
        counts[li, 1] = n_near


@njit(parallel=True, fastmath=True, cache=True)
def treecode_field_points(points, xs, ys, zs, q, start, end, first_child, n_child, centre, radius, mono,
                          dipole, quad, theta, order, out):
    """Field at arbitrary points (m, 3) (one traversal per point; the same acceptance rule with r_leaf = 0)."""
    for i in prange(points.shape[0]):
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        stack = np.empty(8 * 64 + 16, np.int64)
        stack[0] = 0
        sp = 1
        ex = 0.0
        ey = 0.0
        ez = 0.0
        while sp > 0:
            sp -= 1
            nd = stack[sp]
            rx = px - centre[nd, 0]
            ry = py - centre[nd, 1]
            rz = pz - centre[nd, 2]
            d = np.sqrt(rx * rx + ry * ry + rz * rz)
            if d > 0.0 and radius[nd] < theta * d:
                fx, fy, fz = _far_field(nd, rx, ry, rz, order, mono, dipole, quad)
                ex += fx
                ey += fy
                ez += fz
            elif n_child[nd] == 0:
                for j in range(start[nd], end[nd]):
                    sx = px - xs[j]
                    sy = py - ys[j]
                    sz = pz - zs[j]
                    r2 = sx * sx + sy * sy + sz * sz
                    if r2 > 0.0:
                        w = q[j] / (r2 * np.sqrt(r2))
                        ex += w * sx
                        ey += w * sy
                        ez += w * sz
            else:
                fc = first_child[nd]
                for c in range(n_child[nd]):
                    stack[sp] = fc + c
                    sp += 1
        out[i, 0] = ex
        out[i, 1] = ey
        out[i, 2] = ez


@njit(fastmath=True, inline="always")
def _m2l(nd, rx, ry, rz, order, mono, dipole, quad, loc):
    """Add cell nd's field at the leaf centre and its first two derivatives (r = leaf centre - cell centre)
    to loc (19,): E (3), J (9, row-major, dE_i/dx_j), H (upper 7 used as listed in _l2p).

    E: monopole + dipole + quadrupole; J: monopole + dipole; H: monopole (see the module notes)."""
    ex, ey, ez = _far_field(nd, rx, ry, rz, order, mono, dipole, quad)
    loc[0] += ex
    loc[1] += ey
    loc[2] += ez
    r2 = rx * rx + ry * ry + rz * rz
    inv2 = 1.0 / r2
    inv1 = np.sqrt(inv2)
    inv3 = inv1 * inv2
    inv5 = inv3 * inv2
    inv7 = inv5 * inv2
    q = mono[nd]
    r0 = rx
    r1 = ry
    r2_ = rz
    rr = (r0, r1, r2_)
    # J_ij = q (d_ij / r^3 - 3 r_i r_j / r^5) + dipole part
    for i in range(3):
        for j in range(3):
            v = -3.0 * q * rr[i] * rr[j] * inv5
            if i == j:
                v += q * inv3
            loc[3 + 3 * i + j] += v
    if order >= 1:
        px = dipole[nd, 0]
        py = dipole[nd, 1]
        pz = dipole[nd, 2]
        pp = (px, py, pz)
        pr = px * rx + py * ry + pz * rz
        for i in range(3):
            for j in range(3):
                v = 3.0 * (pp[j] * rr[i] + pp[i] * rr[j]) * inv5 - 15.0 * pr * rr[i] * rr[j] * inv7
                if i == j:
                    v += 3.0 * pr * inv5
                loc[3 + 3 * i + j] += v
    # H_ijk = q (-3 (d_ij r_k + d_ik r_j + d_jk r_i) / r^5 + 15 r_i r_j r_k / r^7), fully symmetric:
    # store the 10 independent components (000, 001, 002, 011, 012, 022, 111, 112, 122, 222) at 12..21
    t = 0
    for i in range(3):
        for j in range(i, 3):
            for k in range(j, 3):
                v = 15.0 * q * rr[i] * rr[j] * rr[k] * inv7
                if i == j:
                    v -= 3.0 * q * rr[k] * inv5
                if i == k:
                    v -= 3.0 * q * rr[j] * inv5
                if j == k:
                    v -= 3.0 * q * rr[i] * inv5
                loc[12 + t] += v
                t += 1


@njit(fastmath=True, inline="always")
def _l2p(loc, dx, dy, dz):
    """E at leaf centre + (dx, dy, dz) from the local coefficients: E_i + J_ij d_j + 1/2 H_ijk d_j d_k."""
    d = (dx, dy, dz)
    ex = loc[0] + loc[3] * dx + loc[4] * dy + loc[5] * dz
    ey = loc[1] + loc[6] * dx + loc[7] * dy + loc[8] * dz
    ez = loc[2] + loc[9] * dx + loc[10] * dy + loc[11] * dz
    # unpack the symmetric H
    h000 = loc[12]
    h001 = loc[13]
    h002 = loc[14]
    h011 = loc[15]
    h012 = loc[16]
    h022 = loc[17]
    h111 = loc[18]
    h112 = loc[19]
    h122 = loc[20]
    h222 = loc[21]
    x = d[0]
    y = d[1]
    z = d[2]
    ex += 0.5 * (h000 * x * x + h011 * y * y + h022 * z * z + 2.0 * (h001 * x * y + h002 * x * z + h012 * y * z))
    ey += 0.5 * (h001 * x * x + h111 * y * y + h122 * z * z + 2.0 * (h011 * x * y + h012 * x * z + h112 * y * z))
    ez += 0.5 * (h002 * x * x + h112 * y * y + h222 * z * z + 2.0 * (h012 * x * y + h022 * x * z + h122 * y * z))
    return ex, ey, ez


@njit(parallel=True, fastmath=True, cache=True)
def treecode_field_groups_local(xs, ys, zs, q, start, end, first_child, n_child, centre, radius, mono, dipole,
                                quad, leaves, theta, order, out, counts):
    """As :func:`treecode_field_groups`, but a source cell with r_cell + r_leaf < theta d (d between the
    centres) is converted once into a second-order local (Taylor) expansion of the field about the leaf
    centre (cell-to-leaf, "M2L"), evaluated at the leaf's charges at the end (L2P). Cells that pass
    only the per-target test are evaluated per target as before. counts (L, 3): M2L conversions,
    per-target far evaluations, near pairs."""
    for li in prange(leaves.shape[0]):
        leaf = leaves[li]
        ls = start[leaf]
        le = end[leaf]
        for t in range(ls, le):
            out[t, 0] = 0.0
            out[t, 1] = 0.0
            out[t, 2] = 0.0
        lcx = centre[leaf, 0]
        lcy = centre[leaf, 1]
        lcz = centre[leaf, 2]
        lr = radius[leaf]
        loc = np.zeros(22)
        stack = np.empty(8 * 64 + 16, np.int64)
        stack[0] = 0
        sp = 1
        n_m2l = 0
        n_far = 0
        n_near = 0
        while sp > 0:
            sp -= 1
            nd = stack[sp]
            dx = lcx - centre[nd, 0]
            dy = lcy - centre[nd, 1]
            dz = lcz - centre[nd, 2]
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if radius[nd] + lr < theta * d:
                n_m2l += 1
                _m2l(nd, dx, dy, dz, order, mono, dipole, quad, loc)
            elif d - lr > 0.0 and radius[nd] < theta * (d - lr):
                n_far += le - ls
                _add_cell_far_field(nd, ls, le, xs, ys, zs, centre, order, mono, dipole, quad, out)
            elif n_child[nd] == 0:
                s = start[nd]
                e = end[nd]
                n_near += (le - ls) * (e - s)
                _add_direct_field(ls, le, s, e, xs, ys, zs, q, out)
            else:
                fc = first_child[nd]
                for c in range(n_child[nd]):
                    stack[sp] = fc + c
                    sp += 1
        if n_m2l > 0:
            for t in range(ls, le):
                ex, ey, ez = _l2p(loc, xs[t] - lcx, ys[t] - lcy, zs[t] - lcz)
                out[t, 0] += ex
                out[t, 1] += ey
                out[t, 2] += ez
        counts[li, 0] = n_m2l
        counts[li, 1] = n_far
        counts[li, 2] = n_near
