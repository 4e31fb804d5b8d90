"""Numba kernels for single bounding volumes of capsule segments (rows as in ``bounding_volumes``).

Kinds: 0 = slabs (AABB / k-DOP, row ``[lo_0..lo_{m-1}, hi_0..hi_{m-1}]``), 1 = sphere
(``[c, R]``), 2 = OBB (``[c (3), axes (3×3 rows), half-extents (3)]``). Lengths in m.
"""

from __future__ import annotations

import numpy as np
from numba import njit

KIND_SLAB = 0
KIND_SPHERE = 1
KIND_OBB = 2


@njit(cache=True)
def slab_from_capsule(ax, ay, az, bx, by, bz, r, dirs, bv, row):
    """Slab row of one capsule (Sobottka eq. 7.9): ``[min(nᵀa, nᵀb) − r, max(nᵀa, nᵀb) + r]``."""
    m = dirs.shape[0]
    for i in range(m):
        pa = dirs[i, 0] * ax + dirs[i, 1] * ay + dirs[i, 2] * az
        pb = dirs[i, 0] * bx + dirs[i, 1] * by + dirs[i, 2] * bz
        if pa < pb:
            bv[row, i] = pa - r
            bv[row, m + i] = pb + r
        else:
            bv[row, i] = pb - r
            bv[row, m + i] = pa + r


@njit(cache=True)
def sphere_from_capsule(ax, ay, az, bx, by, bz, r, bv, row):
    """Sphere row of one capsule: midpoint, half length + r."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    bv[row, 0] = 0.5 * (ax + bx)
    bv[row, 1] = 0.5 * (ay + by)
    bv[row, 2] = 0.5 * (az + bz)
    bv[row, 3] = 0.5 * np.sqrt(dx * dx + dy * dy + dz * dz) + r


@njit(cache=True)
def obb_from_capsule(ax, ay, az, bx, by, bz, r, bv, row):
    """Segment-aligned OBB row of one capsule: axis along the segment, half-extents (L/2 + r, r, r)."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    length = np.sqrt(dx * dx + dy * dy + dz * dz)
    if length > 0.0:
        ux, uy, uz = dx / length, dy / length, dz / length
    else:
        ux, uy, uz = 1.0, 0.0, 0.0
    if abs(ux) < 0.9:
        hx, hy, hz = 1.0, 0.0, 0.0
    else:
        hx, hy, hz = 0.0, 1.0, 0.0
    vx, vy, vz = uy * hz - uz * hy, uz * hx - ux * hz, ux * hy - uy * hx
    vn = np.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / vn, vy / vn, vz / vn
    wx, wy, wz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    bv[row, 0] = 0.5 * (ax + bx)
    bv[row, 1] = 0.5 * (ay + by)
    bv[row, 2] = 0.5 * (az + bz)
    bv[row, 3], bv[row, 4], bv[row, 5] = ux, uy, uz
    bv[row, 6], bv[row, 7], bv[row, 8] = vx, vy, vz
    bv[row, 9], bv[row, 10], bv[row, 11] = wx, wy, wz
    bv[row, 12] = 0.5 * length + r
    bv[row, 13] = r
    bv[row, 14] = r


