"""Numba kernels of the hairstyle reconstruction (Sobottka 2008 §5.3.3-5.3.5).

Rod shapes come from Pai's static integration of a Kirchhoff rod under a tip wrench given in the tip's
material frame (``headsim.solvers`` kernel, eqs. 3.128/3.129): with only terminal loads the internal force
is constant, so this is the exact equilibrium of the dead load R(L) f_local, in O(N).
All lengths in m; the objective terms are dimensionless.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from headsim.collide._kernels_distance_field import trilinear_at as _tri
from headsim.solvers._kernels.rods_statics import pai_integrate

# layout of the scalar parameter vector ``par`` of the guide objective
P_W1, P_W2, P_W3, P_W4 = 0, 1, 2, 3          # term weights (sum 1)
P_MARGIN, P_CD, P_EPS = 4, 5, 6              # boundary margin delta (m), exit penalty c_d, smoothing (m)
P_MODE = 7                                   # density model: 0 none, 1 binary (BBM), 2 continuous (KDM)
P_RHO_TOL, P_RHO_PEN = 8, 9                  # KDM predicted-density tolerance and its penalty factor
P_FSCALE, P_LSCALE = 10, 11                  # K/L^2 (N) and K/L (N m): eta -> physical tip wrench
P_DS = 12                                    # segment length, m
P_RHO_SCALE = 13                             # 1 / mean density expected if all strands were spread evenly
P_HEAD_FAR, P_HAIR_FAR = 14, 15              # value of the two fields outside their grids (+far, m)
N_PAR = 16


@njit(cache=True)
def rod_shape(R0, r0, K, ds, tip_force, tip_torque, kappa, n, R, r):
    """Static shape under a local tip wrench into kappa, n (N+1, 3), R (N+1, 3, 3), r (N+1, 3)."""
    nn = r.shape[0]
    z = np.zeros((nn, 3))
    pai_integrate(z, K, ds, R0, r0, z, z, tip_force, tip_torque, kappa, n, R, r)


@njit(cache=True)
def rod_shapes_batch(R0, r0, K, ds, tip_force, tip_torque, kappa, R, r):
    """:func:`rod_shape` for a batch (leading axis = fibre; serial: batches are small and the machine has 2 cores)."""
    for b in range(R0.shape[0]):
        n = np.empty((r.shape[1], 3))
        rod_shape(R0[b], r0[b], K[b], ds[b], tip_force[b], tip_torque[b], kappa[b], n, R[b], r[b])


@njit(cache=True, inline="always")
def _boundary_cost(d, margin, cd, eps):
    """Corrected eq. 5.10 per node: d < 0 inside the admissible side. Inside, (1 + d/delta)^2 within the
    margin delta (penalises approaching the boundary from inside), 0 deeper; outside, the exit penalty
    c_d (a logistic step of width eps, so the objective stays continuous) plus (1 + d/delta)^2."""
    u = 1.0 + d / margin
    base = u * u if u > 0.0 else 0.0
    s = d / eps
    if s > 30.0:
        step = 1.0
    elif s < -30.0:
        step = 0.0
    else:
        step = 1.0 / (1.0 + np.exp(-s))
    return base + cd * step


@njit(cache=True)
def guide_objective(eta, par, R0, r0, K, pre_d3, pre_kl, pre_w,
                    head, head_o, head_h, hair, hair_o, hair_h, dens, dens_o, dens_h,
                    kappa, n, R, r):
    """f(eta) = sum w_i F_i (eq. 5.7) for a tip wrench eta (6,) = (f L^2/K, l L/K) in the tip frame.

    pre_d3 (C, N+1, 3): tangents of the C nearest pre-guides at the same normalised arc length; pre_kl
    (C, N+1, 3): their Darboux vectors times their length; pre_w (C,): weights summing to 1.
    head / hair: signed distance grids (negative inside the head / inside the hair volume);
    dens: density grid (binary occupancy for BBM, Phi_rho for KDM). Fills r, R, kappa with the shape.
    """
    nn = r.shape[0]
    N = nn - 1
    tf = np.empty(3)
    tl = np.empty(3)
    for c in range(3):
        tf[c] = eta[c] * par[P_FSCALE]
        tl[c] = eta[3 + c] * par[P_LSCALE]
    rod_shape(R0, r0, K, par[P_DS], tf, tl, kappa, n, R, r)
    L = N * par[P_DS]
    # F1 direction (eq. 5.8) and F2 similarity (eq. 5.9), trapezoid rule on s in [0, 1]
    F1 = 0.0
    F2 = 0.0
    for c in range(pre_w.shape[0]):
        f1 = 0.0
        f2 = 0.0
        for j in range(nn):
            wj = 0.5 if (j == 0 or j == N) else 1.0
            dot = R[j, 0, 2] * pre_d3[c, j, 0] + R[j, 1, 2] * pre_d3[c, j, 1] + R[j, 2, 2] * pre_d3[c, j, 2]
            f1 += wj * (1.0 - dot)
            e = 0.0
            for k in range(3):
                dk = kappa[j, k] * L - pre_kl[c, j, k]
                e += dk * dk
            f2 += wj * e
        F1 += pre_w[c] * f1 / N
        F2 += pre_w[c] * np.sqrt(f2 / N)
    # F3 boundary (corrected eq. 5.10), mean over the nodes after the root, both surfaces
    margin = par[P_MARGIN]
    cd = par[P_CD]
    eps = par[P_EPS]
    F3 = 0.0
    for j in range(1, nn):
        dh = _tri(hair, hair_o, hair_h, r[j, 0], r[j, 1], r[j, 2], par[P_HAIR_FAR])
        ds_ = -_tri(head, head_o, head_h, r[j, 0], r[j, 1], r[j, 2], par[P_HEAD_FAR])
        F3 += _boundary_cost(dh, margin, cd, eps) + _boundary_cost(ds_, margin, cd, eps)
    F3 /= N
    # F4 density (eqs. 5.11 / 5.12)
    F4 = 0.0
    mode = int(par[P_MODE])
    if mode == 1:  # binary occupancy at the segment midpoints (trilinear relaxation of delta(s_i))
        for j in range(N):
            F4 += _tri(dens, dens_o, dens_h, 0.5 * (r[j, 0] + r[j + 1, 0]), 0.5 * (r[j, 1] + r[j + 1, 1]),
                       0.5 * (r[j, 2] + r[j + 1, 2]), 0.0)
        F4 /= N
    elif mode == 2:  # <h grad Phi_rho, r'/|r'|>^2 by central differences, plus the predicted-density penalty
        h = dens_h
        for j in range(1, nn):
            x, y, z = r[j, 0], r[j, 1], r[j, 2]
            gx = 0.5 * (_tri(dens, dens_o, h, x + h, y, z, 0.0) - _tri(dens, dens_o, h, x - h, y, z, 0.0))
            gy = 0.5 * (_tri(dens, dens_o, h, x, y + h, z, 0.0) - _tri(dens, dens_o, h, x, y - h, z, 0.0))
            gz = 0.5 * (_tri(dens, dens_o, h, x, y, z + h, 0.0) - _tri(dens, dens_o, h, x, y, z - h, 0.0))
            p = (gx * R[j, 0, 2] + gy * R[j, 1, 2] + gz * R[j, 2, 2]) * par[P_RHO_SCALE]
            rho = _tri(dens, dens_o, h, x, y, z, 0.0) * par[P_RHO_SCALE]
            over = rho - par[P_RHO_TOL]
            F4 += p * p + (par[P_RHO_PEN] * over if over > 0.0 else 0.0)
        F4 /= N
    f = par[P_W1] * F1 + par[P_W2] * F2 + par[P_W3] * F3 + par[P_W4] * F4
    if not np.isfinite(f):
        return 1e12  # an overflowing shape: reject, the optimiser backs off
    return f


@njit(cache=True)
def objective_and_gradient(eta, step, par, R0, r0, K, pre_d3, pre_kl, pre_w,
                           head, head_o, head_h, hair, hair_o, hair_h, dens, dens_o, dens_h, grad):
    """f(eta) and its forward-difference gradient (step in eta units) into grad (6,); 7 evaluations."""
    nn = pre_d3.shape[1]
    kappa = np.empty((nn, 3))
    n = np.empty((nn, 3))
    R = np.empty((nn, 3, 3))
    r = np.empty((nn, 3))
    f0 = guide_objective(eta, par, R0, r0, K, pre_d3, pre_kl, pre_w, head, head_o, head_h, hair, hair_o, hair_h,
                         dens, dens_o, dens_h, kappa, n, R, r)
    e = eta.copy()
    for c in range(6):
        e[c] = eta[c] + step
        fp = guide_objective(e, par, R0, r0, K, pre_d3, pre_kl, pre_w, head, head_o, head_h, hair, hair_o,
                             hair_h, dens, dens_o, dens_h, kappa, n, R, r)
        e[c] = eta[c]
        grad[c] = (fp - f0) / step
    return f0


@njit(cache=True)
def distances_serial(values, origin, h, points, outside):
    """Trilinear field values at points (n, 3), serial (no thread-pool start per call inside the loops)."""
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        out[p] = _tri(values, origin, h, points[p, 0], points[p, 1], points[p, 2], outside)
    return out


@njit(cache=True)
def first_exit(hair_d, head_d, seg_len, tol_d, tol_len):
    """Index of the last node kept by the final cut (§5.3.5) of one polyline.

    hair_d (n,) signed distance to the hair surface (negative inside), head_d (n,) to the head (negative
    inside); seg_len (n-1,) m. A node is outside if hair_d > tol_d or head_d < -tol_d. An excursion is
    tolerated if the fibre re-enters within tol_len of arc length; otherwise the fibre ends at the last
    node before the first exit.
    """
    n = hair_d.shape[0]
    j = 1
    while j < n:
        if hair_d[j] > tol_d or head_d[j] < -tol_d:
            out_len = 0.0
            k = j
            while k < n and (hair_d[k] > tol_d or head_d[k] < -tol_d):
                out_len += seg_len[k - 1]
                k += 1
            if k < n and out_len + seg_len[k - 1] <= tol_len:
                j = k  # short excursion: tolerated
                continue
            return j - 1
        j += 1
    return n - 1


@njit(cache=True)
def kdm_add_segment(grid, origin, h, a, b, weight):
    """Continuous density (§5.3.4): every voxel (centred on a grid node, side h) gains
    weight * (length of segment ab inside it) / (cell diagonal), by exact voxel traversal
    (Amanatides & Woo 1987)."""
    nx, ny, nz = grid.shape
    diag = h * np.sqrt(3.0)
    d = np.empty(3)
    p = np.empty(3)
    cell = np.empty(3, np.int64)
    stepc = np.empty(3, np.int64)
    tmax = np.empty(3)
    tdelta = np.empty(3)
    length = 0.0
    for c in range(3):
        d[c] = b[c] - a[c]
        length += d[c] * d[c]
    length = np.sqrt(length)
    if length <= 0.0:
        return
    for c in range(3):
        p[c] = (a[c] - origin[c]) / h + 0.5  # voxel of node i spans [i - 1/2, i + 1/2) -> shifted by 1/2
        cell[c] = int(np.floor(p[c]))
        dc = d[c] / h
        if dc > 0:
            stepc[c] = 1
            tmax[c] = (cell[c] + 1 - p[c]) / dc
            tdelta[c] = 1.0 / dc
        elif dc < 0:
            stepc[c] = -1
            tmax[c] = (p[c] - cell[c]) / -dc
            tdelta[c] = -1.0 / dc
        else:
            stepc[c] = 0
            tmax[c] = np.inf
            tdelta[c] = np.inf
    t = 0.0
    while t < 1.0:
        c = 0
        if tmax[1] < tmax[c]:
            c = 1
        if tmax[2] < tmax[c]:
            c = 2
        t_next = min(tmax[c], 1.0)
        i, j, k = cell[0], cell[1], cell[2]
        if 0 <= i < nx and 0 <= j < ny and 0 <= k < nz:
            grid[i, j, k] += weight * (t_next - t) * length / diag
        t = t_next
        cell[c] += stepc[c]
        tmax[c] += tdelta[c]


@njit(cache=True)
def kdm_add_polylines(grid, origin, h, points, weight):
    """:func:`kdm_add_segment` for every segment of fibres points (F, n, 3)."""
    for f in range(points.shape[0]):
        for j in range(points.shape[1] - 1):
            kdm_add_segment(grid, origin, h, points[f, j], points[f, j + 1], weight)


@njit(cache=True)
def _sat_obb_box(c, ax, ext, bc, bh):
    """Separating-axis test (Gottschalk et al. 1996) of an OBB (centre c, unit axes ax (3, 3) rows,
    half-extents ext) against an axis-aligned cube (centre bc, half-size bh). True if they overlap."""
    t = np.empty(3)
    for k in range(3):
        t[k] = c[k] - bc[k]
    # box axes
    for i in range(3):
        ra = bh
        rb = ext[0] * abs(ax[0, i]) + ext[1] * abs(ax[1, i]) + ext[2] * abs(ax[2, i])
        if abs(t[i]) > ra + rb:
            return False
    # OBB axes
    for i in range(3):
        ra = bh * (abs(ax[i, 0]) + abs(ax[i, 1]) + abs(ax[i, 2]))
        rb = ext[i]
        if abs(t[0] * ax[i, 0] + t[1] * ax[i, 1] + t[2] * ax[i, 2]) > ra + rb:
            return False
    # cross products e_i x a_j
    L = np.empty(3)
    for i in range(3):
        for j in range(3):
            e = np.zeros(3)
            e[i] = 1.0
            L[0] = e[1] * ax[j, 2] - e[2] * ax[j, 1]
            L[1] = e[2] * ax[j, 0] - e[0] * ax[j, 2]
            L[2] = e[0] * ax[j, 1] - e[1] * ax[j, 0]
            nl = abs(L[0]) + abs(L[1]) + abs(L[2])
            if nl < 1e-12:
                continue
            ra = bh * (abs(L[0]) + abs(L[1]) + abs(L[2]))
            rb = 0.0
            for k in range(3):
                rb += ext[k] * abs(L[0] * ax[k, 0] + L[1] * ax[k, 1] + L[2] * ax[k, 2])
            if abs(t[0] * L[0] + t[1] * L[1] + t[2] * L[2]) > ra + rb:
                return False
    return True


@njit(cache=True)
def bbm_add_polyline(grid, origin, h, points, radius):
    """Binary occupancy (§5.3.4): set to 1 every voxel (centred on a grid node, side h) that overlaps the
    OBB of a strand segment (a generalised-cylinder frustum of radius radius[j] (n,) m) by the SAT."""
    nx, ny, nz = grid.shape
    ax = np.empty((3, 3))
    ext = np.empty(3)
    c = np.empty(3)
    bc = np.empty(3)
    for j in range(points.shape[0] - 1):
        rr = max(radius[j], radius[j + 1])
        ln = 0.0
        for k in range(3):
            ax[0, k] = points[j + 1, k] - points[j, k]
            ln += ax[0, k] ** 2
            c[k] = 0.5 * (points[j + 1, k] + points[j, k])
        ln = np.sqrt(ln)
        if ln <= 0.0:
            continue
        for k in range(3):
            ax[0, k] /= ln
        # two unit normals
        if abs(ax[0, 0]) < 0.9:
            ux, uy, uz = 0.0, -ax[0, 2], ax[0, 1]
        else:
            ux, uy, uz = ax[0, 2], 0.0, -ax[0, 0]
        nu = np.sqrt(ux * ux + uy * uy + uz * uz)
        ax[1, 0], ax[1, 1], ax[1, 2] = ux / nu, uy / nu, uz / nu
        ax[2, 0] = ax[0, 1] * ax[1, 2] - ax[0, 2] * ax[1, 1]
        ax[2, 1] = ax[0, 2] * ax[1, 0] - ax[0, 0] * ax[1, 2]
        ax[2, 2] = ax[0, 0] * ax[1, 1] - ax[0, 1] * ax[1, 0]
        ext[0] = 0.5 * ln
        ext[1] = rr
        ext[2] = rr
        lo = np.empty(3, np.int64)
        hi = np.empty(3, np.int64)
        for k in range(3):
            half = ext[0] * abs(ax[0, k]) + ext[1] * abs(ax[1, k]) + ext[2] * abs(ax[2, k])
            lo[k] = max(0, int(np.floor((c[k] - half - origin[k]) / h - 0.5)))
            hi[k] = int(np.ceil((c[k] + half - origin[k]) / h + 0.5))
        hi[0] = min(hi[0], nx - 1)
        hi[1] = min(hi[1], ny - 1)
        hi[2] = min(hi[2], nz - 1)
        for i in range(lo[0], hi[0] + 1):
            for jj in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    if grid[i, jj, k] >= 1.0:
                        continue
                    bc[0] = origin[0] + i * h
                    bc[1] = origin[1] + jj * h
                    bc[2] = origin[2] + k * h
                    if _sat_obb_box(c, ax, ext, bc, 0.5 * h):
                        grid[i, jj, k] = 1.0


@njit(cache=True)
def first_exit_batch(hair_d, head_d, points, tol_d, tol_len, out):
    """:func:`first_exit` for fibres (F, n): distances (F, n), points (F, n, 3) -> out (F,) last kept node."""
    F, n = hair_d.shape
    for f in range(F):
        seg = np.empty(n - 1)
        for j in range(n - 1):
            dx = points[f, j + 1, 0] - points[f, j, 0]
            dy = points[f, j + 1, 1] - points[f, j, 1]
            dz = points[f, j + 1, 2] - points[f, j, 2]
            seg[j] = np.sqrt(dx * dx + dy * dy + dz * dz)
        out[f] = first_exit(hair_d[f], head_d[f], seg, tol_d, tol_len)


def field_distance(field, points) -> np.ndarray:
    """Values of a :class:`~headsim.collide.distance_field.GridDistanceField` (or a DensityGrid-like object with
    values/origin/spacing) at points (..., 3) m, serial trilinear; outside the grid: +far."""
    p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    far = float(getattr(field, "far", 0.0))
    return distances_serial(field.values, field.origin, float(field.spacing), p, far).reshape(np.shape(points)[:-1])
