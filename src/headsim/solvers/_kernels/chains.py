"""Numba kernels of the rigid-segment fibre (kinematic chain) solver (Sobottka 2008, ch. 8).

Bodies are capsule segments with world position x (3,), rotation R (3, 3) (columns = directors
d1, d2, d3; d3 = segment axis, root → tip), velocity v (3,), angular velocity w (3,) (world frame),
mass m and body-frame diagonal inertia I (3,). Segment s has its *inner* joint at −h d3 (h = half
length) and its *outer* joint at +h d3. Joint s is the inner joint of segment s: between segment
s − 1 (body "k", anchor +h d3) and segment s (body "l", anchor −h d3); for the root segment of an
anchored fibre, body k is the fixed root anchor (infinite mass, position ``root_point``, frame
``root_frame``).

The joint impulse of joint j is P_j = (p, L*) (N s, N m s): body k receives (p, L* + r_k × p), body l
receives −(p, L* + r_l × p), each with its own lever arm (the digest's fix of eq. 8.81/8.82).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@njit(cache=True)
def skew(a):
    """3×3 matrix ã with ã b = a × b."""
    s = np.zeros((3, 3))
    s[0, 1] = -a[2]
    s[0, 2] = a[1]
    s[1, 0] = a[2]
    s[1, 2] = -a[0]
    s[2, 0] = -a[1]
    s[2, 1] = a[0]
    return s


@njit(cache=True)
def rodrigues(phi):
    """exp(φ̃) = E + sinθ ξ̃ + (1 − cosθ) ξ̃² with θ = ‖φ‖, ξ = φ/θ (eq. 3.162, digest fix of the typo)."""
    th = np.sqrt(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    out = np.eye(3)
    if th < 1e-12:
        k = skew(phi)
        return out + k + 0.5 * (k @ k)
    k = skew(phi / th)
    return out + np.sin(th) * k + (1.0 - np.cos(th)) * (k @ k)


@njit(cache=True)
def log_so3(R):
    """Rotation vector φ with exp(φ̃) = R (SO(3) log, eq. 8.83: 2 cos θ = tr R − 1, Ω̃ = (R − Rᵀ)/(2 sin θ))."""
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    c = min(1.0, max(-1.0, c))
    th = np.arccos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-6:
        return 0.5 * v
    s = np.sin(th)
    if s > 1e-6:
        return v * (0.5 * th / s)
    # near π: axis from the symmetric part B = cosθ E + (1 − cosθ) a aᵀ
    B = 0.5 * (R + R.T)
    ax = np.zeros(3)
    for j in range(3):
        ax[j] = np.sqrt(max(0.0, (B[j, j] - c) / (1.0 - c)))
    i = np.argmax(ax)
    for j in range(3):
        if j != i:
            ax[j] = B[i, j] / ((1.0 - c) * ax[i])
    ax /= np.sqrt(ax[0] ** 2 + ax[1] ** 2 + ax[2] ** 2)
    if ax[0] * v[0] + ax[1] * v[1] + ax[2] * v[2] < 0:
        ax = -ax
    return ax * th


@njit(cache=True)
def world_inverse_inertia(R, inertia):
    """I_w⁻¹ = R diag(1/I) Rᵀ (1/(kg m²))."""
    out = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            s = 0.0
            for c in range(3):
                s += R[a, c] * R[b, c] / inertia[c]
            out[a, b] = s
    return out


@njit(cache=True)
def _half_step_one(s, x, R, v, w, inertia, h, x_out, R_out, w_out):
    for c in range(3):
        x_out[s, c] = x[s, c] + h * v[s, c]
    Rn = rodrigues(h * w[s]) @ R[s]
    R_out[s] = Rn
    # torque-free rotation keeps the world angular momentum L = I_w ω: ω ← I_w(R_new)⁻¹ I_w(R) ω
    # (with the gyroscopic term neglected a frozen ω would pump energy from the tiny axial inertia
    # of a thin segment into its transverse one; this update only ever lowers that energy)
    bl = R[s].T @ w[s]
    for c in range(3):
        bl[c] *= inertia[s, c]
    L = R[s] @ bl
    bn = Rn.T @ L
    for c in range(3):
        bn[c] /= inertia[s, c]
    wn = Rn @ bn
    for c in range(3):
        w_out[s, c] = wn[c]


@njit(cache=True, parallel=True)
def half_step(x, R, v, w, inertia, h, x_out, R_out, w_out):
    """x + h v, exp(h w̃) R and the angular-momentum-preserving ω for every body (the θ = 1
    position update of Alg. 6, lines 2 and 14)."""
    for s in prange(x.shape[0]):
        _half_step_one(s, x, R, v, w, inertia, h, x_out, R_out, w_out)


# --------------------------------------------------------------------------------------------------
# Method I joint correction (§8.5.1, Alg. 7) with implicit joint springs (§8.5.3)
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def _solve6(A, b):
    return np.linalg.solve(A, b)


@njit(cache=True, inline="always")
def _joint_impulses_on_body(b, s, n, j0, P, R, half):
    """Net linear impulse fl (3,) and angular impulse tq (3,) of the joint impulses P (nj, 6) on body b
    (global segment s) of a chain of n bodies whose first joint row is j0: its inner joint b (body is
    "l") if it exists, and its outer joint b + 1 (body is "k"), applied at the segment ends ±half s."""
    fl = np.zeros(3)
    tq = np.zeros(3)
    if b >= j0:
        jj = b - j0
        p = P[jj, :3]
        rl = -half[s] * R[s, :, 2]
        fl -= p
        tq -= P[jj, 3:] + _cross(rl, p)
    if b + 1 < n:
        jj = b + 1 - j0
        p = P[jj, :3]
        rk = half[s] * R[s, :, 2]
        fl += p
        tq += P[jj, 3:] + _cross(rk, p)
    return fl, tq


@njit(cache=True)
def _fibre_trial(s0, n, j0, P, x, R, v, w, mass, inertia, half, root_point, root_frame, f,
                 dt, gravity, dx_extra, dth_extra, K, rest, damping, res, x_end, R_end, w_new):
    """Trial integration over Δt (eqs. 8.78/8.80) with impulses P (nj, 6); fills the residual
    res (nj, 6): rows 0:3 joint gap d (eq. 8.76), rows 3:6 implicit spring L* − Δt[K_w(θ − θ°) + c ω_rel].
    Returns the largest gap norm, m."""
    nj = n - j0
    for b in range(n):
        s = s0 + b
        fl, tq = _joint_impulses_on_body(b, s, n, j0, P, R, half)
        Iwi = world_inverse_inertia(R[s], inertia[s])
        wn = w[s] + Iwi @ tq
        for c in range(3):
            x_end[b, c] = x[s, c] + dt * (v[s, c] + fl[c] / mass[s]) + 0.5 * dt * dt * gravity[c] + dx_extra[s, c]
            w_new[b, c] = wn[c]
        R_end[b] = rodrigues(dt * wn + dth_extra[s]) @ R[s]
    gmax = 0.0
    for jj in range(nj):
        b = jj + j0
        s = s0 + b
        pl = x_end[b] - half[s] * R_end[b, :, 2]
        if b == 0:
            pk = root_point[f]
            Rk = root_frame[f]
            wk = np.zeros(3)
        else:
            pk = x_end[b - 1] + half[s - 1] * R_end[b - 1, :, 2]
            Rk = R_end[b - 1]
            wk = w_new[b - 1]
        d = pk - pl
        th = log_so3(Rk.T @ R_end[b])
        mom = Rk @ (K[s] * (th - rest[s])) + damping[s] * (w_new[b] - wk)
        for c in range(3):
            res[jj, c] = d[c]
            res[jj, 3 + c] = P[jj, 3 + c] - dt * mom[c]
        g = np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
        if g > gmax:
            gmax = g
    return gmax


@njit(cache=True)
def _wrench_map(r, sign):
    """6×6 map (p, L*) → wrench (f, τ) on a body with lever r: sign·[[E, 0], [r̃, E]] (eq. 8.72)."""
    B = np.zeros((6, 6))
    rt = skew(r)
    for a in range(3):
        B[a, a] = sign
        B[3 + a, 3 + a] = sign
        for c in range(3):
            B[3 + a, c] = sign * rt[a, c]
    return B


@njit(cache=True)
def _rate_map(r, sign):
    """6×6 map twist (v, ω) of a body → (gap rate, relative angular rate): k: [[E, −r̃], [0, −E]],
    l: [[−E, r̃], [0, E]] (sign = +1 for k, −1 for l)."""
    C = np.zeros((6, 6))
    rt = skew(r)
    for a in range(3):
        C[a, a] = sign
        C[3 + a, 3 + a] = -sign
        for c in range(3):
            C[a, 3 + c] = -sign * rt[a, c]
    return C


@njit(cache=True)
def _mobility(s, R, mass, inertia):
    W = np.zeros((6, 6))
    Iwi = world_inverse_inertia(R[s], inertia[s])
    for a in range(3):
        W[a, a] = 1.0 / mass[s]
        for c in range(3):
            W[3 + a, 3 + c] = Iwi[a, c]
    return W


@njit(cache=True)
def _fibre_jacobian(s0, n, j0, R, mass, inertia, half, dt, K, damping, Dg, Lo, Up):
    """First-order (chord) Jacobian of the trial residual w.r.t. the joint impulses, block-tridiagonal:
    Dg[j] = ∂res_j/∂P_j, Lo[j] = ∂res_j/∂P_{j−1}, Up[j] = ∂res_j/∂P_{j+1} (the linearised K-matrix
    coupling of Mirtich / Bender, used as the Newton matrix of Method I)."""
    nj = n - j0
    for jj in range(nj):
        for a in range(6):
            for c in range(6):
                Dg[jj, a, c] = 0.0
                Lo[jj, a, c] = 0.0
                Up[jj, a, c] = 0.0
    for jj in range(nj):
        b = jj + j0
        s = s0 + b
        # bodies of joint jj: l = b (always), k = b - 1 (if b > 0)
        rl = -half[s] * R[s, :, 2]
        Wl = _mobility(s, R, mass, inertia)
        Cl = _rate_map(rl, -1.0)
        Bl = _wrench_map(rl, -1.0)
        blk = Cl @ Wl @ Bl
        if b > 0:
            sk = s - 1
            rk = half[sk] * R[sk, :, 2]
            Wk = _mobility(sk, R, mass, inertia)
            Ck = _rate_map(rk, 1.0)
            blk += Ck @ Wk @ _wrench_map(rk, 1.0)
            if jj > 0:  # joint jj-1 acts on body k as its "l"
                rkl = -half[sk] * R[sk, :, 2]
                Lo[jj] += Ck @ Wk @ _wrench_map(rkl, -1.0)
        if b + 1 < n:  # joint jj+1 acts on body l as its "k"
            rlk = half[s] * R[s, :, 2]
            Up[jj] += Cl @ Wl @ _wrench_map(rlk, 1.0)
        Dg[jj] += blk
        Kw = np.zeros((3, 3))
        Rk = R[s - 1] if b > 0 else R[s]
        for a in range(3):
            for c in range(3):
                Kw[a, c] = Rk[a, 0] * K[s, 0] * Rk[c, 0] + Rk[a, 1] * K[s, 1] * Rk[c, 1] + Rk[a, 2] * K[s, 2] * Rk[c, 2]
        scale = np.zeros((6, 6))
        for a in range(3):
            scale[a, a] = dt
        for a in range(3):
            for c in range(3):
                scale[3 + a, 3 + c] = -(dt * dt * Kw[a, c] + (dt * damping[s] if a == c else 0.0))
        Dg[jj] = scale @ Dg[jj]
        Lo[jj] = scale @ Lo[jj]
        Up[jj] = scale @ Up[jj]
        for a in range(3):
            Dg[jj, 3 + a, 3 + a] += 1.0


@njit(cache=True)
def _block_thomas_factor(nj, Dg, Lo, Up, Dinv, G):
    for jj in range(nj):
        D = Dg[jj].copy()
        if jj > 0:
            G[jj] = Lo[jj] @ Dinv[jj - 1]
            D -= G[jj] @ Up[jj - 1]
        Dinv[jj] = np.linalg.inv(D)


@njit(cache=True)
def _block_thomas_solve(nj, Up, Dinv, G, rhs, out):
    y = np.zeros((nj, 6))
    for jj in range(nj):
        y[jj] = rhs[jj]
        if jj > 0:
            y[jj] -= G[jj] @ y[jj - 1]
    for jj in range(nj - 1, -1, -1):
        t = y[jj].copy()
        if jj < nj - 1:
            t -= Up[jj] @ out[jj + 1]
        out[jj] = Dinv[jj] @ t


@njit(cache=True)
def correct_fibre_joints(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame,
                         dt, gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out):
    """Method I for one fibre (Alg. 7 lines 2–12): Newton-type iteration on the joint-gap system
    (eqs. 8.87/8.89) with the spring rows of §8.5.3 linearly implicit, always restarting the trial
    integration from the saved t_i state. Writes the corrected velocities of the fibre's segments into
    v_out, w_out. Returns (iterations, predicted max gap after correction (m))."""
    s0 = seg_off[f]
    n = seg_off[f + 1] - s0
    j0 = 0 if anchored[f] else 1
    nj = n - j0
    x_end = np.zeros((n, 3))
    R_end = np.zeros((n, 3, 3))
    w_new = np.zeros((n, 3))
    if nj <= 0:
        for b in range(n):
            v_out[s0 + b] = v[s0 + b]
            w_out[s0 + b] = w[s0 + b]
        return 0, 0.0
    P = np.zeros((nj, 6))
    res = np.zeros((nj, 6))
    Dg = np.zeros((nj, 6, 6))
    Lo = np.zeros((nj, 6, 6))
    Up = np.zeros((nj, 6, 6))
    Dinv = np.zeros((nj, 6, 6))
    G = np.zeros((nj, 6, 6))
    _fibre_jacobian(s0, n, j0, R, mass, inertia, half, dt, K, damping, Dg, Lo, Up)
    _block_thomas_factor(nj, Dg, Lo, Up, Dinv, G)
    delta = np.zeros((nj, 6))
    it = 0
    gmax = _fibre_trial(s0, n, j0, P, x, R, v, w, mass, inertia, half, root_point, root_frame, f, dt, gravity,
                        dx_extra, dth_extra, K, rest, damping, res, x_end, R_end, w_new)
    rhs = np.zeros((nj, 6))
    while it < max_iter:
        if it > 0 and gmax <= tol:
            break
        # first pass: the full linearised system (gaps + springs); later passes: gap rows only, the
        # spring rows kept satisfied to first order (linearly implicit springs: a chord Newton on the
        # stiff spring rows would diverge once Δt²K/I ≫ 1, as it is for 70 µm fibres at Δt = 1 ms)
        for jj in range(nj):
            for c in range(3):
                rhs[jj, c] = -res[jj, c]
                rhs[jj, 3 + c] = -res[jj, 3 + c] if it == 0 else 0.0
        _block_thomas_solve(nj, Up, Dinv, G, rhs, delta)
        P += delta
        it += 1
        gmax = _fibre_trial(s0, n, j0, P, x, R, v, w, mass, inertia, half, root_point, root_frame, f, dt,
                            gravity, dx_extra, dth_extra, K, rest, damping, res, x_end, R_end, w_new)
    # apply the impulses to the t_i velocities (Alg. 7 line 12)
    for b in range(n):
        s = s0 + b
        fl, tq = _joint_impulses_on_body(b, s, n, j0, P, R, half)
        Iwi = world_inverse_inertia(R[s], inertia[s])
        wn = w[s] + Iwi @ tq
        for c in range(3):
            v_out[s, c] = v[s, c] + fl[c] / mass[s]
            w_out[s, c] = wn[c]
    return it, gmax


@njit(cache=True, parallel=True)
def correct_joints_batch(fibres, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame,
                         dt, gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out,
                         iterations, gaps):
    """:func:`correct_fibre_joints` for the fibres in ``fibres`` in parallel (each fibre's joint
    solve is independent). iterations (F,) int64 and gaps (F,) float64 receive the per-fibre stats."""
    for q in prange(fibres.shape[0]):
        f = fibres[q]
        it, g = correct_fibre_joints(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point,
                                     root_frame, dt, gravity, dx_extra, dth_extra, K, rest, damping, tol,
                                     max_iter, v_out, w_out)
        iterations[f] = it
        gaps[f] = g


# --------------------------------------------------------------------------------------------------
# per-body contact projection (Alg. 6 lines 5–10) and anisotropic friction (§8.3)
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def _pgs(nc, A, bvec, lam, max_iter, tol):
    """Projected Gauss–Seidel on the dual of QP #1: λ ≥ 0 minimising ½λᵀAλ − λᵀb (A = J M⁻¹ Jᵀ,
    the body's Delassus matrix). Returns the sweeps used."""
    it = 0
    while it < max_iter:
        it += 1
        change = 0.0
        for a in range(nc):
            r = bvec[a]
            for c in range(nc):
                r -= A[a, c] * lam[c]
            new = lam[a] + r / A[a, a]
            if new < 0.0:
                new = 0.0
            d = abs(new - lam[a]) * A[a, a]
            if d > change:
                change = d
            lam[a] = new
        if change <= tol:
            break
    return it


