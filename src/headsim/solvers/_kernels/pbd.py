"""Numba kernels of Position Based Dynamics (Müller et al. 2006; XPBD: Macklin et al. 2016).

Pure array functions, inputs first and ``out`` (or the arrays updated in place) last. Units: positions m,
inverse masses 1/kg, volumes m³; ``alpha_tilde`` = compliance / dt², where a compliance is the inverse
stiffness of the constraint (constraint unit² / J: m/N for distances, m⁶/J for volumes), so that
alpha_tilde · (1/kg) is dimensionless when the gradient is.

Conventions shared by all projections (Monkin 2016 §3, "general constraint projection"):
``dp_i = -s w_i grad_i C`` with ``s = C / sum_j w_j |grad_j C|^2``; with XPBD the multiplier step is
``dlam = (-C - alpha_tilde lam) / (sum_j w_j |grad_j C|^2 + alpha_tilde)`` and ``dp_i = w_i grad_i C dlam``.
A PBD stiffness ``k`` in (0, 1] multiplies ``dlam`` (with ``alpha_tilde = 0``).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from headsim.solvers._kernels.twins import parallel_twin


def _serial_and_parallel(func):
    """Compile ``func`` twice: serial (returned) and with ``parallel=True`` (as ``<name>_parallel``, with its
    own cache files: :func:`headsim.solvers._kernels.twins.parallel_twin`).

    On a few shared cores the per-colour launch of a parallel region costs more than it saves for the
    mesh sizes of a face region; the solver picks one with ``PBDOptions.parallel``.
    """
    func.__globals__[func.__name__ + "_parallel"] = parallel_twin(func)
    return njit(cache=True)(func)


# --------------------------------------------------------------------------------------------------
# distance constraints  C = |p_i - p_j| - d   (Monkin 2016 §3, distance constraint)
# --------------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _edge_step(p, w, i, j, rest, alpha_tilde, lam, stiffness):
    """Return (dlam, nx, ny, nz) of one distance constraint; dlam = 0 when it cannot move."""
    dx = p[i, 0] - p[j, 0]
    dy = p[i, 1] - p[j, 1]
    dz = p[i, 2] - p[j, 2]
    length = np.sqrt(dx * dx + dy * dy + dz * dz)
    wsum = w[i] + w[j]
    if wsum == 0.0 or length < 1e-300:
        return 0.0, 0.0, 0.0, 0.0
    c = length - rest
    dlam = stiffness * (-c - alpha_tilde * lam) / (wsum + alpha_tilde)
    return dlam, dx / length, dy / length, dz / length


@_serial_and_parallel
def project_distance_coloured(edges, rest, color_offsets, w, alpha_tilde, stiffness, lam, p):
    """One graph-coloured Gauss–Seidel sweep over distance constraints, in place.

    edges (s, 2) int64 sorted by colour; rest (s,) m; color_offsets (c+1,) int64 (edges of colour k are
    ``color_offsets[k]:color_offsets[k+1]``; no two share a vertex); w (n,) 1/kg; alpha_tilde: compliance / dt²
    (m/N), 0 for PBD; stiffness: PBD factor in (0, 1] (1 for XPBD); lam (s,) XPBD multipliers, updated;
    p (n, 3) m, updated.
    """
    for k in range(color_offsets.shape[0] - 1):
        for e in prange(color_offsets[k], color_offsets[k + 1]):
            i = edges[e, 0]
            j = edges[e, 1]
            dlam, nx, ny, nz = _edge_step(p, w, i, j, rest[e], alpha_tilde, lam[e], stiffness)
            lam[e] += dlam
            p[i, 0] += w[i] * dlam * nx
            p[i, 1] += w[i] * dlam * ny
            p[i, 2] += w[i] * dlam * nz
            p[j, 0] -= w[j] * dlam * nx
            p[j, 1] -= w[j] * dlam * ny
            p[j, 2] -= w[j] * dlam * nz


@_serial_and_parallel
def project_distance_jacobi(edges, rest, vertex_edge_offsets, vertex_edges, w, alpha_tilde, stiffness, omega,
                            lam, scratch_dlam, scratch_dir, p):
    """One Jacobi sweep over distance constraints with averaging (Macklin et al. 2014 eq. 11), in place.

    All constraints see the same positions; each vertex moves by ``omega / n_i`` times the sum of its
    corrections (n_i = constraints at the vertex). vertex_edge_offsets (n+1,) int64 and vertex_edges
    (2s,) int64: CSR list of the edges at every vertex. scratch_dlam (s,), scratch_dir (s, 3) work arrays.
    Other arguments as in :func:`project_distance_coloured`.
    """
    s = edges.shape[0]
    for e in prange(s):
        dlam, nx, ny, nz = _edge_step(p, w, edges[e, 0], edges[e, 1], rest[e], alpha_tilde, lam[e], stiffness)
        scratch_dlam[e] = dlam
        scratch_dir[e, 0] = nx
        scratch_dir[e, 1] = ny
        scratch_dir[e, 2] = nz
        lam[e] += dlam
    n = p.shape[0]
    for i in prange(n):
        if w[i] == 0.0:
            continue
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        start = vertex_edge_offsets[i]
        stop = vertex_edge_offsets[i + 1]
        for q in range(start, stop):
            e = vertex_edges[q]
            sign = 1.0 if edges[e, 0] == i else -1.0
            f = sign * w[i] * scratch_dlam[e]
            a0 += f * scratch_dir[e, 0]
            a1 += f * scratch_dir[e, 1]
            a2 += f * scratch_dir[e, 2]
        cnt = stop - start
        if cnt > 0:
            scale = omega / cnt
            p[i, 0] += scale * a0
            p[i, 1] += scale * a1
            p[i, 2] += scale * a2


# --------------------------------------------------------------------------------------------------
# volume constraints  C = sum_t (p_t1 x p_t2) . p_t3 / 6 - V_target   (Monkin 2016 §3 and §4.2)
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def body_volumes(p, triangles, triangle_body, n_bodies, out):
    """Signed volume of every closed body, m³ (sum of signed tetrahedra with the origin as common apex).

    p (n, 3) m; triangles (m, 3) int64; triangle_body (m,) int64 body of each triangle; out (n_bodies,).
    """
    for b in range(n_bodies):
        out[b] = 0.0
    for t in range(triangles.shape[0]):
        a = triangles[t, 0]
        b = triangles[t, 1]
        c = triangles[t, 2]
        cx = p[b, 1] * p[c, 2] - p[b, 2] * p[c, 1]
        cy = p[b, 2] * p[c, 0] - p[b, 0] * p[c, 2]
        cz = p[b, 0] * p[c, 1] - p[b, 1] * p[c, 0]
        out[triangle_body[t]] += (p[a, 0] * cx + p[a, 1] * cy + p[a, 2] * cz) / 6.0


@njit(cache=True)
def project_volume(triangles, triangle_body, vertex_body, target, w, alpha_tilde, stiffness, lam, scratch_grad,
                   scratch_vol, scratch_denom, p):
    """Project every body's volume constraint once, in place (Monkin 2016 §3: grad_i C = sum over the
    triangles at i of the cross product of the other two vertices, in order, / 6).

    triangles (m, 3) int64 outward-oriented; triangle_body (m,) int64; vertex_body (n,) int64 body of each
    particle (-1: none; a particle belongs to one body only); target (k,) m³; w (n,) 1/kg; alpha_tilde:
    compliance / dt² (compliance in m⁶/J), 0 for a hard constraint; stiffness PBD factor; lam (k,)
    multipliers, updated; scratch_grad (n, 3), scratch_vol (k,), scratch_denom (k,) work arrays;
    p (n, 3) m, updated. Volume and gradient are accumulated in one pass over the triangles.
    """
    nb = target.shape[0]
    for b in range(nb):
        scratch_vol[b] = 0.0
        scratch_denom[b] = 0.0
    scratch_grad[:, :] = 0.0
    for t in range(triangles.shape[0]):
        a = triangles[t, 0]
        b = triangles[t, 1]
        c = triangles[t, 2]
        # d/da = b x c, d/db = c x a, d/dc = a x b  (each / 6); volume = a . (b x c) / 6
        bcx = p[b, 1] * p[c, 2] - p[b, 2] * p[c, 1]
        bcy = p[b, 2] * p[c, 0] - p[b, 0] * p[c, 2]
        bcz = p[b, 0] * p[c, 1] - p[b, 1] * p[c, 0]
        scratch_vol[triangle_body[t]] += (p[a, 0] * bcx + p[a, 1] * bcy + p[a, 2] * bcz) / 6.0
        scratch_grad[a, 0] += bcx / 6.0
        scratch_grad[a, 1] += bcy / 6.0
        scratch_grad[a, 2] += bcz / 6.0
        scratch_grad[b, 0] += (p[c, 1] * p[a, 2] - p[c, 2] * p[a, 1]) / 6.0
        scratch_grad[b, 1] += (p[c, 2] * p[a, 0] - p[c, 0] * p[a, 2]) / 6.0
        scratch_grad[b, 2] += (p[c, 0] * p[a, 1] - p[c, 1] * p[a, 0]) / 6.0
        scratch_grad[c, 0] += (p[a, 1] * p[b, 2] - p[a, 2] * p[b, 1]) / 6.0
        scratch_grad[c, 1] += (p[a, 2] * p[b, 0] - p[a, 0] * p[b, 2]) / 6.0
        scratch_grad[c, 2] += (p[a, 0] * p[b, 1] - p[a, 1] * p[b, 0]) / 6.0
    for i in range(p.shape[0]):
        bd = vertex_body[i]
        if bd >= 0 and w[i] > 0.0:
            g0 = scratch_grad[i, 0]
            g1 = scratch_grad[i, 1]
            g2 = scratch_grad[i, 2]
            scratch_denom[bd] += w[i] * (g0 * g0 + g1 * g1 + g2 * g2)
    for b in range(nb):
        dl = 0.0
        if scratch_denom[b] + alpha_tilde > 0.0:
            c = scratch_vol[b] - target[b]
            dl = stiffness * (-c - alpha_tilde * lam[b]) / (scratch_denom[b] + alpha_tilde)
            lam[b] += dl
        scratch_denom[b] = dl  # reused: the multiplier step of body b
    for i in range(p.shape[0]):
        bd = vertex_body[i]
        if bd >= 0 and w[i] > 0.0:
            f = w[i] * scratch_denom[bd]
            p[i, 0] += f * scratch_grad[i, 0]
            p[i, 1] += f * scratch_grad[i, 1]
            p[i, 2] += f * scratch_grad[i, 2]


# --------------------------------------------------------------------------------------------------
# collision constraints (inequalities)
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def project_planes(plane_points, plane_normals, radius, w, p):
    """Keep every movable particle at least ``radius`` on the normal side of every plane, in place.

    plane_points (k, 3) m; plane_normals (k, 3) unit; radius m; w (n,) 1/kg; p (n, 3) m.
    Constraint C = (p - o) . n - radius >= 0.
    """
    for i in prange(p.shape[0]):
        if w[i] == 0.0:
            continue
        for k in range(plane_points.shape[0]):
            c = ((p[i, 0] - plane_points[k, 0]) * plane_normals[k, 0]
                 + (p[i, 1] - plane_points[k, 1]) * plane_normals[k, 1]
                 + (p[i, 2] - plane_points[k, 2]) * plane_normals[k, 2]) - radius
            if c < 0.0:
                p[i, 0] -= c * plane_normals[k, 0]
                p[i, 1] -= c * plane_normals[k, 1]
                p[i, 2] -= c * plane_normals[k, 2]


@njit(cache=True)
def build_voxel_grid(p, origin, cell, dims, cell_start, cell_particles):
    """Counting-sort particles into a dense voxel grid (Monkin 2016 §4.1: voxel-accelerated search).

    p (n, 3) m; origin (3,) m; cell m; dims (3,) int64 cells per axis; cell_start (nx*ny*nz+1,) int64 out;
    cell_particles (n,) int64 out: particle ids ordered by cell. Particles outside are clamped to the edge cells.
    """
    ncell = dims[0] * dims[1] * dims[2]
    cell_of = np.empty(p.shape[0], dtype=np.int64)
    cell_start[:] = 0
    for i in range(p.shape[0]):
        ix = min(max(int((p[i, 0] - origin[0]) / cell), 0), dims[0] - 1)
        iy = min(max(int((p[i, 1] - origin[1]) / cell), 0), dims[1] - 1)
        iz = min(max(int((p[i, 2] - origin[2]) / cell), 0), dims[2] - 1)
        c = (ix * dims[1] + iy) * dims[2] + iz
        cell_of[i] = c
        cell_start[c + 1] += 1
    for c in range(ncell):
        cell_start[c + 1] += cell_start[c]
    fill = cell_start[:-1].copy()
    for i in range(p.shape[0]):
        c = cell_of[i]
        cell_particles[fill[c]] = i
        fill[c] += 1


@_serial_and_parallel
def project_particle_contacts(p, w, radius, origin, cell, dims, cell_start, cell_particles, out):
    """Jacobi projection of particle–particle non-penetration |p_i - p_j| >= 2 radius over a voxel grid.

    Writes the averaged correction of every particle into ``out`` (n, 3) m; the caller adds it to ``p``.
    Grid arguments as built by :func:`build_voxel_grid` with ``cell >= 2 radius``.
    """
    d2min = 4.0 * radius * radius
    for i in prange(p.shape[0]):
        out[i, 0] = 0.0
        out[i, 1] = 0.0
        out[i, 2] = 0.0
        if w[i] == 0.0:
            continue
        ix = min(max(int((p[i, 0] - origin[0]) / cell), 0), dims[0] - 1)
        iy = min(max(int((p[i, 1] - origin[1]) / cell), 0), dims[1] - 1)
        iz = min(max(int((p[i, 2] - origin[2]) / cell), 0), dims[2] - 1)
        count = 0
        for ax in range(max(ix - 1, 0), min(ix + 2, dims[0])):
            for ay in range(max(iy - 1, 0), min(iy + 2, dims[1])):
                for az in range(max(iz - 1, 0), min(iz + 2, dims[2])):
                    c = (ax * dims[1] + ay) * dims[2] + az
                    for q in range(cell_start[c], cell_start[c + 1]):
                        j = cell_particles[q]
                        if j == i:
                            continue
                        dx = p[i, 0] - p[j, 0]
                        dy = p[i, 1] - p[j, 1]
                        dz = p[i, 2] - p[j, 2]
                        d2 = dx * dx + dy * dy + dz * dz
                        if d2 < d2min and d2 > 1e-300:
                            d = np.sqrt(d2)
                            share = w[i] / (w[i] + w[j])
                            f = share * (2.0 * radius - d) / d
                            out[i, 0] += f * dx
                            out[i, 1] += f * dy
                            out[i, 2] += f * dz
                            count += 1
        if count > 1:
            out[i, 0] /= count
            out[i, 1] /= count
            out[i, 2] /= count


# --------------------------------------------------------------------------------------------------
# hydrostatic pressure (Monkin 2016 §4.3): F_i = rho g h_i A_i along gravity
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def _ray_triangle(ox, oy, oz, dx, dy, dz, p, a, b, c):
    """Möller–Trumbore: distance along the unit ray to triangle (a, b, c), or -1 when missed."""
    e1x = p[b, 0] - p[a, 0]
    e1y = p[b, 1] - p[a, 1]
    e1z = p[b, 2] - p[a, 2]
    e2x = p[c, 0] - p[a, 0]
    e2y = p[c, 1] - p[a, 1]
    e2z = p[c, 2] - p[a, 2]
    hx = dy * e2z - dz * e2y
    hy = dz * e2x - dx * e2z
    hz = dx * e2y - dy * e2x
    det = e1x * hx + e1y * hy + e1z * hz
    if abs(det) < 1e-300:
        return -1.0
    inv = 1.0 / det
    sx = ox - p[a, 0]
    sy = oy - p[a, 1]
    sz = oz - p[a, 2]
    u = inv * (sx * hx + sy * hy + sz * hz)
    if u < 0.0 or u > 1.0:
        return -1.0
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = inv * (dx * qx + dy * qy + dz * qz)
    if v < 0.0 or u + v > 1.0:
        return -1.0
    return inv * (e2x * qx + e2y * qy + e2z * qz)


@_serial_and_parallel
def column_heights(p, triangles, up, e1, e2, cell, out):
    """Height of the fluid column above every particle (Monkin 2016 §4.3), m.

    h_i = distance from particle i along ``up`` (opposite to gravity) to the nearest point of the surface,
    0 when the upward ray leaves the body. Triangles that contain the particle are skipped. The upward
    rays are answered through a 2-D bucket grid in the plane spanned by e1, e2 (both ⟂ up).

    p (n, 3) m; triangles (m, 3) int64; up, e1, e2 (3,) orthonormal; cell m (bucket size); out (n,) m.
    """
    n = p.shape[0]
    m = triangles.shape[0]
    pu = np.empty(n)
    pv = np.empty(n)
    for i in range(n):
        pu[i] = p[i, 0] * e1[0] + p[i, 1] * e1[1] + p[i, 2] * e1[2]
        pv[i] = p[i, 0] * e2[0] + p[i, 1] * e2[1] + p[i, 2] * e2[2]
    u0 = pu.min()
    v0 = pv.min()
    nu = int((pu.max() - u0) / cell) + 1
    nv = int((pv.max() - v0) / cell) + 1
    counts = np.zeros(nu * nv + 1, dtype=np.int64)
    for t in range(m):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        iu0 = int((min(pu[a], pu[b], pu[c]) - u0) / cell)
        iu1 = int((max(pu[a], pu[b], pu[c]) - u0) / cell)
        iv0 = int((min(pv[a], pv[b], pv[c]) - v0) / cell)
        iv1 = int((max(pv[a], pv[b], pv[c]) - v0) / cell)
        for iu in range(iu0, iu1 + 1):
            for iv in range(iv0, iv1 + 1):
                counts[iu * nv + iv + 1] += 1
    for k in range(nu * nv):
        counts[k + 1] += counts[k]
    bucket = np.empty(counts[nu * nv], dtype=np.int64)
    fill = counts[:-1].copy()
    for t in range(m):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        iu0 = int((min(pu[a], pu[b], pu[c]) - u0) / cell)
        iu1 = int((max(pu[a], pu[b], pu[c]) - u0) / cell)
        iv0 = int((min(pv[a], pv[b], pv[c]) - v0) / cell)
        iv1 = int((max(pv[a], pv[b], pv[c]) - v0) / cell)
        for iu in range(iu0, iu1 + 1):
            for iv in range(iv0, iv1 + 1):
                k = iu * nv + iv
                bucket[fill[k]] = t
                fill[k] += 1
    for i in prange(n):
        k = int((pu[i] - u0) / cell) * nv + int((pv[i] - v0) / cell)
        best = np.inf
        for q in range(counts[k], counts[k + 1]):
            t = bucket[q]
            a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
            if a == i or b == i or c == i:
                continue
            d = _ray_triangle(p[i, 0], p[i, 1], p[i, 2], up[0], up[1], up[2], p, a, b, c)
            if d > 0.0 and d < best:
                best = d
        out[i] = best if best < np.inf else 0.0


@njit(cache=True)
def sum_abs(p):
    """Sum of the absolute values of all coordinates (Monkin 2016 §4.4 stop rule), m."""
    s = 0.0
    for i in range(p.shape[0]):
        s += abs(p[i, 0]) + abs(p[i, 1]) + abs(p[i, 2])
    return s


@njit(cache=True)
def greedy_edge_colouring(edges, n_vertices, out):
    """Colour edges so that no two edges of one colour share a vertex (greedy, ≤ 2Δ-1 colours ≤ 63).

    edges (s, 2) int64; out (s,) int64 colours. Returns the number of colours, or -1 if over 63.
    """
    used = np.zeros(n_vertices, dtype=np.int64)
    n_colours = 0
    for e in range(edges.shape[0]):
        i = edges[e, 0]
        j = edges[e, 1]
        mask = used[i] | used[j]
        c = 0
        while c < 63 and (mask >> c) & 1:
            c += 1
        if c >= 63:
            return -1
        out[e] = c
        used[i] |= 1 << c
        used[j] |= 1 << c
        if c + 1 > n_colours:
            n_colours = c + 1
    return n_colours


# --------------------------------------------------------------------------------------------------
# Anderson acceleration of the PBD step map (headsim.solvers.pbd_anderson)
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def anderson_combine(g, dg, count, gamma, out):
    """out = g - sum_k gamma[k] dg[:, k] over k < count (g (N,), dg (N, m), gamma (m,), out (N,))."""
    for q in range(g.shape[0]):
        s = g[q]
        for k in range(count):
            s -= gamma[k] * dg[q, k]
        out[q] = s


@njit(cache=True)
def sum_abs_difference(a, b):
    """sum |a - b| over all entries of two equal (N,) arrays."""
    s = 0.0
    for q in range(a.shape[0]):
        s += abs(a[q] - b[q])
    return s


@njit(cache=True)
def anderson_record(g, g_new, x_new, f, dF, dG, slot, used, row, rhs):
    """One streaming pass: new residual, new Anderson differences, Gram row and right-hand side.

    g (N,) previous value Φ(x); g_new = Φ(x_new), x_new (N,); f (N,) previous residual g - x on entry,
    g_new - x_new on exit; dF, dG (N, m): column ``slot`` receives the residual and value differences
    (only when ``used`` > 0); row[k] = dF[:, k] . dF[:, slot] and rhs[k] = dF[:, k] . f_new for k < used.
    Returns Σ|g_new - x_new|.
    """
    res = 0.0
    for k in range(used):
        row[k] = 0.0
        rhs[k] = 0.0
    for q in range(g.shape[0]):
        fn = g_new[q] - x_new[q]
        res += abs(fn)
        if used > 0:
            d = fn - f[q]
            dF[q, slot] = d
            dG[q, slot] = g_new[q] - g[q]
            for k in range(used):
                row[k] += dF[q, k] * d
                rhs[k] += dF[q, k] * fn
        f[q] = fn
    return res


@njit(cache=True)
def project_gs_volume_iterations(n_iterations, edges, rest, color_offsets, w, alpha_edge, stiffness, lam_e,
                                 triangles, triangle_body, vertex_body, target, alpha_volume, lam_v, scratch_grad,
                                 scratch_vol, scratch_denom, p):
    """``n_iterations`` × (coloured Gauss–Seidel distance sweep, then volume projection), in place: the
    solver iterations of one PBD step for a model with only distance and volume constraints (one call
    instead of two per iteration). Arguments as in :func:`project_distance_coloured` and
    :func:`project_volume` (volume stiffness 1)."""
    for _ in range(n_iterations):
        project_distance_coloured(edges, rest, color_offsets, w, alpha_edge, stiffness, lam_e, p)
        if target.shape[0] > 0:
            project_volume(triangles, triangle_body, vertex_body, target, w, alpha_volume, 1.0, lam_v, scratch_grad,
                           scratch_vol, scratch_denom, p)
