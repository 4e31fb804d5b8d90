"""The seed-literal friction programme (Sobottka 2008, eq. 8.62, Alg. 6 line 8) as a linear programme.

Objective: ``min (u^f)ᵀ M u⁺`` — linear in the friction impulse (the kinetic-metric form of 8.62).
Admissible set: the consistent V-representation ``f_α = D_α w_α, w_α ≥ 0, Σ_β w_αβ/μ_β ≤ λ_α``
(eq. 8.51) per active contact, generators as in :class:`headsim.solvers.chains.FrictionLaw`.
The printed H-representation bound of (8.63) restricts only the linear part of M u*, so for a rigid
segment the angular part of the LP is unbounded; we therefore keep the seed's objective and use the
bounded V-representation. Solved per body by HiGHS (``scipy.optimize.linprog``). Being linear, the
programme always saturates the bound (the digest's pitfall: slow sliding is reversed instead of
stopped); the QP objective is the default for that reason.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from headsim.errors import ConvergenceError

__all__ = ["lp_friction", "tangent_frames"]


def tangent_frames(axis: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3), (n, 3): t₁ = axis projected on the tangent plane (unit), t₂ = n × t₁."""
    axis = np.broadcast_to(axis, normal.shape)
    t1 = axis - (axis * normal).sum(1, keepdims=True) * normal
    ln = np.linalg.norm(t1, axis=1, keepdims=True)
    bad = ln[:, 0] < 1e-9
    if bad.any():
        helper = np.where((np.abs(normal[bad, 0]) < 0.9)[:, None], [1.0, 0, 0], [0, 1.0, 0])
        t1[bad] = helper - (helper * normal[bad]).sum(1, keepdims=True) * normal[bad]
        ln[bad] = np.linalg.norm(t1[bad], axis=1, keepdims=True)
    t1 = t1 / ln
    return t1, np.cross(normal, t1)


def lp_friction(bodies, row_off, u_minus, u_plus, model, R, normal, lever, target, lam, mu_cos, mu_sin, options):
    """Add the LP friction impulse to ``u_plus`` (S, 6) for every body with contacts; returns the new array."""
    out = u_plus.copy()
    mu = np.hypot(mu_cos, mu_sin)
    dirs = np.stack([mu_cos / mu, mu_sin / mu], axis=1)
    m = len(mu)
    for q, s in enumerate(bodies):
        a, b = row_off[q], row_off[q + 1]
        act = np.nonzero(lam[a:b] > 0)[0]
        if not len(act):
            continue
        n = normal[a:b][act]
        r = lever[a:b][act]
        t1, t2 = tangent_frames(R[s, :, 2], n)
        u = out[s]
        vt = lambda t, rr: t @ u[:3] + np.cross(rr, t) @ u[3:]  # noqa: E731
        k = len(act)
        c = np.empty(k * m)
        for i in range(k):
            v2 = np.array([vt(t1[i], r[i]), vt(t2[i], r[i])])
            c[i * m:(i + 1) * m] = dirs @ v2  # power of a unit generator force with u⁺
        A = np.zeros((k, k * m))
        for i in range(k):
            A[i, i * m:(i + 1) * m] = 1.0 / mu
        res = linprog(c, A_ub=A, b_ub=lam[a:b][act], bounds=(0, None), method="highs")
        if res.status != 0:
            raise ConvergenceError(f"friction LP of segment {s} failed: {res.message}")
        w = res.x.reshape(k, m)
        Iwi = R[s] @ np.diag(1.0 / model.inertia[s]) @ R[s].T
        for i in range(k):
            f2 = w[i] @ dirs
            f = f2[0] * t1[i] + f2[1] * t2[i]
            out[s, :3] += f / model.mass[s]
            out[s, 3:] += Iwi @ np.cross(r[i], f)
    return out