@njit(cache=True)
def _polygon_qp(B, c, px, py, m):
    """min ½ fᵀBf + fᵀc over the convex polygon with CCW vertices (px, py) containing the origin
    (the friction set λ·conv{μ_β d_β}, V-representation of eq. 8.51). Exact: interior minimiser or
    the best clamped minimiser over the edges."""
    det = B[0, 0] * B[1, 1] - B[0, 1] * B[1, 0]
    fx = -(B[1, 1] * c[0] - B[0, 1] * c[1]) / det
    fy = -(-B[1, 0] * c[0] + B[0, 0] * c[1]) / det
    inside = True
    for i in range(m):
        j = (i + 1) % m
        ex, ey = px[j] - px[i], py[j] - py[i]
        if ex * (fy - py[i]) - ey * (fx - px[i]) < 0.0:
            inside = False
            break
    if inside:
        return fx, fy
    best = np.inf
    bx, by = 0.0, 0.0
    for i in range(m):
        j = (i + 1) % m
        ex, ey = px[j] - px[i], py[j] - py[i]
        gx = B[0, 0] * px[i] + B[0, 1] * py[i] + c[0]
        gy = B[1, 0] * px[i] + B[1, 1] * py[i] + c[1]
        eBe = ex * (B[0, 0] * ex + B[0, 1] * ey) + ey * (B[1, 0] * ex + B[1, 1] * ey)
        t = 0.0
        if eBe > 0:
            t = -(ex * gx + ey * gy) / eBe
            t = min(1.0, max(0.0, t))
        qx, qy = px[i] + t * ex, py[i] + t * ey
        q = 0.5 * (qx * (B[0, 0] * qx + B[0, 1] * qy) + qy * (B[1, 0] * qx + B[1, 1] * qy)) + qx * c[0] + qy * c[1]
        if q < best:
            best = q
            bx, by = qx, qy
    return bx, by


