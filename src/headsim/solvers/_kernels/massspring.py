"""Numba kernels of the mass-spring-damper model (Heinze eqs. 2.2-2.8)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def spring_damper_forces(positions, velocities, edges, rest_length, stiffness, damping, out):
    """Add spring and parallel damper forces into ``out`` (Heinze eqs. 2.4-2.8).

    positions (n, 3) m; velocities (n, 3) m/s; edges (s, 2) int64; rest_length (s,) m;
    stiffness (s,) N/m; damping (s,) N s/m; out (n, 3) N (added to).
    A zero-length spring contributes no force (its direction is undefined).
    """
    for k in range(edges.shape[0]):
        i = edges[k, 0]
        j = edges[k, 1]
        d0 = positions[j, 0] - positions[i, 0]
        d1 = positions[j, 1] - positions[i, 1]
        d2 = positions[j, 2] - positions[i, 2]
        length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if length == 0.0:
            continue
        r0 = d0 / length  # eq. 2.4
        r1 = d1 / length
        r2 = d2 / length
        vrel = ((velocities[j, 0] - velocities[i, 0]) * r0 + (velocities[j, 1] - velocities[i, 1]) * r1
                + (velocities[j, 2] - velocities[i, 2]) * r2)
        s = stiffness[k] * (length - rest_length[k]) + damping[k] * vrel  # eqs. 2.5, 2.7
        out[i, 0] += s * r0  # F on i; eqs. 2.6, 2.8: the opposite on j
        out[i, 1] += s * r1
        out[i, 2] += s * r2
        out[j, 0] -= s * r0
        out[j, 1] -= s * r1
        out[j, 2] -= s * r2


@njit(cache=True)
def spring_energy(positions, edges, rest_length, stiffness):
    """Elastic energy sum_k k (l - l0)^2 / 2, J.  positions (n, 3) m."""
    e = 0.0
    for k in range(edges.shape[0]):
        i = edges[k, 0]
        j = edges[k, 1]
        d0 = positions[j, 0] - positions[i, 0]
        d1 = positions[j, 1] - positions[i, 1]
        d2 = positions[j, 2] - positions[i, 2]
        length = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        e += 0.5 * stiffness[k] * (length - rest_length[k]) ** 2
    return e


@njit(cache=True)
def spring_hessian_blocks(positions, edges, rest_length, stiffness, project, out):
    """3x3 stiffness block K_k of every spring, written into ``out`` (s, 3, 3), N/m.

    K = k [r r^T + (1 - l0/l)(I - r r^T)] (second derivative of k (l - l0)^2 / 2 w.r.t. x_j); the
    6x6 spring Hessian is [[K, -K], [-K, K]]. With ``project`` the factor (1 - l0/l) is clamped at
    0, which makes K (and the assembled Hessian) positive semi-definite for Newton's method.
    """
    for k in range(edges.shape[0]):
        i = edges[k, 0]
        j = edges[k, 1]
        d = np.empty(3)
        for c in range(3):
            d[c] = positions[j, c] - positions[i, c]
        length = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if length == 0.0:
            for a in range(3):
                for b in range(3):
                    out[k, a, b] = stiffness[k] if a == b else 0.0
            continue
        t = 1.0 - rest_length[k] / length
        if project and t < 0.0:
            t = 0.0
        for a in range(3):
            for b in range(3):
                rr = d[a] * d[b] / (length * length)
                out[k, a, b] = stiffness[k] * (rr + t * ((1.0 if a == b else 0.0) - rr))


@njit(cache=True)
def explicit_euler_step(positions, velocities, mass, fixed, forces, dt, out_positions, out_velocities):
    """Heinze eqs. 3.1-3.2: v' = v + dt F/m, x' = x + dt v (old velocity), into new buffers.

    positions, velocities, forces (n, 3); mass (n,) kg; fixed (n,) bool (kept in place, v = 0);
    out_positions, out_velocities (n, 3) written. The forces were all computed from the old state.
    """
    for i in range(positions.shape[0]):
        if fixed[i]:
            for c in range(3):
                out_positions[i, c] = positions[i, c]
                out_velocities[i, c] = 0.0
            continue
        for c in range(3):
            out_velocities[i, c] = velocities[i, c] + dt * forces[i, c] / mass[i]  # eq. 3.1
            out_positions[i, c] = positions[i, c] + dt * velocities[i, c]  # eq. 3.2
