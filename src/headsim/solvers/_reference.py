"""Slow reference implementations (pure NumPy / finite differences), used by the tests only."""

from __future__ import annotations

import numpy as np


def spring_damper_forces_reference(positions, velocities, edges, rest_length, stiffness, damping):
    """Heinze eqs. 2.4-2.8, vectorised NumPy: (n, 3) N."""
    d = positions[edges[:, 1]] - positions[edges[:, 0]]
    length = np.linalg.norm(d, axis=1)
    r = d / length[:, None]  # eq. 2.4
    dv = velocities[edges[:, 1]] - velocities[edges[:, 0]]
    f = (stiffness * (length - rest_length) + damping * np.einsum("ij,ij->i", dv, r))[:, None] * r  # 2.5, 2.7
    out = np.zeros_like(positions)
    np.add.at(out, edges[:, 0], f)  # eqs. 2.6, 2.8
    np.add.at(out, edges[:, 1], -f)
    return out


def snh_energy_reference(positions, rest_positions, tets, mu_lame, lambda_lame):
    """Stable neo-Hookean energy (Smith et al. 2018, eq. 14) per tet with explicit Dm^-1, J."""
    x, X, t = positions, rest_positions, tets
    dm = np.stack([X[t[:, k]] - X[t[:, 0]] for k in (1, 2, 3)], axis=2)
    ds = np.stack([x[t[:, k]] - x[t[:, 0]] for k in (1, 2, 3)], axis=2)
    f = ds @ np.linalg.inv(dm)
    vol = np.linalg.det(dm) / 6.0
    mu = np.broadcast_to(mu_lame, (len(t),))
    lam = np.broadcast_to(lambda_lame, (len(t),)) + mu
    alpha = 1.0 + mu / lam
    psi = 0.5 * mu * (np.einsum("tij,tij->t", f, f) - 3) + 0.5 * lam * (np.linalg.det(f) - alpha) ** 2 \
        - 0.5 * mu**2 / lam
    return float(np.sum(vol * psi))


def finite_difference_gradient(fun, x, h=1e-7):
    """Central differences of a scalar function of an (n, 3) array."""
    g = np.zeros_like(x)
    for i in range(x.shape[0]):
        for c in range(x.shape[1]):
            xp = x.copy()
            xp[i, c] += h
            xm = x.copy()
            xm[i, c] -= h
            g[i, c] = (fun(xp) - fun(xm)) / (2 * h)
    return g