@njit(cache=True)
def project_body(u_minus, mass, Iwi, normal, lever, axis, target, mu_cos, mu_sin, restitution,
                 normal_mode, qp_iter, tol, u_out, lam_out):
    """Alg. 6 lines 5–10 for one body with nc contacts.

    u_minus (6,) pre-impact twist (v, ω); normal (nc, 3) unit normals (direction the body may move);
    lever (nc, 3) contact point − centre of mass, m; axis (3,) own segment axis (t₁ of the friction
    frame, root → tip); target (nc,) lower bounds v_N of J u (m/s, eq. 8.69);
    mu_cos, mu_sin (m,) friction generators μ_β d_β in (t₁, t₂) coordinates, CCW (m = 0: frictionless).
    QP #1 in its dual by projected Gauss–Seidel (u⁺), then the friction QP
    min ½(u⁺ + u^f)ᵀM(u⁺ + u^f) over the per-contact polygons by block Gauss–Seidel (exact 2-D solves),
    interleaved with dual normal rows on the current velocity so that J(u⁺ + u^f) ≥ v_N still holds
    and the friction bound follows the normal impulse that friction torques add; then the restitution
    u = (1 + ε)u⁺ − εu⁻ + u^f (eq. 8.64 with the digest's sign fix).
    normal_mode 0: friction bound from the dual λ_α; 1: from eq. 8.27, ν_α = n_αᵀ m (v⁺ − v⁻).
    Returns the PGS + friction sweeps.
    """
    nc = normal.shape[0]
    J = np.zeros((nc, 6))
    MiJ = np.zeros((nc, 6))
    for a in range(nc):
        rn = _cross(lever[a], normal[a])
        for c in range(3):
            J[a, c] = normal[a, c]
            J[a, 3 + c] = rn[c]
            MiJ[a, c] = normal[a, c] / mass
        MiJ[a, 3:] = Iwi @ rn
    A = J @ MiJ.T
    for a in range(nc):
        A[a, a] += 1e-14 * A[a, a] + 1e-300
    bvec = target - J @ u_minus
    lam = np.zeros(nc)
    sweeps = _pgs(nc, A, bvec, lam, qp_iter, tol)
    u_plus = u_minus + MiJ.T @ lam
    u = u_plus.copy()
    m = mu_cos.shape[0]
    if m >= 3:
        bound = lam.copy()
        if normal_mode == 1:
            dv = u_plus[:3] - u_minus[:3]
            for a in range(nc):
                bound[a] = max(0.0, mass * (normal[a, 0] * dv[0] + normal[a, 1] * dv[1] + normal[a, 2] * dv[2]))
        T = np.zeros((nc, 2, 6))
        MiT = np.zeros((nc, 2, 6))
        for a in range(nc):
            n = normal[a]
            t1 = axis - (axis[0] * n[0] + axis[1] * n[1] + axis[2] * n[2]) * n
            l1 = np.sqrt(t1[0] ** 2 + t1[1] ** 2 + t1[2] ** 2)
            if l1 < 1e-9:
                helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
                t1 = helper - (helper[0] * n[0] + helper[1] * n[1] + helper[2] * n[2]) * n
                l1 = np.sqrt(t1[0] ** 2 + t1[1] ** 2 + t1[2] ** 2)
            t1 = t1 / l1
            t2 = _cross(n, t1)
            for k in range(2):
                t = t1 if k == 0 else t2
                rt = _cross(lever[a], t)
                for c in range(3):
                    T[a, k, c] = t[c]
                    T[a, k, 3 + c] = rt[c]
                    MiT[a, k, c] = t[c] / mass
                MiT[a, k, 3:] = Iwi @ rt
        fr = np.zeros((nc, 2))
        px = np.zeros(m)
        py = np.zeros(m)
        Bl = np.zeros((2, 2))
        cl = np.zeros(2)
        for sweep in range(qp_iter):
            change = 0.0
            for a in range(nc):
                # normal row (dual PGS step on the current u: keeps J u ≥ v_N with the friction present)
                r = target[a]
                for c in range(6):
                    r -= J[a, c] * u[c]
                new = lam[a] + r / A[a, a]
                if new < 0.0:
                    new = 0.0
                dl = new - lam[a]
                if dl != 0.0:
                    for c in range(6):
                        u[c] += MiJ[a, c] * dl
                    d = abs(dl) * A[a, a]
                    if d > change:
                        change = d
                lam[a] = new
                if normal_mode == 0:
                    bound[a] = lam[a]
                if bound[a] <= 0.0:
                    if fr[a, 0] != 0.0 or fr[a, 1] != 0.0:
                        for c in range(6):
                            u[c] -= MiT[a, 0, c] * fr[a, 0] + MiT[a, 1, c] * fr[a, 1]
                        fr[a, 0] = 0.0
                        fr[a, 1] = 0.0
                    continue
                # friction block: exact 2-D QP over the polygon bound·conv{μ_β d_β}
                for k in range(2):
                    for q in range(2):
                        Bl[k, q] = 0.0
                        for c in range(6):
                            Bl[k, q] += T[a, k, c] * MiT[a, q, c]
                    cl[k] = 0.0
                    for c in range(6):
                        cl[k] += T[a, k, c] * u[c]
                    cl[k] -= Bl[k, 0] * fr[a, 0] + Bl[k, 1] * fr[a, 1]
                for b in range(m):
                    px[b] = bound[a] * mu_cos[b]
                    py[b] = bound[a] * mu_sin[b]
                nx, ny = _polygon_qp(Bl, cl, px, py, m)
                dx, dy = nx - fr[a, 0], ny - fr[a, 1]
                if dx != 0.0 or dy != 0.0:
                    for c in range(6):
                        u[c] += MiT[a, 0, c] * dx + MiT[a, 1, c] * dy
                    d = np.sqrt(dx * dx * Bl[0, 0] + dy * dy * Bl[1, 1])
                    if d > change:
                        change = d
                fr[a, 0] = nx
                fr[a, 1] = ny
            sweeps += 1
            if change <= tol:
                break
    for c in range(6):
        u_out[c] = u[c] + restitution * (u_plus[c] - u_minus[c])
    for a in range(nc):
        lam_out[a] = lam[a]
    return sweeps


