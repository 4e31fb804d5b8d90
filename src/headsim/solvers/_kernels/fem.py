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


@njit(cache=True)
def _sym3_eig(a, w, q):
    """Eigen-decomposition of the symmetric 3 x 3 ``a`` by cyclic Jacobi rotations (no allocation).

    On return w (3,) holds the eigenvalues and the columns of q (3, 3) the orthonormal eigenvectors;
    ``a`` is overwritten.
    """
    for i in range(3):
        for j in range(3):
            q[i, j] = 1.0 if i == j else 0.0
    scale = abs(a[0, 0]) + abs(a[1, 1]) + abs(a[2, 2]) + abs(a[0, 1]) + abs(a[0, 2]) + abs(a[1, 2])
    for sweep in range(30):
        off = abs(a[0, 1]) + abs(a[0, 2]) + abs(a[1, 2])
        if off <= 1e-18 * scale or off == 0.0:
            break
        for p in range(2):
            for r in range(p + 1, 3):
                apr = a[p, r]
                if apr == 0.0:
                    continue
                theta = (a[r, r] - a[p, p]) / (2.0 * apr)
                tt = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(tt * tt + 1.0)
                sn = tt * c
                for k in range(3):  # a <- a J (columns p, r)
                    akp = a[k, p]
                    akr = a[k, r]
                    a[k, p] = c * akp - sn * akr
                    a[k, r] = sn * akp + c * akr
                for k in range(3):  # a <- J^T a (rows p, r)
                    apk = a[p, k]
                    ark = a[r, k]
                    a[p, k] = c * apk - sn * ark
                    a[r, k] = sn * apk + c * ark
                for k in range(3):
                    qkp = q[k, p]
                    qkr = q[k, r]
                    q[k, p] = c * qkp - sn * qkr
                    q[k, r] = sn * qkp + c * qkr
    for i in range(3):
        w[i] = a[i, i]


@njit(cache=True)
def _rotation_variant_svd(f, u, s, v, work, w3):
    """F = U diag(s) V^T with U, V proper rotations (det +1), a reflection in s[2] < 0 (no allocation).

    V: eigenvectors of F^T F (Jacobi), sorted by decreasing eigenvalue; U by Gram-Schmidt of F V
    (u2 = u0 x u1), s_k = u_k . F v_k, so s[2] carries the sign of det F.
    """
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += f[k, i] * f[k, j]
            work[i, j] = acc
    _sym3_eig(work, w3, v)
    # sort descending
    for i in range(2):
        best = i
        for j in range(i + 1, 3):
            if w3[j] > w3[best]:
                best = j
        if best != i:
            tmp = w3[i]
            w3[i] = w3[best]
            w3[best] = tmp
            for k in range(3):
                tmp = v[k, i]
                v[k, i] = v[k, best]
                v[k, best] = tmp
    # V a rotation
    det_v = (v[0, 0] * (v[1, 1] * v[2, 2] - v[2, 1] * v[1, 2]) - v[0, 1] * (v[1, 0] * v[2, 2] - v[2, 0] * v[1, 2])
             + v[0, 2] * (v[1, 0] * v[2, 1] - v[2, 0] * v[1, 1]))
    if det_v < 0.0:
        for k in range(3):
            v[k, 2] = -v[k, 2]
    # F V columns
    for k in range(3):
        for i in range(3):
            work[i, k] = f[i, 0] * v[0, k] + f[i, 1] * v[1, k] + f[i, 2] * v[2, k]
    n0 = np.sqrt(work[0, 0] ** 2 + work[1, 0] ** 2 + work[2, 0] ** 2)
    if n0 > 0.0:
        for i in range(3):
            u[i, 0] = work[i, 0] / n0
    else:
        for i in range(3):
            u[i, 0] = 1.0 if i == 0 else 0.0
    d = u[0, 0] * work[0, 1] + u[1, 0] * work[1, 1] + u[2, 0] * work[2, 1]
    for i in range(3):
        u[i, 1] = work[i, 1] - d * u[i, 0]
    n1 = np.sqrt(u[0, 1] ** 2 + u[1, 1] ** 2 + u[2, 1] ** 2)
    if n1 <= 1e-300 or n1 <= 1e-14 * n0:
        # F v1 ~ 0: any unit vector orthogonal to u0
        k = 0 if abs(u[0, 0]) < 0.9 else 1
        e = np.zeros(3)
        e[k] = 1.0
        d = u[0, 0] * e[0] + u[1, 0] * e[1] + u[2, 0] * e[2]
        for i in range(3):
            u[i, 1] = e[i] - d * u[i, 0]
        n1 = np.sqrt(u[0, 1] ** 2 + u[1, 1] ** 2 + u[2, 1] ** 2)
    for i in range(3):
        u[i, 1] /= n1
    u[0, 2] = u[1, 0] * u[2, 1] - u[2, 0] * u[1, 1]
    u[1, 2] = u[2, 0] * u[0, 1] - u[0, 0] * u[2, 1]
    u[2, 2] = u[0, 0] * u[1, 1] - u[1, 0] * u[0, 1]
    for k in range(3):
        s[k] = u[0, k] * work[0, k] + u[1, k] * work[1, k] + u[2, k] * work[2, k]


