"""Numba kernels of the tetrahedral stable neo-Hookean FEM (Smith, de Goes & Kim 2018).

Per tet: F = sum_a x_a g_a^T with the shape-function gradients G (4, 3) (rows g_a, 1/m), computed at
rest; energy density Psi(F) = mu/2 (tr F^T F - 3) + lam/2 (J - alpha)^2 - mu^2/(2 lam),
alpha = 1 + mu/lam, J = det F (Smith et al. 2018, eq. 14, shifted so that Psi(I) = 0). With
mu = mu_Lame and lam = lambda_Lame + mu_Lame it linearises to linear elasticity with (mu_Lame,
lambda_Lame) -- see headsim.solvers.fem.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _deformation_gradient(positions, tet, grad, out):
    for i in range(3):
        for j in range(3):
            s = 0.0
            for a in range(4):
                s += positions[tet[a], i] * grad[a, j]
            out[i, j] = s


@njit(cache=True)
def _cofactor(f, out):
    # column j of cof(F) = dJ/d(column j): f1 x f2, f2 x f0, f0 x f1
    for j in range(3):
        p = (j + 1) % 3
        q = (j + 2) % 3
        out[0, j] = f[1, p] * f[2, q] - f[2, p] * f[1, q]
        out[1, j] = f[2, p] * f[0, q] - f[0, p] * f[2, q]
        out[2, j] = f[0, p] * f[1, q] - f[1, p] * f[0, q]


@njit(cache=True)
def snh_energy(positions, tets, grads, volumes, mu, lam):
    """Total elastic energy, J. positions (n, 3) m; tets (m, 4); grads (m, 4, 3) 1/m;
    volumes (m,) m^3; mu, lam (m,) Pa. Returns inf if any tet has J <= -1 (hopelessly inverted)."""
    f = np.empty((3, 3))
    c = np.empty((3, 3))
    e = 0.0
    for t in range(tets.shape[0]):
        _deformation_gradient(positions, tets[t], grads[t], f)
        _cofactor(f, c)
        jac = f[0, 0] * c[0, 0] + f[1, 0] * c[1, 0] + f[2, 0] * c[2, 0]
        ic = 0.0
        for i in range(3):
            for j in range(3):
                ic += f[i, j] * f[i, j]
        alpha = 1.0 + mu[t] / lam[t]
        psi = 0.5 * mu[t] * (ic - 3.0) + 0.5 * lam[t] * (jac - alpha) ** 2 - 0.5 * mu[t] * mu[t] / lam[t]
        e += volumes[t] * psi
    return e


@njit(cache=True)
def snh_gradient(positions, tets, grads, volumes, mu, lam, out):
    """Add dE/dx (n, 3), N, into ``out``: V P g_a for each vertex a, P = mu F + lam (J - alpha) cof F."""
    f = np.empty((3, 3))
    c = np.empty((3, 3))
    for t in range(tets.shape[0]):
        _deformation_gradient(positions, tets[t], grads[t], f)
        _cofactor(f, c)
        jac = f[0, 0] * c[0, 0] + f[1, 0] * c[1, 0] + f[2, 0] * c[2, 0]
        s = lam[t] * (jac - 1.0 - mu[t] / lam[t])
        for a in range(4):
            va = tets[t, a]
            for i in range(3):
                g = 0.0
                for j in range(3):
                    g += (mu[t] * f[i, j] + s * c[i, j]) * grads[t, a, j]
                out[va, i] += volumes[t] * g


@njit(cache=True)
def snh_min_jacobian(positions, tets, grads):
    """Smallest det F over all tets (<= 0 means an inverted element)."""
    f = np.empty((3, 3))
    c = np.empty((3, 3))
    jmin = np.inf
    for t in range(tets.shape[0]):
        _deformation_gradient(positions, tets[t], grads[t], f)
        _cofactor(f, c)
        jac = f[0, 0] * c[0, 0] + f[1, 0] * c[1, 0] + f[2, 0] * c[2, 0]
        if jac < jmin:
            jmin = jac
    return jmin


@njit(cache=True)
def snh_hessian_values(positions, tets, grads, volumes, mu, lam, project, out):
    """Element Hessians d2E/dx2 (m, 12, 12), N/m, local dof order (vertex a, component i) -> 3a + i.

    d2Psi/dF2 = mu I + lam vec(cof F) vec(cof F)^T + lam (J - alpha) d2J/dF2 (9 x 9, index 3 i + j
    for F_ij). With ``project`` its negative eigenvalues are clamped to 0 (per element), so the
    assembled Hessian is positive semi-definite (Teran et al. 2005 style projection).
    """
    f = np.empty((3, 3))
    c = np.empty((3, 3))
    A = np.empty((9, 9))
    for t in range(tets.shape[0]):
        _deformation_gradient(positions, tets[t], grads[t], f)
        _cofactor(f, c)
        jac = f[0, 0] * c[0, 0] + f[1, 0] * c[1, 0] + f[2, 0] * c[2, 0]
        s = lam[t] * (jac - 1.0 - mu[t] / lam[t])
        for p in range(9):
            for q in range(9):
                A[p, q] = lam[t] * c[p // 3, p % 3] * c[q // 3, q % 3]
            A[p, p] += mu[t]
        # d2J / dF_ij dF_kl for columns j != l: J = f0 . (f1 x f2); d2J/df_j df_l = eps-type skew of f_m
        for j in range(3):
            for l in range(3):
                if j == l:
                    continue
                m = 3 - j - l
                # sign: +1 if (j, l, m) is an even permutation of (0, 1, 2)
                sign = 1.0 if (l - j) % 3 == 1 else -1.0
                # d2J/d f_j[i] d f_l[k] = sign * eps_{i k n} f_m[n]
                for i in range(3):
                    for k in range(3):
                        if i == k:
                            continue
                        n = 3 - i - k
                        eps = 1.0 if (k - i) % 3 == 1 else -1.0
                        A[3 * i + j, 3 * k + l] += s * sign * eps * f[n, m]
        if project:
            w, vecs = np.linalg.eigh(A)
            for p in range(9):
                if w[p] < 0.0:
                    w[p] = 0.0
            for p in range(9):
                for q in range(9):
                    acc = 0.0
                    for r in range(9):
                        acc += vecs[p, r] * w[r] * vecs[q, r]
                    A[p, q] = acc
        g = grads[t]
        vol = volumes[t]
        for a in range(4):
            for i in range(3):
                for b in range(4):
                    for k in range(3):
                        acc = 0.0
                        for j in range(3):
                            for l in range(3):
                                acc += A[3 * i + j, 3 * k + l] * g[a, j] * g[b, l]
                        out[t, 3 * a + i, 3 * b + k] = vol * acc
