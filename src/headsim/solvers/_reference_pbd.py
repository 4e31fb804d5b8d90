"""Slow, plain NumPy/Python references of the PBD kernels (tests) and a straightforward NumPy PBD loop
(the benchmark baseline). Not for production use."""

from __future__ import annotations

import numpy as np


def project_distance_sequential(edges, rest, w, alpha_tilde, stiffness, lam, p):
    """Gauss–Seidel over the edges in the given order, one Python iteration per edge (in place)."""
    for e, (i, j) in enumerate(edges):
        d = p[i] - p[j]
        length = np.linalg.norm(d)
        wsum = w[i] + w[j]
        if wsum == 0 or length == 0:
            continue
        n = d / length
        dlam = stiffness * (-(length - rest[e]) - alpha_tilde * lam[e]) / (wsum + alpha_tilde)
        lam[e] += dlam
        p[i] += w[i] * dlam * n
        p[j] -= w[j] * dlam * n


def project_distance_jacobi_numpy(edges, rest, w, alpha_tilde, stiffness, omega, lam, p):
    """Jacobi with averaging, vectorised with np.add.at (in place)."""
    i, j = edges[:, 0], edges[:, 1]
    d = p[i] - p[j]
    length = np.linalg.norm(d, axis=1)
    wsum = w[i] + w[j]
    ok = (wsum > 0) & (length > 0)
    n = np.zeros_like(d)
    n[ok] = d[ok] / length[ok, None]
    dlam = np.zeros(len(edges))
    dlam[ok] = stiffness * (-(length[ok] - rest[ok]) - alpha_tilde * lam[ok]) / (wsum[ok] + alpha_tilde)
    lam += dlam
    acc = np.zeros_like(p)
    np.add.at(acc, i, (w[i] * dlam)[:, None] * n)
    np.add.at(acc, j, -(w[j] * dlam)[:, None] * n)
    count = np.bincount(np.concatenate([i, j]), minlength=len(p))
    moving = (count > 0) & (w > 0)
    p[moving] += omega * acc[moving] / count[moving, None]


def volume_and_gradient(p, triangles):
    """Volume sum a.(b x c)/6, m³, and its gradient (n, 3) (Monkin §3)."""
    a, b, c = p[triangles[:, 0]], p[triangles[:, 1]], p[triangles[:, 2]]
    vol = float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)
    grad = np.zeros_like(p)
    np.add.at(grad, triangles[:, 0], np.cross(b, c) / 6.0)
    np.add.at(grad, triangles[:, 1], np.cross(c, a) / 6.0)
    np.add.at(grad, triangles[:, 2], np.cross(a, b) / 6.0)
    return vol, grad


def project_volume_numpy(triangles, target, w, alpha_tilde, lam, p):
    """One projection of a single body's volume constraint (in place); returns the new multiplier."""
    vol, grad = volume_and_gradient(p, triangles)
    on = np.zeros(len(p), bool)
    on[triangles.ravel()] = True
    denom = float(np.sum(w[on] * np.sum(grad[on] ** 2, axis=1)))
    dlam = (-(vol - target) - alpha_tilde * lam) / (denom + alpha_tilde)
    p[on] += (w[on] * dlam)[:, None] * grad[on]
    return lam + dlam


def numpy_pbd_solve(positions, edges, rest, w, triangles, target, *, dt, iterations, damping, edge_compliance,
                    stop_tolerance, max_steps, omega=1.0, stop_patience=1):
    """Straightforward NumPy PBD/XPBD loop (Jacobi edges + one volume constraint, no gravity), to the stop
    rule of Monkin §4.4 (held on ``stop_patience`` consecutive steps). Returns (positions, steps)."""
    x = np.array(positions, dtype=float)
    v = np.zeros_like(x)
    at_e = edge_compliance / dt**2
    previous = np.abs(x).sum()
    quiet = 0
    for step in range(1, max_steps + 1):
        p = x + dt * v
        lam_e = np.zeros(len(edges))
        lam_v = 0.0
        for _ in range(iterations):
            project_distance_jacobi_numpy(edges, rest, w, at_e, 1.0, omega, lam_e, p)
            lam_v = project_volume_numpy(triangles, target, w, 0.0, lam_v, p)
        v = (1.0 - damping) * (p - x) / dt
        x = p
        current = np.abs(x).sum()
        quiet = quiet + 1 if abs(current - previous) < stop_tolerance * len(x) else 0
        if step >= 3 and quiet >= stop_patience:
            return x, step
        previous = current
    return x, max_steps