@njit(cache=True)
def snh_hessian_values_projected(positions, tets, grads, volumes, mu, lam, out):
    """Element Hessians (m, 12, 12), N/m, projected to PSD through the analytic eigensystem.

    Smith, de Goes & Kim 2018 (stable neo-Hookean, sec. 4.4 / appendix) and Smith, de Goes & Kim 2019
    (analytic eigensystems of isotropic energies): with the rotation-variant SVD F = U diag(s) V^T and
    tau = lam (J - alpha), the 9 x 9 d2Psi/dF2 has the eigenpairs
      twist_k: mu + tau s_k,  vec(U (e_p e_r^T - e_r e_p^T) V^T) / sqrt 2,
      flip_k:  mu - tau s_k,  vec(U (e_p e_r^T + e_r e_p^T) V^T) / sqrt 2,   (p, r) = the other two axes,
      scaling: eigenpairs (w, q) of the 3 x 3 d2Psi/ds2, vec(U diag(q) V^T),
    d2Psi/ds_i2 = mu + lam (J / s_i)^2, d2Psi/ds_i ds_j = lam (J / s_i)(J / s_j) + tau s_k.
    The projected element Hessian is vol sum_m max(w_m, 0) b_m b_m^T with b_m = D^T vec(Q_m) (12,),
    the same matrix as clamping the eigenvalues of the full 9 x 9 (snh_hessian_values), without a
    9 x 9 eigensolve per element.
    """
    f = np.empty((3, 3))
    u = np.empty((3, 3))
    v = np.empty((3, 3))
    s = np.empty(3)
    work = np.empty((3, 3))
    qs = np.empty((3, 3))
    ws = np.empty(3)
    gv = np.empty((4, 3))
    a3 = np.empty((3, 3))
    b = np.empty((9, 12))
    w = np.empty(9)
    r2 = 1.0 / np.sqrt(2.0)
    for t in range(tets.shape[0]):
        _deformation_gradient(positions, tets[t], grads[t], f)
        _rotation_variant_svd(f, u, s, v, work, ws)
        jac = s[0] * s[1] * s[2]
        tau = lam[t] * (jac - 1.0 - mu[t] / lam[t])
        g = grads[t]
        for a in range(4):
            for k in range(3):
                gv[a, k] = g[a, 0] * v[0, k] + g[a, 1] * v[1, k] + g[a, 2] * v[2, k]
        for k in range(3):
            p = (k + 1) % 3
            r = (k + 2) % 3
            w[2 * k] = mu[t] + tau * s[k]
            w[2 * k + 1] = mu[t] - tau * s[k]
            for a in range(4):
                for i in range(3):
                    x1 = u[i, p] * gv[a, r]
                    x2 = u[i, r] * gv[a, p]
                    b[2 * k, 3 * a + i] = r2 * (x1 - x2)
                    b[2 * k + 1, 3 * a + i] = r2 * (x1 + x2)
        # scaling block: partial J / partial s_i = J / s_i written without the division
        ps0 = s[1] * s[2]
        ps1 = s[0] * s[2]
        ps2 = s[0] * s[1]
        ps = (ps0, ps1, ps2)
        for i in range(3):
            for j in range(3):
                if i == j:
                    a3[i, i] = mu[t] + lam[t] * ps[i] * ps[i]
                else:
                    a3[i, j] = lam[t] * ps[i] * ps[j] + tau * s[3 - i - j]
        _sym3_eig(a3, ws, qs)
        for m in range(3):
            w[6 + m] = ws[m]
            for a in range(4):
                for i in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += qs[k, m] * u[i, k] * gv[a, k]
                    b[6 + m, 3 * a + i] = acc
        vol = volumes[t]
        for m in range(9):
            if w[m] < 0.0:
                w[m] = 0.0
            w[m] *= vol
        for p in range(12):
            for q in range(p, 12):
                acc = 0.0
                for m in range(9):
                    acc += w[m] * b[m, p] * b[m, q]
                out[t, p, q] = acc
                out[t, q, p] = acc
