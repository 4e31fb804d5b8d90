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


@njit(cache=True, inline="always")
def _log_so3_parts(R):
    """The components of :func:`log_so3` (R) as three scalars (no temporary arrays)."""
    c = 0.5 * (R[0, 0] + R[1, 1] + R[2, 2] - 1.0)
    c = min(1.0, max(-1.0, c))
    th = np.arccos(c)
    v0, v1, v2 = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    if th < 1e-6:
        return 0.5 * v0, 0.5 * v1, 0.5 * v2
    s = np.sin(th)
    if s > 1e-6:
        f = 0.5 * th / s
        return v0 * f, v1 * f, v2 * f
    # near π: axis from the symmetric part B = cosθ E + (1 − cosθ) a aᵀ (its largest diagonal entry first)
    a0 = np.sqrt(max(0.0, (R[0, 0] - c) / (1.0 - c)))
    a1 = np.sqrt(max(0.0, (R[1, 1] - c) / (1.0 - c)))
    a2 = np.sqrt(max(0.0, (R[2, 2] - c) / (1.0 - c)))
    if a0 >= a1 and a0 >= a2:
        a1 = 0.5 * (R[0, 1] + R[1, 0]) / ((1.0 - c) * a0)
        a2 = 0.5 * (R[0, 2] + R[2, 0]) / ((1.0 - c) * a0)
    elif a1 >= a2:
        a0 = 0.5 * (R[1, 0] + R[0, 1]) / ((1.0 - c) * a1)
        a2 = 0.5 * (R[1, 2] + R[2, 1]) / ((1.0 - c) * a1)
    else:
        a0 = 0.5 * (R[2, 0] + R[0, 2]) / ((1.0 - c) * a2)
        a1 = 0.5 * (R[2, 1] + R[1, 2]) / ((1.0 - c) * a2)
    nrm = np.sqrt(a0 ** 2 + a1 ** 2 + a2 ** 2)
    a0, a1, a2 = a0 / nrm, a1 / nrm, a2 / nrm
    if a0 * v0 + a1 * v1 + a2 * v2 < 0:
        a0, a1, a2 = -a0, -a1, -a2
    return a0 * th, a1 * th, a2 * th


@njit(cache=True)
def log_so3(R):
    """Rotation vector φ with exp(φ̃) = R (SO(3) log, eq. 8.83: 2 cos θ = tr R − 1, Ω̃ = (R − Rᵀ)/(2 sin θ);
    near θ = π the axis from the symmetric part of R)."""
    t0, t1, t2 = _log_so3_parts(R)
    return np.array([t0, t1, t2])


@njit(cache=True, inline="always")
def _inv_inertia_into(R, inertia, out):
    """out (3, 3) ← R diag(1/I) Rᵀ (world inverse inertia, 1/(kg m²))."""
    for a in range(3):
        for b in range(3):
            s = 0.0
            for c in range(3):
                s += R[a, c] * R[b, c] / inertia[c]
            out[a, b] = s


@njit(cache=True)
def world_inverse_inertia(R, inertia):
    """I_w⁻¹ = R diag(1/I) Rᵀ (1/(kg m²))."""
    out = np.zeros((3, 3))
    _inv_inertia_into(R, inertia, out)
    return out


@njit(cache=True, inline="always")
def _rodrigues_entries(p0, p1, p2):
    """The entries (e00, e01, e02, e10, e11, e12, e20, e21, e22) of exp(φ̃) for φ = (p0, p1, p2) (Rodrigues
    as :func:`rodrigues`: E = I + a k̃ + b k̃², k̃² = k kᵀ − |k|² I)."""
    th = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    if th < 1e-12:
        a, b2 = 1.0, 0.5
        k0, k1, k2 = p0, p1, p2
    else:
        a, b2 = np.sin(th), 1.0 - np.cos(th)
        k0, k1, k2 = p0 / th, p1 / th, p2 / th
    kk = k0 * k0 + k1 * k1 + k2 * k2
    return (1.0 + b2 * (k0 * k0 - kk), -a * k2 + b2 * k0 * k1, a * k1 + b2 * k0 * k2,
            a * k2 + b2 * k0 * k1, 1.0 + b2 * (k1 * k1 - kk), -a * k0 + b2 * k1 * k2,
            -a * k1 + b2 * k0 * k2, a * k0 + b2 * k1 * k2, 1.0 + b2 * (k2 * k2 - kk))