@njit(cache=True)
def enclosing_ball(centres, radii, out):
    """Near-minimal ball enclosing the balls (``centres`` (n, 3) m, ``radii`` (n,) m) into ``out`` (4,).

    Ritter's start, then 96 Bădoiu–Clarkson steps towards the farthest ball, then the radius is set
    to the exact maximum ``‖c_i − c‖ + r_i``: the result always encloses every ball and is
    minimal to within a few percent (the thesis used Gärtner's exact code; see the module notes).
    """
    n = centres.shape[0]
    cx, cy, cz = centres[0, 0], centres[0, 1], centres[0, 2]
    # Ritter start: farthest from first, then farthest from that
    best, ia = -1.0, 0
    for i in range(n):
        d = np.sqrt((centres[i, 0] - cx) ** 2 + (centres[i, 1] - cy) ** 2 + (centres[i, 2] - cz) ** 2) + radii[i]
        if d > best:
            best, ia = d, i
    best, ib = -1.0, 0
    for i in range(n):
        d = np.sqrt((centres[i, 0] - centres[ia, 0]) ** 2 + (centres[i, 1] - centres[ia, 1]) ** 2
                    + (centres[i, 2] - centres[ia, 2]) ** 2) + radii[i]
        if d > best:
            best, ib = d, i
    cx = 0.5 * (centres[ia, 0] + centres[ib, 0])
    cy = 0.5 * (centres[ia, 1] + centres[ib, 1])
    cz = 0.5 * (centres[ia, 2] + centres[ib, 2])
    for it in range(1, 97):
        best = -1.0
        fx, fy, fz = 0.0, 0.0, 0.0
        for i in range(n):
            dx, dy, dz = centres[i, 0] - cx, centres[i, 1] - cy, centres[i, 2] - cz
            dn = np.sqrt(dx * dx + dy * dy + dz * dz)
            d = dn + radii[i]
            if d > best:
                best = d
                if dn > 0:
                    fx = centres[i, 0] + radii[i] * dx / dn
                    fy = centres[i, 1] + radii[i] * dy / dn
                    fz = centres[i, 2] + radii[i] * dz / dn
                else:
                    fx, fy, fz = centres[i, 0] + radii[i], centres[i, 1], centres[i, 2]
        w = 1.0 / (it + 1.0)
        cx += (fx - cx) * w
        cy += (fy - cy) * w
        cz += (fz - cz) * w
    rr = 0.0
    for i in range(n):
        d = np.sqrt((centres[i, 0] - cx) ** 2 + (centres[i, 1] - cy) ** 2 + (centres[i, 2] - cz) ** 2) + radii[i]
        if d > rr:
            rr = d
    out[0], out[1], out[2], out[3] = cx, cy, cz, rr


@njit(cache=True)
def sphere_merge(bv, a, b, out, row):
    """Smallest sphere enclosing spheres ``bv[a]`` and ``bv[b]`` (closed form) into ``out[row]``."""
    dx, dy, dz = bv[b, 0] - bv[a, 0], bv[b, 1] - bv[a, 1], bv[b, 2] - bv[a, 2]
    dist = np.sqrt(dx * dx + dy * dy + dz * dz)
    ra, rb = bv[a, 3], bv[b, 3]
    if dist + rb <= ra:
        for k in range(4):
            out[row, k] = bv[a, k]
        return
    if dist + ra <= rb:
        for k in range(4):
            out[row, k] = bv[b, k]
        return
    r = 0.5 * (dist + ra + rb)
    f = (r - ra) / dist
    out[row, 0] = bv[a, 0] + f * dx
    out[row, 1] = bv[a, 1] + f * dy
    out[row, 2] = bv[a, 2] + f * dz
    out[row, 3] = r


@njit(cache=True)
def obb_from_points(pts, pad, out, row):
    """PCA box (Sobottka eqs. 7.10–7.12) of points ``pts`` (n, 3), each inflated by ``pad`` (n,)."""
    n = pts.shape[0]
    mean = np.zeros(3)
    for i in range(n):
        for k in range(3):
            mean[k] += pts[i, k]
    mean /= n
    cov = np.zeros((3, 3))
    for i in range(n):
        for k in range(3):
            for l in range(3):
                cov[k, l] += (pts[i, k] - mean[k]) * (pts[i, l] - mean[l])
    cov /= n
    _, vec = np.linalg.eigh(cov)
    axes = np.empty((3, 3))
    for k in range(3):
        axes[0, k] = vec[k, 2]
        axes[1, k] = vec[k, 1]
    axes[2, 0] = axes[0, 1] * axes[1, 2] - axes[0, 2] * axes[1, 1]
    axes[2, 1] = axes[0, 2] * axes[1, 0] - axes[0, 0] * axes[1, 2]
    axes[2, 2] = axes[0, 0] * axes[1, 1] - axes[0, 1] * axes[1, 0]
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(n):
        for a in range(3):
            p = 0.0
            for k in range(3):
                p += (pts[i, k] - mean[k]) * axes[a, k]
            if p - pad[i] < lo[a]:
                lo[a] = p - pad[i]
            if p + pad[i] > hi[a]:
                hi[a] = p + pad[i]
    for k in range(3):
        c = mean[k]
        for a in range(3):
            c += 0.5 * (lo[a] + hi[a]) * axes[a, k]
        out[row, k] = c
    for a in range(3):
        for k in range(3):
            out[row, 3 + 3 * a + k] = axes[a, k]
        out[row, 12 + a] = 0.5 * (hi[a] - lo[a])


