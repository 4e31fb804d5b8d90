"""Numba kernels of the implicit Kirchhoff rod (Sobottka 2008, ch. 3, §3.4).

State per node x = (v, omega, kappa, n) in local (material) components, index layout
``x[0:3] = v`` (m/s), ``x[3:6] = omega`` (1/s), ``x[6:9] = kappa`` (1/m), ``x[9:12] = n`` (N).
Equation rows use the same index ranges: rows 0:3 linear momentum (eq. 3.61), rows 3:6 angular
momentum (eq. 3.62, Euler-form gyroscopic terms), rows 6:9 compatibility (eq. 3.63), rows 9:12
inextensibility / unshearability (eq. 3.64: d_s v + kappa x v - omega x e3 = 0).

Each node satisfies ``Mhat dx/dt - P dx/ds - g(x) = 0`` (eq. 3.66 with Lambda = -g), where
``Mhat = diag(rhoA, rhoI, 1, 0)`` acts row-wise on the same components, and ``P`` moves the
s-derivative into its row: lin <- n', ang <- K kappa', compat <- omega', constraint <- v'.

Packed parameter vector ``par`` (float64):
  0 ds, 1 dt, 2 rhoA, 3:6 rhoI (I1, I2, I3 times rho), 6:9 K = (EI1, EI2, GJ),
  9 alpha_t, 10 beta_t, 11 gamma_t, 12 alpha_s, 13 beta_s, 14 gamma_s,
  15 tolerance (scaled max-norm of the residual), 16 max_iterations, 17 armijo iota,
  18 tip_mode (0: force/torque tip, 1: prescribed tip velocity and angular velocity,
  2: prescribed tip velocity and tip torque, 3: prescribed tip velocity, transverse angular
  velocity (omega1, omega2) and axial torque m3, 4: as 3 but the tip POSITION prescribed instead of
  its velocity, 5: tip position and tip angular velocity prescribed), 19 max_halvings, 20 frame map of the position integration (1: Cayley, 0: exp)
Packed boundary vector ``bc`` (float64, global components, held constant over the step):
  0:3 root velocity, 3:6 root angular velocity, 6:9 tip force, 9:12 tip torque,
  12:15 tip velocity (tip_modes 4, 5: tip position at the end of the step, m), 15:18 tip angular
  velocity, 18:21 root position at the start of the step (m; used by tip_modes 4, 5)

Tip mode 4 is the seed's "geometric (point-to-point) boundary condition" (§3.4.7: positions are
recomputed inside the Newton loop). The tip position depends on the curvature of every node, so its
three Jacobian rows are dense: the banded matrix holds identity rows on v_N in their place and the
dense rows W (3, 12 (N+1)) are added by the Sherman-Morrison-Woodbury identity (three extra banded
solves per factorisation and a 3 x 3 system).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

NPAR = 21
NBC = 21


@njit(cache=True, inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True)
def hat_into(v, out):
    """Skew matrix of v (3,) into out (3, 3): hat(v) @ w = v x w."""
    out[0, 0] = 0.0
    out[0, 1] = -v[2]
    out[0, 2] = v[1]
    out[1, 0] = v[2]
    out[1, 1] = 0.0
    out[1, 2] = -v[0]
    out[2, 0] = -v[1]
    out[2, 1] = v[0]
    out[2, 2] = 0.0


@njit(cache=True)
def rodrigues_into(theta, out):
    """Exponential map exp(hat(theta)) (Sobottka eq. 3.162, with the corrected (1 - cos) factor)
    into out (3, 3); theta (3,) rad. Uses hat(t)^2 = t t^T - |t|^2 I."""
    t2 = theta[0] * theta[0] + theta[1] * theta[1] + theta[2] * theta[2]
    if t2 < 1e-8:
        a = 1.0 - t2 / 6.0 + t2 * t2 / 120.0
        b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0
    else:
        t = np.sqrt(t2)
        a = np.sin(t) / t
        b = (1.0 - np.cos(t)) / t2
    for i in range(3):
        for j in range(3):
            out[i, j] = b * theta[i] * theta[j]
        out[i, i] += 1.0 - b * t2
    out[0, 1] -= a * theta[2]
    out[0, 2] += a * theta[1]
    out[1, 0] += a * theta[2]
    out[1, 2] -= a * theta[0]
    out[2, 0] -= a * theta[1]
    out[2, 1] += a * theta[0]


@njit(cache=True)
def rodrigues(theta):
    """Exponential map exp(hat(theta)) as a new (3, 3) array."""
    out = np.empty((3, 3))
    rodrigues_into(theta, out)
    return out


@njit(cache=True, inline="always")
def so3_jacobian_coefficients(t2):
    """(a, b) of the SO(3) Jacobians J_l(θ) = E + a θ̃ + b θ̃², J_r(θ) = J_l(−θ), for t2 = |θ|²:
    a = (1 − cos t)/t², b = (t − sin t)/t³ (their series below t = 1e-4)."""
    if t2 < 1e-8:
        return 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0
    t = np.sqrt(t2)
    return (1.0 - np.cos(t)) / t2, (t - np.sin(t)) / (t2 * t)


@njit(cache=True)
def right_jacobian_into(theta, out):
    """Right Jacobian of SO(3) into out (3, 3): exp(hat(theta + d)) ~= exp(hat(theta)) exp(hat(J_r d))."""
    t2 = theta[0] * theta[0] + theta[1] * theta[1] + theta[2] * theta[2]
    a, b = so3_jacobian_coefficients(t2)
    for i in range(3):
        for j in range(3):
            out[i, j] = b * theta[i] * theta[j]
        out[i, i] += 1.0 - b * t2
    out[0, 1] += a * theta[2]
    out[0, 2] -= a * theta[1]
    out[1, 0] -= a * theta[2]
    out[1, 2] += a * theta[0]
    out[2, 0] += a * theta[1]
    out[2, 1] -= a * theta[0]


@njit(cache=True)
def right_jacobian(theta):
    """Right Jacobian of SO(3) as a new (3, 3) array."""
    out = np.empty((3, 3))
    right_jacobian_into(theta, out)
    return out


@njit(cache=True, inline="always")
def _matmul3(A, B, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True)
def arc_chord(kappa, ds):
    """Integral of exp(sigma hat(kappa)) e3 over sigma in [0, ds]: the chord of a constant-curvature
    segment in its start frame (3,), m. kappa (3,) 1/m."""
    k2 = kappa[0] * kappa[0] + kappa[1] * kappa[1] + kappa[2] * kappa[2]
    k = np.sqrt(k2)
    th = k * ds
    if th < 1e-3:
        c1 = ds * ds * (0.5 - th * th / 24.0)
        c2 = ds * ds * ds * (1.0 / 6.0 - th * th / 120.0)
    else:
        c1 = (1.0 - np.cos(th)) / k2
        c2 = (ds - np.sin(th) / k) / k2
    # hat(kappa) e3 = (kappa1, -kappa0, 0); hat(kappa)^2 e3 = kappa (kappa.e3) - k2 e3
    out = np.empty(3)
    out[0] = c1 * kappa[1] + c2 * kappa[0] * kappa[2]
    out[1] = -c1 * kappa[0] + c2 * kappa[1] * kappa[2]
    out[2] = ds + c2 * (kappa[2] * kappa[2] - k2)
    return out


@njit(cache=True)
def node_g(x, f, l, k0, dk0, rhoA, rhoI, K, out):
    """Non-derivative terms g(x) of one node (Sobottka eqs. 3.61-3.64, 3.67 with Lambda = -g).

    x (12,) state; f (3,) N/m and l (3,) N m/m local body force and couple; k0, dk0 (3,) natural
    curvature 1/m and its s-derivative 1/m^2; rhoA kg/m; rhoI (3,) kg m; K (3,) N m^2; out (12,).
    """
    v0, v1, v2 = x[0], x[1], x[2]
    w0, w1, w2 = x[3], x[4], x[5]
    k_0, k_1, k_2 = x[6], x[7], x[8]
    n0, n1, n2 = x[9], x[10], x[11]
    a0, a1, a2 = _cross(k_0, k_1, k_2, n0, n1, n2)
    b0, b1, b2 = _cross(w0, w1, w2, v0, v1, v2)
    out[0] = a0 - rhoA * b0 + f[0]
    out[1] = a1 - rhoA * b1 + f[1]
    out[2] = a2 - rhoA * b2 + f[2]
    m0 = K[0] * (k_0 - k0[0])
    m1 = K[1] * (k_1 - k0[1])
    m2 = K[2] * (k_2 - k0[2])
    c0, c1, c2 = _cross(k_0, k_1, k_2, m0, m1, m2)
    h0, h1, h2 = rhoI[0] * w0, rhoI[1] * w1, rhoI[2] * w2
    d0, d1, d2 = _cross(w0, w1, w2, h0, h1, h2)
    out[3] = -K[0] * dk0[0] + c0 - n1 - d0 + l[0]
    out[4] = -K[1] * dk0[1] + c1 + n0 - d1 + l[1]
    out[5] = -K[2] * dk0[2] + c2 - d2 + l[2]
    e0, e1, e2 = _cross(k_0, k_1, k_2, w0, w1, w2)
    out[6] = e0
    out[7] = e1
    out[8] = e2
    p0, p1, p2 = _cross(k_0, k_1, k_2, v0, v1, v2)
    out[9] = p0 - w1
    out[10] = p1 + w0
    out[11] = p2


@njit(cache=True, inline="always")
def _add_hat(v, scale, out, r0, c0):
    """out[r0:r0+3, c0:c0+3] += scale * hat(v)."""
    out[r0, c0 + 1] -= scale * v[2]
    out[r0, c0 + 2] += scale * v[1]
    out[r0 + 1, c0] += scale * v[2]
    out[r0 + 1, c0 + 2] -= scale * v[0]
    out[r0 + 2, c0] -= scale * v[1]
    out[r0 + 2, c0 + 1] += scale * v[0]


@njit(cache=True, inline="always")
def _add_hat_times(v, J, out, r0, c0):
    """out[r0:r0+3, c0:c0+3] += hat(v) @ J."""
    for b in range(3):
        c0_, c1_, c2_ = _cross(v[0], v[1], v[2], J[0, b], J[1, b], J[2, b])
        out[r0, c0 + b] += c0_
        out[r0 + 1, c0 + b] += c1_
        out[r0 + 2, c0 + b] += c2_


@njit(cache=True)
def node_dg(x, f, l, k0, Jload, rhoA, rhoI, K, out):
    """Analytic Jacobian dg/dx (12, 12) of :func:`node_g` into out.

    Jload (3, 3): d(local load)/d(omega) factor, i.e. d f_loc / d omega = hat(f_loc) @ Jload
    (Jload = J_r(theta) dt/2 for loads rotated by the step's exponential map; zero if fixed).
    """
    out[:, :] = 0.0
    v = x[0:3]
    w = x[3:6]
    kap = x[6:9]
    n = x[9:12]
    m0 = K[0] * (kap[0] - k0[0])
    m1 = K[1] * (kap[1] - k0[1])
    m2 = K[2] * (kap[2] - k0[2])
    # linear momentum: kappa x n - rhoA w x v + f
    _add_hat(n, -1.0, out, 0, 6)
    _add_hat(kap, 1.0, out, 0, 9)
    _add_hat(v, rhoA, out, 0, 3)
    _add_hat(w, -rhoA, out, 0, 0)
    _add_hat_times(f, Jload, out, 0, 3)
    # angular momentum: kappa x m + e3 x n - w x (rhoI w) + l
    # d(kappa x m)/dkappa = hat(kappa) K - hat(m)
    out[3, 7] += -kap[2] * K[1]
    out[3, 8] += kap[1] * K[2]
    out[4, 6] += kap[2] * K[0]
    out[4, 8] += -kap[0] * K[2]
    out[5, 6] += -kap[1] * K[0]
    out[5, 7] += kap[0] * K[1]
    out[3, 7] += m2
    out[3, 8] -= m1
    out[4, 6] -= m2
    out[4, 8] += m0
    out[5, 6] += m1
    out[5, 7] -= m0
    out[3, 10] -= 1.0
    out[4, 9] += 1.0
    # d(-w x (rhoI w))/dw = -hat(w) rhoI + hat(rhoI w)
    h0, h1, h2 = rhoI[0] * w[0], rhoI[1] * w[1], rhoI[2] * w[2]
    out[3, 4] += w[2] * rhoI[1] - h2
    out[3, 5] += -w[1] * rhoI[2] + h1
    out[4, 3] += -w[2] * rhoI[0] + h2
    out[4, 5] += w[0] * rhoI[2] - h0
    out[5, 3] += w[1] * rhoI[0] - h1
    out[5, 4] += -w[0] * rhoI[1] + h0
    _add_hat_times(l, Jload, out, 3, 3)
    # compatibility: kappa x w
    _add_hat(w, -1.0, out, 6, 6)
    _add_hat(kap, 1.0, out, 6, 3)
    # constraint: kappa x v - w x e3
    _add_hat(v, -1.0, out, 9, 6)
    _add_hat(kap, 1.0, out, 9, 0)
    out[9, 4] -= 1.0
    out[10, 3] += 1.0


@njit(cache=True)
def apply_pinv(q, K, out):
    """out = P^-1 q for q (12,): v' = q[9:12], omega' = q[6:9], kappa' = q[3:6]/K, n' = q[0:3]."""
    for i in range(3):
        out[i] = q[9 + i]
        out[3 + i] = q[6 + i]
        out[6 + i] = q[3 + i] / K[i]
        out[9 + i] = q[i]


@njit(cache=True, fastmath=True)
def banded_factor(band, kl, ku, piv):
    """In-place LU factorisation with partial pivoting of a band matrix (LAPACK dgbtf2 convention:
    multipliers stay where they were computed, later row swaps touch only columns to the right).

    band (n, 2 kl + ku + 1): band[i, c] = A[i, i - kl + c] (filled up to column i + ku; the extra
    kl columns hold fill-in); piv (n,) int64 out. Returns False if a pivot is zero.
    """
    n = band.shape[0]
    w = band.shape[1]
    prow = np.empty(w)
    for k in range(n):
        last = min(n - 1, k + kl)
        p = k
        best = abs(band[k, kl])
        for r in range(k + 1, last + 1):
            val = abs(band[r, k - r + kl])
            if val > best:
                best = val
                p = r
        piv[k] = p
        if best == 0.0:
            return False
        jmax = min(n, k + kl + ku + 1)
        if p != k:
            for j in range(k, jmax):
                ck = j - k + kl
                cp = j - p + kl
                tmp = band[k, ck]
                band[k, ck] = band[p, cp] if cp < w else 0.0
                if cp < w:
                    band[p, cp] = tmp
        piv_val = band[k, kl]
        m = jmax - k - 1
        for t in range(m):
            prow[t] = band[k, kl + 1 + t]
        for r in range(k + 1, last + 1):
            fac = band[r, k - r + kl] / piv_val
            band[r, k - r + kl] = fac  # multiplier, kept for the solves
            if fac != 0.0:
                br = band[r]
                c0 = k + 1 - r + kl
                for t in range(m):
                    br[c0 + t] -= fac * prow[t]
    return True


@njit(cache=True)
def banded_lu_solve(band, piv, kl, ku, rhs, out):
    """Solve with the factors of :func:`banded_factor`; rhs (n,) is overwritten; solution in out."""
    n = band.shape[0]
    for k in range(n):
        p = piv[k]
        if p != k:
            tmp = rhs[k]
            rhs[k] = rhs[p]
            rhs[p] = tmp
        rk = rhs[k]
        if rk != 0.0:
            for r in range(k + 1, min(n - 1, k + kl) + 1):
                rhs[r] -= band[r, k - r + kl] * rk
    for k in range(n - 1, -1, -1):
        s = rhs[k]
        jmax = min(n, k + kl + ku + 1)
        for j in range(k + 1, jmax):
            s -= band[k, j - k + kl] * out[j]
        out[k] = s / band[k, kl]


@njit(cache=True)
def banded_solve(band, rhs, kl, ku, out):
    """Solve A y = rhs (band storage of :func:`banded_factor`); overwrites band and rhs.
    Returns False if a pivot is zero."""
    piv = np.empty(band.shape[0], dtype=np.int64)
    if not banded_factor(band, kl, ku, piv):
        return False
    banded_lu_solve(band, piv, kl, ku, rhs, out)
    return True


KL = 17
KU = 17
BAND_WIDTH = 2 * KL + KU + 1


@njit(cache=True)
def _segment_map(kappa_mean, ds, cayley, E, chord):
    """Rotation E (3, 3) and chord (3,) (in the segment's start frame) of one segment with mean
    curvature kappa_mean (3,), for the exp or the Cayley frame map (see :func:`integrate_frames`)."""
    ka = np.empty(3)
    sc = 1.0
    if cayley:
        sc = cayley_angle_scale(ds * np.sqrt(kappa_mean[0] ** 2 + kappa_mean[1] ** 2 + kappa_mean[2] ** 2))
    th = np.empty(3)
    for c in range(3):
        ka[c] = sc * kappa_mean[c]
        th[c] = ds * ka[c]
    rodrigues_into(th, E)
    ch = arc_chord(ka, ds)
    for c in range(3):
        chord[c] = ch[c]


@njit(cache=True)
def tip_position_rows(x, x_old, R, R_old, bc, par, want_jac, F, band, W, rt, ct):
    """Rows rt..rt+2 of tip_modes 4 and 5: (r_N(x) - r_target) / ds, with r_N integrated in s from the root
    point (eq. 3.165 with the iterate's root velocity) and the iterate's root frame along the
    iterate's curvature. Jacobian: identity stand-in on v_N in ``band`` and the dense correction W
    (d r_N / d kappa_j by central differences per segment, O(N); root terms analytic)."""
    nn = x.shape[0]
    N = nn - 1
    ds = par[0]
    dt = par[1]
    cay = par[20] > 0.5
    Rs = np.empty((nn, 3, 3))
    rs = np.empty((nn, 3))
    Es = np.empty((nn, 3, 3))
    chs = np.empty((nn, 3))
    ka = np.empty(3)
    for c in range(3):
        vn = 0.0
        vo = 0.0
        for b in range(3):
            vn += R[0, c, b] * x[0, b]
            vo += R_old[0, c, b] * x_old[0, b]
        rs[0, c] = bc[18 + c] + 0.5 * dt * (vn + vo)
    Rs[0] = R[0]
    for k in range(1, nn):
        for c in range(3):
            ka[c] = 0.5 * (x[k - 1, 6 + c] + x[k, 6 + c])
        _segment_map(ka, ds, cay, Es[k], chs[k])
        for c in range(3):
            rs[k, c] = rs[k - 1, c] + Rs[k - 1, c, 0] * chs[k, 0] + Rs[k - 1, c, 1] * chs[k, 1] + Rs[k - 1, c, 2] * chs[k, 2]
        _matmul3(Rs[k - 1], Es[k], Rs[k])
    for c in range(3):
        F[rt + c] = (rs[N, c] - bc[12 + c]) / ds
    if not want_jac:
        return
    W[:, :] = 0.0
    for c in range(3):
        r = rt + c
        band[r, ct + c - r + KL] = 1.0
        W[c, ct + c] -= 1.0
    # root point and root frame: r0 = r0_old + dt/2 (R0 v0 + ...), R0 = R0_old exp(dt/2 (w0 + w0_old))
    theta = np.empty(3)
    for c in range(3):
        theta[c] = 0.5 * dt * (x[0, 3 + c] + x_old[0, 3 + c])
    Jr = np.empty((3, 3))
    right_jacobian_into(theta, Jr)
    q = np.empty(3)  # R0^T (r_N - r0) + dt/2 v0: everything that turns with the root frame
    for c in range(3):
        q[c] = 0.0
        for b in range(3):
            q[c] += R[0, b, c] * (rs[N, b] - rs[0, b])
        q[c] += 0.5 * dt * x[0, c]
    H = np.zeros((3, 3))
    _add_hat_times(q, Jr, H, 0, 0)  # hat(q) J_r
    for c in range(3):
        for b in range(3):
            W[c, b] += 0.5 * dt * R[0, c, b] / ds
            acc = 0.0
            for e in range(3):
                acc += R[0, c, e] * H[e, b]
            W[c, 3 + b] += -0.5 * dt * acc / ds
    # segments: d r_N / d kappa_mean_k = R_{k-1} (d chord + dE E^T R_{k-1}^T (r_N - r_k))
    E2 = np.empty((3, 3))
    E3 = np.empty((3, 3))
    c2 = np.empty(3)
    c3 = np.empty(3)
    w = np.empty(3)
    u = np.empty(3)
    dl = np.empty(3)
    G = np.empty(3)
    eps = 1e-6 / ds
    for k in range(1, nn):
        for c in range(3):
            w[c] = 0.0
            for b in range(3):
                w[c] += Rs[k - 1, b, c] * (rs[N, b] - rs[k, b])
        # E^T w
        for c in range(3):
            u[c] = Es[k, 0, c] * w[0] + Es[k, 1, c] * w[1] + Es[k, 2, c] * w[2]
        for a in range(3):
            for c in range(3):
                ka[c] = 0.5 * (x[k - 1, 6 + c] + x[k, 6 + c])
            ka[a] += eps
            _segment_map(ka, ds, cay, E2, c2)
            ka[a] -= 2.0 * eps
            _segment_map(ka, ds, cay, E3, c3)
            for c in range(3):
                loc = (c2[c] - c3[c]) + (E2[c, 0] - E3[c, 0]) * u[0] + (E2[c, 1] - E3[c, 1]) * u[1] + (E2[c, 2] - E3[c, 2]) * u[2]
                dl[c] = loc / (2.0 * eps)
            for c in range(3):
                G[c] = Rs[k - 1, c, 0] * dl[0] + Rs[k - 1, c, 1] * dl[1] + Rs[k - 1, c, 2] * dl[2]
            # kappa_mean_k = (kappa_{k-1} + kappa_k) / 2
            for c in range(3):
                W[c, 12 * (k - 1) + 6 + a] += 0.5 * G[c] / ds
                W[c, 12 * k + 6 + a] += 0.5 * G[c] / ds


@njit(cache=True)
def evaluate(x, x_old, xt_old, xs_old, g_old, R_old, k0, dk0, fdist, bc, par, scale, want_jac,
             F, band, xt, xs, g, R, W):
    """Residual (and banded Jacobian) of one implicit rod step (Sobottka eqs. 3.153-3.161).

    Inputs (N+1 nodes): x, x_old, xt_old, xs_old, g_old (N+1, 12); R_old (N+1, 3, 3) node frames
    at the previous step (columns d1, d2, d3); k0, dk0 (N+1, 3); fdist (N+1, 3) global body force
    per length N/m (gravity included); bc (NBC,); par (NPAR,); scale (12,) characteristic size of each
    state component (row scaling of the residual).
    Outputs: F (12 (N+1),) scaled residual; band (12 (N+1), BAND_WIDTH) Jacobian if want_jac;
    xt, xs, g (N+1, 12) derivatives and g(x) at the iterate; R (N+1, 3, 3) frames at the iterate;
    W (3, 12 (N+1)) dense tip-position rows minus their banded stand-in (tip_mode 4 and want_jac only).

    Unknown ordering: node-major, 12 per node. Equation rows: 6 root velocity BCs, then 12 link rows
    per segment j = 1..N, then 6 tip BCs.
    """
    nn = x.shape[0]
    ds = par[0]
    dt = par[1]
    rhoA = par[2]
    rhoI = par[3:6]
    K = par[6:9]
    at, bt, gt = par[9], par[10], par[11]
    as_, bs, gs = par[12], par[13], par[14]
    tip_mode = int(par[18])
    Mdiag = np.zeros(12)
    for i in range(3):
        Mdiag[i] = rhoA
        Mdiag[3 + i] = rhoI[i]
        Mdiag[6 + i] = 1.0
    theta = np.empty(3)
    fl = np.empty(3)
    ll = np.zeros(3)
    Jl = np.empty((3, 3))
    E = np.empty((3, 3))
    Jr = np.empty((3, 3))
    dG = np.empty((12, 12))
    Q = np.empty((12, 12))
    D_prev = np.empty((12, 12))
    D_cur = np.empty((12, 12))
    mass_prev = np.empty(12)
    stiff_prev = np.empty(12)
    mass = np.empty(12)
    rhs = np.empty(12)
    tmp = np.empty(12)
    if want_jac:
        band[:, :] = 0.0
    ctime = (1.0 - at) / (gt * dt)
    for j in range(nn):
        # orientation at the iterate: R = R_old exp(dt (w + w_old) / 2)  (eq. 3.164, right multiplication)
        for c in range(3):
            theta[c] = 0.5 * dt * (x[j, 3 + c] + x_old[j, 3 + c])
        rodrigues_into(theta, E)
        _matmul3(R_old[j], E, R[j])
        right_jacobian_into(theta, Jr)
        for a in range(3):
            for b in range(3):
                Jl[a, b] = 0.5 * dt * Jr[a, b]
        for c in range(3):
            fl[c] = R[j, 0, c] * fdist[j, 0] + R[j, 1, c] * fdist[j, 1] + R[j, 2, c] * fdist[j, 2]
        # time derivative (eq. 3.154) and time-weighted mass term
        for c in range(12):
            xt[j, c] = ((x[j, c] - x_old[j, c]) - dt * (1.0 - gt) * xt_old[j, c]) / (gt * dt)
            mass[c] = Mdiag[c] * ((1.0 - at) * xt[j, c] + at * xt_old[j, c])
        node_g(x[j], fl, ll, k0[j], dk0[j], rhoA, rhoI, K, g[j])
        # spatial weighting: the stiffness term of node j from the cell equation (eq. 3.153)
        if j == 0:
            for c in range(12):
                rhs[c] = mass[c]
            cmass = ctime
        else:
            for c in range(12):
                rhs[c] = ((1.0 - as_) * mass[c] + as_ * mass_prev[c] - bs * stiff_prev[c]) / (1.0 - bs)
            cmass = ctime * (1.0 - as_) / (1.0 - bs)
        # P xs = (rhs - bt P xs_old - (1 - bt) g - bt g_old) / (1 - bt)
        apply_pinv(g_old[j], K, tmp)
        for c in range(12):
            tmp[c] = bt * (xs_old[j, c] + tmp[c])
        apply_pinv(rhs, K, xs[j])
        apply_pinv(g[j], K, mass_prev)  # scratch: P^-1 g
        for c in range(12):
            xs[j, c] = (xs[j, c] - (1.0 - bt) * mass_prev[c] - tmp[c]) / (1.0 - bt)
        for c in range(12):
            stiff_prev[c] = rhs[c]
            mass_prev[c] = mass[c]
        if want_jac:
            node_dg(x[j], fl, ll, k0[j], Jl, rhoA, rhoI, K, dG)
            for a in range(12):
                for b in range(12):
                    Q[a, b] = -(1.0 - bt) * dG[a, b]
                Q[a, a] += cmass * Mdiag[a]
            # D = dxs/dx = P^-1 Q / (1 - bt)
            for b in range(12):
                for i in range(3):
                    D_cur[i, b] = Q[9 + i, b] / (1.0 - bt)
                    D_cur[3 + i, b] = Q[6 + i, b] / (1.0 - bt)
                    D_cur[6 + i, b] = Q[3 + i, b] / (K[i] * (1.0 - bt))
                    D_cur[9 + i, b] = Q[i, b] / (1.0 - bt)
        if j >= 1:
            # link rows (generalised trapezoid in s, eq. 3.155)
            row0 = 6 + 12 * (j - 1)
            for c in range(12):
                F[row0 + c] = (x[j, c] - x[j - 1, c] - ds * (gs * xs[j, c] + (1.0 - gs) * xs[j - 1, c])) / scale[c]
            if want_jac:
                col_prev = 12 * (j - 1)
                col_cur = 12 * j
                for c in range(12):
                    r = row0 + c
                    for b in range(12):
                        vp = -ds * (1.0 - gs) * D_prev[c, b]
                        vc = -ds * gs * D_cur[c, b]
                        if b == c:
                            vp -= 1.0
                            vc += 1.0
                        band[r, col_prev + b - r + KL] = vp / scale[c]
                        band[r, col_cur + b - r + KL] = vc / scale[c]
        if want_jac:
            for a in range(12):
                for b in range(12):
                    D_prev[a, b] = D_cur[a, b]
    # root boundary conditions: v, omega prescribed in global frame, re-expressed locally
    for c in range(3):
        vloc = R[0, 0, c] * bc[0] + R[0, 1, c] * bc[1] + R[0, 2, c] * bc[2]
        wloc = R[0, 0, c] * bc[3] + R[0, 1, c] * bc[4] + R[0, 2, c] * bc[5]
        F[c] = (x[0, c] - vloc) / scale[c]
        F[3 + c] = (x[0, 3 + c] - wloc) / scale[3 + c]
        if want_jac:
            band[c, c - c + KL] = 1.0 / scale[c]
            band[3 + c, 3 + c - (3 + c) + KL] = 1.0 / scale[3 + c]
    # tip boundary conditions
    N = nn - 1
    rt = 6 + 12 * N
    ct = 12 * N
    if tip_mode == 0:
        # kappa = kappa0 + K^-1 R^T torque (eq. 3.4.4), n = R^T force
        for c in range(3):
            theta[c] = 0.5 * dt * (x[N, 3 + c] + x_old[N, 3 + c])
        right_jacobian_into(theta, Jr)
        for a in range(3):
            for b in range(3):
                Jl[a, b] = 0.5 * dt * Jr[a, b]
        mloc = np.empty(3)
        for c in range(3):
            fl[c] = R[N, 0, c] * bc[6] + R[N, 1, c] * bc[7] + R[N, 2, c] * bc[8]
            mloc[c] = R[N, 0, c] * bc[9] + R[N, 1, c] * bc[10] + R[N, 2, c] * bc[11]
        for c in range(3):
            F[rt + c] = (x[N, 6 + c] - k0[N, c] - mloc[c] / K[c]) / scale[6 + c]
            F[rt + 3 + c] = (x[N, 9 + c] - fl[c]) / scale[9 + c]
        if want_jac:
            Am = np.zeros((3, 3))
            _add_hat_times(mloc, Jl, Am, 0, 0)
            Af = np.zeros((3, 3))
            _add_hat_times(fl, Jl, Af, 0, 0)
            for c in range(3):
                r = rt + c
                band[r, ct + 6 + c - r + KL] = 1.0 / scale[6 + c]
                r2 = rt + 3 + c
                band[r2, ct + 9 + c - r2 + KL] = 1.0 / scale[9 + c]
                for b in range(3):
                    band[r, ct + 3 + b - r + KL] = -Am[c, b] / (K[c] * scale[6 + c])
                    band[r2, ct + 3 + b - r2 + KL] = -Af[c, b] / scale[9 + c]
    else:
        # tip_mode 1: velocity and angular velocity prescribed; 2: velocity and torque prescribed
        if tip_mode == 4 or tip_mode == 5:
            tip_position_rows(x, x_old, R, R_old, bc, par, want_jac, F, band, W, rt, ct)
        else:
            for c in range(3):
                vloc = R[N, 0, c] * bc[12] + R[N, 1, c] * bc[13] + R[N, 2, c] * bc[14]
                F[rt + c] = (x[N, c] - vloc) / scale[c]
                if want_jac:
                    r = rt + c
                    band[r, ct + c - r + KL] = 1.0 / scale[c]
        if tip_mode == 1 or tip_mode == 5:
            for c in range(3):
                wloc = R[N, 0, c] * bc[15] + R[N, 1, c] * bc[16] + R[N, 2, c] * bc[17]
                F[rt + 3 + c] = (x[N, 3 + c] - wloc) / scale[3 + c]
                if want_jac:
                    r2 = rt + 3 + c
                    band[r2, ct + 3 + c - r2 + KL] = 1.0 / scale[3 + c]
        elif tip_mode == 3 or tip_mode == 4:
            # guided tip: transverse rotation rates prescribed (omega1, omega2), axial torque m3 prescribed
            for c in range(3):
                theta[c] = 0.5 * dt * (x[N, 3 + c] + x_old[N, 3 + c])
            right_jacobian_into(theta, Jr)
            for a in range(3):
                for b in range(3):
                    Jl[a, b] = 0.5 * dt * Jr[a, b]
            for c in range(2):
                wloc = R[N, 0, c] * bc[15] + R[N, 1, c] * bc[16] + R[N, 2, c] * bc[17]
                F[rt + 3 + c] = (x[N, 3 + c] - wloc) / scale[3 + c]
                if want_jac:
                    r2 = rt + 3 + c
                    band[r2, ct + 3 + c - r2 + KL] = 1.0 / scale[3 + c]
            mloc3 = np.empty(3)
            for c in range(3):
                mloc3[c] = R[N, 0, c] * bc[9] + R[N, 1, c] * bc[10] + R[N, 2, c] * bc[11]
            F[rt + 5] = (x[N, 8] - k0[N, 2] - mloc3[2] / K[2]) / scale[8]
            if want_jac:
                Am3 = np.zeros((3, 3))
                _add_hat_times(mloc3, Jl, Am3, 0, 0)
                r2 = rt + 5
                band[r2, ct + 8 - r2 + KL] = 1.0 / scale[8]
                for b in range(3):
                    band[r2, ct + 3 + b - r2 + KL] = -Am3[2, b] / (K[2] * scale[8])
        else:
            for c in range(3):
                theta[c] = 0.5 * dt * (x[N, 3 + c] + x_old[N, 3 + c])
            right_jacobian_into(theta, Jr)
            for a in range(3):
                for b in range(3):
                    Jl[a, b] = 0.5 * dt * Jr[a, b]
            mloc2 = np.empty(3)
            for c in range(3):
                mloc2[c] = R[N, 0, c] * bc[9] + R[N, 1, c] * bc[10] + R[N, 2, c] * bc[11]
            for c in range(3):
                F[rt + 3 + c] = (x[N, 6 + c] - k0[N, c] - mloc2[c] / K[c]) / scale[6 + c]
            if want_jac:
                Am2 = np.zeros((3, 3))
                _add_hat_times(mloc2, Jl, Am2, 0, 0)
                for c in range(3):
                    r2 = rt + 3 + c
                    band[r2, ct + 6 + c - r2 + KL] = 1.0 / scale[6 + c]
                    for b in range(3):
                        band[r2, ct + 3 + b - r2 + KL] = -Am2[c, b] / (K[c] * scale[6 + c])


@njit(cache=True)
def _max_abs(F):
    m = 0.0
    for i in range(F.shape[0]):
        a = abs(F[i])
        if a > m or a != a:
            m = a if a == a else np.inf
    return m


@njit(cache=True)
def _woodbury_setup(band, piv, W, rt, unit, Z, Cinv):
    """For J = B + E W (B factorised, E = unit columns at rows rt..rt+2): Z = (B^-1 E)^T and
    Cinv = (I + W B^-1 E)^-1. Returns False if the 3 x 3 capacitance matrix is singular."""
    n = band.shape[0]
    for c in range(3):
        for i in range(n):
            unit[i] = 0.0
        unit[rt + c] = 1.0
        banded_lu_solve(band, piv, KL, KU, unit, Z[c])
    C = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            acc = 1.0 if a == b else 0.0
            for i in range(n):
                acc += W[a, i] * Z[b, i]
            C[a, b] = acc
    det = (C[0, 0] * (C[1, 1] * C[2, 2] - C[1, 2] * C[2, 1]) - C[0, 1] * (C[1, 0] * C[2, 2] - C[1, 2] * C[2, 0])
           + C[0, 2] * (C[1, 0] * C[2, 1] - C[1, 1] * C[2, 0]))
    if det == 0.0 or not np.isfinite(det):
        return False
    Cinv[0, 0] = (C[1, 1] * C[2, 2] - C[1, 2] * C[2, 1]) / det
    Cinv[0, 1] = (C[0, 2] * C[2, 1] - C[0, 1] * C[2, 2]) / det
    Cinv[0, 2] = (C[0, 1] * C[1, 2] - C[0, 2] * C[1, 1]) / det
    Cinv[1, 0] = (C[1, 2] * C[2, 0] - C[1, 0] * C[2, 2]) / det
    Cinv[1, 1] = (C[0, 0] * C[2, 2] - C[0, 2] * C[2, 0]) / det
    Cinv[1, 2] = (C[0, 2] * C[1, 0] - C[0, 0] * C[1, 2]) / det
    Cinv[2, 0] = (C[1, 0] * C[2, 1] - C[1, 1] * C[2, 0]) / det
    Cinv[2, 1] = (C[0, 1] * C[2, 0] - C[0, 0] * C[2, 1]) / det
    Cinv[2, 2] = (C[0, 0] * C[1, 1] - C[0, 1] * C[1, 0]) / det
    return True


@njit(cache=True)
def _woodbury_correct(W, Z, Cinv, y):
    """y <- y - Z^T Cinv W y: turns y = B^-1 b into (B + E W)^-1 b (Sherman-Morrison-Woodbury)."""
    n = y.shape[0]
    t = np.zeros(3)
    for a in range(3):
        for i in range(n):
            t[a] += W[a, i] * y[i]
    for c in range(3):
        sc = Cinv[c, 0] * t[0] + Cinv[c, 1] * t[1] + Cinv[c, 2] * t[2]
        for i in range(n):
            y[i] -= sc * Z[c, i]


@njit(cache=True)
def newton_step(x_old, xt_old, xs_old, g_old, R_old, k0, dk0, fdist, bc, par, scale,
                x, xt, xs, g, R, info):
    """One implicit step of one fibre: globalised Newton (Sobottka Algorithm 1, §3.4.7).

    Warm start from ``x`` (normally x_old); analytic banded Jacobian, factorised by Gaussian
    elimination with partial pivoting on the band and re-used while the residual falls by at least
    a factor 4 per iteration (re-evaluated and re-factorised otherwise); Armijo backtracking on
    0.5 |F|^2 with mu halved from 1. Outputs x, xt, xs, g (N+1, 12), R (N+1, 3, 3); info (5,):
    iterations, final scaled residual max-norm, status (0 converged, 1 line search failed,
    2 iteration limit, 3 singular/non-finite), residual evaluations, Jacobian factorisations.
    """
    nn = x.shape[0]
    n = 12 * nn
    tol = par[15]
    max_it = int(par[16])
    iota = par[17]
    max_halv = int(par[19])
    F = np.empty(n)
    Ft = np.empty(n)
    band = np.empty((n, BAND_WIDTH))
    piv = np.empty(n, dtype=np.int64)
    delta = np.empty(n)
    negF = np.empty(n)
    xtr = np.empty_like(x)
    xt_t = np.empty_like(xt)
    xs_t = np.empty_like(xs)
    g_t = np.empty_like(g)
    R_t = np.empty_like(R)
    tip_mode = int(par[18])
    bordered = tip_mode == 4 or tip_mode == 5
    nb = n if bordered else 1  # the dense rows exist only for the geometric tip BC
    W = np.zeros((3, nb))
    Z = np.zeros((3, nb))  # rows: B^-1 e_(tip position row c)
    Cinv = np.zeros((3, 3))
    unit = np.empty(nb)
    rt = n - 6
    evals = 0
    factors = 0
    evaluate(x, x_old, xt_old, xs_old, g_old, R_old, k0, dk0, fdist, bc, par, scale, False,
             F, band, xt, xs, g, R, W)
    evals += 1
    res = _max_abs(F)
    it = 0
    status = 0
    have_factor = False
    res_prev = np.inf
    while res > tol:
        if it >= max_it:
            status = 2
            break
        if not np.isfinite(res):
            status = 3
            break
        if not have_factor or res > 0.25 * res_prev:
            evaluate(x, x_old, xt_old, xs_old, g_old, R_old, k0, dk0, fdist, bc, par, scale, True,
                     F, band, xt, xs, g, R, W)
            evals += 1
            if not banded_factor(band, KL, KU, piv):
                status = 3
                break
            factors += 1
            have_factor = True
            if bordered and not _woodbury_setup(band, piv, W, rt, unit, Z, Cinv):
                status = 3
                break
        for i in range(n):
            negF[i] = -F[i]
        banded_lu_solve(band, piv, KL, KU, negF, delta)
        if bordered:
            _woodbury_correct(W, Z, Cinv, delta)
        phi0 = 0.0
        for i in range(n):
            phi0 += F[i] * F[i]
        phi0 *= 0.5
        mu = 1.0
        accepted = False
        for h in range(max_halv + 1):
            for j in range(nn):
                for c in range(12):
                    xtr[j, c] = x[j, c] + mu * delta[12 * j + c]
            evaluate(xtr, x_old, xt_old, xs_old, g_old, R_old, k0, dk0, fdist, bc, par, scale, False,
                     Ft, band, xt_t, xs_t, g_t, R_t, W)
            evals += 1
            phi = 0.0
            for i in range(n):
                phi += Ft[i] * Ft[i]
            phi *= 0.5
            if phi <= (1.0 - 2.0 * iota * mu) * phi0:
                accepted = True
                break
            mu *= 0.5
        it += 1
        x[:, :] = xtr
        xt[:, :] = xt_t
        xs[:, :] = xs_t
        g[:, :] = g_t
        R[:, :, :] = R_t
        F[:] = Ft
        res_prev = res
        res = _max_abs(F)
        if not accepted:
            if res <= tol:
                break
            if factors > 0 and mu < 1.0 and have_factor:
                # retry once with a fresh Jacobian before giving up
                have_factor = False
                res_prev = np.inf
                if it < max_it:
                    continue
            status = 1
            break
        status = 0
    info[0] = it
    info[1] = res
    info[2] = status
    info[3] = evals
    info[4] = factors


@njit(cache=True)
def cayley_angle_scale(theta_norm):
    """2 atan(t / 2) / t: the rotation angle of the Cayley transform cay(hat(theta)) =
    (I - hat(theta) / 2)^-1 (I + hat(theta) / 2) over |theta| = t (its axis is theta's)."""
    if theta_norm < 1e-12:
        return 1.0
    return 2.0 * np.arctan(0.5 * theta_norm) / theta_norm


@njit(cache=True)
def integrate_frames(R0, kappa, ds, R, r0, r, cayley=False):
    """Frames and centreline by integration in s (eqs. 3.162-3.164, tangent integration §3.4.6).

    R0 (3, 3) root frame; kappa (N+1, 3) 1/m (segment curvature = mean of its two nodes); ds m;
    out R (N+1, 3, 3); r0 (3,) root position m; out r (N+1, 3) m. Segments are exact constant-curvature arcs.

    cayley=False: R_j = R_{j-1} exp(ds hat(kappa_mean)) (Rodrigues, eq. 3.162).
    cayley=True: R_j = R_{j-1} cay(ds hat(kappa_mean)), i.e. the arc's turning angle |kappa| ds is
    replaced by 2 atan(|kappa| ds / 2). This is the map by which the box scheme in s
    (alpha_s = beta_s = gamma_s = 1/2) transports vectors along the rod: for constant kappa its
    link rows read (I + ds/2 hat(kappa)) y_j = (I - ds/2 hat(kappa)) y_{j-1} for the local
    components y of a vector that is constant in space (the velocity of a rigid translation, the
    angular velocity of a rigid rotation, the contact force of an unloaded rod). Frames
    integrated with it make a rigid translation of a twisted / bent rod an exact discrete solution
    (see ``tests/solvers/test_rods_consistency.py``); with the exponential map the two
    kinematics disagree at O((|kappa| ds)^2), which shows as position drift of strongly twisted rods.
    """
    nn = kappa.shape[0]
    R[0] = R0
    r[0] = r0
    ka = np.empty(3)
    th = np.empty(3)
    E = np.empty((3, 3))
    for j in range(1, nn):
        for c in range(3):
            ka[c] = 0.5 * (kappa[j - 1, c] + kappa[j, c])
        if cayley:
            sc = cayley_angle_scale(ds * np.sqrt(ka[0] * ka[0] + ka[1] * ka[1] + ka[2] * ka[2]))
            for c in range(3):
                ka[c] *= sc
        for c in range(3):
            th[c] = ds * ka[c]
        ch = arc_chord(ka, ds)
        for c in range(3):
            r[j, c] = r[j - 1, c] + R[j - 1, c, 0] * ch[0] + R[j - 1, c, 1] * ch[1] + R[j - 1, c, 2] * ch[2]
        rodrigues_into(th, E)
        _matmul3(R[j - 1], E, R[j])


@njit(cache=True, parallel=True)
def newton_step_batch(x_old, xt_old, xs_old, g_old, R_old, k0, dk0, fdist, bc, par, scale,
                      x, xt, xs, g, R, info):
    """:func:`newton_step` for a batch of fibres in parallel (leading axis = fibre)."""
    nf = x.shape[0]
    for f in prange(nf):
        newton_step(x_old[f], xt_old[f], xs_old[f], g_old[f], R_old[f], k0[f], dk0[f], fdist[f],
                    bc[f], par[f], scale[f], x[f], xt[f], xs[f], g[f], R[f], info[f])


@njit(cache=True, parallel=True)
def integrate_frames_batch(R0, kappa, ds, R, r0, r, cayley=False):
    """:func:`integrate_frames` for a batch; R0 (F, 3, 3), kappa (F, N+1, 3), ds (F,), r0 (F, 3)."""
    for f in prange(R0.shape[0]):
        integrate_frames(R0[f], kappa[f], ds[f], R[f], r0[f], r[f], cayley)


@njit(cache=True)
def newton_step_serial(x_old, xt_old, xs_old, g_old, R_old, k0, dk0, fdist, bc, par, scale,
                       x, xt, xs, g, R, info):
    """:func:`newton_step_batch` without threads (small batches: no thread-pool overhead)."""
    for f in range(x.shape[0]):
        newton_step(x_old[f], xt_old[f], xs_old[f], g_old[f], R_old[f], k0[f], dk0[f], fdist[f],
                    bc[f], par[f], scale[f], x[f], xt[f], xs[f], g[f], R[f], info[f])


@njit(cache=True)
def integrate_frames_serial(R0, kappa, ds, R, r0, r, cayley=False):
    """:func:`integrate_frames_batch` without threads."""
    for f in range(R0.shape[0]):
        integrate_frames(R0[f], kappa[f], ds[f], R[f], r0[f], r[f], cayley)