@njit(cache=True, inline="always")
def _half_step_one(s, x, R, v, w, inertia, h, x_out, R_out, w_out):
    """Body s of :func:`half_step`, without temporaries (scalars only: an allocation per body made the
    parallel loop ≈ 8× slower). R_out may be R."""
    for c in range(3):
        x_out[s, c] = x[s, c] + h * v[s, c]
    # torque-free rotation keeps the world angular momentum L = I_w ω
    w0, w1, w2 = w[s, 0], w[s, 1], w[s, 2]
    b0 = (R[s, 0, 0] * w0 + R[s, 1, 0] * w1 + R[s, 2, 0] * w2) * inertia[s, 0]
    b1 = (R[s, 0, 1] * w0 + R[s, 1, 1] * w1 + R[s, 2, 1] * w2) * inertia[s, 1]
    b2 = (R[s, 0, 2] * w0 + R[s, 1, 2] * w1 + R[s, 2, 2] * w2) * inertia[s, 2]
    L0 = R[s, 0, 0] * b0 + R[s, 0, 1] * b1 + R[s, 0, 2] * b2
    L1 = R[s, 1, 0] * b0 + R[s, 1, 1] * b1 + R[s, 1, 2] * b2
    L2 = R[s, 2, 0] * b0 + R[s, 2, 1] * b1 + R[s, 2, 2] * b2
    i1 = inertia[s, 0]
    if inertia[s, 1] == i1:
        # axisymmetric body (I₁ = I₂, axis e₃ = R[:, 2]): the exact torque-free motion, R(h) = exp(h L̃/I₁) R
        # exp(h λ ẽ₃) with λ = L₃ (1/I₃ − 1/I₁) (precession about the fixed L, spin about the body axis;
        # its angular velocity L/I₁ + λ e₃ = I_w⁻¹ L is ω at every instant, and the body's axial spin ω₃ and
        # the kinetic energy stay constant). The frozen-ω exponential exp(h ω̃) R with ω re-derived from L
        # instead turns L into the axis at second order: ω₃ grows by the factor 1 + ½ h² (I₁/I₃) |ω⊥|² per
        # step, and a thin segment's I₁/I₃ is ≈ 1,200 (3 mm × 70 µm): ×8,400 in 10 half steps of 0.5 ms at
        # ω⊥ = 100 rad/s, its kinetic energy ×6.8 (issue 10, thirty-fifth session). With the spherical inertia of
        # chain_model_from_polylines' default (I₃ = I₁) λ = 0 and L/I₁ = ω: the two updates coincide; this one matters
        # for the true axial moment (spherical_inertia=False)
        phi = h * b2 * (1.0 / inertia[s, 2] - 1.0 / i1)  # h λ, body frame b2 = L₃
        _exp_times_into(h * L0 / i1, h * L1 / i1, h * L2 / i1, R[s], R_out[s])
        cp, sp = np.cos(phi), np.sin(phi)
        for c in range(3):  # R_out ← R_out Rz(hλ): columns 0 and 1 turn about column 2
            e0, e1 = R_out[s, c, 0], R_out[s, c, 1]
            R_out[s, c, 0] = cp * e0 + sp * e1
            R_out[s, c, 1] = cp * e1 - sp * e0
    else:
        # (asymmetric inertia) the frozen-ω exponential, R_new = exp(h w̃) R
        _exp_times_into(h * w[s, 0], h * w[s, 1], h * w[s, 2], R[s], R_out[s])
    n0 = (R_out[s, 0, 0] * L0 + R_out[s, 1, 0] * L1 + R_out[s, 2, 0] * L2) / inertia[s, 0]
    n1 = (R_out[s, 0, 1] * L0 + R_out[s, 1, 1] * L1 + R_out[s, 2, 1] * L2) / inertia[s, 1]
    n2 = (R_out[s, 0, 2] * L0 + R_out[s, 1, 2] * L1 + R_out[s, 2, 2] * L2) / inertia[s, 2]
    for c in range(3):
        w_out[s, c] = R_out[s, c, 0] * n0 + R_out[s, c, 1] * n1 + R_out[s, c, 2] * n2


@njit(cache=True, inline="always")
def _exp_step_one(s, x, R, v, w, h, x_out, R_out):
    """Body s of :func:`exp_step`."""
    for c in range(3):
        x_out[s, c] = x[s, c] + h * v[s, c]
    _exp_times_into(h * w[s, 0], h * w[s, 1], h * w[s, 2], R[s], R_out[s])


@njit(cache=True, parallel=True)
def exp_step(x, R, v, w, h, x_out, R_out):
    """x + h v and exp(h w̃) R for every body: a position correction by the twist (v, w) over h (the exponential
    map; :func:`half_step` is the torque-free motion)."""
    for s in prange(x.shape[0]):
        _exp_step_one(s, x, R, v, w, h, x_out, R_out)


@njit(cache=True)
def exp_step_serial(x, R, v, w, h, x_out, R_out):
    """Serial twin of :func:`exp_step`."""
    for s in range(x.shape[0]):
        _exp_step_one(s, x, R, v, w, h, x_out, R_out)