@njit(cache=True)
def obb_merge(bv, a, b, out, row):
    """PCA box over the 16 corners of boxes ``bv[a]`` and ``bv[b]`` (OL rule, §7.3.7.3.2)."""
    pts = np.empty((16, 3))
    j = 0
    for node in (a, b):
        for s0 in (-1.0, 1.0):
            for s1 in (-1.0, 1.0):
                for s2 in (-1.0, 1.0):
                    for k in range(3):
                        pts[j, k] = (bv[node, k] + s0 * bv[node, 12] * bv[node, 3 + k]
                                     + s1 * bv[node, 13] * bv[node, 6 + k]
                                     + s2 * bv[node, 14] * bv[node, 9 + k])
                    j += 1
    obb_from_points(pts, np.zeros(16), out, row)


@njit(cache=True)
def obb_overlap(bv, u, v):
    """Separating-axis test of two OBB rows (15 axes, Gottschalk et al. 1996)."""
    # rotation of v's axes in u's frame and translation
    rm = np.empty((3, 3))
    arm = np.empty((3, 3))
    t = np.empty(3)
    for i in range(3):
        ti = 0.0
        for k in range(3):
            ti += (bv[v, k] - bv[u, k]) * bv[u, 3 + 3 * i + k]
        t[i] = ti
        for j in range(3):
            s = 0.0
            for k in range(3):
                s += bv[u, 3 + 3 * i + k] * bv[v, 3 + 3 * j + k]
            rm[i, j] = s
            arm[i, j] = abs(s) + 1e-12
    ha0, ha1, ha2 = bv[u, 12], bv[u, 13], bv[u, 14]
    hb0, hb1, hb2 = bv[v, 12], bv[v, 13], bv[v, 14]
    ha = (ha0, ha1, ha2)
    hb = (hb0, hb1, hb2)
    for i in range(3):
        if abs(t[i]) > ha[i] + hb0 * arm[i, 0] + hb1 * arm[i, 1] + hb2 * arm[i, 2]:
            return False
    for j in range(3):
        if abs(t[0] * rm[0, j] + t[1] * rm[1, j] + t[2] * rm[2, j]) > (
            hb[j] + ha0 * arm[0, j] + ha1 * arm[1, j] + ha2 * arm[2, j]
        ):
            return False
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            ra = ha[i1] * arm[i2, j] + ha[i2] * arm[i1, j]
            rb = hb[j1] * arm[i, j2] + hb[j2] * arm[i, j1]
            if abs(t[i2] * rm[i1, j] - t[i1] * rm[i2, j]) > ra + rb:
                return False
    return True


@njit(cache=True)
def bv_overlap(bv, u, v, kind, m):
    """Do BV rows ``u`` and ``v`` of ``bv`` overlap? (kind 0: m slabs; 1: spheres; 2: OBBs)."""
    if kind == 0:
        for i in range(m):
            if bv[u, i] > bv[v, m + i] or bv[v, i] > bv[u, m + i]:
                return False
        return True
    if kind == 1:
        dx = bv[u, 0] - bv[v, 0]
        dy = bv[u, 1] - bv[v, 1]
        dz = bv[u, 2] - bv[v, 2]
        rs = bv[u, 3] + bv[v, 3]
        return dx * dx + dy * dy + dz * dz <= rs * rs
    return obb_overlap(bv, u, v)


@njit(cache=True)
def bv_size(bv, u, kind, m):
    """A size measure used by the 'volume' descent rule: slab-width sum, sphere radius, OBB half-extent sum."""
    if kind == 0:
        s = 0.0
        for i in range(m):
            s += bv[u, m + i] - bv[u, i]
        return s
    if kind == 1:
        return bv[u, 3]
    return bv[u, 12] + bv[u, 13] + bv[u, 14]
