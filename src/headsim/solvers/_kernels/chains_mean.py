"""Numba kernels of the chain solver's joint stage with the impulses at the mean levers
(``ChainOptions.joint_levers`` = "mean"; Sobottka 2008 §8.5, Method I, eqs. 8.72/8.76/8.78/8.80 with the levers
changed; SI units).

Method I applies each joint impulse at the levers ±h R e₃ of the start of the step (eq. 8.72) while the gap it must
close is measured at the end of the step, where the levers have turned: the impulses then do work on the end
velocities, and a strongly bent, stiff chain turning by ≈ 1 rad per step gains energy
(``benchmarks/bench_joint_stage_root.py``). Here each impulse acts at the lever averaged over its body's rotation
φ = Δt ω' + Δθ_extra of the step, J_l(φ) r (J_l the left Jacobian of SO(3); (exp(φ̃) − E) r = φ × J_l(φ) r), so
the end-of-step gap is exactly Δt times the joint's relative velocity at those levers and the impulses do no work
on the end velocities. Since the levers depend on the end twists, the twists u' = (v', ω') and the joint impulses P
of a fibre are solved together: Newton on the whole residual (body momentum rows, joint gaps at the end, implicit
springs at the end frames) with a coloured forward-difference Jacobian (block-tridiagonal, 12 × 12 blocks; 36
residual passes per evaluation, where central differences took 72 for the same roots), a block-Thomas solve and a
backtracking line search. The Jacobian's factors are reused while full steps on them more than halve the residual,
also across calls: the solver keeps each fibre's last factors for its next harmonisation pass and step, where
the Jacobian has changed little, so that most calls take chord steps only. 7 × 30 helical drape (aniso, 400 steps):
the joint stage 8.6 → 5.7 ms per step with forward differences, → 2.3 ms with the factors kept across calls and the
start levers' kernel run only where the Newton fails (it ran for every fibre before; the start levers: 0.9 ms).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from headsim.solvers._kernels.chains import _exp_times_into, _joint_gap_and_moment, skew_series_times
from headsim.solvers._kernels.rods import so3_jacobian_coefficients

BLOCK = 12  # unknowns per body b: v' (3), ω' (3), and the impulse P_b = (p, L*) of its inner joint b (6)
CHORD_CONTRACTION = 0.5  # a Newton step on reused Jacobian factors must shrink ‖residual‖ by this factor


@njit(cache=True, inline="always")
def _mean_lever(p0, p1, p2, r0, r1, r2):
    """J_l(φ) r = r + a φ × r + b φ × (φ × r), a = (1 − cos θ)/θ², b = (θ − sin θ)/θ³ (series below 1e-4 rad)."""
    a, b = so3_jacobian_coefficients(p0 * p0 + p1 * p1 + p2 * p2)
    return skew_series_times(p0, p1, p2, a, b, r0, r1, r2)


@njit(cache=True)
def mean_lever_residual(s0, n, j0, z, x, R, v, w, mass, inertia, half, root_point, root_frame, f, dt, gravity,
                        dx_extra, dth_extra, K, rest, damping, x_end, R_end, out):
    """Residual out (n, 12) of the unknowns z (n, 12) of fibre f (segments s0 … s0 + n − 1; j0 = 1 when its root is
    free, 0 when anchored), in impulse units (N s): rows 0:3 m (v' − v) − the net joint impulse; rows 3:6
    (I_w (ω' − ω) − the net angular impulse at the mean levers) / h; rows 6:9 the end-of-step joint gap (eq. 8.76)
    × m/Δt; rows 9:12 (L* − Δt [R_k J_l⁻ᵀ(θ) K (θ − θ°) + c ω_rel]) / h, the implicit spring at the end frames
    (as ``_kernels.chains._fibre_trial``). A free root (b < j0) has no joint: its rows 6:12 are P_b itself.
    x_end (n, 3), R_end (n, 3, 3): work arrays (the end positions and frames)."""
    Q = np.empty((3, 3))
    for b in range(n):
        s = s0 + b
        for c in range(3):
            x_end[b, c] = x[s, c] + dt * z[b, c] + 0.5 * dt * dt * gravity[c] + dx_extra[s, c]
        _exp_times_into(dt * z[b, 3] + dth_extra[s, 0], dt * z[b, 4] + dth_extra[s, 1],
                        dt * z[b, 5] + dth_extra[s, 2], R[s], R_end[b])
    for b in range(n):
        s = s0 + b
        p0 = dt * z[b, 3] + dth_extra[s, 0]
        p1 = dt * z[b, 4] + dth_extra[s, 1]
        p2 = dt * z[b, 5] + dth_extra[s, 2]
        f0, f1, f2, t0, t1, t2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        for side in range(2):  # 0: inner joint b (this body is its "l"), 1: outer joint b + 1 (its "k")
            if side == 0:
                if b < j0:
                    continue
                q, h, sign = b, -half[s], -1.0
            else:
                if b + 1 >= n:
                    continue
                q, h, sign = b + 1, half[s], 1.0
            r0, r1, r2 = _mean_lever(p0, p1, p2, h * R[s, 0, 2], h * R[s, 1, 2], h * R[s, 2, 2])
            a0, a1, a2 = z[q, 6], z[q, 7], z[q, 8]
            f0 += sign * a0
            f1 += sign * a1
            f2 += sign * a2
            t0 += sign * (z[q, 9] + r1 * a2 - r2 * a1)
            t1 += sign * (z[q, 10] + r2 * a0 - r0 * a2)
            t2 += sign * (z[q, 11] + r0 * a1 - r1 * a0)
        out[b, 0] = mass[s] * (z[b, 0] - v[s, 0]) - f0
        out[b, 1] = mass[s] * (z[b, 1] - v[s, 1]) - f1
        out[b, 2] = mass[s] * (z[b, 2] - v[s, 2]) - f2
        # I_w (ω' − ω) = R diag(I) Rᵀ (ω' − ω)
        e0, e1, e2 = z[b, 3] - w[s, 0], z[b, 4] - w[s, 1], z[b, 5] - w[s, 2]
        g0 = (R[s, 0, 0] * e0 + R[s, 1, 0] * e1 + R[s, 2, 0] * e2) * inertia[s, 0]
        g1 = (R[s, 0, 1] * e0 + R[s, 1, 1] * e1 + R[s, 2, 1] * e2) * inertia[s, 1]
        g2 = (R[s, 0, 2] * e0 + R[s, 1, 2] * e1 + R[s, 2, 2] * e2) * inertia[s, 2]
        hs = half[s]
        out[b, 3] = (R[s, 0, 0] * g0 + R[s, 0, 1] * g1 + R[s, 0, 2] * g2 - t0) / hs
        out[b, 4] = (R[s, 1, 0] * g0 + R[s, 1, 1] * g1 + R[s, 1, 2] * g2 - t1) / hs
        out[b, 5] = (R[s, 2, 0] * g0 + R[s, 2, 1] * g1 + R[s, 2, 2] * g2 - t2) / hs
        if b < j0:
            for c in range(6, 12):
                out[b, c] = z[b, c]
            continue
        d0, d1, d2, m0, m1, m2 = _joint_gap_and_moment(b, s, f, x_end, R_end, half, root_point, root_frame, K,
                                                       rest, damping, z, 3, Q)
        scale = mass[s] / dt
        out[b, 6] = d0 * scale
        out[b, 7] = d1 * scale
        out[b, 8] = d2 * scale
        out[b, 9] = (z[b, 9] - dt * m0) / hs
        out[b, 10] = (z[b, 10] - dt * m1) / hs
        out[b, 11] = (z[b, 11] - dt * m2) / hs


@njit(cache=True)
def _invert_into(A, out):
    """out ← A⁻¹ (Gauss–Jordan with partial pivoting; A is overwritten)."""
    m = A.shape[0]
    for a in range(m):
        for c in range(m):
            out[a, c] = 1.0 if a == c else 0.0
    for c in range(m):
        p = c
        best = abs(A[c, c])
        for a in range(c + 1, m):
            if abs(A[a, c]) > best:
                best = abs(A[a, c])
                p = a
        if p != c:
            for k in range(m):
                A[c, k], A[p, k] = A[p, k], A[c, k]
                out[c, k], out[p, k] = out[p, k], out[c, k]
        d = 1.0 / A[c, c]
        for k in range(m):
            A[c, k] *= d
            out[c, k] *= d
        for a in range(m):
            if a != c and A[a, c] != 0.0:
                g = A[a, c]
                for k in range(m):
                    A[a, k] -= g * A[c, k]
                    out[a, k] -= g * out[c, k]


@njit(cache=True)
def _block_tridiagonal_factor(n, Lo, Dg, Up, inv, G):
    """Block Thomas elimination of the block-tridiagonal matrix (Lo[b], Dg[b], Up[b]: the blocks of row b at
    z_{b−1}, z_b, z_{b+1}): inv[b] the inverse of the eliminated diagonal block, G[b] = Lo[b] inv[b − 1] (Dg is
    overwritten)."""
    _invert_into(Dg[0], inv[0])
    for b in range(1, n):
        G[b] = Lo[b] @ inv[b - 1]
        Dg[b] -= G[b] @ Up[b - 1]
        _invert_into(Dg[b], inv[b])


@njit(cache=True)
def _block_tridiagonal_solve(n, Up, inv, G, rhs, out):
    """out (n, 12) ← the solution for rhs (n, 12) (overwritten) with the factors of :func:`_block_tridiagonal_factor`."""
    for b in range(1, n):
        rhs[b] -= G[b] @ rhs[b - 1]
    out[n - 1] = inv[n - 1] @ rhs[n - 1]
    for b in range(n - 2, -1, -1):
        out[b] = inv[b] @ (rhs[b] - Up[b] @ out[b + 1])


@njit(cache=True)
def _merit(r):
    t = 0.0
    for i in range(r.shape[0]):
        for c in range(r.shape[1]):
            t += r[i, c] * r[i, c]
    return np.sqrt(t)


@njit(cache=True)
def solve_fibre_mean_levers(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame, dt,
                            gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, z, inv, G, Up, kept):
    """Fibre f's joint stage with mean levers solved to its root by Newton, from z (n, 12) on entry (the twists
    and impulses to start from; the solution on exit). Converged when every residual row is below the impulse
    tol × m/Δt (the gap rows: a gap below ``tol`` m; the others: that impulse). inv, G, Up (n, 12, 12): the
    factors of a Jacobian (:func:`_block_tridiagonal_factor`), used as they are for the first (chord) step where
    ``kept`` (an earlier call's, e.g. the previous step's: the Jacobian changes little from call to call), and
    left holding the last factors used. Returns (Newton iterations, converged)."""
    s0 = seg_off[f]
    n = seg_off[f + 1] - s0
    j0 = 0 if anchored[f] else 1
    x_end = np.empty((n, 3))
    R_end = np.empty((n, 3, 3))
    res = np.empty((n, BLOCK))
    rp = np.empty((n, BLOCK))
    rm = np.empty((n, BLOCK))
    Dg = np.empty((n, BLOCK, BLOCK))
    Lo = np.zeros((n, BLOCK, BLOCK))
    step = np.empty((n, BLOCK))
    trial = np.empty((n, BLOCK))
    hz = np.empty((n, BLOCK))
    m_min = np.inf
    for b in range(n):
        s = s0 + b
        m_min = min(m_min, mass[s])
        i_max = max(inertia[s, 0], max(inertia[s, 1], inertia[s, 2]))
        for c in range(3):
            hz[b, c] = 1e-6  # m/s
            hz[b, 3 + c] = 1e-4  # rad/s
            hz[b, 6 + c] = 1e-6 * mass[s]  # N s
            hz[b, 9 + c] = 1e-4 * i_max  # N m s
    limit = tol * m_min / dt
    mean_lever_residual(s0, n, j0, z, x, R, v, w, mass, inertia, half, root_point, root_frame, f, dt, gravity,
                        dx_extra, dth_extra, K, rest, damping, x_end, R_end, res)
    merit = _merit(res)
    it = 0
    fresh = not kept  # the Jacobian is evaluated again (else its last factors are reused: a chord step)
    while True:
        if np.abs(res).max() <= limit:
            return it, True
        if it == max_iter:
            return it, False
        for colour in range(3 if fresh else 0):  # block b reaches the rows of blocks b − 1 … b + 1
            for a in range(BLOCK):
                for b in range(colour, n, 3):
                    z[b, a] += hz[b, a]
                mean_lever_residual(s0, n, j0, z, x, R, v, w, mass, inertia, half, root_point, root_frame, f, dt,
                                    gravity, dx_extra, dth_extra, K, rest, damping, x_end, R_end, rp)
                for b in range(colour, n, 3):
                    z[b, a] -= hz[b, a]
                    scale = 1.0 / hz[b, a]
                    for r in range(BLOCK):
                        Dg[b, r, a] = (rp[b, r] - res[b, r]) * scale
                        if b > 0:
                            Up[b - 1, r, a] = (rp[b - 1, r] - res[b - 1, r]) * scale
                        if b + 1 < n:
                            Lo[b + 1, r, a] = (rp[b + 1, r] - res[b + 1, r]) * scale
        if fresh:
            Up[n - 1] = 0.0
            _block_tridiagonal_factor(n, Lo, Dg, Up, inv, G)
        for b in range(n):
            for r in range(BLOCK):
                rp[b, r] = -res[b, r]
        _block_tridiagonal_solve(n, Up, inv, G, rp, step)
        t = 1.0
        for _ in range(40):  # backtracking on ‖residual‖
            for b in range(n):
                for r in range(BLOCK):
                    trial[b, r] = z[b, r] + t * step[b, r]
            mean_lever_residual(s0, n, j0, trial, x, R, v, w, mass, inertia, half, root_point, root_frame, f, dt,
                                gravity, dx_extra, dth_extra, K, rest, damping, x_end, R_end, rm)
            new = _merit(rm)
            if new < (1.0 - 1e-4 * t) * merit:
                break
            t *= 0.5
        # keep the factors while a full chord step more than halves the residual; else evaluate the Jacobian again
        fresh = not (t == 1.0 and new < CHORD_CONTRACTION * merit)
        z[:] = trial
        res[:] = rm
        merit = new
        it += 1


@njit(cache=True)
def _solve_one(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame, dt, gravity, dx_extra,
               dth_extra, K, rest, damping, tol, max_iter, v_out, w_out, iterations, converged, inv, G, Up, kept):
    """Fibre f of :func:`solve_mean_levers_batch`."""
    s0 = seg_off[f]
    n = seg_off[f + 1] - s0
    z = np.zeros((n, BLOCK))
    for b in range(n):
        for c in range(3):
            z[b, c] = v[s0 + b, c]
            z[b, 3 + c] = w[s0 + b, c]
    it, ok = solve_fibre_mean_levers(f, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame,
                                     dt, gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, z,
                                     inv[s0:s0 + n], G[s0:s0 + n], Up[s0:s0 + n], kept[f])
    iterations[f] = it
    converged[f] = ok
    kept[f] = ok
    if ok:
        for b in range(n):
            for c in range(3):
                v_out[s0 + b, c] = z[b, c]
                w_out[s0 + b, c] = z[b, 3 + c]


@njit(cache=True, parallel=True)
def solve_mean_levers_batch(fibres, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame, dt,
                            gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out, iterations,
                            converged, inv, G, Up, kept):
    """:func:`solve_fibre_mean_levers` for the fibres in ``fibres`` in parallel, each from its start-of-step twists
    v, w and zero impulses (the start levers' answer was a worse start: on the 3 mm coil at 0.5 ms the Newton failed
    from the 4th step from it, converging in every step from these); where a fibre's Newton converges its twists
    are written to v_out, w_out (S, 3), else they are left as they are (the caller fills them with the start
    levers' answer). iterations (F,) int64, converged (F,) bool. inv, G, Up (S, 12, 12): the Jacobian factors kept
    across calls, valid for fibre f where kept[f] (F,) bool (in and out: True after a converged solve)."""
    for q in prange(fibres.shape[0]):
        _solve_one(fibres[q], seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame, dt,
                   gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out, iterations, converged,
                   inv, G, Up, kept)


@njit(cache=True)
def solve_mean_levers_serial(fibres, seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame, dt,
                             gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out, iterations,
                             converged, inv, G, Up, kept):
    """Serial twin of :func:`solve_mean_levers_batch` (small problems)."""
    for q in range(fibres.shape[0]):
        _solve_one(fibres[q], seg_off, anchored, x, R, v, w, mass, inertia, half, root_point, root_frame, dt,
                   gravity, dx_extra, dth_extra, K, rest, damping, tol, max_iter, v_out, w_out, iterations, converged,
                   inv, G, Up, kept)