@njit(cache=True, parallel=True)
def half_step(x, R, v, w, inertia, h, x_out, R_out, w_out):
    """x + h v, the torque-free rotation of R with initial angular velocity w over h (exact for axisymmetric
    bodies, see :func:`_half_step_one`; else exp(h w̃) R) and the angular-momentum-preserving ω for every body
    (the θ = 1 position update of Alg. 6, lines 2 and 14)."""
    for s in prange(x.shape[0]):
        _half_step_one(s, x, R, v, w, inertia, h, x_out, R_out, w_out)


# --------------------------------------------------------------------------------------------------
# Method I joint correction (§8.5.1, Alg. 7) with implicit joint springs (§8.5.3)
# --------------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _joint_impulses_into(b, s, n, j0, P, R, half, fl, tq):
    """Net linear impulse fl (3,) and angular impulse tq (3,) (written in place) of the joint impulses P
    (nj, 6) on body b (global segment s) of a chain of n bodies whose first joint row is j0: its inner joint
    b (body is "l") if it exists, and its outer joint b + 1 (body is "k"), applied at the segment ends
    ±half s."""
    for c in range(3):
        fl[c] = 0.0
        tq[c] = 0.0
    if b >= j0:
        jj = b - j0
        h = -half[s]
        r0, r1, r2 = h * R[s, 0, 2], h * R[s, 1, 2], h * R[s, 2, 2]
        p0, p1, p2 = P[jj, 0], P[jj, 1], P[jj, 2]
        fl[0] -= p0
        fl[1] -= p1
        fl[2] -= p2
        tq[0] -= P[jj, 3] + r1 * p2 - r2 * p1
        tq[1] -= P[jj, 4] + r2 * p0 - r0 * p2
        tq[2] -= P[jj, 5] + r0 * p1 - r1 * p0
    if b + 1 < n:
        jj = b + 1 - j0
        h = half[s]
        r0, r1, r2 = h * R[s, 0, 2], h * R[s, 1, 2], h * R[s, 2, 2]
        p0, p1, p2 = P[jj, 0], P[jj, 1], P[jj, 2]
        fl[0] += p0
        fl[1] += p1
        fl[2] += p2
        tq[0] += P[jj, 3] + r1 * p2 - r2 * p1
        tq[1] += P[jj, 4] + r2 * p0 - r0 * p2
        tq[2] += P[jj, 5] + r0 * p1 - r1 * p0


@njit(cache=True, inline="always")
def _exp_times_into(p0, p1, p2, Rs, out):
    """out (3, 3) ← exp(φ̃) Rs for φ = (p0, p1, p2) (Rodrigues as :func:`rodrigues`); out may be Rs (each
    column is read before it is written)."""
    e00, e01, e02, e10, e11, e12, e20, e21, e22 = _rodrigues_entries(p0, p1, p2)
    for c in range(3):
        r0, r1, r2 = Rs[0, c], Rs[1, c], Rs[2, c]
        out[0, c] = e00 * r0 + e01 * r1 + e02 * r2
        out[1, c] = e10 * r0 + e11 * r1 + e12 * r2
        out[2, c] = e20 * r0 + e21 * r1 + e22 * r2


@njit(cache=True, inline="always")
def _spring_moment(t0, t1, t2, e0, e1, e2):
    """The joint spring's moment in the frame of the joint's first body k: J_l⁻ᵀ(θ) e, the gradient of the energy
    ½ Σ_c K_c (θ_c − θ°_c)² (e = K(θ − θ°)) with respect to a rotation of the second body, θ = log(R_kᵀ R_l) (eq.
    8.83). J_l⁻ᵀ(θ) = E + ½ θ̃ + c θ̃², c = 1/θ² − (1 + cos θ)/(2 θ sin θ) (the inverse left Jacobian of SO(3),
    transposed). The moment e alone (J ≈ E) is exact only for small θ: with unequal bending and torsion
    stiffnesses its error ½ θ × e is a circulatory (non-conservative) moment, which gave a free, tightly coiled
    fibre energy without bound (issue 10, thirty-fourth session: 20 × 3 mm segments on a 5 mm helix, 30 × its
    initial energy in 0.3 s)."""
    th2 = t0 * t0 + t1 * t1 + t2 * t2
    if th2 < 1e-8:
        c = 1.0 / 12.0
    else:
        th = np.sqrt(th2)
        c = 1.0 / th2 - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th))
    return skew_series_times(t0, t1, t2, 0.5, c, e0, e1, e2)


@njit(cache=True, inline="always")
def skew_series_times(p0, p1, p2, a, b, r0, r1, r2):
    """(E + a p̃ + b p̃²) r = r + a p × r + b p × (p × r), as three scalars (the form of the SO(3) Jacobians and
    their inverses)."""
    c0 = p1 * r2 - p2 * r1
    c1 = p2 * r0 - p0 * r2
    c2 = p0 * r1 - p1 * r0
    d0 = p1 * c2 - p2 * c1
    d1 = p2 * c0 - p0 * c2
    d2 = p0 * c1 - p1 * c0
    return r0 + a * c0 + b * d0, r1 + a * c1 + b * d1, r2 + a * c2 + b * d2


