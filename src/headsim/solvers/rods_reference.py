"""Slow, readable reference of the rod residual (tests only): NumPy and SciPy, no Numba.

Mirrors :func:`headsim.solvers._kernels.rods.evaluate` equation by equation (Sobottka eqs.
3.61-3.64, 3.153-3.155) so that the fast kernel can be checked against an independent transcription.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def node_terms(x, f, k0, dk0, rhoA, rhoI, K):
    """g(x) (12,) of one node: the non-derivative terms of eqs. 3.61-3.64 (Lambda = -g)."""
    v, w, kap, n = x[0:3], x[3:6], x[6:9], x[9:12]
    e3 = np.array([0.0, 0.0, 1.0])
    m = K * (kap - k0)
    lin = np.cross(kap, n) - rhoA * np.cross(w, v) + f
    ang = -K * dk0 + np.cross(kap, m) + np.cross(e3, n) - np.cross(w, rhoI * w)
    comp = np.cross(kap, w)
    con = np.cross(kap, v) - np.cross(w, e3)
    return np.concatenate([lin, ang, comp, con])


def p_inverse(q, K):
    """P^-1 q: the s-derivative (v', w', kappa', n') from the row vector (lin, ang, comp, con)."""
    return np.concatenate([q[9:12], q[6:9], q[3:6] / K, q[0:3]])


def residual(x, x_old, xt_old, xs_old, g_old, R_old, k0, dk0, fdist, bc, par, scale):
    """Scaled residual (12 (N+1),) with the kernel's packing (see ``_kernels/rods.py``)."""
    nn = x.shape[0]
    ds, dt, rhoA = par[0], par[1], par[2]
    rhoI, K = par[3:6], par[6:9]
    at, bt, gt, as_, bs, gs = par[9:15]
    tip_mode = int(par[18])
    Mdiag = np.concatenate([np.full(3, rhoA), rhoI, np.ones(3), np.zeros(3)])
    R = np.empty((nn, 3, 3))
    xs = np.empty((nn, 12))
    mass_prev = stiff_prev = None
    for j in range(nn):
        theta = 0.5 * dt * (x[j, 3:6] + x_old[j, 3:6])
        R[j] = R_old[j] @ Rotation.from_rotvec(theta).as_matrix()
        f = R[j].T @ fdist[j]
        xt = ((x[j] - x_old[j]) - dt * (1 - gt) * xt_old[j]) / (gt * dt)  # eq. 3.154
        mass = Mdiag * ((1 - at) * xt + at * xt_old[j])
        g = node_terms(x[j], f, k0[j], dk0[j], rhoA, rhoI, K)
        if j == 0:
            stiff = mass
        else:
            stiff = ((1 - as_) * mass + as_ * mass_prev - bs * stiff_prev) / (1 - bs)  # eq. 3.153
        # stiff = P ((1 - bt) xs + bt xs_old) + (1 - bt) g + bt g_old
        xs[j] = (p_inverse(stiff - (1 - bt) * g - bt * g_old[j], K) - bt * xs_old[j]) / (1 - bt)
        mass_prev, stiff_prev = mass, stiff
    F = np.empty(12 * nn)
    for j in range(1, nn):
        link = x[j] - x[j - 1] - ds * (gs * xs[j] + (1 - gs) * xs[j - 1])  # eq. 3.155
        F[6 + 12 * (j - 1):6 + 12 * j] = link / scale
    F[0:3] = (x[0, 0:3] - R[0].T @ bc[0:3]) / scale[0:3]
    F[3:6] = (x[0, 3:6] - R[0].T @ bc[3:6]) / scale[3:6]
    N = nn - 1
    rt = 6 + 12 * N
    if tip_mode == 0:
        F[rt:rt + 3] = (x[N, 6:9] - k0[N] - (R[N].T @ bc[9:12]) / K) / scale[6:9]
        F[rt + 3:rt + 6] = (x[N, 9:12] - R[N].T @ bc[6:9]) / scale[9:12]
    else:
        F[rt:rt + 3] = (x[N, 0:3] - R[N].T @ bc[12:15]) / scale[0:3]
        if tip_mode == 1:
            F[rt + 3:rt + 6] = (x[N, 3:6] - R[N].T @ bc[15:18]) / scale[3:6]
        elif tip_mode == 3:
            F[rt + 3:rt + 5] = (x[N, 3:5] - (R[N].T @ bc[15:18])[0:2]) / scale[3:5]
            F[rt + 5] = (x[N, 8] - k0[N, 2] - (R[N].T @ bc[9:12])[2] / K[2]) / scale[8]
        else:
            F[rt + 3:rt + 6] = (x[N, 6:9] - k0[N] - (R[N].T @ bc[9:12]) / K) / scale[6:9]
    return F
