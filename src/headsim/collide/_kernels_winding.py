"""Numba kernel: generalized winding number over the BVH (Barill et al. 2018, "Fast winding numbers").

w(p) = (1 / 4π) Σ_t Ω_t(p), Ω_t the signed solid angle of triangle t seen from p (Van Oosterom &
Strackee 1983). Nodes whose bounding sphere is small compared with the distance (|c - p| > β r) use
the far-field Taylor expansion about their area-weighted centroid c, up to the Hessian term
(Barill's "order 2"):

    Ω_node ≈ N · g(r) + J(r) : M + ½ H(r) ⋮ T,   r = c - p,   g(r) = r / |r|^3,
    J_ij = ∂_j g_i = δ_ij / |r|^3 - 3 r_i r_j / |r|^5,
    H_ijk = ∂_j ∂_k g_i = -3 (δ_ij r_k + δ_ik r_j + δ_jk r_i) / |r|^5 + 15 r_i r_j r_k / |r|^7,

with N, M, T the area-vector moments of ``refit_winding_moments``. β = inf
gives the exact sum. Points within ``surface_tolerance`` of a triangle are flagged as on the surface.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from headsim.collide._kernels_closest import CHUNK, closest_point_triangle


@njit(cache=True, inline="always")
def _solid_angle(p0, p1, p2, A, B, C):
    """Signed solid angle of triangle ABC seen from p (Van Oosterom & Strackee 1983), det = a·(b×c)
    and la lb + lb lc + lc la (an upper bound of |(B - A) × (C - A)|), with a = A - p etc."""
    ax = A[0] - p0
    ay = A[1] - p1
    az = A[2] - p2
    bx = B[0] - p0
    by = B[1] - p1
    bz = B[2] - p2
    cx = C[0] - p0
    cy = C[1] - p1
    cz = C[2] - p2
    la = np.sqrt(ax * ax + ay * ay + az * az)
    lb = np.sqrt(bx * bx + by * by + bz * bz)
    lc = np.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    denom = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (ax * cx + ay * cy + az * cz) * lb
             + (bx * cx + by * cy + bz * cz) * la)
    return 2.0 * np.arctan2(det, denom), det, la * lb + lb * lc + lc * la


@njit(cache=True, parallel=True)
def winding_numbers_bvh(points, tri_coords, node_child, node_start, node_count,
                        node_center, node_radius, node_normal, node_moment, node_tensor, beta, surface_tolerance,
                        stack_size, out_winding, out_on_surface):
    """Generalized winding number of every point and whether it lies on the surface.

    points (q, 3) float64, m; tri_coords (m, 3, 3) float64, m, triangle corners in leaf order;
    node_* the tree and its far-field data; beta float > 1 (inf = exact); surface_tolerance m.
    Outputs: out_winding (q,) float64 (≈ 1 inside, 0 outside a closed outward-oriented surface);
    out_on_surface (q,) bool (distance to some triangle <= surface_tolerance).
    """
    q = points.shape[0]
    inv4pi = 1.0 / (4.0 * np.pi)
    tol2 = surface_tolerance * surface_tolerance
    n_chunks = (q + CHUNK - 1) // CHUNK
    for chunk in prange(n_chunks):
        stack = np.empty(stack_size, np.int64)
        for i in range(chunk * CHUNK, min(q, (chunk + 1) * CHUNK)):
            p0 = points[i, 0]
            p1 = points[i, 1]
            p2 = points[i, 2]
            total = 0.0
            on_surface = False
            stack[0] = 0
            top = 1
            while top > 0:
                top -= 1
                node = stack[top]
                rx = node_center[node, 0] - p0
                ry = node_center[node, 1] - p1
                rz = node_center[node, 2] - p2
                r2 = rx * rx + ry * ry + rz * rz
                rad = beta * node_radius[node]
                if r2 > rad * rad:
                    inv_r = 1.0 / np.sqrt(r2)
                    inv_r3 = inv_r * inv_r * inv_r
                    inv_r5 = inv_r3 * inv_r * inv_r
                    M = node_moment[node]
                    rMr = (rx * (M[0, 0] * rx + M[0, 1] * ry + M[0, 2] * rz)
                           + ry * (M[1, 0] * rx + M[1, 1] * ry + M[1, 2] * rz)
                           + rz * (M[2, 0] * rx + M[2, 1] * ry + M[2, 2] * rz))
                    T = node_tensor[node]
                    # (a · r) with a_k = sum_i T_iik; (b · r) with b_i = sum_j T_ijj; T[r, r, r]
                    br = (rx * (T[0, 0, 0] + T[0, 1, 1] + T[0, 2, 2]) + ry * (T[1, 0, 0] + T[1, 1, 1] + T[1, 2, 2])
                          + rz * (T[2, 0, 0] + T[2, 1, 1] + T[2, 2, 2]))
                    ar = (rx * (T[0, 0, 0] + T[1, 1, 0] + T[2, 2, 0]) + ry * (T[0, 0, 1] + T[1, 1, 1] + T[2, 2, 1])
                          + rz * (T[0, 0, 2] + T[1, 1, 2] + T[2, 2, 2]))
                    rv = (rx, ry, rz)
                    trrr = 0.0
                    for ii in range(3):
                        for jj in range(3):
                            rij = rv[ii] * rv[jj]
                            trrr += rij * (T[ii, jj, 0] * rx + T[ii, jj, 1] * ry + T[ii, jj, 2] * rz)
                    inv_r7 = inv_r5 * inv_r * inv_r
                    total += ((node_normal[node, 0] * rx + node_normal[node, 1] * ry + node_normal[node, 2] * rz) * inv_r3
                              + (M[0, 0] + M[1, 1] + M[2, 2]) * inv_r3 - 3.0 * rMr * inv_r5
                              + 0.5 * (-3.0 * (2.0 * ar + br) * inv_r5 + 15.0 * trrr * inv_r7))
                    continue
                c = node_child[node]
                if c < 0:
                    for k in range(node_start[node], node_start[node] + node_count[node]):
                        A = tri_coords[k, 0]
                        B = tri_coords[k, 1]
                        C = tri_coords[k, 2]
                        omega, det, nbound = _solid_angle(p0, p1, p2, A, B, C)
                        total += omega
                        # |det| / |n| is the distance from the plane and |n| <= nbound: cheap pre-filter
                        if not on_surface and det * det <= tol2 * nbound * nbound:
                            e1x = B[0] - A[0]
                            e1y = B[1] - A[1]
                            e1z = B[2] - A[2]
                            e2x = C[0] - A[0]
                            e2y = C[1] - A[1]
                            e2z = C[2] - A[2]
                            nx = e1y * e2z - e1z * e2y
                            ny = e1z * e2x - e1x * e2z
                            nz = e1x * e2y - e1y * e2x
                            # |det| / |n| is the distance of p from the triangle's plane
                            if det * det <= tol2 * (nx * nx + ny * ny + nz * nz):
                                u, v, w = closest_point_triangle(p0, p1, p2, A, B, C)
                                dx = u * A[0] + v * B[0] + w * C[0] - p0
                                dy = u * A[1] + v * B[1] + w * C[1] - p1
                                dz = u * A[2] + v * B[2] + w * C[2] - p2
                                if dx * dx + dy * dy + dz * dz <= tol2:
                                    on_surface = True
                else:
                    stack[top] = c
                    stack[top + 1] = c + 1
                    top += 2
            out_winding[i] = total * inv4pi
            out_on_surface[i] = on_surface
