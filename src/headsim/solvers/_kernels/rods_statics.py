"""Numba kernels of the static rod solvers (Sobottka 2008, §3.3.2): energy and its adjoint gradient
over piecewise-constant segment curvatures, and Pai's two-phase explicit integration."""

from __future__ import annotations

import numpy as np
from numba import njit

from headsim.solvers._kernels.rods import (
    _matmul3,
    arc_chord,
    integrate_frames,
    right_jacobian_into,
    rodrigues_into,
)

# 3-point Gauss-Legendre on [0, 1]
_GL_X = np.array([0.5 - 0.5 * np.sqrt(0.6), 0.5, 0.5 + 0.5 * np.sqrt(0.6)])
_GL_W = np.array([5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0])


@njit(cache=True)
def chord_jacobian(kappa, ds, gx, gw, out):
    """d chord / d kappa (3, 3) of :func:`arc_chord`: -int_0^ds sigma exp(sigma K) hat(e3) J_r(sigma kappa) d sigma
    (Gauss-Legendre, 3 points)."""
    out[:, :] = 0.0
    th = np.empty(3)
    E = np.empty((3, 3))
    J = np.empty((3, 3))
    for q in range(3):
        sg = ds * gx[q]
        for c in range(3):
            th[c] = sg * kappa[c]
        rodrigues_into(th, E)
        right_jacobian_into(th, J)
        # hat(e3) J: rows (-J[1], J[0], 0)
        for i in range(3):
            for b in range(3):
                hj = -E[i, 0] * J[1, b] + E[i, 1] * J[0, b]
                out[i, b] -= ds * gw[q] * sg * hj


@njit(cache=True)
def static_energy_gradient(kappa, k0, K, ds, R0, r0, Fnodes, gx, gw, grad, R, r):
    """Total potential energy (J) of a rod with constant curvature kappa_k (N, 3) on segment k and
    its exact gradient (adjoint, O(N)) into grad (N, 3) (Sobottka eqs. 3.130-3.135; loads in the
    GLOBAL frame, so no follower loads).

    E = sum_k ds/2 (kappa_k - k0_k)^T K (kappa_k - k0_k) - sum_i F_i . r_i
    k0 (N, 3) natural curvature per segment; K (3,) N m^2; ds m; R0 (3, 3), r0 (3,) root;
    Fnodes (N+1, 3) N, nodal dead loads (gravity lumped, point and tip forces);
    outputs R (N+1, 3, 3), r (N+1, 3).
    """
    N = kappa.shape[0]
    R[0] = R0
    r[0] = r0
    th = np.empty(3)
    E = np.empty((3, 3))
    for k in range(N):
        for c in range(3):
            th[c] = ds * kappa[k, c]
        ch = arc_chord(kappa[k], ds)
        for c in range(3):
            r[k + 1, c] = r[k, c] + R[k, c, 0] * ch[0] + R[k, c, 1] * ch[1] + R[k, c, 2] * ch[2]
        rodrigues_into(th, E)
        _matmul3(R[k], E, R[k + 1])
    energy = 0.0
    for k in range(N):
        for c in range(3):
            d = kappa[k, c] - k0[k, c]
            energy += 0.5 * ds * K[c] * d * d
    for i in range(N + 1):
        energy -= Fnodes[i, 0] * r[i, 0] + Fnodes[i, 1] * r[i, 1] + Fnodes[i, 2] * r[i, 2]
    # backward sums: S = sum_{l >= i} F_l, C = sum_{l >= i} r_l x F_l
    S = np.zeros(3)
    C = np.zeros(3)
    J = np.empty((3, 3))
    Jc = np.empty((3, 3))
    M = np.empty(3)
    a = np.empty(3)
    for k in range(N - 1, -1, -1):
        i = k + 1
        for c in range(3):
            S[c] += Fnodes[i, c]
        C[0] += r[i, 1] * Fnodes[i, 2] - r[i, 2] * Fnodes[i, 1]
        C[1] += r[i, 2] * Fnodes[i, 0] - r[i, 0] * Fnodes[i, 2]
        C[2] += r[i, 0] * Fnodes[i, 1] - r[i, 1] * Fnodes[i, 0]
        # moment about r_{k+1} of the loads beyond it
        M[0] = C[0] - (r[i, 1] * S[2] - r[i, 2] * S[1])
        M[1] = C[1] - (r[i, 2] * S[0] - r[i, 0] * S[2])
        M[2] = C[2] - (r[i, 0] * S[1] - r[i, 1] * S[0])
        for c in range(3):
            th[c] = ds * kappa[k, c]
        right_jacobian_into(th, J)
        # a = R_{k+1}^T M
        for c in range(3):
            a[c] = R[i, 0, c] * M[0] + R[i, 1, c] * M[1] + R[i, 2, c] * M[2]
        chord_jacobian(kappa[k], ds, gx, gw, Jc)
        # b = R_k^T S
        b0 = R[k, 0, 0] * S[0] + R[k, 1, 0] * S[1] + R[k, 2, 0] * S[2]
        b1 = R[k, 0, 1] * S[0] + R[k, 1, 1] * S[1] + R[k, 2, 1] * S[2]
        b2 = R[k, 0, 2] * S[0] + R[k, 1, 2] * S[1] + R[k, 2, 2] * S[2]
        for c in range(3):
            g = ds * K[c] * (kappa[k, c] - k0[k, c])
            g -= ds * (J[0, c] * a[0] + J[1, c] * a[1] + J[2, c] * a[2])
            g -= Jc[0, c] * b0 + Jc[1, c] * b1 + Jc[2, c] * b2
            grad[k, c] = g
    return energy