@njit(cache=True, inline="always")
def _joint_gap_and_moment(b, s, f, x_end, R_end, half, root_point, root_frame, K, rest, damping, twists, col, Q):
    """Joint b's (segment s, fibre f) end-of-step gap d (eq. 8.76; m) and spring moment (world, N m: R_k J_l⁻ᵀ(θ)
    K (θ − θ°) + c ω_rel, θ = log(R_kᵀ R_l) at the end frames, §8.5.3), from the bodies' end positions x_end and
    frames R_end (local rows b − 1, b; the root anchor for b = 0) and their angular velocities twists[:, col:col + 3]
    (rad/s). Q (3, 3): a work array. Returns (d0, d1, d2, m0, m1, m2)."""
    hl = half[s]
    if b == 0:
        Rk = root_frame[f]
        d0 = root_point[f, 0] - (x_end[b, 0] - hl * R_end[b, 0, 2])
        d1 = root_point[f, 1] - (x_end[b, 1] - hl * R_end[b, 1, 2])
        d2 = root_point[f, 2] - (x_end[b, 2] - hl * R_end[b, 2, 2])
        wk0, wk1, wk2 = 0.0, 0.0, 0.0
    else:
        Rk = R_end[b - 1]
        hk = half[s - 1]
        d0 = x_end[b - 1, 0] + hk * Rk[0, 2] - (x_end[b, 0] - hl * R_end[b, 0, 2])
        d1 = x_end[b - 1, 1] + hk * Rk[1, 2] - (x_end[b, 1] - hl * R_end[b, 1, 2])
        d2 = x_end[b - 1, 2] + hk * Rk[2, 2] - (x_end[b, 2] - hl * R_end[b, 2, 2])
        wk0, wk1, wk2 = twists[b - 1, col], twists[b - 1, col + 1], twists[b - 1, col + 2]
    for r in range(3):
        for c in range(3):
            Q[r, c] = Rk[0, r] * R_end[b, 0, c] + Rk[1, r] * R_end[b, 1, c] + Rk[2, r] * R_end[b, 2, c]
    th0, th1, th2 = _log_so3_parts(Q)
    e0, e1, e2 = _spring_moment(th0, th1, th2, K[s, 0] * (th0 - rest[s, 0]), K[s, 1] * (th1 - rest[s, 1]),
                                K[s, 2] * (th2 - rest[s, 2]))
    c_d = damping[s]
    m0 = Rk[0, 0] * e0 + Rk[0, 1] * e1 + Rk[0, 2] * e2 + c_d * (twists[b, col] - wk0)
    m1 = Rk[1, 0] * e0 + Rk[1, 1] * e1 + Rk[1, 2] * e2 + c_d * (twists[b, col + 1] - wk1)
    m2 = Rk[2, 0] * e0 + Rk[2, 1] * e1 + Rk[2, 2] * e2 + c_d * (twists[b, col + 2] - wk2)
    return d0, d1, d2, m0, m1, m2


@njit(cache=True)
def _fibre_trial(s0, n, j0, P, x, R, v, w, mass, inertia, half, root_point, root_frame, f,
                 dt, gravity, dx_extra, dth_extra, K, rest, damping, res, x_end, R_end, w_new):
    """Trial integration over Δt (eqs. 8.78/8.80) with impulses P (nj, 6); fills the residual
    res (nj, 6): rows 0:3 joint gap d (eq. 8.76), rows 3:6 implicit spring L* − Δt[K_w(θ − θ°) + c ω_rel].
    Returns the largest gap norm, m. Scalar loops (no temporary arrays per segment)."""
    nj = n - j0
    fl = np.empty(3)
    tq = np.empty(3)
    body_tq = np.empty(3)
    Q = np.empty((3, 3))
    for b in range(n):
        s = s0 + b
        _joint_impulses_into(b, s, n, j0, P, R, half, fl, tq)
        # ω_new = ω + I_w⁻¹ τ, I_w⁻¹ = R diag(1/I) Rᵀ
        for a in range(3):
            t = 0.0
            for c in range(3):
                t += R[s, c, a] * tq[c]
            body_tq[a] = t / inertia[s, a]
        for a in range(3):
            w_new[b, a] = w[s, a] + R[s, a, 0] * body_tq[0] + R[s, a, 1] * body_tq[1] + R[s, a, 2] * body_tq[2]
        for c in range(3):
            x_end[b, c] = x[s, c] + dt * (v[s, c] + fl[c] / mass[s]) + 0.5 * dt * dt * gravity[c] + dx_extra[s, c]
        _exp_times_into(dt * w_new[b, 0] + dth_extra[s, 0], dt * w_new[b, 1] + dth_extra[s, 1],
                        dt * w_new[b, 2] + dth_extra[s, 2], R[s], R_end[b])
    gmax = 0.0
    for jj in range(nj):
        b = jj + j0
        s = s0 + b
        d0, d1, d2, m0, m1, m2 = _joint_gap_and_moment(b, s, f, x_end, R_end, half, root_point, root_frame, K, rest,
                                                       damping, w_new, 0, Q)
        res[jj, 0] = d0
        res[jj, 1] = d1
        res[jj, 2] = d2
        res[jj, 3] = P[jj, 3] - dt * m0
        res[jj, 4] = P[jj, 4] - dt * m1
        res[jj, 5] = P[jj, 5] - dt * m2
        g = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if g > gmax:
            gmax = g
    return gmax