@njit(cache=True, inline="always")
def _project_listed_body(q, bodies, row_off, u_minus, mass, R, inertia, normal, lever, target, mu_cos, mu_sin,
                         restitution, normal_mode, qp_iter, tol, u_out, lam_out, sweeps_out):
    """:func:`project_body` for body ``bodies[q]`` (contact rows row_off[q]:row_off[q+1]), written into
    u_out, lam_out and sweeps_out[q]: the loop body of the batched and the serial projection."""
    s = bodies[q]
    a, b = row_off[q], row_off[q + 1]
    Iwi = world_inverse_inertia(R[s], inertia[s])
    uo = np.zeros(6)
    lo = np.zeros(b - a)
    sweeps_out[q] = project_body(u_minus[s], mass[s], Iwi, normal[a:b], lever[a:b], R[s, :, 2].copy(),
                                 target[a:b], mu_cos, mu_sin, restitution, normal_mode, qp_iter, tol, uo, lo)
    for c in range(6):
        u_out[s, c] = uo[c]
    for k in range(b - a):
        lam_out[a + k] = lo[k]


@njit(cache=True, parallel=True)
def project_bodies_batch(bodies, row_off, u_minus, mass, R, inertia, normal, lever, target, mu_cos, mu_sin,
                         restitution, normal_mode, qp_iter, tol, u_out, lam_out, sweeps_out):
    """:func:`project_body` for every body in ``bodies`` (its contact rows row_off[q]:row_off[q+1]),
    in parallel. u_minus, u_out (S, 6); lam_out (rows,); sweeps_out (len(bodies),)."""
    for q in prange(bodies.shape[0]):
        _project_listed_body(q, bodies, row_off, u_minus, mass, R, inertia, normal, lever, target, mu_cos, mu_sin,
                             restitution, normal_mode, qp_iter, tol, u_out, lam_out, sweeps_out)