@njit(cache=True)
def pai_integrate(k0, K, ds, R0, r0, f_local, l_local, tip_force_local, tip_torque_local, kappa, n, R, r):
    """Pai (2002) two-phase explicit integration (Sobottka eqs. 3.128/3.129, signs re-derived from
    n' + kappa x n + f = 0 and m' + kappa x m + e3 x n + l = 0): contact force and moment from the tip
    to the root with ALL loads in local frames (hence follower loads), then frames and centreline
    from the root to the tip by exponential maps.

    k0 (N+1, 3); K (3,); f_local, l_local (N+1, 3) per length; tip loads (3,) local;
    outputs kappa, n (N+1, 3), R (N+1, 3, 3), r (N+1, 3).
    """
    nn = k0.shape[0]
    N = nn - 1
    m = np.empty(3)
    for c in range(3):
        n[N, c] = tip_force_local[c]
        m[c] = tip_torque_local[c]
        kappa[N, c] = k0[N, c] + m[c] / K[c]
    for i in range(N, 0, -1):
        kn0 = kappa[i, 1] * n[i, 2] - kappa[i, 2] * n[i, 1]
        kn1 = kappa[i, 2] * n[i, 0] - kappa[i, 0] * n[i, 2]
        kn2 = kappa[i, 0] * n[i, 1] - kappa[i, 1] * n[i, 0]
        km0 = kappa[i, 1] * m[2] - kappa[i, 2] * m[1]
        km1 = kappa[i, 2] * m[0] - kappa[i, 0] * m[2]
        km2 = kappa[i, 0] * m[1] - kappa[i, 1] * m[0]
        # e3 x n = (-n1, n0, 0)
        m0 = m[0] + ds * (km0 - n[i, 1] + l_local[i, 0])
        m1 = m[1] + ds * (km1 + n[i, 0] + l_local[i, 1])
        m2 = m[2] + ds * (km2 + l_local[i, 2])
        n[i - 1, 0] = n[i, 0] + ds * (kn0 + f_local[i, 0])
        n[i - 1, 1] = n[i, 1] + ds * (kn1 + f_local[i, 1])
        n[i - 1, 2] = n[i, 2] + ds * (kn2 + f_local[i, 2])
        m[0], m[1], m[2] = m0, m1, m2
        for c in range(3):
            kappa[i - 1, c] = k0[i - 1, c] + m[c] / K[c]
    integrate_frames(R0, kappa, ds, R, r0, r)