@njit(cache=True, inline="always")
def _wrench_map(r, sign, B):
    """B (6, 6) ← map (p, L*) → wrench (f, τ) on a body with lever r: sign·[[E, 0], [r̃, E]] (eq. 8.72)."""
    for a in range(6):
        for c in range(6):
            B[a, c] = 0.0
    for a in range(3):
        B[a, a] = sign
        B[3 + a, 3 + a] = sign
    B[3, 1] = -sign * r[2]
    B[3, 2] = sign * r[1]
    B[4, 0] = sign * r[2]
    B[4, 2] = -sign * r[0]
    B[5, 0] = -sign * r[1]
    B[5, 1] = sign * r[0]


@njit(cache=True, inline="always")
def _rate_map(r, sign, C):
    """C (6, 6) ← map twist (v, ω) of a body → (gap rate, relative angular rate): k: [[E, −r̃], [0, −E]],
    l: [[−E, r̃], [0, E]] (sign = +1 for k, −1 for l)."""
    for a in range(6):
        for c in range(6):
            C[a, c] = 0.0
    for a in range(3):
        C[a, a] = sign
        C[3 + a, 3 + a] = -sign
    C[0, 4] = sign * r[2]
    C[0, 5] = -sign * r[1]
    C[1, 3] = -sign * r[2]
    C[1, 5] = sign * r[0]
    C[2, 3] = sign * r[1]
    C[2, 4] = -sign * r[0]


@njit(cache=True, inline="always")
def _rate_times_mobility(s, r, sign, R, mass, inertia, out, C, Iwi):
    """out (6, 6) ← C(r, sign) W_s (rate map times the body's mobility diag(E/m, I_w⁻¹)); C (6, 6) and
    Iwi (3, 3) are work arrays."""
    _rate_map(r, sign, C)
    _inv_inertia_into(R[s], inertia[s], Iwi)
    im = 1.0 / mass[s]
    for a in range(6):
        for c in range(3):
            out[a, c] = C[a, c] * im
            t = 0.0
            for z in range(3):
                t += C[a, 3 + z] * Iwi[z, c]
            out[a, 3 + c] = t


@njit(cache=True, inline="always")
def _mm6_add(A, B, out, scale):
    """out (6, 6) += scale · A B."""
    for a in range(6):
        for c in range(6):
            t = 0.0
            for z in range(6):
                t += A[a, z] * B[z, c]
            out[a, c] += scale * t


@njit(cache=True, inline="always")
def inv6_into(A, out):
    """out ← A⁻¹ (6 × 6, Gauss–Jordan with partial pivoting; A is overwritten)."""
    for a in range(6):
        for c in range(6):
            out[a, c] = 1.0 if a == c else 0.0
    for c in range(6):
        p = c
        best = abs(A[c, c])
        for a in range(c + 1, 6):
            if abs(A[a, c]) > best:
                best = abs(A[a, c])
                p = a
        if p != c:
            for z in range(6):
                t = A[c, z]
                A[c, z] = A[p, z]
                A[p, z] = t
                t = out[c, z]
                out[c, z] = out[p, z]
                out[p, z] = t
        d = 1.0 / A[c, c]
        for z in range(6):
            A[c, z] *= d
            out[c, z] *= d
        for a in range(6):
            if a != c:
                f = A[a, c]
                if f != 0.0:
                    for z in range(6):
                        A[a, z] -= f * A[c, z]
                        out[a, z] -= f * out[c, z]


