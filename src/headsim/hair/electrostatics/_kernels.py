"""Numba kernels: charge sampling along fibres, the direct Coulomb sum, and the gather to rod nodes.

All kernels take inputs first and ``out`` last. Charges in C and positions in m; the Coulomb sums
return the field WITHOUT the factor K = 1/(4 pi eps0) (i.e. sum q_j r / |r|^3, C/m^2), which the
callers apply once.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def sample_positions(node_positions, fibre, segment, t, out):
    """Particle positions by linear interpolation between rod nodes (Sobottka §4.3.1).

    node_positions (F, N+1, 3) m; fibre, segment (n,) int64; t (n,) in [0, 1]; out (n, 3) m.
    x = (1 - t) r_j + t r_{j+1} with j = segment.
    """
    for k in prange(fibre.shape[0]):
        f = fibre[k]
        j = segment[k]
        a = 1.0 - t[k]
        b = t[k]
        for c in range(3):
            out[k, c] = a * node_positions[f, j, c] + b * node_positions[f, j + 1, c]


@njit(parallel=True, cache=True)
def gather_node_forces(forces, offsets, segment, t, out):
    """Transpose of :func:`sample_positions`: particle forces -> rod node forces (consistent loads).

    forces (n, 3) N; offsets (F+1,) int64 (particles of fibre f are offsets[f]:offsets[f+1]);
    segment (n,) int64; t (n,); out (F, N+1, 3) N, overwritten. The same virtual work: sum_k f_k . x_k
    = sum_nodes F_node . r_node for every node motion.
    """
    nf = offsets.shape[0] - 1
    for f in prange(nf):
        for j in range(out.shape[1]):
            for c in range(3):
                out[f, j, c] = 0.0
        for k in range(offsets[f], offsets[f + 1]):
            j = segment[k]
            a = 1.0 - t[k]
            b = t[k]
            for c in range(3):
                out[f, j, c] += a * forces[k, c]
                out[f, j + 1, c] += b * forces[k, c]


@njit(parallel=True, fastmath=True, cache=True)
def coulomb_field_direct(targets, sources, charges, out):
    """Exact field sum (Sobottka eq. 4.2 without c0 and q_i): E_i = sum_j q_j (x_i - x_j)/|x_i - x_j|^3.

    targets (m, 3) m; sources (n, 3) m; charges (n,) C; out (m, 3) C/m^2 (multiply by K for V/m).
    Coincident pairs (|r| = 0, in particular a charge and itself) are skipped.
    """
    n = sources.shape[0]
    sx = np.ascontiguousarray(sources[:, 0])
    sy = np.ascontiguousarray(sources[:, 1])
    sz = np.ascontiguousarray(sources[:, 2])
    for i in prange(targets.shape[0]):
        xi = targets[i, 0]
        yi = targets[i, 1]
        zi = targets[i, 2]
        ex = 0.0
        ey = 0.0
        ez = 0.0
        for j in range(n):
            dx = xi - sx[j]
            dy = yi - sy[j]
            dz = zi - sz[j]
            r2 = dx * dx + dy * dy + dz * dz
            if r2 > 0.0:
                w = charges[j] / (r2 * np.sqrt(r2))
                ex += w * dx
                ey += w * dy
                ez += w * dz
        out[i, 0] = ex
        out[i, 1] = ey
        out[i, 2] = ez
