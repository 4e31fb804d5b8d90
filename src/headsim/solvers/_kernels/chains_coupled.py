"""Numba kernels of the coupled contact stage of the chain solver (Sobottka 2008 ch. 8; Moreau–Jean NSCD).

One projected nonlinear Gauss–Seidel over all contacts in which every touched fibre's joints (point
row + implicit bending/torsion spring row, 6 unknowns each) form **one block per fibre**, solved
exactly by a block-tridiagonal (Thomas) factorisation made once per call: a sweep solves every
fibre's whole joint system for the current velocities (fibres in parallel — their joint rows share
no body), then visits the contacts one by one. A point-by-point sweep over the joints (the previous
form) needs O(n²) sweeps to carry a contact impulse along a chain of n segments; the fibre block
carries it in one.

Conventions as in :mod:`headsim.solvers._kernels.chains`: twists u = (v, ω) (m/s, rad/s, world
frame); joint j couples body k (−1: fixed root anchor) with lever r_k and body l with lever r_l; its
impulse (p, Λ) (N s, N m s) acts as +(p, r_k × p + Λ) on k and −(p, r_l × p + Λ) on l.

The set-up (:func:`coupled_setup`: contact Jacobians, Delassus blocks, chain factorisations) and the
iteration (:func:`coupled_iterate`) are separate kernels, so that solves on the same geometry (the
velocity and the push-out solve of one harmonisation pass) share the set-up; :func:`project_coupled`
runs both. Each is compiled twice from the same Python function: serial and ``parallel`` (``prange``
over fibres and contacts in the set-up, over fibres in the sweeps).

Inlining: the helpers that loop over a chain or fill a whole row (:func:`_chain_factor`, :func:`_chain_sweep`,
:func:`_coupling_block`, :func:`_contact_rows`) are called, not inlined at Numba-IR level: every ``prange`` loop
of the parallel build got its own inlined copy, and Numba's type inference of those copies was most of the
compilation (measured cold, one process: set-up 16.8 → 5.4 s serial, 43.5 → 6.5 s parallel; iteration
29 → 25 s serial, 64 → 40 s parallel), with the same iterates bitwise (4-step state hash of the reference
ringlet start) and the time per step within the noise (reference ringlet 1.02–1.10 against 1.05–1.06 s;
resting 40 × 30 strand, serial contact phase +2 % (noise), parallel the same). The per-row-visit helpers stay
inlined (un-inlining ``_extrapolate_rows`` too cost the serial resting contact phase ≈ 4 %).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from headsim.solvers._kernels.chains import _inv_inertia_into, _polygon_qp, _tangents_into, inv6_into
from headsim.solvers._kernels.chains_pairs import row_normal_speed
from headsim.solvers._kernels.twins import serial_and_parallel

# The partial sweeps' slack band per row (see the sweep schedule in _coupled_iterate_impl): this factor × the
# point-velocity changes of its two bodies since the previous full sweep. Measured with the captured solves of
# the 355 × 100 drape: the falling strand (t = 61 ms) gives bitwise the iterates of the former band (the
# largest change of any row in the last full sweep, for every row) in 0.088–0.10 s instead of 0.10–0.12 s per
# solve; the landing (t = 86 ms, 144 k rows) 1.30–1.32 s instead of 1.39–1.43 s (other iterates: the last
# change 0.10363 against 0.10361 m/s, the same promotions); the ringlet start 41.8 µm largest penetration
# against 44.2 µm (46.5 µm with the factor 1), the same time per step.
BAND_FACTOR = 2.0
# rows per task of the set-up's parallel row loop (its work arrays are allocated once per task)
ROW_CHUNK = 1024


@njit(cache=True, inline="always")
def _skew(r, b, c):
    """Element (b, c) of the cross-product matrix r̃ (r̃ x = r × x)."""
    if b == c:
        return 0.0
    if b == 0:
        return -r[2] if c == 1 else r[1]
    if b == 1:
        return r[2] if c == 0 else -r[0]
    return -r[1] if c == 0 else r[0]


@njit(cache=True)
def _coupling_block(out, scale, im, Iw, rj, ri, C, X, Y):
    """out (6, 6) += scale · [[E/m − r̃_j I⁻¹ r̃_i, −r̃_j I⁻¹], [−C I⁻¹ r̃_i, −C I⁻¹]]: the change of joint j's
    residual (gap-rate row with lever r_j, spring row with compliance C) per unit impulse (p, Λ) of a joint
    with lever r_i on a shared body of inverse mass im and world inverse inertia Iw. X, Y (3, 3): work arrays
    (the caller's, so that a set-up does not allocate two per joint and block)."""
    # X = I⁻¹ r̃_i (3×3), Y = r̃_j I⁻¹ (3×3)
    for a in range(3):
        for c in range(3):
            s = 0.0
            t = 0.0
            for b in range(3):
                s += Iw[a, b] * _skew(ri, b, c)
                t += _skew(rj, a, b) * Iw[b, c]
            X[a, c] = s
            Y[a, c] = t
    for a in range(3):
        for c in range(3):
            # r̃_j X = r̃_j I⁻¹ r̃_i = Y r̃_i
            s = 0.0
            cx = 0.0
            cy = 0.0
            for b in range(3):
                s += Y[a, b] * _skew(ri, b, c)
                cx += C[a, b] * X[b, c]
                cy += C[a, b] * Iw[b, c]
            out[a, c] += scale * ((im if a == c else 0.0) - s)
            out[a, 3 + c] -= scale * Y[a, c]
            out[3 + a, c] -= scale * cx
            out[3 + a, 3 + c] -= scale * cy


@njit(cache=True)
def _chain_factor(j0, j1, joint_k, joint_l, joint_rk, joint_rl, C, mass, Ik, Il, Dinv, G, Up):
    """Block-tridiagonal (Thomas) factorisation of the joint system of one chain (rows j0:j1, consecutive
    joints along one fibre): Dinv[j] = (D_j − G_j Up_{j−1})⁻¹, G[j] = Lo_j Dinv[j−1], Up[j] = ∂e_j/∂q_{j+1}."""
    D = np.empty((6, 6))
    Lo = np.empty((6, 6))
    X = np.empty((3, 3))
    Y = np.empty((3, 3))
    for j in range(j0, j1):
        for a in range(6):
            for c in range(6):
                D[a, c] = 0.0
                Lo[a, c] = 0.0
                Up[j, a, c] = 0.0
        k = joint_k[j]
        l = joint_l[j]
        if k >= 0:
            _coupling_block(D, 1.0, 1.0 / mass[k], Ik[j], joint_rk[j], joint_rk[j], C[j], X, Y)
        _coupling_block(D, 1.0, 1.0 / mass[l], Il[j], joint_rl[j], joint_rl[j], C[j], X, Y)
        for a in range(3):
            D[3 + a, 3 + a] -= 1.0
        if j > j0:  # body k of joint j is body l of joint j − 1
            _coupling_block(Lo, -1.0, 1.0 / mass[k], Ik[j], joint_rk[j], joint_rl[j - 1], C[j], X, Y)
        if j + 1 < j1:  # body l of joint j is body k of joint j + 1
            _coupling_block(Up[j], -1.0, 1.0 / mass[l], Il[j], joint_rl[j], joint_rk[j + 1], C[j], X, Y)
        if j > j0:
            for a in range(6):
                for c in range(6):
                    s = 0.0
                    for z in range(6):
                        s += Lo[a, z] * Dinv[j - 1, z, c]
                    G[j, a, c] = s
            for a in range(6):
                for c in range(6):
                    s = 0.0
                    for z in range(6):
                        s += G[j, a, z] * Up[j - 1, z, c]
                    D[a, c] -= s
        inv6_into(D, Dinv[j])


@njit(cache=True)
def _chain_sweep(j0, j1, joint_k, joint_l, joint_rk, joint_rl, joint_target, C, joint_w0, u, mass, Ik, Il,
                 Dinv, G, Up, Lam, y, dq):
    """Solve the whole joint system of one chain exactly for the current twists u and apply the impulse
    change; y, dq (rows, 6) are work rows. Returns the largest joint gap-rate residual before the solve, m/s."""
    worst = 0.0
    for j in range(j0, j1):
        k = joint_k[j]
        l = joint_l[j]
        rl = joint_rl[j]
        v0 = joint_target[j, 0] + u[l, 0] + (u[l, 4] * rl[2] - u[l, 5] * rl[1])
        v1 = joint_target[j, 1] + u[l, 1] + (u[l, 5] * rl[0] - u[l, 3] * rl[2])
        v2 = joint_target[j, 2] + u[l, 2] + (u[l, 3] * rl[1] - u[l, 4] * rl[0])
        w0 = u[l, 3] - joint_w0[j, 0]
        w1 = u[l, 4] - joint_w0[j, 1]
        w2 = u[l, 5] - joint_w0[j, 2]
        if k >= 0:
            rk = joint_rk[j]
            v0 -= u[k, 0] + (u[k, 4] * rk[2] - u[k, 5] * rk[1])
            v1 -= u[k, 1] + (u[k, 5] * rk[0] - u[k, 3] * rk[2])
            v2 -= u[k, 2] + (u[k, 3] * rk[1] - u[k, 4] * rk[0])
            w0 -= u[k, 3]
            w1 -= u[k, 4]
            w2 -= u[k, 5]
        # rhs = −e: e = (gap rate − target, C ω_rel − Λ)
        y[j, 0] = v0
        y[j, 1] = v1
        y[j, 2] = v2
        for z in range(3):
            y[j, 3 + z] = Lam[j, z] - (C[j, z, 0] * w0 + C[j, z, 1] * w1 + C[j, z, 2] * w2)
        d = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        if d > worst:
            worst = d
        if j > j0:
            for a in range(6):
                s = 0.0
                for z in range(6):
                    s += G[j, a, z] * y[j - 1, z]
                dq[j, a] = s
            for a in range(6):
                y[j, a] -= dq[j, a]
    for j in range(j1 - 1, j0 - 1, -1):
        for a in range(6):
            t = y[j, a]
            if j + 1 < j1:
                for z in range(6):
                    t -= Up[j, a, z] * dq[j + 1, z]
            y[j, a] = t
        for a in range(6):
            s = 0.0
            for z in range(6):
                s += Dinv[j, a, z] * y[j, z]
            dq[j, a] = s
    for j in range(j0, j1):
        k = joint_k[j]
        l = joint_l[j]
        for z in range(3):
            Lam[j, z] += dq[j, 3 + z]
        if k >= 0:
            _apply_joint_impulse(u, k, joint_rk[j], dq, j, Ik, mass, 1.0)
        _apply_joint_impulse(u, l, joint_rl[j], dq, j, Il, mass, -1.0)
    return worst


@njit(cache=True, inline="always")
def _apply_joint_impulse(u, b, r, dq, j, Iw, mass, sign):
    """u[b] += sign · (p / m, I⁻¹ (r × p + Λ)) for the joint impulse change dq[j] = (p, Λ) acting on body b
    with lever r (sign +1 on the joint's inner body k, −1 on its outer body l; Iw[j] that body's world
    inverse inertia)."""
    t0 = r[1] * dq[j, 2] - r[2] * dq[j, 1] + dq[j, 3]
    t1 = r[2] * dq[j, 0] - r[0] * dq[j, 2] + dq[j, 4]
    t2 = r[0] * dq[j, 1] - r[1] * dq[j, 0] + dq[j, 5]
    im = sign / mass[b]
    for z in range(3):
        u[b, z] += dq[j, z] * im
        u[b, 3 + z] += sign * (Iw[j, z, 0] * t0 + Iw[j, z, 1] * t1 + Iw[j, z, 2] * t2)


@njit(cache=True)
def _contact_rows(c, sc, body, partner, normal, lever, partner_lever, mass, R, inertia, JA, JB, MA, MB, W, Iw, T):
    """Jacobian rows (n, t₁, t₂) of contact c on both bodies, their mobility images M⁻¹Jᵀ and the 3×3
    Delassus block W = J_A M_A⁻¹ J_Aᵀ + J_B M_B⁻¹ J_Bᵀ (t₁ from body A's axis), stored at slot ``sc``.
    Iw (3, 3), T (2, 3): work arrays."""
    a = body[c]
    n = normal[c]
    _tangents_into(R[a, 0, 2], R[a, 1, 2], R[a, 2, 2], n, T)  # t₁ from body A's axis R[a, :, 2]
    t1 = T[0]
    t2 = T[1]
    for side in range(2):
        b = a if side == 0 else partner[c]
        lev = lever[c] if side == 0 else partner_lever[c]
        Jr = JA if side == 0 else JB
        Mr = MA if side == 0 else MB
        if b < 0:
            for k in range(3):
                for z in range(6):
                    Jr[sc, k, z] = 0.0
                    Mr[sc, k, z] = 0.0
            continue
        _inv_inertia_into(R[b], inertia[b], Iw)
        for k in range(3):
            d0 = n[0] if k == 0 else (t1[0] if k == 1 else t2[0])
            d1 = n[1] if k == 0 else (t1[1] if k == 1 else t2[1])
            d2 = n[2] if k == 0 else (t1[2] if k == 1 else t2[2])
            r0 = lev[1] * d2 - lev[2] * d1
            r1 = lev[2] * d0 - lev[0] * d2
            r2 = lev[0] * d1 - lev[1] * d0
            Jr[sc, k, 0] = d0
            Jr[sc, k, 1] = d1
            Jr[sc, k, 2] = d2
            Jr[sc, k, 3] = r0
            Jr[sc, k, 4] = r1
            Jr[sc, k, 5] = r2
            im = 1.0 / mass[b]
            Mr[sc, k, 0] = d0 * im
            Mr[sc, k, 1] = d1 * im
            Mr[sc, k, 2] = d2 * im
            for z in range(3):
                Mr[sc, k, 3 + z] = Iw[z, 0] * r0 + Iw[z, 1] * r1 + Iw[z, 2] * r2
    for k in range(3):
        for q in range(3):
            s = 0.0
            for z in range(6):
                s += JA[sc, k, z] * MA[sc, q, z] + JB[sc, k, z] * MB[sc, q, z]
            W[sc, k, q] = s


@njit(cache=True, inline="always")
def _slot(c, n0, pslot):
    """Storage slot of contact c's Jacobian rows and Delassus block: c for the n0 rows of the set-up, else the
    slot its promotion gave it (pslot[c − n0])."""
    return c if c < n0 else pslot[c - n0]


@njit(cache=True)
def breadth_first_cover(indptr, indices, starts):
    """(N,) int64 breadth-first order of all N vertices of a graph in CSR form (indptr, indices; symmetric: an
    undirected graph): a search from starts[0], then from each later start not yet reached, in order; the
    neighbours of a vertex are queued in their CSR order. Each search gives the order of
    ``scipy.sparse.csgraph.breadth_first_order(G, s, directed=False)``; one kernel call replaces one SciPy call
    per connected component (a strand before its first contact: one per fibre)."""
    n = len(indptr) - 1
    seen = np.zeros(n, np.bool_)
    out = np.empty(n, np.int64)
    end = 0
    for s in starts:
        if seen[s]:
            continue
        seen[s] = True
        out[end] = s
        head = end
        end += 1
        while head < end:
            p = out[head]
            head += 1
            for i in range(indptr[p], indptr[p + 1]):
                c = indices[i]
                if not seen[c]:
                    seen[c] = True
                    out[end] = c
                    end += 1
    return out[:end]


@njit(cache=True)
def _segment_rows(rows, n, dom, n_domains, out, off):
    """Stable partition of rows[:n] by their domain (dom[c] ∈ 0..n_domains, n_domains = the cross rows) into
    out[:n]; off (n_domains + 2,) gets the segment offsets."""
    cnt = np.zeros(n_domains + 1, np.int64)
    for q in range(n):
        cnt[dom[rows[q]]] += 1
    off[0] = 0
    for d in range(n_domains + 1):
        off[d + 1] = off[d] + cnt[d]
    pos = off[:-1].copy()
    for q in range(n):
        d = dom[rows[q]]
        out[pos[d]] = rows[q]
        pos[d] += 1


@njit(cache=True, inline="always")
def _restart_term(c, sc, lam, lam_start, lam_prev, W):
    """W_c (λ_c − y_c)(y_c − λ_{c,k−1}) of contact c (Delassus block at slot ``sc``): its term of the Nesterov
    restart test (:func:`_listed_sum`)."""
    return (lam[c] - lam_start[c]) * (lam_start[c] - lam_prev[c]) * W[sc, 0, 0]


@njit(cache=True, inline="always")
def _listed_sum(term, lo, cnt):
    """Σ term[lo:lo + cnt] in order: the restart test Σ_c W_c (λ_c − y_c)(y_c − λ_{c,k−1}) of the Nesterov
    extrapolation over one segment of the listed rows (see ``momentum`` of :func:`_coupled_iterate_impl`),
    from the terms the sweep wrote at the rows' positions in ``listed``."""
    dot = 0.0
    for z in range(cnt):
        dot += term[lo + z]
    return dot


@njit(cache=True, inline="always")
def _extrapolate_rows(listed, lo, cnt, beta, lam, lam_prev, lam_start, fr, u, dun, body, partner, MA, MB, n0,
                      pslot):
    """Extrapolate the contact impulses of the listed rows listed[lo:lo + cnt] along their last change,
    λ ← max(0, λ_k + β (λ_k − λ_{k−1})), the friction impulses scaled with their normal impulse (so they stay
    in their polygon λ·conv{μ_β d_β}), and move the twists u by the extrapolation's impulses (slots:
    :func:`_slot`)."""
    for z in range(cnt):
        c = listed[lo + z]
        now = lam[c]
        y = now + beta * (now - lam_prev[c])
        if y < 0.0:
            y = 0.0
        lam_prev[c] = now
        lam_start[c] = y
        dl = y - now
        if dl == 0.0:
            continue
        scale = y / now - 1.0 if now > 0.0 else 0.0  # friction in proportion: stays in y·conv{μ_β d_β}
        dx = fr[c, 0] * scale
        dy = fr[c, 1] * scale
        a = body[c]
        b = partner[c]
        sc = _slot(c, n0, pslot)
        _add_impulse_twists(u, dun, a, b, sc, dl, dx, dy, MA, MB)
        lam[c] = y
        fr[c, 0] += dx
        fr[c, 1] += dy


@njit(cache=True, inline="always")
def _row_speed(JA, JB, sc, k, a, b, u):
    """Relative velocity of contact slot ``sc`` along its row k (0: normal, 1–2: tangents t₁, t₂), m/s."""
    s = 0.0
    for z in range(6):
        s += JA[sc, k, z] * u[a, z]
        if b >= 0:
            s -= JB[sc, k, z] * u[b, z]
    return s


@njit(cache=True, inline="always")
def _add_normal_twists(dun, a, b, sc, dl, MA, MB):
    """Add a normal impulse change dl (N s) of contact slot ``sc`` (bodies a, b; b = −1: obstacle) to the
    normal-impulse twists dun (S, 6) that the restitution ε scales (kept only when ε > 0: an empty dun, left
    alone)."""
    if dun.shape[0] == 0:
        return
    for z in range(6):
        dun[a, z] += MA[sc, 0, z] * dl
    if b >= 0:
        for z in range(6):
            dun[b, z] -= MB[sc, 0, z] * dl


@njit(cache=True, inline="always")
def _add_impulse_twists(u, dun, a, b, sc, dl, dx, dy, MA, MB):
    """Move the twists u (S, 6) by an impulse change of contact slot ``sc`` (bodies a, b; b = −1: obstacle):
    normal dl, friction dx, dy (N s) along its rows, u_A += M_A⁻¹J_Aᵀ(dl, dx, dy), u_B −= M_B⁻¹J_Bᵀ(…); and the
    restitution's normal-impulse twists dun by dl (:func:`_add_normal_twists`). The warm start and the
    extrapolation (:func:`_extrapolate_rows`) move all three rows at once."""
    for z in range(6):
        u[a, z] += MA[sc, 0, z] * dl + MA[sc, 1, z] * dx + MA[sc, 2, z] * dy
    if b >= 0:
        for z in range(6):
            u[b, z] -= MB[sc, 0, z] * dl + MB[sc, 1, z] * dx + MB[sc, 2, z] * dy
    _add_normal_twists(dun, a, b, sc, dl, MA, MB)


@njit(cache=True, inline="always")
def _set_normal_impulse(c, sc, a, b, new, vr, lam, u, dun, MA, MB, W):
    """Give contact c (slot ``sc``, bodies a, b) the normal impulse ``new`` (N s): move the twists u (and the
    normal-impulse twists dun of the restitution) and the row velocities vr (3,) by its change; returns the
    change as a velocity, |Δλ| W₀₀ (m/s)."""
    dl = new - lam[c]
    ch = 0.0
    if dl != 0.0:
        for z in range(6):
            u[a, z] += MA[sc, 0, z] * dl
        if b >= 0:
            for z in range(6):
                u[b, z] -= MB[sc, 0, z] * dl
        _add_normal_twists(dun, a, b, sc, dl, MA, MB)
        for k in range(3):
            vr[k] += W[sc, k, 0] * dl
        ch = abs(dl) * W[sc, 0, 0]
    lam[c] = new
    return ch


@njit(cache=True, inline="always")
def _solve_friction(c, sc, a, b, vr, lam, fr, u, MA, MB, W, mu_cos, mu_sin, m, px, py, Bl, cl):
    """Exact 2-D block solve of contact c's friction impulse in its polygon λ_c·conv{μ_β d_β} for the row
    velocities vr (3,) (:func:`headsim.solvers._kernels.chains._polygon_qp`); moves u by its change and returns
    the change as a velocity (m/s). px, py (m,), Bl (2, 2), cl (2,): work arrays."""
    Bl[0, 0] = W[sc, 1, 1]
    Bl[0, 1] = W[sc, 1, 2]
    Bl[1, 0] = W[sc, 2, 1]
    Bl[1, 1] = W[sc, 2, 2]
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
    ch = 0.0
    if dx != 0.0 or dy != 0.0:
        for z in range(6):
            u[a, z] += MA[sc, 1, z] * dx + MA[sc, 2, z] * dy
        if b >= 0:
            for z in range(6):
                u[b, z] -= MB[sc, 1, z] * dx + MB[sc, 2, z] * dy
        ch = np.sqrt(dx * dx * Bl[0, 0] + dy * dy * Bl[1, 1])
    fr[c, 0] = nx
    fr[c, 1] = ny
    return ch


@njit(cache=True, inline="always")
def _touches_root(root_pos, a, b):
    """Whether a contact between bodies a and b (−1: obstacle) touches the root region (``root_pos`` ≥ 0: a
    body's segment number from its anchored root; ``root_sweeps`` of :func:`_coupled_iterate_impl`)."""
    return root_pos[a] >= 0 or (b >= 0 and root_pos[b] >= 0)


@njit(cache=True)
def _visit_root_rows(forward, rows, lo, hi, n0, pslot, body, partner, JA, JB, MA, MB, W, target, lam, fr, u, dun,
                     mu_cos, mu_sin, m):
    """One Gauss–Seidel visit of the root rows ``rows[lo:hi]`` (one domain's, or the cross rows; forwards or
    backwards; ``root_sweeps`` of :func:`_coupled_iterate_impl`): the normal row, then the friction block, as in
    the kernel's sweeps."""
    vr = np.zeros(3)
    px = np.zeros(max(m, 1))
    py = np.zeros(max(m, 1))
    Bl = np.zeros((2, 2))
    cl = np.zeros(2)
    for q in range(hi - lo):
        c = rows[lo + q] if forward else rows[hi - 1 - q]
        sc = _slot(c, n0, pslot)
        a = body[c]
        b = partner[c]
        vr[0] = _row_speed(JA, JB, sc, 0, a, b, u)
        new = lam[c] + (target[c] - vr[0]) / W[sc, 0, 0]
        if new < 0.0:
            new = 0.0
        if new == 0.0 and lam[c] == 0.0 and fr[c, 0] == 0.0 and fr[c, 1] == 0.0:
            continue
        for k in range(1, 3):
            vr[k] = _row_speed(JA, JB, sc, k, a, b, u)
        _set_normal_impulse(c, sc, a, b, new, vr, lam, u, dun, MA, MB, W)
        if m >= 3:
            _solve_friction(c, sc, a, b, vr, lam, fr, u, MA, MB, W, mu_cos, mu_sin, m, px, py, Bl, cl)


@njit(cache=True, inline="always")
def _point_change(u, u0, z, rho):
    """|Δv| + |Δω| ρ of body z between the twists u0 and u (m/s): a bound of the velocity change of every point
    within ρ (m) of its centre."""
    dv = 0.0
    dw = 0.0
    for q in range(3):
        dv += (u[z, q] - u0[z, q]) ** 2
        dw += (u[z, 3 + q] - u0[z, 3 + q]) ** 2
    return np.sqrt(dv) + np.sqrt(dw) * rho


@njit(cache=True, inline="always")
def _screen_margin(u_ref, rho):
    """Rounding margin of the candidate screen, m/s: 1e-12 + 1e-9 × the largest contact-point speed
    |v| + |ω| ρ at the reference twists u_ref (ρ (S,): the bodies' lever bounds, m)."""
    umax = 0.0
    for z in range(u_ref.shape[0]):
        umax = max(umax, np.sqrt(u_ref[z, 0] ** 2 + u_ref[z, 1] ** 2 + u_ref[z, 2] ** 2)
                   + np.sqrt(u_ref[z, 3] ** 2 + u_ref[z, 4] ** 2 + u_ref[z, 5] ** 2) * rho[z])
    return 1e-12 + 1e-9 * umax


def _coupled_setup_impl(body, partner, normal, lever, partner_lever, mass, R, inertia, joint_k, joint_l, joint_rk,
                        joint_rl, joint_compliance_inv, chain_off, n_listed_rows, storage):
    """Set-up of :func:`_coupled_iterate_impl` that depends only on the geometry (rows, R, joints), not on
    the targets or the starting impulses: per contact row (the first ``n_listed_rows``; −1: all) the
    Jacobian rows J_A, J_B (nc, 3, 6), their mobility images M⁻¹Jᵀ (nc, 3, 6) and the 3×3 Delassus block
    W (nc, 3, 3); per joint the world inverse inertias of its bodies Ik, Il (nj, 3, 3) and the block-Thomas
    factors Dinv, G, Up (nj, 6, 6) of every chain. The rows are set at their index; the candidates' slots
    are left unset (and untouched by this kernel: the memory of these arrays is only mapped when written),
    the iteration fills them in the order it promotes candidates (:func:`_slot`), not at the candidates'
    indices, whose scattered first writes cost a page fault each (landing drape strand, 1.9 M candidates,
    25 k promotions: 0.085 s of its 2.2 s serial solve). ``storage``: an empty array whose dtype (float64 or
    float32, ``ChainOptions.kernel_precision``) these arrays take; the arithmetic is float64 either way (the
    iteration reads them into float64 sums). Returns (JA, JB, MA, MB, W, Ik, Il, Dinv, G, Up);
    the velocity solve and the push-out solve of one harmonisation pass share it (each iteration fills the
    candidates' slots from the first)."""
    nc = body.shape[0]
    n_on = nc if n_listed_rows < 0 else min(n_listed_rows, nc)
    MA = np.empty((nc, 3, 6), storage.dtype)  # every entry of a row is written by _contact_rows
    MB = np.empty((nc, 3, 6), storage.dtype)
    JA = np.empty((nc, 3, 6), storage.dtype)
    JB = np.empty((nc, 3, 6), storage.dtype)
    W = np.empty((nc, 3, 3), storage.dtype)
    for q in prange((n_on + ROW_CHUNK - 1) // ROW_CHUNK):  # work arrays per chunk of rows, not per row
        Iw = np.empty((3, 3))
        T = np.empty((2, 3))
        for c in range(q * ROW_CHUNK, min(n_on, (q + 1) * ROW_CHUNK)):
            _contact_rows(c, c, body, partner, normal, lever, partner_lever, mass, R, inertia, JA, JB, MA, MB, W, Iw,
                          T)
    nj = joint_k.shape[0]
    nch = chain_off.shape[0] - 1
    Ik = np.zeros((nj, 3, 3), storage.dtype)
    Il = np.zeros((nj, 3, 3), storage.dtype)
    Dinv = np.zeros((nj, 6, 6), storage.dtype)
    G = np.zeros((nj, 6, 6), storage.dtype)
    Up = np.zeros((nj, 6, 6), storage.dtype)
    for j in prange(nj):
        if joint_k[j] >= 0:
            _inv_inertia_into(R[joint_k[j]], inertia[joint_k[j]], Ik[j])
        _inv_inertia_into(R[joint_l[j]], inertia[joint_l[j]], Il[j])
    for ch in prange(nch):
        _chain_factor(chain_off[ch], chain_off[ch + 1], joint_k, joint_l, joint_rk, joint_rl, joint_compliance_inv,
                      mass, Ik, Il, Dinv, G, Up)
    return JA, JB, MA, MB, W, Ik, Il, Dinv, G, Up


def _coupled_iterate_impl(JA, JB, MA, MB, W, Ik, Il, Dinv, G, Up, body, partner, normal, lever, partner_lever, target,
                          u, mass, R, inertia, mu_cos, mu_sin, restitution, max_iter, tol, lam_out, fr_out, joint_k,
                          joint_l, joint_rk, joint_rl, joint_target, joint_compliance_inv, joint_w0, chain_off,
                          n_listed_rows, joints_last, body_part, momentum, ref_vn, u_ref0, rho0, root_sweeps,
                          root_segments, late_speed):
    """The iteration of :func:`project_coupled` on the set-up of :func:`_coupled_setup_impl` (whose
    candidate rows it fills in when it promotes them). Projected nonlinear Gauss–Seidel over all contacts (one row per pair, relative velocities):
    ``min Σ_b ½‖u_b − u⁻_b‖²_M`` s.t. n·(u_A − u_B)(contact) ≥ target, with the friction polygon
    λ_c·conv{μ_β d_β} per contact (frame t₁ from body A's axis) solved by exact 2-D block solves
    (:func:`headsim.solvers._kernels.chains._polygon_qp`). u (S, 6) holds u⁻ on entry and the result on
    exit (restitution ε added to the normal part). partner = −1: static obstacle.

    lam_out (nc,), fr_out (nc, 2): on entry the initial normal and friction impulses (warm start, N s,
    friction in the contact's (t₁, t₂) frame; zeros: cold start), applied here to u = u⁻ before the first
    sweep; on exit the solution.

    Joint rows (joint_k, joint_l bodies, −1 = fixed root anchor; levers joint_rk, joint_rl (nj, 3), m;
    joint_target (nj, 3) m/s; grouped in chains ``chain_off`` (CSR over the rows, consecutive joints of
    one fibre)) are bilateral point-joint constraints (u_k + ω_k × r_k) − (u_l + ω_l × r_l) = target,
    each with its implicit spring row (joint_compliance_inv (nj, 3, 3): C = ½Δt² K_w + Δt c E over the
    second half step; joint_w0 (nj, 3) rad/s: relative angular velocity ω_l − ω_k of u⁻): the extra
    angular impulse pair (+Λ on k, −Λ on l) obeys Λ = C (ω_rel(u) − ω_rel,0). Every sweep solves each
    chain's 6·n_j rows exactly (block Thomas, factorised once in the set-up), then the contacts (symmetric
    order; partial sweeps over the rows that carry an impulse or are close to their bound in between, see
    the schedule below). Stops when, in a full sweep, the largest impulse change (as a velocity, m/s) and
    the largest joint gap-rate residual fall below ``tol``.

    Reserve rows: only the first ``n_listed_rows`` contacts (−1: all) are rows from the start; the others
    are candidates (speculative pairs that were not closing fast enough at u⁻ to need a row) and take no
    part until a full sweep finds their bound violated at the current u (the pair would now close its gap
    within the step): they are then set up and join the iteration. The iteration does not stop on a full
    sweep that added rows: up to ``max_iter`` extra sweeps are run for them (the last sweep is full, so no
    candidate ends violated unless that cap is hit). ``late_speed`` (m/s, ≥ 0): a full sweep at the sweep cap
    extends it (by 9 sweeps, up to 2 ``max_iter``) only when one of the candidates it promoted violates its
    bound by more than this, target − n·(u_A − u_B) > ``late_speed`` (× Δt: the overlap the pair would reach by
    the step's end if the solve stopped there); 0: every promotion at the cap extends it (the former rule).
    Returns the sweeps used, the last change (m/s) and the number of candidates that became rows.

    ``root_sweeps``, ``root_segments`` (``ChainOptions.root_sweeps``): after every full sweep that has not met
    the stopping rule, ``root_sweeps`` extra sweeps over the root region alone: an exact solve of the first
    ``root_segments`` joints of every chain anchored at its root (the Thomas factors of those rows are the
    whole chain's first ones; the joint after them keeps its impulse), then a visit of every row that
    touches one of those segments, forwards and backwards in turn, by domain as the full sweeps visit theirs
    (``body_part``: each domain's root rows in parallel, then the cross rows; backwards the other way round; one
    domain: the rows in their order, as before). Block Gauss–Seidel steps in another
    order: the fixed point is the same, and the sweep that ends a converged iteration is a plain full
    sweep (the Nesterov extrapolation after the sweep counts the root sweeps' changes as the sweep's). 0
    (either): the former iterates, bitwise. Why the root: a push on a segment next to the anchored
    root moves little once the stiff joints are solved, so each contact visit there (its step sized by the
    free bodies' Delassus diagonal W₀₀) moves the solved chain by only a small part of what it asks for
    (measured on the reference scene at rest, 400 sampled rows: W₀₀ with the chains solved / without is
    0.015 at least and 0.057 in the median on segments 0–4, 0.11 in the median beyond segment 50), and the
    rows between neighbouring roots are the slowest of the whole solve (the largest impulse changes
    between 100 and 200 sweeps are all on segments 0–4).

    ``joints_last``: end with one more exact joint solve of every chain (the sweeps end with the contacts,
    so an iteration stopped at the sweep cap leaves the joint rows violated by the last contact updates).
    Used for the split push-out solve, whose twists only move the positions: a push-out that breaks the
    joints opens joint gaps that the next step's joint stage closes again, moving the segments back into
    their contacts in its unconstrained first half step (measured on the settled 40 × 30 drape strand:
    27.6 mm/s joint-rate residual after the 60-sweep push-out, 17 µm joint gaps, 12–16 mm/s closing speed
    at the deepest contacts after the joint stage; see ``ChainOptions.recovery_keeps_joints``).

    ``body_part`` (S,) int64: domain 0 … D − 1 of every body (``ChainOptions.contact_domains``).
    The contact part of every sweep visits the rows of each domain (both bodies in it; obstacle rows:
    the body's) in parallel, each domain's rows in their order above, and then the cross rows (the reverse
    sweep visits the same sequence backwards: the cross rows first). Rows of different domains share no
    body, so this is one Gauss–Seidel sweep over all rows in that order, whatever the number of threads.
    Every body in domain 0 (or an empty array): the single sequence, the former iterates bitwise.

    ``momentum`` (0: off, the plain Gauss–Seidel; 1: Nesterov): after every sweep that is followed by another,
    the contact impulses are extrapolated along their last change (Nesterov 1983; adaptive restart of
    O'Donoghue & Candès 2015): λ ← max(0, λ_k + β_k (λ_k − λ_{k−1})), β_k = momentum · (k − 1)/(k + 2) with
    k the sweeps since the last restart, the friction impulses scaled with their normal impulse (so they
    stay in their polygon λ·conv{μ_β d_β}), and the twists u moved by the extrapolation's impulses; the
    joints are not extrapolated (each sweep solves them exactly). Restart (k = 0, no extrapolation) when
    the sweep's own step opposes the extrapolation, Σ_c W_c (λ_c − y_c)(y_c − λ_{c,k−1}) < 0 (y: the
    extrapolated impulses the sweep started from; promoted candidates enter with λ = y = λ_{k−1} = 0). The
    sweep that ends the iteration is not extrapolated, so the result is a Gauss–Seidel iterate (the joints
    solved, every visited row projected) and the fixed point is the same. Measured on the drape reference
    scene's solves (``benchmarks/bench_contact_convergence.py``): the error of 60 plain sweeps in 20–30.
    Promotions do not restart: a restart on every full sweep that promoted candidates (the former rule) left
    the landing strand's solves (t = 87 ms, 144 k rows, 1.9 M candidates, 25–111 k promotions, a promotion in
    nearly every full sweep) almost without extrapolation: after 60 sweeps the summed bound violation
    Σ max(0, target − n·Δu) was 247–272 m/s against 60–83 m/s without that restart (128–152 m/s after 40).

    ``ref_vn`` (nc,) m/s, ``u_ref0`` (S, 6), ``rho0`` (S,) m: the candidates' normal relative velocities
    n·(u_A − u_B) at the contact points for the twists u_ref0 (computed where the rows were detected) and a
    bound of every body's contact levers (h + r); with them the first candidate test is screened as the later
    ones are (see the candidate block), instead of reading every candidate. Empty ``ref_vn``: the first test
    reads them all."""
    nc = body.shape[0]
    m = mu_cos.shape[0]
    n_on = nc if n_listed_rows < 0 else min(n_listed_rows, nc)
    rowid = np.empty(nc, np.int64)  # rowid[:n_on]: the contacts that are rows, in sweep order
    n0 = n_on  # the set-up's rows (slot c); promoted candidates get the next free slot (see _slot)
    pslot = np.empty(nc - n0, np.int64)
    n_slots = n0
    for c in range(n_on):
        rowid[c] = c
    is_row = np.zeros(nc, np.bool_)
    is_row[:n_on] = True
    nj = joint_k.shape[0]
    nch = chain_off.shape[0] - 1
    Lam = np.zeros((nj, 3))
    y = np.zeros((nj, 6))
    dq = np.zeros((nj, 6))
    chain_worst = np.zeros(nch)
    lam = lam_out  # iterated in place (on exit: the solution)
    fr = fr_out
    dun = np.zeros((u.shape[0] if restitution > 0.0 else 0, 6))  # the restitution's normal twists (ε > 0 only)
    if m < 3:
        for c in range(nc):
            fr[c, 0] = 0.0
            fr[c, 1] = 0.0
    # warm start: apply the initial impulses (the first joint sweep then re-closes the joints); candidates
    # start without impulse
    for c in range(nc):
        if c >= n_on:
            lam[c] = 0.0
        if lam[c] < 0.0:
            lam[c] = 0.0
        if lam[c] == 0.0:
            fr[c, 0] = 0.0
            fr[c, 1] = 0.0
            continue
        a = body[c]
        b = partner[c]
        _add_impulse_twists(u, dun, a, b, c, lam[c], fr[c, 0], fr[c, 1], MA, MB)
    Iw1 = np.empty((3, 3))
    T1 = np.empty((2, 3))
    promoted = 0
    screened = False  # candidate screening state (see the candidate block)
    u_ref = np.empty((0, 6))
    cand_slack = np.empty(0)
    rho = np.empty(0)
    dbound = np.empty(0)
    screen_margin = 0.0
    if ref_vn.shape[0] == nc and n_on < nc:  # slacks known at u_ref0: the first test is screened too
        screened = True
        u_ref = u_ref0.copy()
        rho = rho0.copy()
        dbound = np.zeros(u.shape[0])
        cand_slack = np.empty(nc)
        for c in range(n_on, nc):
            cand_slack[c] = ref_vn[c] - target[c]
        screen_margin = _screen_margin(u_ref, rho)
    n_prom = 0
    sweep_cap = max_iter
    # sweep schedule: a full sweep visits every row; the partial sweeps in between visit only the rows
    # that carry an impulse or were within their slack band of their bound in the last full sweep (a row
    # with λ = 0 whose bound holds is left unchanged by a Gauss–Seidel visit, so skipping it changes
    # nothing until another row's impulse makes it bind). The band: with ``rho0``, BAND_FACTOR × the
    # point-velocity changes |Δv| + |Δω| ρ of the row's two bodies between the last two full sweeps (at
    # least 10 tol; every row after the first full sweep), else ``slack_band``, the largest change of any
    # row in the last full sweep. The iteration only stops on a full sweep with a change ≤ tol, and the
    # last permitted sweep is full: the fixed point is the plain Gauss–Seidel one.
    # domains (``body_part``): the rows whose bodies all lie in domain d form segment d of ``order``, the
    # others (the cross rows) the last segment; off: segment offsets; listed: the partial sweeps' rows, segment
    # d at listed[off[d]:off[d] + lcnt[d]]
    # a local copy: with the argument itself the compiled kernel ran 10 × slower (measured, serial)
    bpart = np.empty(body_part.shape[0], np.int64)
    bpart[:] = body_part
    nd = 1
    for z in range(bpart.shape[0]):
        nd = max(nd, bpart[z] + 1)
    dom = np.empty(nc, np.int64)  # rows only (candidates get theirs when they become rows)
    for c in range(n_on):
        dom[c] = 0
    if nd > 1:
        for c in range(n_on):
            pa = bpart[body[c]]
            pb = bpart[partner[c]] if partner[c] >= 0 else pa
            dom[c] = pa if pa == pb else nd
    order = np.empty(nc, np.int64)
    off = np.zeros(nd + 2, np.int64)
    _segment_rows(rowid, n_on, dom, nd, order, off)
    old_off = off.copy()
    lcnt_off = np.zeros(nd + 2, np.int64)
    lcnt = np.zeros(nd + 1, np.int64)
    seg_change = np.zeros(nd + 1)
    listed = np.empty(nc, np.int64)
    tmp = np.empty(nc, np.int64)
    prom_rows = np.empty(nc, np.int64)
    violated = np.zeros(nc if n_on < nc else 0, np.bool_)  # the candidates a full sweep's test found violated
    slack_now = np.empty(nc if n_on < nc else 0)
    full = True
    since_full = 0
    last_full_change = np.inf
    it = 0
    # momentum: λ after the previous sweep (before its extrapolation) and the extrapolated λ a sweep starts from
    lam_prev = np.empty(nc if momentum > 0.0 else 0)
    lam_start = np.empty(nc if momentum > 0.0 else 0)
    if momentum > 0.0:  # rows only; a candidate's are set (0) when it becomes a row
        for c in range(n_on):
            lam_prev[c] = lam[c]
            lam_start[c] = lam[c]
    k_mom = 0
    ext_dot = np.zeros(nd + 1)
    # the restart test's terms W_c (λ_c − y_c)(y_c − λ_{c,k−1}) of the listed rows, at their positions in
    # ``listed``, written when a sweep visits them (their λ_c is then final for the sweep)
    ext_term = np.empty(nc if momentum > 0.0 else 0)
    change = 0.0
    by_body = rho0.shape[0] == u.shape[0]  # the bodies' lever bounds are known: per-row slack bands
    band_body = np.zeros(u.shape[0] if by_body else 0)
    u_last_full = np.empty((u.shape[0] if by_body else 0, 6))
    have_full = False
    # the root region (``root_sweeps``): rows that touch one of the first ``root_segments`` segments of a chain
    # anchored at its root (its first joint has no body k), visited in row order by the root sweeps
    n_root = 0
    root_pos = np.full(u.shape[0] if root_sweeps > 0 else 0, -1, np.int64)  # a body's segment from the root
    root_rows = np.empty(nc if root_sweeps > 0 else 0, np.int64)
    if root_sweeps > 0 and root_segments > 0:
        for ch in range(nch):
            j0 = chain_off[ch]
            if joint_k[j0] < 0:
                for j in range(j0, min(chain_off[ch + 1], j0 + root_segments)):
                    root_pos[joint_l[j]] = j - j0
        for c in range(n_on):
            if _touches_root(root_pos, body[c], partner[c]):
                root_rows[n_root] = c
                n_root += 1
    # the root rows by domain (as ``order``: each domain's, then the cross rows), visited like the full sweeps
    root_seg = np.empty(nc if root_sweeps > 0 else 0, np.int64)
    root_off = np.zeros(nd + 2, np.int64)
    if n_root > 0:
        _segment_rows(root_rows, n_root, dom, nd, root_seg, root_off)
    while it < sweep_cap:
        it += 1
        if it == sweep_cap:
            full = True
        change = 0.0
        if full and by_body:
            for z in prange(u.shape[0]):
                band_body[z] = _point_change(u, u_last_full, z, rho0[z]) if have_full else np.inf
                for q in range(6):
                    u_last_full[z, q] = u[z, q]
            have_full = True
        for ch in prange(nch):
            chain_worst[ch] = _chain_sweep(chain_off[ch], chain_off[ch + 1], joint_k, joint_l, joint_rk, joint_rl,
                                           joint_target, joint_compliance_inv, joint_w0, u, mass, Ik, Il, Dinv, G,
                                           Up, Lam, y, dq)
        for ch in range(nch):
            if chain_worst[ch] > change:
                change = chain_worst[ch]
        slack_band = max(10.0 * tol, last_full_change)
        # contact rows: the rows of each domain (their bodies all in that domain) in parallel, then the cross
        # rows; the reverse sweep visits the same sequence backwards (symmetric Gauss–Seidel)
        fwd = it % 2 == 1
        for phase in range(2):
            par_phase = (phase == 0) == fwd  # forward: the domains, then the cross rows; reverse: the other way
            nseg = nd if par_phase else 1
            base = 0 if par_phase else nd
            for dd in prange(nseg):
                d = np.int64(dd) + base
                lo = off[d]
                hi = off[d + 1] if full else off[d] + lcnt[d]
                px = np.zeros(max(m, 1))
                py = np.zeros(max(m, 1))
                Bl = np.zeros((2, 2))
                cl = np.zeros(2)
                vr = np.zeros(3)
                n_new = 0
                seg_ch = 0.0
                for q in range(hi - lo):
                    qq = lo + q if fwd else hi - 1 - q
                    c = order[qq] if full else listed[qq]
                    sc = _slot(c, n0, pslot)
                    a = body[c]
                    b = partner[c]
                    s = _row_speed(JA, JB, sc, 0, a, b, u)
                    vr[0] = s
                    new = lam[c] + (target[c] - s) / W[sc, 0, 0]
                    if new < 0.0:
                        new = 0.0
                    pos = qq  # the row's position in ``listed`` (a full sweep lists it, if at all, at lo + n_new)
                    if new == 0.0 and lam[c] == 0.0 and fr[c, 0] == 0.0 and fr[c, 1] == 0.0:
                        if full:
                            pos = -1
                            band = slack_band
                            if by_body:
                                band = max(10.0 * tol, BAND_FACTOR * (band_body[a] + (band_body[b] if b >= 0 else 0.0)))
                            if s - target[c] <= band:
                                pos = lo + n_new
                                listed[pos] = c
                                n_new += 1
                        if momentum > 0.0 and pos >= 0:
                            ext_term[pos] = _restart_term(c, sc, lam, lam_start, lam_prev, W)
                        continue  # bound holds, no impulse: the visit changes nothing
                    if full:
                        pos = lo + n_new
                        listed[pos] = c
                        n_new += 1
                    for k in range(1, 3):
                        vr[k] = _row_speed(JA, JB, sc, k, a, b, u)
                    seg_ch = max(seg_ch, _set_normal_impulse(c, sc, a, b, new, vr, lam, u, dun, MA, MB, W))
                    if momentum > 0.0:
                        ext_term[pos] = _restart_term(c, sc, lam, lam_start, lam_prev, W)
                    if m < 3:
                        continue
                    seg_ch = max(seg_ch, _solve_friction(c, sc, a, b, vr, lam, fr, u, MA, MB, W, mu_cos, mu_sin, m,
                                                         px, py, Bl, cl))
                seg_change[d] = seg_ch
                if full:
                    lcnt[d] = n_new
        for d in range(nd + 1):
            if seg_change[d] > change:
                change = seg_change[d]
        if n_root > 0 and full and change > tol:
            # root sweeps: block Gauss–Seidel over the root region alone, each an exact solve of the first
            # ``root_segments`` joints of every anchored chain (the Thomas factors of the whole chain's first
            # rows are those of that sub-chain; the joint after it keeps its impulse) and a visit of every
            # root row, alternating forwards and backwards
            for rs in range(root_sweeps):
                for ch in prange(nch):
                    j0 = chain_off[ch]
                    if joint_k[j0] < 0:
                        _chain_sweep(j0, min(chain_off[ch + 1], j0 + root_segments), joint_k, joint_l, joint_rk,
                                     joint_rl, joint_target, joint_compliance_inv, joint_w0, u, mass, Ik, Il, Dinv, G,
                                     Up, Lam, y, dq)
                # the root rows: each domain's in parallel, then the cross rows (backwards: the other way round)
                fwd_r = rs % 2 == 0
                for phase in range(2):
                    par_phase = (phase == 0) == fwd_r
                    nseg = nd if par_phase else 1
                    base = 0 if par_phase else nd
                    for dd in prange(nseg):
                        d = np.int64(dd) + base
                        _visit_root_rows(fwd_r, root_seg, root_off[d], root_off[d + 1], n0, pslot, body, partner, JA,
                                         JB, MA, MB, W, target, lam, fr, u, dun, mu_cos, mu_sin, m)
        dot = 0.0  # the momentum's restart test over this sweep's listed rows (before promotions move them)
        if momentum > 0.0:
            for dd in prange(nd + 1):
                ext_dot[dd] = _listed_sum(ext_term, off[dd], lcnt[dd])
            for d in range(nd + 1):
                dot += ext_dot[d]
        n_prom = 0
        if full and n_on < nc:
            # candidates whose bound the current velocities violate become rows. Screening (same promotions,
            # fewer loads): the first test records every candidate's slack σ_c = n·(u_A − u_B) − target at the
            # twists u_ref of that sweep and, per body, ρ = its largest lever among the candidates tested then;
            # later |n·Δu(contact point)| ≤ δ = |Δv| + |Δω| ρ per body (Δ from u_ref), so a candidate with
            # δ_A + δ_B + margin < σ_c cannot be violated and is skipped without reading its normal, levers
            # and twists (margin 1e-12 m/s + 1e-9 × the largest contact-point speed at u_ref, far above the
            # rounding of the tests). On the reference scene this skips 99.8 % of the 1.6 M candidate tests.
            # With ``ref_vn`` the slacks at u_ref = u_ref0 are known before the first test (ρ = rho0), so that
            # test is screened as well. A full sweep that tested any candidate exactly moves the reference to its
            # u: the tested candidates keep their exact slacks, the others the lower bound σ_c − (δ_A + δ_B +
            # margin), so the screen stays a bound while only the drift since the last rebase counts (landing
            # strand, t = 86 ms, 1.85 M candidates, 9 full sweeps: 2.2 M exact tests instead of 5.7 M; its solve
            # 1.52–1.62 → 1.39–1.43 s, the same promotions).
            if screened:  # the bound and the exact test of every candidate in parallel, the promotions in order
                for z in prange(u.shape[0]):
                    dbound[z] = _point_change(u, u_ref, z, rho[z])
                n_tested = 0
                for c in prange(nc):
                    violated[c] = False
                    if is_row[c]:
                        continue
                    bnd = dbound[body[c]] + screen_margin
                    if partner[c] >= 0:
                        bnd += dbound[partner[c]]
                    if bnd < cand_slack[c]:
                        slack_now[c] = cand_slack[c] - bnd
                        continue
                    sv = row_normal_speed(c, body, partner, normal, lever, partner_lever, u)
                    violated[c] = sv < target[c]
                    slack_now[c] = sv - target[c]
                    n_tested += 1
                if n_tested > 0:  # rebase: the slacks (exact or lower bounds) at this u become the reference
                    cand_slack, slack_now = slack_now, cand_slack  # (every candidate's was written above)
                    for z in prange(u.shape[0]):
                        for q in range(6):
                            u_ref[z, q] = u[z, q]
            else:  # the first test without ``ref_vn``: records the slacks and levers of the screening
                u_ref = u.copy()
                cand_slack = np.empty(nc)
                rho = np.zeros(u.shape[0])
                dbound = np.zeros(u.shape[0])
                for c in range(nc):
                    violated[c] = False
                    if is_row[c]:
                        continue
                    a = body[c]
                    b = partner[c]
                    sv = row_normal_speed(c, body, partner, normal, lever, partner_lever, u)
                    cand_slack[c] = sv - target[c]
                    r = lever[c]
                    rho[a] = max(rho[a], np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]))
                    if b >= 0:
                        r = partner_lever[c]
                        rho[b] = max(rho[b], np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]))
                    violated[c] = sv < target[c]
            worst_new = 0.0  # the promoted candidates' largest bound deficit target − n·Δu, m/s
            for c in range(nc):
                if violated[c]:
                    worst_new = max(worst_new, -cand_slack[c])  # the exact slack of a tested candidate
                    a = body[c]
                    b = partner[c]
                    pslot[c - n0] = n_slots
                    _contact_rows(c, n_slots, body, partner, normal, lever, partner_lever, mass, R, inertia, JA, JB,
                                  MA, MB, W, Iw1, T1)
                    n_slots += 1
                    is_row[c] = True
                    rowid[n_on] = c
                    n_on += 1
                    pa = bpart[a] if nd > 1 else 0
                    pb = bpart[b] if nd > 1 and b >= 0 else pa
                    dom[c] = pa if pa == pb else nd
                    if momentum > 0.0:
                        lam_prev[c] = 0.0
                        lam_start[c] = 0.0
                    prom_rows[n_prom] = c
                    if root_sweeps > 0 and _touches_root(root_pos, a, b):
                        root_rows[n_root] = c
                        n_root += 1
                    n_prom += 1
            if not screened:
                screen_margin = _screen_margin(u_ref, rho)
            screened = True
            promoted += n_prom
            if n_root > root_off[nd + 1]:  # promoted root rows join the root rows' domain segments
                _segment_rows(root_rows, n_root, dom, nd, root_seg, root_off)
            if n_prom > 0:  # the new rows join their domains' segments (and lists, after the listed rows)
                _segment_rows(rowid, n_on, dom, nd, order, off)
                q = 0
                for d in range(nd + 1):
                    for z in range(lcnt[d]):
                        tmp[q] = listed[old_off[d] + z]
                        q += 1
                for z in range(n_prom):
                    tmp[q] = prom_rows[z]
                    q += 1
                _segment_rows(tmp, q, dom, nd, listed, lcnt_off)
                for d in range(nd + 1):
                    lcnt[d] = lcnt_off[d + 1] - lcnt_off[d]
                for d in range(nd, -1, -1):  # move segment d from lcnt_off[d] to off[d] (off[d] ≥ lcnt_off[d])
                    for z in range(lcnt[d] - 1, -1, -1):
                        listed[off[d] + z] = listed[lcnt_off[d] + z]
                old_off[:] = off
            if n_prom > 0 and worst_new > late_speed and it >= sweep_cap - 1 and sweep_cap < 2 * max_iter:
                sweep_cap = min(it + 9, 2 * max_iter)  # sweeps for the new rows, the last one full
        if full:
            last_full_change = change
            if change <= tol and n_prom == 0:
                break
            full = False
            since_full = 0
        else:
            since_full += 1
            # back to a full sweep when the listed rows have settled, or every 8 partial sweeps
            full = change <= tol or since_full >= 8
        if momentum > 0.0 and it < sweep_cap:
            # Nesterov extrapolation of the impulses after a sweep (``momentum``) over the rows the sweep may have
            # changed (the listed rows: a full sweep lists every row it changed, a partial sweep visits only
            # them); k: sweeps since the last restart. The domains' rows in parallel (they share no body), then
            # the cross rows: every body's twist receives its rows' changes in the serial order.
            k_mom = 0 if dot < 0.0 else k_mom + 1
            beta = momentum * (k_mom - 1.0) / (k_mom + 2.0) if k_mom > 1 else 0.0  # 0: restarted, nothing moves
            for dd in prange(nd):
                _extrapolate_rows(listed, off[dd], lcnt[dd], beta, lam, lam_prev, lam_start, fr, u, dun, body,
                                  partner, MA, MB, n0, pslot)
            _extrapolate_rows(listed, off[nd], lcnt[nd], beta, lam, lam_prev, lam_start, fr, u, dun, body, partner,
                              MA, MB, n0, pslot)
    if joints_last:
        # one more joint solve after the last contact visits: u then meets every joint row exactly (the contact
        # rows to the iteration's accuracy); see ``joints_last`` in the docstring
        for ch in prange(nch):
            _chain_sweep(chain_off[ch], chain_off[ch + 1], joint_k, joint_l, joint_rk, joint_rl, joint_target,
                         joint_compliance_inv, joint_w0, u, mass, Ik, Il, Dinv, G, Up, Lam, y, dq)
    if restitution > 0.0:
        for s in range(u.shape[0]):
            for z in range(6):
                u[s, z] += restitution * dun[s, z]
    return it, change, promoted


