"""Numba kernels: per-segment frame products of the chain solver (:mod:`headsim.solvers.chains`), one pass
over the segments instead of NumPy's batched 3 × 3 products and their temporaries (≈ 8 ms per call on the
35,500 segments of the reference scene, several calls per step)."""

from __future__ import annotations

import numpy as np
from numba import prange

from headsim.solvers._kernels.chains import _log_so3_parts
from headsim.solvers._kernels.twins import serial_and_parallel


def _apply_scaled_impl(R, d, w, out):
    """out[s] = R_s diag(d_s) R_sᵀ w_s (R (S, 3, 3), d (S, 3), w (S, 3)): a world inertia tensor (or its
    inverse) applied to a vector without forming it."""
    for s in prange(R.shape[0]):
        b0 = (w[s, 0] * R[s, 0, 0] + w[s, 1] * R[s, 1, 0] + w[s, 2] * R[s, 2, 0]) * d[s, 0]
        b1 = (w[s, 0] * R[s, 0, 1] + w[s, 1] * R[s, 1, 1] + w[s, 2] * R[s, 2, 1]) * d[s, 1]
        b2 = (w[s, 0] * R[s, 0, 2] + w[s, 1] * R[s, 1, 2] + w[s, 2] * R[s, 2, 2]) * d[s, 2]
        for i in range(3):
            out[s, i] = R[s, i, 0] * b0 + R[s, i, 1] * b1 + R[s, i, 2] * b2


def _scaled_frames_impl(R, d, out):
    """out[s] = R_s diag(d_s) R_sᵀ (S, 3, 3)."""
    for s in prange(R.shape[0]):
        for i in range(3):
            for j in range(3):
                out[s, i, j] = (R[s, i, 0] * d[s, 0] * R[s, j, 0] + R[s, i, 1] * d[s, 1] * R[s, j, 1]
                                + R[s, i, 2] * d[s, 2] * R[s, j, 2])


def _point_speed_impl(u, lever, out):
    """out[s] = |v_s| + ρ_s |ω_s| of twists u (n, 6) (m/s); lever (n,) m, or (1,) for one ρ for all."""
    one = lever.shape[0] == 1
    for s in prange(u.shape[0]):
        rho = lever[0] if one else lever[s]
        out[s] = (np.sqrt(u[s, 0] * u[s, 0] + u[s, 1] * u[s, 1] + u[s, 2] * u[s, 2])
                  + rho * np.sqrt(u[s, 3] * u[s, 3] + u[s, 4] * u[s, 4] + u[s, 5] * u[s, 5]))


apply_scaled, apply_scaled_parallel = serial_and_parallel(_apply_scaled_impl)
scaled_frames, scaled_frames_parallel = serial_and_parallel(_scaled_frames_impl)
point_speed, point_speed_parallel = serial_and_parallel(_point_speed_impl)


def _joint_rows_impl(seg, is_root, fib, x, R, half, root_point, root_frame, stiffness, damping, u, target_scale,
                     spring_scale, damping_scale, k_out, rk_out, rl_out, target_out, C_out, w0_out):
    """The joint rows of the segments ``seg`` (:meth:`headsim.solvers.chains.ChainSolver._joint_rows`): body
    k_out = seg − 1 (−1 at a root: the fixed anchor), levers rk_out = h_k d3_k (0 at a root), rl_out = −h d3
    (m), target_out = target_scale × d with d = p_k − p_l the mid-step joint gap (m), the spring rows' C_out =
    spring_scale × R_k diag(K_w) R_kᵀ + damping_scale × c E (R_k the root frame at a root), and w0_out = ω_l −
    ω_k of the twists u (S, 6) (ω_k = 0 at a root; u empty: 0)."""
    have_u = u.shape[0] > 0
    for q in prange(seg.shape[0]):
        s = seg[q]
        root = is_root[q]
        kk = 0 if root else s - 1
        k_out[q] = -1 if root else s - 1
        for i in range(3):
            rl_out[q, i] = -half[s] * R[s, i, 2]
            rk_out[q, i] = 0.0 if root else half[kk] * R[kk, i, 2]
        for i in range(3):
            pk = root_point[fib[q], i] if root else x[kk, i] + rk_out[q, i]
            target_out[q, i] = target_scale * (pk - (x[s, i] + rl_out[q, i]))
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for c in range(3):
                    rik = root_frame[fib[q], i, c] if root else R[kk, i, c]
                    rjk = root_frame[fib[q], j, c] if root else R[kk, j, c]
                    acc += rik * stiffness[s, c] * rjk
                C_out[q, i, j] = spring_scale * acc + (damping_scale * damping[s] if i == j else 0.0)
        for i in range(3):
            if have_u:
                w0_out[q, i] = u[s, 3 + i] - (0.0 if root else u[kk, 3 + i])
            else:
                w0_out[q, i] = 0.0


joint_rows, joint_rows_parallel = serial_and_parallel(_joint_rows_impl)


def _chain_stats_impl(x, R, v, w, mass, inertia, half, is_root, active, fib, root_point, root_frame, stiffness,
                      rest, work, kinetic_out, spring_out, gap_out):
    """Per segment s of a chain state (:mod:`headsim.solvers.chains`, SI units), in one pass:
    kinetic_out[s] = ½ (m v² + Σ_c I_c (R_sᵀ ω)_c²) (J); spring_out[s] = ½ Σ_c K_c (θ_c − θ°_c)² of its inner joint,
    θ = log(R_kᵀ R_s) (Sobottka eq. 8.83; R_k the previous segment's frame, the root frame at a root) (J); gap_out[s]
    = ‖p_k − (x_s − h_s d3_s)‖ of its inner joint (eq. 8.76; p_k the previous segment's outer end or the root
    point) (m). Both 0 where the joint is not ``active`` (a free root). work (S, 3, 3): R_kᵀ R_s."""
    for s in prange(x.shape[0]):
        e = mass[s] * (v[s, 0] * v[s, 0] + v[s, 1] * v[s, 1] + v[s, 2] * v[s, 2])
        for c in range(3):
            b = w[s, 0] * R[s, 0, c] + w[s, 1] * R[s, 1, c] + w[s, 2] * R[s, 2, c]
            e += inertia[s, c] * b * b
        kinetic_out[s] = 0.5 * e
        if not active[s]:
            spring_out[s] = 0.0
            gap_out[s] = 0.0
            continue
        root = is_root[s]
        k = s - 1
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for c in range(3):
                    acc += (root_frame[fib[s], c, i] if root else R[k, c, i]) * R[s, c, j]
                work[s, i, j] = acc
        t0, t1, t2 = _log_so3_parts(work[s])
        spring_out[s] = 0.5 * (stiffness[s, 0] * (t0 - rest[s, 0]) ** 2 + stiffness[s, 1] * (t1 - rest[s, 1]) ** 2
                               + stiffness[s, 2] * (t2 - rest[s, 2]) ** 2)
        g = 0.0
        for i in range(3):
            pk = root_point[fib[s], i] if root else x[k, i] + half[k] * R[k, i, 2]
            d = pk - (x[s, i] - half[s] * R[s, i, 2])
            g += d * d
        gap_out[s] = np.sqrt(g)


chain_stats, chain_stats_parallel = serial_and_parallel(_chain_stats_impl)
