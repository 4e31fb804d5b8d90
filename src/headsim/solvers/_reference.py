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


def bfs_propagate_reference(positions, vertex_ids, colliding, assigned, depth, direction, neighbours):
    """Pure-Python level-synchronous BFS of Heinze eqs. 3.12-3.13 (variant 1); returns new arrays.

    neighbours : list of lists of local ids (springs). Same contract as the Numba kernel
    :func:`headsim.solvers._kernels.contact.bfs_propagate`.
    """
    assigned = assigned.copy()
    depth = depth.copy()
    direction = direction.copy()
    level = [i for i in range(len(vertex_ids)) if assigned[i]]
    queued = set(level)
    while level:
        nxt = []
        for a in level:
            for b in neighbours[a]:
                if colliding[b] and b not in queued:
                    queued.add(b)
                    nxt.append(b)
        for p in nxt:
            xp = positions[vertex_ids[p]]
            ws, ds, rs = 0.0, 0.0, np.zeros(3)
            for q in neighbours[p]:
                if not assigned[q]:
                    continue
                diff = positions[vertex_ids[q]] - xp
                w = 1.0 / np.linalg.norm(diff)  # eq. 3.10
                ds += w * (diff @ direction[q] + depth[q])  # eq. 3.12
                rs += w * direction[q]  # eq. 3.13
                ws += w
            depth[p] = ds / ws
            direction[p] = rs / np.linalg.norm(rs)
        for p in nxt:
            assigned[p] = True
        level = nxt
    return assigned, depth, direction