coupled_setup, coupled_setup_parallel = serial_and_parallel(_coupled_setup_impl)
coupled_iterate, coupled_iterate_parallel = serial_and_parallel(_coupled_iterate_impl)


def project_coupled(body, partner, normal, lever, partner_lever, target, u, mass, R, inertia, mu_cos, mu_sin,
                    restitution, max_iter, tol, lam_out, fr_out, joint_k, joint_l, joint_rk, joint_rl, joint_target,
                    joint_compliance_inv, joint_w0, chain_off, n_listed_rows=-1, parallel=False, body_part=None,
                    momentum=0.0, root_sweeps=0, root_segments=0, late_speed=0.0, joints_last=False,
                    storage=np.float64):
    """Set-up and iteration in one call (see :func:`_coupled_iterate_impl` for the arguments and the
    result); ``parallel``: the ``prange`` versions; ``body_part``: the body domains of the contact sweep;
    ``storage``: floating-point type of the set-up's stored row and chain arrays (``ChainOptions.kernel_precision``);
    ``joints_last``: end with an exact joint solve of every chain;
    ``momentum``: Nesterov extrapolation (0: plain Gauss–Seidel); ``root_sweeps``, ``root_segments``: the
    root region's extra sweeps (0: none); ``late_speed``: the bound deficit (m/s) above which a promotion at
    the sweep cap extends it (0: every one)."""
    if body_part is None:
        body_part = np.zeros(0, np.int64)
    setup = coupled_setup_parallel if parallel else coupled_setup
    iterate = coupled_iterate_parallel if parallel else coupled_iterate
    pre = setup(body, partner, normal, lever, partner_lever, mass, R, inertia, joint_k, joint_l, joint_rk, joint_rl,
                joint_compliance_inv, chain_off, n_listed_rows, np.zeros(0, storage))
    return iterate(*pre, body, partner, normal, lever, partner_lever, target, u, mass, R, inertia, mu_cos, mu_sin,
                   restitution, max_iter, tol, lam_out, fr_out, joint_k, joint_l, joint_rk, joint_rl, joint_target,
                   joint_compliance_inv, joint_w0, chain_off, n_listed_rows, bool(joints_last), body_part,
                   float(momentum),
                   np.zeros(0), np.zeros((0, 6)), np.zeros(0), int(root_sweeps), int(root_segments),
                   float(late_speed))


def project_coupled_parallel(*args):
    """:func:`project_coupled` with the ``prange`` kernels."""
    return project_coupled(*args, parallel=True)