@njit(cache=True)
def _fibre_jacobian(s0, n, j0, R, mass, inertia, half, dt, K, damping, Dg, Lo, Up):
    """First-order (chord) Jacobian of the trial residual w.r.t. the joint impulses, block-tridiagonal:
    Dg[j] = ∂res_j/∂P_j, Lo[j] = ∂res_j/∂P_{j−1}, Up[j] = ∂res_j/∂P_{j+1} (the linearised K-matrix
    coupling of Mirtich / Bender, used as the Newton matrix of Method I). Allocation-free 6 × 6 loops."""
    nj = n - j0
    CWl = np.empty((6, 6))
    CWk = np.empty((6, 6))
    B = np.empty((6, 6))
    T = np.empty((6, 6))
    C = np.empty((6, 6))
    Iwi = np.empty((3, 3))
    rv = np.empty(3)
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
        for c in range(3):
            rv[c] = -half[s] * R[s, c, 2]
        _rate_times_mobility(s, rv, -1.0, R, mass, inertia, CWl, C, Iwi)
        _wrench_map(rv, -1.0, B)
        _mm6_add(CWl, B, Dg[jj], 1.0)
        if b > 0:
            sk = s - 1
            for c in range(3):
                rv[c] = half[sk] * R[sk, c, 2]
            _rate_times_mobility(sk, rv, 1.0, R, mass, inertia, CWk, C, Iwi)
            _wrench_map(rv, 1.0, B)
            _mm6_add(CWk, B, Dg[jj], 1.0)
            if jj > 0:  # joint jj-1 acts on body k as its "l"
                for c in range(3):
                    rv[c] = -half[sk] * R[sk, c, 2]
                _wrench_map(rv, -1.0, B)
                _mm6_add(CWk, B, Lo[jj], 1.0)
        if b + 1 < n:  # joint jj+1 acts on body l as its "k"
            for c in range(3):
                rv[c] = half[s] * R[s, c, 2]
            _wrench_map(rv, 1.0, B)
            _mm6_add(CWl, B, Up[jj], 1.0)
        # row scaling diag(Δt E, −(Δt² K_w + Δt c E)) of the gap and spring rows, then + E on the spring rows
        Rk = R[s - 1] if b > 0 else R[s]
        for a in range(6):
            for c in range(6):
                T[a, c] = 0.0
        for a in range(3):
            T[a, a] = dt
            for c in range(3):
                kw = Rk[a, 0] * K[s, 0] * Rk[c, 0] + Rk[a, 1] * K[s, 1] * Rk[c, 1] + Rk[a, 2] * K[s, 2] * Rk[c, 2]
                T[3 + a, 3 + c] = -(dt * dt * kw + (dt * damping[s] if a == c else 0.0))
        for M in (Dg, Lo, Up):
            for a in range(6):
                for c in range(6):
                    B[a, c] = M[jj, a, c]
                    M[jj, a, c] = 0.0
            _mm6_add(T, B, M[jj], 1.0)
        for a in range(3):
            Dg[jj, 3 + a, 3 + a] += 1.0


@njit(cache=True)
def _block_thomas_factor(nj, Dg, Lo, Up, Dinv, G):
    D = np.empty((6, 6))
    for jj in range(nj):
        for a in range(6):
            for c in range(6):
                D[a, c] = Dg[jj, a, c]
        if jj > 0:
            for a in range(6):
                for c in range(6):
                    G[jj, a, c] = 0.0
            _mm6_add(Lo[jj], Dinv[jj - 1], G[jj], 1.0)
            _mm6_add(G[jj], Up[jj - 1], D, -1.0)
        inv6_into(D, Dinv[jj])


@njit(cache=True)
def _block_thomas_solve(nj, Up, Dinv, G, rhs, out):
    y = np.empty((nj, 6))
    for jj in range(nj):
        for a in range(6):
            t = rhs[jj, a]
            if jj > 0:
                for z in range(6):
                    t -= G[jj, a, z] * y[jj - 1, z]
            y[jj, a] = t
    t6 = np.empty(6)
    for jj in range(nj - 1, -1, -1):
        for a in range(6):
            t = y[jj, a]
            if jj < nj - 1:
                for z in range(6):
                    t -= Up[jj, a, z] * out[jj + 1, z]
            t6[a] = t
        for a in range(6):
            t = 0.0
            for z in range(6):
                t += Dinv[jj, a, z] * t6[z]
            out[jj, a] = t


@njit(cache=True)
def correct_fibre_joints(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame,
                         dt, gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out,
                         factor_up, factor_dinv, factor_g, factor_ready):
    """Method I for one fibre (Alg. 7 lines 2–12): Newton-type iteration on the joint-gap system
    (eqs. 8.87/8.89) with the spring rows of §8.5.3 linearly implicit, always restarting the trial
    integration from the saved t_i state. Writes the corrected velocities of the fibre's segments into
    v_out, w_out. Returns (iterations, predicted max gap after correction (m)).

    factor_up, factor_dinv, factor_g (S, 6, 6): the block-Thomas factorisation of the Newton matrix, the
    fibre's joints at its segment rows seg_off[f]:; computed into them unless ``factor_ready`` (the matrix
    depends on the rotations R and the constants only, so the harmonisation passes of one step share it)."""
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
    Up = factor_up[s0:s0 + nj]
    Dinv = factor_dinv[s0:s0 + nj]
    G = factor_g[s0:s0 + nj]
    if not factor_ready:
        Dg = np.zeros((nj, 6, 6))
        Lo = np.zeros((nj, 6, 6))
        Up[:] = 0.0
        Dinv[:] = 0.0
        G[:] = 0.0
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
    fl = np.empty(3)
    tq = np.empty(3)
    Iwi = np.empty((3, 3))
    for b in range(n):
        s = s0 + b
        _joint_impulses_into(b, s, n, j0, P, R, half, fl, tq)
        _inv_inertia_into(R[s], inertia[s], Iwi)
        for c in range(3):
            v_out[s, c] = v[s, c] + fl[c] / mass[s]
            w_out[s, c] = w[s, c] + (Iwi[c, 0] * tq[0] + Iwi[c, 1] * tq[1] + Iwi[c, 2] * tq[2])
    return it, gmax