# --------------------------------------------------------------------------------------------------
# coupled contact projection: nonlinear Gauss–Seidel over all contacts (Moreau–Jean NSCD)
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def _frame(axis, n):
    t1 = axis - (axis[0] * n[0] + axis[1] * n[1] + axis[2] * n[2]) * n
    l1 = np.sqrt(t1[0] ** 2 + t1[1] ** 2 + t1[2] ** 2)
    if l1 < 1e-9:
        helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        t1 = helper - (helper[0] * n[0] + helper[1] * n[1] + helper[2] * n[2]) * n
        l1 = np.sqrt(t1[0] ** 2 + t1[1] ** 2 + t1[2] ** 2)
    t1 = t1 / l1
    return t1, _cross(n, t1)


@njit(cache=True)
def project_coupled(body, partner, normal, lever, partner_lever, target, u, mass, R, inertia, mu_cos, mu_sin,
                    restitution, max_iter, tol, lam_out, joint_k, joint_l, joint_rk, joint_rl, joint_target,
                    joint_compliance_inv, joint_w0):
    """Projected nonlinear Gauss–Seidel over all contacts (one row per pair, relative velocities):
    ``min Σ_b ½‖u_b − u⁻_b‖²_M`` s.t. n·(u_A − u_B)(contact) ≥ target, with the friction polygon
    λ_c·conv{μ_β d_β} per contact (frame t₁ from body A's axis) and the same exact 2-D block solves as
    :func:`project_body`. u (S, 6) holds u⁻ on entry and the result on exit (restitution added to the
    normal part). partner = −1: static obstacle.

    Joint rows (joint_k, joint_l bodies, −1 = fixed root anchor; levers joint_rk, joint_rl (nj, 3), m;
    joint_target (nj, 3) m/s) are bilateral point-joint constraints (u_k + ω_k × r_k) − (u_l + ω_l × r_l)
    = target, solved in the same sweeps with their exact 3×3 K-matrix blocks (Mirtich 1996), so the
    contact impulses and the joints agree at the velocity level (the velocity-level counterpart of the
    seed's harmonisation).

    Spring rows (joint_compliance_inv (nj, 3, 3): C = ½Δt² K_w + Δt c E, the implicit bending/torsion
    spring of §8.5.3 seen over the second half step; joint_w0 (nj, 3) rad/s: relative angular velocity
    ω_l − ω_k on entry): the joint's extra angular impulse pair (+Λ on k, −Λ on l) obeys
    Λ = C (ω_rel(u) − ω_rel,0), i.e. the contact stage sees the same linearly implicit springs as the
    joint stage. Without these rows the contact stage treats the chain as a floppy ball-joint chain:
    an off-centre contact impulse bends it freely, and the springs of the next joint stage then push
    back from a state they never agreed to, which pumps energy into stacked multi-segment fibres.
    Returns the sweeps used."""
    nc = body.shape[0]
    m = mu_cos.shape[0]
    MA = np.zeros((nc, 3, 6))
    MB = np.zeros((nc, 3, 6))
    JA = np.zeros((nc, 3, 6))
    JB = np.zeros((nc, 3, 6))
    W = np.zeros((nc, 3, 3))
    for c in range(nc):
        a = body[c]
        n = normal[c]
        t1, t2 = _frame(R[a, :, 2].copy(), n)
        IA = world_inverse_inertia(R[a], inertia[a])
        for k in range(3):
            d = n if k == 0 else (t1 if k == 1 else t2)
            rd = _cross(lever[c], d)
            for q in range(3):
                JA[c, k, q] = d[q]
                JA[c, k, 3 + q] = rd[q]
                MA[c, k, q] = d[q] / mass[a]
            MA[c, k, 3:] = IA @ rd
        b = partner[c]
        if b >= 0:
            IB = world_inverse_inertia(R[b], inertia[b])
            for k in range(3):
                d = n if k == 0 else (t1 if k == 1 else t2)
                rd = _cross(partner_lever[c], d)
                for q in range(3):
                    JB[c, k, q] = d[q]
                    JB[c, k, 3 + q] = rd[q]
                    MB[c, k, q] = d[q] / mass[b]
                MB[c, k, 3:] = IB @ rd
        for k in range(3):
            for q in range(3):
                s = 0.0
                for z in range(6):
                    s += JA[c, k, z] * MA[c, q, z] + JB[c, k, z] * MB[c, q, z]
                W[c, k, q] = s
    nj = joint_k.shape[0]
    # joint blocks: point row and implicit spring row of a joint solved together, δ(p, Λ) = −W6 e with the
    # exact 6×6 block  [[K_pp, K_pa], [K_ap, K_aa]]  (body k: Δv = p/m, Δω = I⁻¹(r̃_k p + Λ); body l: minus that
    # with its own lever): K_pp = Σ(E/m − r̃ I⁻¹ r̃), K_pa = −Σ r̃ I⁻¹, K_ap = −C Σ I⁻¹ r̃, K_aa = −C Σ I⁻¹ − E
    Ik = np.zeros((nj, 3, 3))
    Il = np.zeros((nj, 3, 3))
    W6 = np.zeros((nj, 6, 6))
    for j in range(nj):
        M6 = np.zeros((6, 6))
        Cq = joint_compliance_inv[j]
        for side in range(2):
            b = joint_k[j] if side == 0 else joint_l[j]
            if b < 0:
                continue
            r = joint_rk[j] if side == 0 else joint_rl[j]
            rt = skew(r)
            Iw = world_inverse_inertia(R[b], inertia[b])
            if side == 0:
                Ik[j] = Iw
            else:
                Il[j] = Iw
            M6[:3, :3] += np.eye(3) / mass[b] - rt @ Iw @ rt
            M6[:3, 3:] -= rt @ Iw
            M6[3:, :3] -= Cq @ Iw @ rt
            M6[3:, 3:] -= Cq @ Iw
        for z in range(3):
            M6[3 + z, 3 + z] -= 1.0
        W6[j] = np.linalg.inv(M6)
    Lam = np.zeros((nj, 3))
    e6 = np.zeros(6)
    dq6 = np.zeros(6)
    tk = np.zeros(3)
    lam = np.zeros(nc)
    fr = np.zeros((nc, 2))
    dun = np.zeros(u.shape)
    px = np.zeros(max(m, 1))
    py = np.zeros(max(m, 1))
    Bl = np.zeros((2, 2))
    cl = np.zeros(2)
    vr = np.zeros(3)
    it = 0
    while it < max_iter:
        it += 1
        change = 0.0
        for jq in range(2 * nj):
            j = jq if jq < nj else 2 * nj - 1 - jq  # forward and backward along the chains
            k = joint_k[j]
            l = joint_l[j]
            rl = joint_rl[j]
            v0 = -joint_target[j, 0] - u[l, 0] - (u[l, 4] * rl[2] - u[l, 5] * rl[1])
            v1 = -joint_target[j, 1] - u[l, 1] - (u[l, 5] * rl[0] - u[l, 3] * rl[2])
            v2 = -joint_target[j, 2] - u[l, 2] - (u[l, 3] * rl[1] - u[l, 4] * rl[0])
            if k >= 0:
                rk = joint_rk[j]
                v0 += u[k, 0] + (u[k, 4] * rk[2] - u[k, 5] * rk[1])
                v1 += u[k, 1] + (u[k, 5] * rk[0] - u[k, 3] * rk[2])
                v2 += u[k, 2] + (u[k, 3] * rk[1] - u[k, 4] * rk[0])
            # spring row residual: C (ω_l − ω_k − ω_rel,0) − Λ
            Cq = joint_compliance_inv[j]
            for z in range(3):
                e6[z] = v0
                e6[3 + z] = u[l, 3 + z] - (u[k, 3 + z] if k >= 0 else 0.0) - joint_w0[j, z]
            e6[1] = v1
            e6[2] = v2
            wa0, wa1, wa2 = e6[3], e6[4], e6[5]
            for z in range(3):
                e6[3 + z] = Cq[z, 0] * wa0 + Cq[z, 1] * wa1 + Cq[z, 2] * wa2 - Lam[j, z]
            # allocation-free: δ = −W6 e, then the impulse pair (p, Λ) on k (+) and l (−)
            for z in range(6):
                sacc = 0.0
                for q in range(6):
                    sacc += W6[j, z, q] * e6[q]
                dq6[z] = -sacc
            for z in range(3):
                Lam[j, z] += dq6[3 + z]
            if k >= 0:
                rk = joint_rk[j]
                tk[0] = rk[1] * dq6[2] - rk[2] * dq6[1] + dq6[3]
                tk[1] = rk[2] * dq6[0] - rk[0] * dq6[2] + dq6[4]
                tk[2] = rk[0] * dq6[1] - rk[1] * dq6[0] + dq6[5]
                im = 1.0 / mass[k]
                for z in range(3):
                    u[k, z] += dq6[z] * im
                    u[k, 3 + z] += Ik[j, z, 0] * tk[0] + Ik[j, z, 1] * tk[1] + Ik[j, z, 2] * tk[2]
            tk[0] = rl[1] * dq6[2] - rl[2] * dq6[1] + dq6[3]
            tk[1] = rl[2] * dq6[0] - rl[0] * dq6[2] + dq6[4]
            tk[2] = rl[0] * dq6[1] - rl[1] * dq6[0] + dq6[5]
            im = 1.0 / mass[l]
            for z in range(3):
                u[l, z] -= dq6[z] * im
                u[l, 3 + z] -= Il[j, z, 0] * tk[0] + Il[j, z, 1] * tk[1] + Il[j, z, 2] * tk[2]
            d = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            if d > change:
                change = d
        for q in range(nc):
            c = q if it % 2 == 1 else nc - 1 - q  # symmetric Gauss–Seidel
            a = body[c]
            b = partner[c]
            for k in range(3):
                s = 0.0
                for z in range(6):
                    s += JA[c, k, z] * u[a, z]
                    if b >= 0:
                        s -= JB[c, k, z] * u[b, z]
                vr[k] = s
            new = lam[c] + (target[c] - vr[0]) / W[c, 0, 0]
            if new < 0.0:
                new = 0.0
            dl = new - lam[c]
            if dl != 0.0:
                for z in range(6):
                    u[a, z] += MA[c, 0, z] * dl
                    dun[a, z] += MA[c, 0, z] * dl
                    if b >= 0:
                        u[b, z] -= MB[c, 0, z] * dl
                        dun[b, z] -= MB[c, 0, z] * dl
                for k in range(3):
                    vr[k] += W[c, k, 0] * dl
                change = max(change, abs(dl) * W[c, 0, 0])
            lam[c] = new
            if m < 3:
                continue
            Bl[0, 0] = W[c, 1, 1]
            Bl[0, 1] = W[c, 1, 2]
            Bl[1, 0] = W[c, 2, 1]
            Bl[1, 1] = W[c, 2, 2]
            cl[0] = vr[1] - Bl[0, 0] * fr[c, 0] - Bl[0, 1] * fr[c, 1]
            cl[1] = vr[2] - Bl[1, 0] * fr[c, 0] - Bl[1, 1] * fr[c, 1]
            if lam[c] > 0.0:
                for z in range(m):
                    px[z] = lam[c] * mu_cos[z]
                    py[z] = lam[c] * mu_sin[z]
                nx, ny = _polygon_qp(Bl, cl, px, py, m)
            else:
                nx, ny = 0.0, 0.0
            dx, dy = nx - fr[c, 0], ny - fr[c, 1]
            if dx != 0.0 or dy != 0.0:
                for z in range(6):
                    u[a, z] += MA[c, 1, z] * dx + MA[c, 2, z] * dy
                    if b >= 0:
                        u[b, z] -= MB[c, 1, z] * dx + MB[c, 2, z] * dy
                change = max(change, np.sqrt(dx * dx * Bl[0, 0] + dy * dy * Bl[1, 1]))
            fr[c, 0] = nx
            fr[c, 1] = ny
        if change <= tol:
            break
    if restitution > 0.0:
        for s in range(u.shape[0]):
            for z in range(6):
                u[s, z] += restitution * dun[s, z]
    for c in range(nc):
        lam_out[c] = lam[c]
    return it


