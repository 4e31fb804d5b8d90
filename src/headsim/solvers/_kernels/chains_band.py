"""Numba kernels of the local-motion bound behind the chain solver's relative candidate band
(:class:`headsim.solvers.chain_band.LocalMotionBound`).

A reference velocity field F over a regular grid of cell size c (m): the segments' point velocities
v + ω × (t d₃) (m/s, eq. 8.7) sampled along each segment are gathered on the grid nodes with trilinear
weights (mass-weighted means), empty nodes next to filled ones take the mean of those (two layers; the
nodes beyond keep 0 or take their nearest filled node's value, see
:class:`~headsim.solvers.chain_band.LocalMotionBound`), and F is the trilinear interpolation of the node
values everywhere. Within one cell ∂F/∂x is a convex combination of the cell's four x-edge differences / c
(likewise y, z), so |F(p) − F(q)| ≤ L_cell |p − q|
along any straight path inside the cell, L_cell = ‖(G_x, G_y, G_z)‖ with G_q the largest edge difference
along axis q / c (1/s); F is continuous across cells.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def _point_velocity(x, d3, v, w, s, t):
    """Position and velocity (m, m/s) of the point at arc length t (m, from the centre) of segment s."""
    r0 = t * d3[s, 0]
    r1 = t * d3[s, 1]
    r2 = t * d3[s, 2]
    return (x[s, 0] + r0, x[s, 1] + r1, x[s, 2] + r2,
            v[s, 0] + w[s, 1] * r2 - w[s, 2] * r1,
            v[s, 1] + w[s, 2] * r0 - w[s, 0] * r2,
            v[s, 2] + w[s, 0] * r1 - w[s, 1] * r0)


@njit(cache=True, inline="always")
def _cell_of(lo, cell, p0, p1, p2):
    f0 = (p0 - lo[0]) / cell
    f1 = (p1 - lo[1]) / cell
    f2 = (p2 - lo[2]) / cell
    i = int(np.floor(f0))
    j = int(np.floor(f1))
    k = int(np.floor(f2))
    return i, j, k, f0 - i, f1 - j, f2 - k


@njit(cache=True)
def gather_reference(x, d3, v, w, half, mass, cell, lo, samples, M, MV):
    """Mass-weighted trilinear gathering of ``samples`` (≥ 2) evenly spaced point velocities per segment onto
    the node arrays M (nx, ny, nz) (kg) and MV (nx, ny, nz, 3) (kg m/s), both zero on entry."""
    S = x.shape[0]
    for s in range(S):
        m = mass[s] / samples
        for j in range(samples):
            t = -half[s] + 2.0 * half[s] * j / (samples - 1)
            p0, p1, p2, u0, u1, u2 = _point_velocity(x, d3, v, w, s, t)
            i, jj, kk, f0, f1, f2 = _cell_of(lo, cell, p0, p1, p2)
            for di in range(2):
                wx = f0 if di else 1.0 - f0
                for dj in range(2):
                    wy = f1 if dj else 1.0 - f1
                    for dk in range(2):
                        mm = wx * wy * (f2 if dk else 1.0 - f2) * m
                        M[i + di, jj + dj, kk + dk] += mm
                        MV[i + di, jj + dj, kk + dk, 0] += mm * u0
                        MV[i + di, jj + dj, kk + dk, 1] += mm * u1
                        MV[i + di, jj + dj, kk + dk, 2] += mm * u2


@njit(cache=True, parallel=True)
def node_values(M, MV, V, filled):
    """V = MV / M (m/s) at the nodes with mass (``filled``), 0 elsewhere."""
    nx, ny, nz = M.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                f = M[i, j, k] > 0.0
                filled[i, j, k] = f
                for q in range(3):
                    V[i, j, k, q] = MV[i, j, k, q] / M[i, j, k] if f else 0.0


@njit(cache=True, parallel=True)
def dilate_values(V, filled, V_out, filled_out):
    """One layer of filling: an empty node with filled neighbours (26-neighbourhood) gets their mean."""
    nx, ny, nz = filled.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                for q in range(3):
                    V_out[i, j, k, q] = V[i, j, k, q]
                filled_out[i, j, k] = filled[i, j, k]
                if filled[i, j, k]:
                    continue
                c = 0
                a0 = 0.0
                a1 = 0.0
                a2 = 0.0
                for ii in range(max(i - 1, 0), min(i + 2, nx)):
                    for jj in range(max(j - 1, 0), min(j + 2, ny)):
                        for kk in range(max(k - 1, 0), min(k + 2, nz)):
                            if filled[ii, jj, kk]:
                                c += 1
                                a0 += V[ii, jj, kk, 0]
                                a1 += V[ii, jj, kk, 1]
                                a2 += V[ii, jj, kk, 2]
                if c:
                    V_out[i, j, k, 0] = a0 / c
                    V_out[i, j, k, 1] = a1 / c
                    V_out[i, j, k, 2] = a2 / c
                    filled_out[i, j, k] = True


@njit(cache=True, inline="always")
def _edge2(V, i0, j0, k0, i1, j1, k1):
    d0 = V[i1, j1, k1, 0] - V[i0, j0, k0, 0]
    d1 = V[i1, j1, k1, 1] - V[i0, j0, k0, 1]
    d2 = V[i1, j1, k1, 2] - V[i0, j0, k0, 2]
    return d0 * d0 + d1 * d1 + d2 * d2


@njit(cache=True, parallel=True)
def cell_lipschitz(V, cell, L):
    """L (nx−1, ny−1, nz−1) (1/s): the Lipschitz bound of the trilinear F in every cell (module docstring)."""
    nx, ny, nz = L.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                gx = 0.0
                gy = 0.0
                gz = 0.0
                for a in range(2):
                    for b in range(2):
                        gx = max(gx, _edge2(V, i, j + a, k + b, i + 1, j + a, k + b))
                        gy = max(gy, _edge2(V, i + a, j, k + b, i + a, j + 1, k + b))
                        gz = max(gz, _edge2(V, i + a, j + b, k, i + a, j + b, k + 1))
                L[i, j, k] = np.sqrt(gx + gy + gz) / cell


@njit(cache=True, inline="always")
def _box_max(L, i, j, k, n):
    """Largest L over the cells within n cells (index distance) of cell (i, j, k); inf where that box leaves
    the grid."""
    nx, ny, nz = L.shape
    if i - n < 0 or j - n < 0 or k - n < 0 or i + n >= nx or j + n >= ny or k + n >= nz:
        return np.inf
    m = 0.0
    for ii in range(i - n, i + n + 1):
        for jj in range(j - n, j + n + 1):
            for kk in range(k - n, k + n + 1):
                m = max(m, L[ii, jj, kk])
    return m


@njit(cache=True, parallel=True)
def neighbourhood_max(L, Ln):
    """Ln = the largest L over each cell's 3 × 3 × 3 block (inf at the grid's border cells)."""
    nx, ny, nz = L.shape
    for i in prange(nx):
        for j in range(ny):
            for k in range(nz):
                Ln[i, j, k] = _box_max(L, i, j, k, 1)


@njit(cache=True, inline="always")
def _interpolate(V, lo, cell, p0, p1, p2):
    i, j, k, f0, f1, f2 = _cell_of(lo, cell, p0, p1, p2)
    F0 = 0.0
    F1 = 0.0
    F2 = 0.0
    for di in range(2):
        wx = f0 if di else 1.0 - f0
        for dj in range(2):
            wy = f1 if dj else 1.0 - f1
            for dk in range(2):
                ww = wx * wy * (f2 if dk else 1.0 - f2)
                F0 += ww * V[i + di, j + dj, k + dk, 0]
                F1 += ww * V[i + di, j + dj, k + dk, 1]
                F2 += ww * V[i + di, j + dj, k + dk, 2]
    return F0, F1, F2, i, j, k


@njit(cache=True, parallel=True)
def segment_deviation(x, d3, v, w, half, cell, lo, V, Ln, samples, out_e):
    """out_e[s] (m/s) ≥ max over the points p of segment s of |v_s + ω_s × (p − x_s) − F(p)|: the deviation
    e_j at ``samples`` evenly spaced points (spacing δ, each within the grid's 3 × 3 × 3 block of its cell
    when δ ≤ c), and between two samples at most ½(e_j + e_{j+1} + δ(|ω_s| + L_n)) (both terms are Lipschitz
    along the segment: |ω_s| and the block's largest L_n)."""
    S = x.shape[0]
    for s in prange(S):
        wn = np.sqrt(w[s, 0] * w[s, 0] + w[s, 1] * w[s, 1] + w[s, 2] * w[s, 2])
        delta = 2.0 * half[s] / (samples - 1)
        e_prev = 0.0
        L_prev = 0.0
        worst = 0.0
        for j in range(samples):
            t = -half[s] + delta * j
            p0, p1, p2, u0, u1, u2 = _point_velocity(x, d3, v, w, s, t)
            F0, F1, F2, i, jj, kk = _interpolate(V, lo, cell, p0, p1, p2)
            e = np.sqrt((u0 - F0) ** 2 + (u1 - F1) ** 2 + (u2 - F2) ** 2)
            Lj = Ln[i, jj, kk]
            if j == 0:
                worst = e
            else:
                worst = max(worst, 0.5 * (e + e_prev + delta * (wn + max(Lj, L_prev))))
            e_prev = e
            L_prev = Lj
        out_e[s] = worst


@njit(cache=True, parallel=True)
def segment_lipschitz(x, d3, half, cell, lo, L, Ln, samples, radius, out_L):
    """out_L[s] (1/s) ≥ L over every cell a straight path of length ≤ radius[s] (m) from a point of segment
    s can enter: the largest L over the cells within n = ⌈(radius + ½δ)/c⌉ cells of the cells of its
    ``samples`` points (spacing δ; n = 1: the blocks' maxima Ln); inf where that box leaves the grid."""
    S = x.shape[0]
    for s in prange(S):
        delta = 2.0 * half[s] / (samples - 1)
        n = int(np.ceil((radius[s] + 0.5 * delta) / cell))
        worst = 0.0
        for j in range(samples):
            t = -half[s] + delta * j
            i, jj, kk, _, _, _ = _cell_of(lo, cell, x[s, 0] + t * d3[s, 0], x[s, 1] + t * d3[s, 1],
                                          x[s, 2] + t * d3[s, 2])
            worst = max(worst, Ln[i, jj, kk] if n == 1 else _box_max(L, i, jj, kk, n))
            if worst == np.inf:
                break
        out_L[s] = worst


@njit(cache=True, parallel=True)
def segment_oscillation(x, d3, half, cell, lo, V, samples, radius, which, out):
    """out[q] (m/s) ≥ |F(p) − F(m)| for any point p of segment s = which[q] and any m within radius[s] (m) of
    it: F there is a convex combination of the node values of the cells within n = ⌈(radius + ½δ)/c⌉ cells
    of the samples' cells (δ the sample spacing), so the diameter of those values bounds it; taken over the
    nodes of the index box of those cells (a superset), as √Σ_q (max_q − min_q)². inf where the box leaves the
    grid."""
    nx, ny, nz = V.shape[0], V.shape[1], V.shape[2]
    for q in prange(len(which)):
        s = which[q]
        delta = 2.0 * half[s] / (samples - 1)
        n = int(np.ceil((radius[s] + 0.5 * delta) / cell))
        lo_i = np.empty(3, np.int64)
        hi_i = np.empty(3, np.int64)
        for j in range(2):
            t = -half[s] if j == 0 else half[s]
            i, jj, kk, _, _, _ = _cell_of(lo, cell, x[s, 0] + t * d3[s, 0], x[s, 1] + t * d3[s, 1],
                                          x[s, 2] + t * d3[s, 2])
            if j == 0:
                lo_i[0], lo_i[1], lo_i[2] = i, jj, kk
                hi_i[0], hi_i[1], hi_i[2] = i, jj, kk
            else:
                lo_i[0], lo_i[1], lo_i[2] = min(lo_i[0], i), min(lo_i[1], jj), min(lo_i[2], kk)
                hi_i[0], hi_i[1], hi_i[2] = max(hi_i[0], i), max(hi_i[1], jj), max(hi_i[2], kk)
        if (lo_i[0] - n < 0 or lo_i[1] - n < 0 or lo_i[2] - n < 0 or hi_i[0] + n + 1 >= nx
                or hi_i[1] + n + 1 >= ny or hi_i[2] + n + 1 >= nz):
            out[q] = np.inf
            continue
        mn = np.full(3, np.inf)
        mx = np.full(3, -np.inf)
        for i in range(lo_i[0] - n, hi_i[0] + n + 2):
            for jj in range(lo_i[1] - n, hi_i[1] + n + 2):
                for kk in range(lo_i[2] - n, hi_i[2] + n + 2):
                    for c in range(3):
                        mn[c] = min(mn[c], V[i, jj, kk, c])
                        mx[c] = max(mx[c], V[i, jj, kk, c])
        out[q] = np.sqrt((mx[0] - mn[0]) ** 2 + (mx[1] - mn[1]) ** 2 + (mx[2] - mn[2]) ** 2)