@njit(cache=True, parallel=True)
def correct_joints_batch(fibres, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame,
                         dt, gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out,
                         factor_up, factor_dinv, factor_g, factor_ready, iterations, gaps):
    """:func:`correct_fibre_joints` for the fibres in ``fibres`` in parallel (each fibre's joint
    solve is independent). iterations (F,) int64 and gaps (F,) float64 receive the per-fibre stats."""
    for q in prange(fibres.shape[0]):
        f = fibres[q]
        it, g = correct_fibre_joints(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point,
                                     root_frame, dt, gravity, dx_extra, dth_extra, K, rest, damping, tol,
                                     max_iter, v_out, w_out, factor_up, factor_dinv, factor_g, factor_ready)
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


@njit(cache=True, inline="always")
def _edge_terms(B, c, px, py, i, m):
    """(j, ex, ey, gx, gy, bex, bey, eBe) of the polygon edge from vertex i to vertex j = i + 1 (mod m) of
    (px, py) for q(f) = ½ fᵀBf + fᵀc: the edge e, the gradient g = B v_i + c at its start, B e and eᵀBe."""
    j = i + 1 if i + 1 < m else 0
    ex, ey = px[j] - px[i], py[j] - py[i]
    gx = B[0, 0] * px[i] + B[0, 1] * py[i] + c[0]
    gy = B[1, 0] * px[i] + B[1, 1] * py[i] + c[1]
    bex = B[0, 0] * ex + B[0, 1] * ey
    bey = B[1, 0] * ex + B[1, 1] * ey
    return j, ex, ey, gx, gy, bex, bey, ex * bex + ey * bey


@njit(cache=True, inline="always")
def _edge_minimiser(B, c, px, py, i, m):
    """(q, fx, fy): the minimiser of q(f) = ½ fᵀBf + fᵀc on the polygon edge from vertex i to vertex i + 1
    (mod m) of (px, py) (the clamped one of its line) and its value."""
    _, ex, ey, gx, gy, _, _, eBe = _edge_terms(B, c, px, py, i, m)
    t = 0.0
    if eBe > 0:
        t = -(ex * gx + ey * gy) / eBe
        t = min(1.0, max(0.0, t))
    qx, qy = px[i] + t * ex, py[i] + t * ey
    q = 0.5 * (qx * (B[0, 0] * qx + B[0, 1] * qy) + qy * (B[1, 0] * qx + B[1, 1] * qy)) + qx * c[0] + qy * c[1]
    return q, qx, qy


@njit(cache=True, inline="always")
def _kkt_edge(B, c, px, py, i, m):
    """Walk along the polygon's boundary from edge i to the edge or vertex where q(f) = ½ fᵀBf + fᵀc meets
    the KKT conditions of its minimisation over the polygon (see :func:`_polygon_qp`): the index of an edge
    holding that point, or −1 where the walk would turn back or passes m edges (rounding at a vertex)."""
    came = 0
    for _ in range(m):
        j, ex, ey, gx, gy, bex, bey, eBe = _edge_terms(B, c, px, py, i, m)
        t = -(ex * gx + ey * gy) / eBe if eBe > 0 else 0.0
        if t > 0.0 and t < 1.0:  # inside the edge: optimal if the gradient there opposes the outward normal
            if (gx + t * bex) * ey - (gy + t * bey) * ex <= 0.0:
                return i
            return -1
        if t <= 0.0:  # at vertex i: optimal unless the previous edge descends towards it
            h = i - 1 if i > 0 else m - 1
            if gx * (px[i] - px[h]) + gy * (py[i] - py[h]) <= 0.0:
                return i
            if came == 1:
                return -1
            i = h
            came = -1
        else:  # at vertex j: optimal unless the next edge descends away from it
            k = j + 1 if j + 1 < m else 0
            if (gx + bex) * (px[k] - px[j]) + (gy + bey) * (py[k] - py[j]) >= 0.0:
                return i
            if came == -1:
                return -1
            i = j
            came = 1
    return -1