@njit(cache=True)
def correct_joints_serial(fibres, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame,
                          dt, gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out,
                          iterations, gaps):
    """Serial twin of :func:`correct_joints_batch` (small problems, loaded machines)."""
    for q in range(fibres.shape[0]):
        f = fibres[q]
        it, g = correct_fibre_joints(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point,
                                     root_frame, dt, gravity, dx_extra, dth_extra, K, rest, damping, tol,
                                     max_iter, v_out, w_out)
        iterations[f] = it
        gaps[f] = g


@njit(cache=True)
def project_bodies_serial(bodies, row_off, u_minus, mass, R, inertia, normal, lever, target, mu_cos, mu_sin,
                          restitution, normal_mode, qp_iter, tol, u_out, lam_out, sweeps_out):
    """Serial twin of :func:`project_bodies_batch`."""
    for q in range(bodies.shape[0]):
        _project_listed_body(q, bodies, row_off, u_minus, mass, R, inertia, normal, lever, target, mu_cos, mu_sin,
                             restitution, normal_mode, qp_iter, tol, u_out, lam_out, sweeps_out)


@njit(cache=True)
def half_step_serial(x, R, v, w, inertia, h, x_out, R_out, w_out):
    """Serial twin of :func:`half_step`."""
    for s in range(x.shape[0]):
        _half_step_one(s, x, R, v, w, inertia, h, x_out, R_out, w_out)