@njit(cache=True)
def _polygon_qp(B, c, px, py, m):
    """min ½ fᵀBf + fᵀc over the convex polygon with CCW vertices (px, py) containing the origin
    (the friction set λ·conv{μ_β d_β}, V-representation of eq. 8.51). Exact: the interior minimiser, or
    the best clamped minimiser over the edges (lowest q, the first edge on ties; :func:`_boundary_qp`)."""
    det = B[0, 0] * B[1, 1] - B[0, 1] * B[1, 0]
    fx = -(B[1, 1] * c[0] - B[0, 1] * c[1]) / det
    fy = -(-B[1, 0] * c[0] + B[0, 0] * c[1]) / det
    for i in range(m):
        j = (i + 1) % m
        ex, ey = px[j] - px[i], py[j] - py[i]
        if ex * (fy - py[i]) - ey * (fx - px[i]) < 0.0:
            return _boundary_qp(B, c, px, py, m, i)
    return fx, fy


@njit(cache=True)
def _boundary_qp(B, c, px, py, m, first):
    """:func:`_polygon_qp` where the unconstrained minimiser f* = −B⁻¹c violates edge ``first`` (the first
    such edge): the best clamped minimiser over the edges (lowest q, the first edge on ties), without
    comparing all m edges. A walk along the boundary from edge ``first`` moves to the neighbour that
    descends until a point meets the KKT conditions of the convex problem (inside an edge: the gradient
    Bf + c there opposes the edge's outward normal; at a vertex: neither edge descends into the polygon),
    which makes it the unique minimiser (:func:`_kkt_edge`). Only that edge and its two neighbours are then
    compared (they hold every point near it), so the result is the full comparison's to the last bit except
    on exact ties between farther edges; a walk that fails (rounding at a vertex) compares all m edges."""
    e = _kkt_edge(B, c, px, py, first, m)
    best = np.inf
    bx, by = 0.0, 0.0
    if e < 0 or m <= 3:
        for i in range(m):
            q, qx, qy = _edge_minimiser(B, c, px, py, i, m)
            if q < best:
                best = q
                bx, by = qx, qy
        return bx, by
    # edges e − 1, e, e + 1 (mod m) in index order (0 before m − 2 and m − 1 where they wrap)
    if e == 0:
        a0, a1, a2 = 0, 1, m - 1
    elif e == m - 1:
        a0, a1, a2 = 0, m - 2, m - 1
    else:
        a0, a1, a2 = e - 1, e, e + 1
    for r in range(3):
        i = a0 if r == 0 else (a1 if r == 1 else a2)
        q, qx, qy = _edge_minimiser(B, c, px, py, i, m)
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
        Tf = np.empty((2, 3))
        for a in range(nc):
            _tangents_into(axis[0], axis[1], axis[2], normal[a], Tf)
            for k in range(2):
                t = Tf[k]
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
# friction frame (shared with the coupled contact projection, chains_coupled.py)
# --------------------------------------------------------------------------------------------------


@njit(cache=True)
def _frame(axis, n):
    """(t₁, t₂) of :func:`_tangents_into` for the axis (3,) as arrays."""
    T = np.empty((2, 3))
    _tangents_into(axis[0], axis[1], axis[2], n, T)
    return T[0], T[1]


@njit(cache=True, inline="always")
def _tangents_into(x0, x1, x2, n, T):
    """T[0], T[1] ← the friction frame's tangents for the axis (x0, x1, x2) and the unit normal n: t₁ the axis
    projected onto the contact plane (a fixed helper direction where the axis is along n), t₂ = n × t₁. Writes
    into T (2, 3), so that the coupled set-up allocates nothing per contact row."""
    d = x0 * n[0] + x1 * n[1] + x2 * n[2]
    y0, y1, y2 = x0 - d * n[0], x1 - d * n[1], x2 - d * n[2]
    l1 = np.sqrt(y0 ** 2 + y1 ** 2 + y2 ** 2)
    if l1 < 1e-9:
        x0, x1, x2 = (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0)
        d = x0 * n[0] + x1 * n[1] + x2 * n[2]
        y0, y1, y2 = x0 - d * n[0], x1 - d * n[1], x2 - d * n[2]
        l1 = np.sqrt(y0 ** 2 + y1 ** 2 + y2 ** 2)
    y0, y1, y2 = y0 / l1, y1 / l1, y2 / l1
    T[0, 0], T[0, 1], T[0, 2] = y0, y1, y2
    T[1, 0] = n[1] * y2 - n[2] * y1
    T[1, 1] = n[2] * y0 - n[0] * y2
    T[1, 2] = n[0] * y1 - n[1] * y0


@njit(cache=True)
def correct_joints_serial(fibres, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame,
                          dt, gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out,
                          factor_up, factor_dinv, factor_g, factor_ready, iterations, gaps):
    """Serial twin of :func:`correct_joints_batch` (small problems, loaded machines)."""
    for q in range(fibres.shape[0]):
        f = fibres[q]
        it, g = correct_fibre_joints(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point,
                                     root_frame, dt, gravity, dx_extra, dth_extra, K, rest, damping, tol,
                                     max_iter, v_out, w_out, factor_up, factor_dinv, factor_g, factor_ready)
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
