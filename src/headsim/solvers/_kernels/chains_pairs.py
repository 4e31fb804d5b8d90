"""Numba kernels that turn fibre–fibre closest-point pairs into contact rows and evaluate rows' relative
normal velocities for the chain solver (:mod:`headsim.solvers.chains`; Sobottka 2008 §8.4, eqs. 8.7, 8.9).

Conventions as in :mod:`headsim.solvers._kernels.chains`: twists u = (v, ω) (m/s, rad/s, world frame);
segment s has centre x_s, axis d3_s and half length h_s; a contact point's velocity is v + ω × r with r
the lever from the centre (eq. 8.7).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from headsim.collide._kernels_fibre_traverse import segment_segment_closest
from headsim.solvers._kernels.twins import serial_and_parallel


@njit(cache=True, inline="always")
def _pair_band(a, b, radius, speed, band_fraction, margin, dt):
    """(row band, detection band) of pair (a, b), m: ½ band_fraction (r_a + r_b) + margin, and that plus
    0.75 (speed_a + speed_b) Δt (a pair is kept when its gap is below the detection band)."""
    band = 0.5 * band_fraction * (radius[a] + radius[b]) + margin
    return band, band + 0.75 * (speed[a] + speed[b]) * dt


@njit(cache=True, inline="always")
def _twist_normal_speed(u, s, n0, n1, n2, r0, r1, r2):
    """n·(v_s + ω_s × r) (m/s) of twist u[s] = (v, ω) at lever r (m) for the unit normal n."""
    return (n0 * (u[s, 0] + u[s, 4] * r2 - u[s, 5] * r1) + n1 * (u[s, 1] + u[s, 5] * r0 - u[s, 3] * r2)
            + n2 * (u[s, 2] + u[s, 3] * r1 - u[s, 4] * r0))


@njit(cache=True, inline="always")
def _axes_cross(d3, a, b):
    """e_a × e_b of the unit axes d3 of segments a and b, and its norm (the sine of their angle)."""
    c0 = d3[a, 1] * d3[b, 2] - d3[a, 2] * d3[b, 1]
    c1 = d3[a, 2] * d3[b, 0] - d3[a, 0] * d3[b, 2]
    c2 = d3[a, 0] * d3[b, 1] - d3[a, 1] * d3[b, 0]
    return c0, c1, c2, np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)


@njit(cache=True, inline="always")
def _touching_normal(d3, a, b):
    """Normal of two segments whose axes touch (no direction between the closest points): the axes' cross
    product, +y where they are also parallel."""
    c0, c1, c2, cn = _axes_cross(d3, a, b)
    if cn > 1e-12:
        return c0 / cn, c1 / cn, c2 / cn
    return 0.0, 1.0, 0.0


@njit(cache=True, inline="always")
def _pair_geometry(q, pairs, params, x, d3, half, radius, speed, band_fraction, margin, dt, u, have_u,
                   closing_factor, mark_tight, smooth, sep_allow, dq_half):
    """Row of pair q (the geometry and tests of :func:`fibre_pair_rows`, which the fused detection pass
    shares). Returns (keep, tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, vn) with vn = n·(u_a(p_a) −
    u_b(p_b)) (m/s; 0 without u)."""
    a = pairs[q, 0]
    b = pairs[q, 1]
    ta = (2.0 * params[q, 0] - 1.0) * half[a]
    tb = (2.0 * params[q, 1] - 1.0) * half[b]
    dv0 = x[a, 0] + ta * d3[a, 0] - x[b, 0] - tb * d3[b, 0]
    dv1 = x[a, 1] + ta * d3[a, 1] - x[b, 1] - tb * d3[b, 1]
    dv2 = x[a, 2] + ta * d3[a, 2] - x[b, 2] - tb * d3[b, 2]
    dist = np.sqrt(dv0 * dv0 + dv1 * dv1 + dv2 * dv2)
    ra = radius[a]
    rb = radius[b]
    gap = dist - ra - rb
    band, outer = _pair_band(a, b, radius, speed, band_fraction, margin, dt)
    if not gap < outer:
        return False, False, gap, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    flipped = False
    if dq_half.shape[0] > 0 and dist > 1e-12 and 0.0 < params[q, 0] < 1.0 and 0.0 < params[q, 1] < 1.0:
        # the closest points' separation along this normal at t_i (first order: less the first half step's motion
        # dq_half (S, 6) of the axis points): a pair whose centre lines passed through each other in the first half
        # step (closest points inside both segments: not a pair going round an end) separates the other way at
        # t_i; its normal is the t_i side and its gap −(dist + r_a + r_b)
        m0, m1, m2 = dv0 / dist, dv1 / dist, dv2 / dist
        flipped = dist - (_twist_normal_speed(dq_half, a, m0, m1, m2, ta * d3[a, 0], ta * d3[a, 1], ta * d3[a, 2])
                          - _twist_normal_speed(dq_half, b, m0, m1, m2, tb * d3[b, 0], tb * d3[b, 1],
                                                tb * d3[b, 2])) < 0.0
    if flipped:
        n0, n1, n2 = -dv0 / dist, -dv1 / dist, -dv2 / dist
        gap = -dist - ra - rb
    elif dist > 1e-12:
        n0, n1, n2 = dv0 / dist, dv1 / dist, dv2 / dist
    else:
        n0, n1, n2 = _touching_normal(d3, a, b)
    la0 = ta * d3[a, 0] - ra * n0
    la1 = ta * d3[a, 1] - ra * n1
    la2 = ta * d3[a, 2] - ra * n2
    lb0 = tb * d3[b, 0] + rb * n0
    lb1 = tb * d3[b, 1] + rb * n1
    lb2 = tb * d3[b, 2] + rb * n2
    tight = True
    vn = 0.0
    if have_u:
        va0 = u[a, 0] + u[a, 4] * la2 - u[a, 5] * la1
        va1 = u[a, 1] + u[a, 5] * la0 - u[a, 3] * la2
        va2 = u[a, 2] + u[a, 3] * la1 - u[a, 4] * la0
        vb0 = u[b, 0] + u[b, 4] * lb2 - u[b, 5] * lb1
        vb1 = u[b, 1] + u[b, 5] * lb0 - u[b, 3] * lb2
        vb2 = u[b, 2] + u[b, 3] * lb1 - u[b, 4] * lb0
        vn = n0 * (va0 - vb0) + n1 * (va1 - vb1) + n2 * (va2 - vb2)
        closing = -vn
        if -closing > smooth:
            if mark_tight == 2 and gap < 0.0:  # a separating penetration: kept as a candidate row
                return True, False, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, vn
            if sep_allow.shape[0] > 0 and vn <= smooth + sep_allow[a] + sep_allow[b]:
                # separating, but slower than this step's velocity changes may turn it round: a candidate row
                return True, False, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, vn
            return False, False, gap, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, vn
        if closing < 0.0:
            closing = 0.0
        if mark_tight:
            tight = gap < band - margin + closing_factor * closing * dt
    return True, tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, vn


@njit(cache=True, nogil=True)
def drop_pairs_without_rows(pairs, params, x, d3, half, radius, speed, band_fraction, margin, dt, u, closing_factor,
                            mark_tight, smooth, sep_allow, dq_half):
    """Compact (in place, returning their number) the closest-point pairs (P, 2) and params (P, 2) of one
    detection chunk to the ones :func:`_pair_geometry` keeps (within the detection band; not separating
    faster than ``smooth``, except a separating penetration with ``mark_tight`` = 2). The detection pass
    that follows then finds a pair's joint copy (:func:`_joint_duplicate`) among the kept pairs only: a
    contact at a joint is dropped as the copy of its neighbour's only where that one is kept (the two share
    the point, its gap and normal, and their velocities differ by the joint's velocity error, so they are
    kept or dropped alike but at the persistence threshold; keeping every pair near a segment end for the
    former lookup among all pairs would keep most of them: ≈ 98 % of the reference scene's pairs touch a
    segment end). No gil: runs in the tree query's worker threads."""
    have_u = u.shape[0] > 0
    n = 0
    for q in range(pairs.shape[0]):
        if _pair_geometry(q, pairs, params, x, d3, half, radius, speed, band_fraction, margin, dt, u, have_u,
                          closing_factor, mark_tight, smooth, sep_allow, dq_half)[0]:
            pairs[n, 0] = pairs[q, 0]
            pairs[n, 1] = pairs[q, 1]
            params[n, 0] = params[q, 0]
            params[n, 1] = params[q, 1]
            n += 1
    return n


@njit(cache=True, inline="always")
def _write_row(k, a, b, tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, a_out, b_out, n_out, la_out, lb_out,
               gap_out, tight_out):
    """Store row k (the values of :func:`_pair_geometry`) in the row arrays."""
    a_out[k] = a
    b_out[k] = b
    n_out[k, 0] = n0
    n_out[k, 1] = n1
    n_out[k, 2] = n2
    la_out[k, 0] = la0
    la_out[k, 1] = la1
    la_out[k, 2] = la2
    lb_out[k, 0] = lb0
    lb_out[k, 1] = lb1
    lb_out[k, 2] = lb2
    gap_out[k] = gap
    tight_out[k] = tight


@njit(cache=True)
def fibre_pair_rows(pairs, params, x, d3, half, radius, speed, band_fraction, margin, dt, u, closing_factor,
                    mark_tight, smooth, sep_allow, dq_half, a_out, b_out, n_out, la_out, lb_out, gap_out, tight_out):
    """Contact rows of closest-point pairs (pairs (P, 2) segment ids, params (P, 2) axis parameters in
    [0, 1]). Per pair: closest points c_a, c_b, normal n = (c_a − c_b)/‖·‖ (the axes' cross product for
    touching axes, +y for parallel touching ones), gap g = ‖c_a − c_b‖ − r_a − r_b, contact points
    p_a = c_a − r_a n, p_b = c_b + r_b n and levers p − x. A pair is kept when
    g < band + 0.75 (speed_a + speed_b) Δt with band = ½ band_fraction (r_a + r_b) + margin (m; speed
    (S,) m/s: each segment's |v| + h|ω|), and marked ``tight`` when g < band − margin + closing_factor · c Δt
    (the contact band without the speculative margin: a pair that only the margin reaches is a candidate,
    which the coupled solve turns into a row when its velocities close it) with
    c = max(0, −n·(u_a(p_a) − u_b(p_b))) the normal closing speed of the twists u (S, 6) (only with
    ``mark_tight``; otherwise, and for an empty u, every kept pair is tight). With u given, pairs that
    separate faster than ``smooth`` (m/s, n·(u_a − u_b) > smooth) are dropped (persistence filter, eq. 8.9),
    except, with ``mark_tight`` = 2, the penetrating ones (g < 0), and, with ``sep_allow`` (S,) m/s given (empty:
    none), the ones separating slower than smooth + sep_allow_a + sep_allow_b, which are kept as candidates (not
    tight). Writes the kept rows compactly to the outputs (length ≥ P) and
    returns their number."""
    k = 0
    have_u = u.shape[0] > 0
    for q in range(pairs.shape[0]):
        keep, tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, _ = _pair_geometry(
            q, pairs, params, x, d3, half, radius, speed, band_fraction, margin, dt, u, have_u, closing_factor,
            mark_tight, smooth, sep_allow, dq_half)
        if not keep:
            continue
        _write_row(k, pairs[q, 0], pairs[q, 1], tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2,
                   a_out, b_out, n_out, la_out, lb_out, gap_out, tight_out)
        k += 1
    return k


@njit(cache=True, inline="always")
def row_normal_speed(c, body, partner, normal, lever, partner_lever, u):
    """n_c · (u_A(p_A) − u_B(p_B)) (m/s) of row c with bodies A = body[c], B = partner[c] (−1: a static
    obstacle, zero velocity) and their levers, for twists u (S, 6)."""
    a = body[c]
    n = normal[c]
    r = lever[c]
    s = _twist_normal_speed(u, a, n[0], n[1], n[2], r[0], r[1], r[2])
    b = partner[c]
    if b >= 0:
        r = partner_lever[c]
        s -= _twist_normal_speed(u, b, n[0], n[1], n[2], r[0], r[1], r[2])
    return s


def _row_normal_velocity_impl(body, partner, normal, lever, partner_lever, u, out):
    """out[c] = :func:`row_normal_speed` of every row c (m/s). With u = (Δx, Δθ) per body it is the
    first-order change of the rows' gaps (m)."""
    for c in prange(body.shape[0]):
        out[c] = row_normal_speed(c, body, partner, normal, lever, partner_lever, u)


@njit(cache=True)
def touched_fibres(body, partner, fibre, n_fibres):
    """(n_fibres,) bool: the fibres with a body or partner (≥ 0) among the rows (fibre: (S,) fibre of every
    segment); one pass instead of NumPy's gathers and scatters over the millions of rows."""
    out = np.zeros(n_fibres, np.bool_)
    for c in range(body.shape[0]):
        out[fibre[body[c]]] = True
        b = partner[c]
        if b >= 0:
            out[fibre[b]] = True
    return out


row_normal_velocity, row_normal_velocity_parallel = serial_and_parallel(_row_normal_velocity_impl)


@njit(cache=True)
def _find_key(skey, k, lo, hi):
    """Index of k in the increasing skey[lo:hi] (its first occurrence), or −1."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if skey[mid] < k:
            lo = mid + 1
        else:
            hi = mid
    return lo if lo < skey.shape[0] and skey[lo] == k else -1


@njit(cache=True)
def joint_duplicate_contacts(pairs, params, half_length, radius, fibre, is_root, drop):
    """drop (P,) bool: True for the copies of a contact at a joint that
    :func:`headsim.solvers.chains._unique_joint_contacts` removes (its docstring has the rule): a pair whose
    closest point on one side lies within that segment's radius of its inner end (not a root) is dropped
    when the pair (previous segment of the same fibre, same partner) exists with its closest point within
    the radius of the previous segment's outer end. pairs (P, 2) int64 with a distinct a·S + b key per row
    (a < b, sorted by key: then no sort is made; otherwise the keys are sorted here); params (P, 2) the
    closest points' axis parameters in [0, 1]; lengths in m."""
    P = pairs.shape[0]
    S = half_length.shape[0]
    key = np.empty(P, np.int64)
    ordered = True
    for i in range(P):
        a = min(pairs[i, 0], pairs[i, 1])
        b = max(pairs[i, 0], pairs[i, 1])
        key[i] = a * S + b
        if i and key[i] <= key[i - 1]:
            ordered = False
    if ordered:
        order = np.arange(P)
        skey = key
    else:
        order = np.argsort(key, kind="mergesort")
        skey = key[order]
    # CSR of the sorted keys over their first segment (the lookups search one segment's partners only)
    start = np.zeros(S + 1, np.int64)
    for i in range(P):
        start[skey[i] // S + 1] += 1
    for z in range(S):
        start[z + 1] += start[z]
    for i in range(P):
        drop[i] = False
    for side in range(2):
        for i in range(P):
            own = pairs[i, side]
            other = pairs[i, 1 - side]
            if is_root[own] or not (params[i, side] * 2 * half_length[own] <= radius[own]):
                continue
            prev = own - 1
            if fibre[prev] != fibre[own]:
                continue
            lo = min(prev, other)
            q = _find_key(skey, lo * S + max(prev, other), start[lo], start[lo + 1])
            if q < 0:
                continue
            idx = order[q]
            ps = 0 if pairs[idx, 0] == prev else 1
            if (1.0 - params[idx, ps]) * 2 * half_length[prev] <= radius[prev]:
                drop[i] = True


def _warm_start_rows_impl(keys, primary, warm_keys, warm_lam, warm_fr, fraction, lam, fr):
    """Warm-start impulses per row (:meth:`headsim.solvers.chains.ChainSolver._warm_start_impulses`):
    lam (n,) = fraction × the previous step's normal impulse (N s) of the row's contact (same key) and
    fr (n, 2) likewise for the friction impulse, 0 for new contacts and non-primary rows. warm_keys
    increasing."""
    nw = warm_keys.shape[0]
    for i in prange(keys.shape[0]):
        lam[i] = 0.0
        fr[i, 0] = 0.0
        fr[i, 1] = 0.0
        if not primary[i]:
            continue
        j = _find_key(warm_keys, keys[i], 0, nw)
        if j >= 0:
            lam[i] = fraction * warm_lam[j]
            fr[i, 0] = fraction * warm_fr[j, 0]
            fr[i, 1] = fraction * warm_fr[j, 1]


def _kernel_row_inputs_impl(order, gaps, beta, dt, warm_lam, warm_fr, target, lam, fr):
    """Inputs of the coupled kernel in its row order ``order``: target[q] = −g/Δt for a gap g > 0 (a
    speculative contact) and −β g/(½Δt) for a penetration (m/s), and the starting impulses lam[q], fr[q]
    of row order[q] (warm_lam (n,) N s, warm_fr (n, 2); empty: zeros)."""
    warm = warm_lam.shape[0] > 0
    for q in prange(order.shape[0]):
        r = order[q]
        g = gaps[r]
        target[q] = -g / dt if g > 0 else -beta * g / (0.5 * dt)
        if warm:
            lam[q] = warm_lam[r]
            fr[q, 0] = warm_fr[r, 0]
            fr[q, 1] = warm_fr[r, 1]
        else:
            lam[q] = 0.0
            fr[q, 0] = 0.0
            fr[q, 1] = 0.0


def _scatter_kernel_impulses_impl(order, lam_k, fr_k, lam, fr):
    """lam (n,), fr (n, 2) in row order: 0, then the kernel's impulses lam_k, fr_k (order) at rows order
    (order: distinct rows, so the parallel version writes every row once)."""
    for i in prange(lam.shape[0]):
        lam[i] = 0.0
        fr[i, 0] = 0.0
        fr[i, 1] = 0.0
    for q in prange(order.shape[0]):
        r = order[q]
        lam[r] = lam_k[q]
        fr[r, 0] = fr_k[q, 0]
        fr[r, 1] = fr_k[q, 1]


def _end_velocity_gaps_impl(gaps, gaps0, body, radius, slop_fraction, out, out_pos):
    """The gaps of a last pass with ``end_velocity_positions`` (:meth:`headsim.solvers.chains.ChainSolver._pass_gaps`),
    m: out = min(g, ½ g⁰) for g⁰ > 0 else min(g, g⁰) (velocity solve; g the mid-step gap, g⁰ the gap at t_i),
    out_pos = g⁰ + slop where g⁰ < −slop, else max(out, 0) (push-out solve; slop = slop_fraction × the body's
    radius)."""
    for i in prange(gaps.shape[0]):
        g0 = gaps0[i]
        lim = 0.5 * g0 if g0 > 0 else g0
        g = min(gaps[i], lim)
        out[i] = g
        slop = slop_fraction * radius[body[i]]
        out_pos[i] = g0 + slop if g0 < -slop else max(g, 0.0)


# per-row passes: serial, and ``prange`` versions for the ≈ 2–7 M rows and candidates of the reference scene
warm_start_rows, warm_start_rows_parallel = serial_and_parallel(_warm_start_rows_impl)
kernel_row_inputs, kernel_row_inputs_parallel = serial_and_parallel(_kernel_row_inputs_impl)
scatter_kernel_impulses, scatter_kernel_impulses_parallel = serial_and_parallel(_scatter_kernel_impulses_impl)
end_velocity_gaps, end_velocity_gaps_parallel = serial_and_parallel(_end_velocity_gaps_impl)


def _gather_rows_impl(order, body, partner, normal, lever, partner_lever, ob, op, on, ol, opl):
    """ob[q] = body[order[q]] etc.: the geometry of the rows in the coupled kernel's order, the five arrays
    in one pass (NumPy's fancy indexing of the ≈ 2 M rows of the reference scene took 0.42 s per step for
    the five arrays, single-threaded)."""
    for q in prange(order.shape[0]):
        r = order[q]
        ob[q] = body[r]
        op[q] = partner[r]
        for z in range(3):
            on[q, z] = normal[r, z]
            ol[q, z] = lever[r, z]
            opl[q, z] = partner_lever[r, z]


gather_rows, gather_rows_parallel = serial_and_parallel(_gather_rows_impl)


# -- fused detection pass: sort + joint-duplicate filter + rows (ChainSolver._detect) ----------------------------

@njit(cache=True, inline="always")
def _find_partner(sp, start, lo, hi_id):
    """Position of pair (lo, hi_id) in the pairs sp (P, 2) sorted by (a, b), start the CSR over a; or −1."""
    i0 = start[lo]
    i1 = start[lo + 1]
    while i0 < i1:
        mid = (i0 + i1) >> 1
        if sp[mid, 1] < hi_id:
            i0 = mid + 1
        else:
            i1 = mid
    return i0 if i0 < start[lo + 1] and sp[i0, 1] == hi_id else -1


@njit(cache=True, inline="always")
def _joint_duplicate(q, start, pairs, params, half_length, radius, fibre, is_root):
    """The rule of :func:`joint_duplicate_contacts` for pair q of the pairs sorted by (a, b)."""
    for side in range(2):
        own = pairs[q, side]
        other = pairs[q, 1 - side]
        if is_root[own] or not (params[q, side] * 2 * half_length[own] <= radius[own]):
            continue
        prev = own - 1
        if fibre[prev] != fibre[own]:
            continue
        lo = min(prev, other)
        idx = _find_partner(pairs, start, lo, max(prev, other))
        if idx < 0:
            continue
        ps = 0 if pairs[idx, 0] == prev else 1
        if (1.0 - params[idx, ps]) * 2 * half_length[prev] <= radius[prev]:
            return True
    return False


@njit(cache=True, inline="always")
def _reserve_gap(a, b, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, dq0, half_gap):
    """G of a reserve pair (m; see :func:`_detect_rows_impl`): g, or with ``half_gap`` min(g, ½ g⁰) for g⁰ > 0,
    else g⁰, g⁰ = g − n·(dq0_a(p_a) − dq0_b(p_b))."""
    if not half_gap or dq0.shape[0] == 0:
        return gap
    g0 = gap - (_twist_normal_speed(dq0, a, n0, n1, n2, la0, la1, la2)
                - _twist_normal_speed(dq0, b, n0, n1, n2, lb0, lb1, lb2))
    if g0 > 0.0:
        return min(gap, 0.5 * g0)
    return g0


def _detect_rows_impl(pairs, params, x, d3, half, radius, fibre, is_root, speed, band_fraction, margin, dt, u,
                      closing_factor, mark_tight, smooth, sep_allow, dq_half, a_out, b_out, n_out, la_out, lb_out, gap_out,
                      tight_out, key_out, allow, dq0, half_gap, res_margin, warm_keys, sp, spar, tmp_p, tmp_r, res_idx, res_sigma,
                      res_count, old_speed):
    """Contact rows of unsorted closest-point pairs (pairs (P, 2) with pairs[:, 0] < pairs[:, 1] and distinct
    (a, b), params (P, 2)) in one fused pass, the same rows in the same order as
    ``sort_pairs`` → :func:`joint_duplicate_contacts` → :func:`fibre_pair_rows`: the pairs are ordered by
    (a, b) (a counting pass over a, then each a's partners by b: a stable sort, ≈ 120 per segment on the
    reference scene, up to ≈ 1,300), the
    joint copies dropped, and the rows of :func:`fibre_pair_rows` (plus key = a·S + b) written compactly
    to the outputs (length ≥ P). Returns the number of rows, or −1 when a pair has a ≥ b (nothing written:
    the caller takes the sorting path).

    sp (P, 2) int64, spar (P, 2): work arrays that receive the pairs and parameters in (a, b) order (tmp_p,
    tmp_r alike: the intermediate order by b). ``old_speed`` (S,) m/s (empty: off): pairs whose gap is within the
    band of those speeds (1e-12 m inside it) are dropped (a wider band's detection keeps only the pairs the
    narrower one did not find).
    Reserve (``ChainOptions.candidate_reserve``; ``allow`` (S,) m/s non-empty, and u given): a candidate
    (kept, not tight) with gap g > 0 whose key is not among ``warm_keys`` (increasing; the contacts that
    carried an impulse last step) and whose slack σ = vn + G/Δt (m/s; vn = n·(u_a − u_b) at the contact
    points, > 0 separating) exceeds allow_a + allow_b + res_margin, with G > 0, is not written as a row but kept
    in reserve. G = g, or with ``half_gap`` (``end_velocity_positions``) the smallest gap a pass gives the
    row at the detection's mid state: min(g, ½ g⁰) for g⁰ > 0, else g⁰, g⁰ = g − n·(dq0_a(p_a) − dq0_b(p_b)) its
    gap at t_i (dq0 (S, 6): the first half step's (Δx, Δθ)). Reserve: res_idx[j] its position in sp, res_sigma[j] = σ, res_count[0] their number. The coupled solve
    would promote such a pair only if its bodies' twists changed by more than the allowances (the bound of
    the kernel's screened candidate test); :meth:`headsim.solvers.chains.ChainSolver._reserve_violations`
    checks that after every solve."""
    P = pairs.shape[0]
    S = half.shape[0]
    have_u = u.shape[0] > 0
    bad = 0
    for q in prange(P):
        if pairs[q, 0] >= pairs[q, 1]:
            bad += 1
    if bad:
        return -1
    # the pairs ordered by (a, b) with two stable counting passes (by b, then by a; LSD radix sort), each
    # counted per chunk and scattered in parallel (chunk c writes behind the chunks before it, for every key):
    # 0.1 s on the reference scene's 4.8 M pairs against 0.3 s for a bucket pass by a and a sort of each
    # bucket; the (a, b) keys are distinct, so the order is the same
    # (hist per chunk row: chunk c's counts contiguous; 64 chunks for the large calls, fewer for the small ones,
    # whose cost was the (S, 64) histogram's 2.3 M entries: 28 ms for a widened band's 46 k pairs)
    n_chunks = min(64, max(1, P // 4096))
    step = (P + n_chunks - 1) // n_chunks
    hist = np.empty((n_chunks, S), np.int64)
    start = np.zeros(S + 1, np.int64)
    running = np.empty(S, np.int64)
    for rnd in range(2):
        col = 1 - rnd
        if rnd == 0:
            src_p, src_r, dst_p, dst_r = pairs, params, tmp_p, tmp_r
        else:
            src_p, src_r, dst_p, dst_r = tmp_p, tmp_r, sp, spar
        for c in prange(n_chunks):
            for z in range(S):
                hist[c, z] = 0
            for i in range(c * step, min(P, (c + 1) * step)):
                hist[c, src_p[i, col]] += 1
        for z in range(S):
            running[z] = 0
        for c in range(n_chunks):
            for z in range(S):
                running[z] += hist[c, z]
        pos = 0
        for z in range(S):
            start[z] = pos
            t = running[z]
            running[z] = pos
            pos += t
        start[S] = pos
        for c in range(n_chunks):  # chunk c of key z writes behind the chunks before it
            for z in range(S):
                t = hist[c, z]
                hist[c, z] = running[z]
                running[z] += t
        for c in prange(n_chunks):
            for i in range(c * step, min(P, (c + 1) * step)):
                k = src_p[i, col]
                q = hist[c, k]
                hist[c, k] = q + 1
                dst_p[q, 0] = src_p[i, 0]
                dst_p[q, 1] = src_p[i, 1]
                dst_r[q, 0] = src_r[i, 0]
                dst_r[q, 1] = src_r[i, 1]
    # keep flags per sorted position (0 dropped, 1 row, 2 reserve), counted per chunk; then the rows and the
    # reserve written at the chunks' offsets
    tiers = allow.shape[0] > 0 and have_u
    nw = warm_keys.shape[0]
    keep = np.empty(P, np.int8)
    counts = np.zeros(n_chunks + 1, np.int64)
    rcounts = np.zeros(n_chunks + 1, np.int64)
    for c in prange(n_chunks):
        k = 0
        kr = 0
        for i in range(c * step, min(P, (c + 1) * step)):
            flag = 0
            if not _joint_duplicate(i, start, sp, spar, half, radius, fibre, is_root):
                ok, tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, vn = _pair_geometry(
                    i, sp, spar, x, d3, half, radius, speed, band_fraction, margin, dt, u, have_u, closing_factor,
                    mark_tight, smooth, sep_allow, dq_half)
                if ok and old_speed.shape[0] > 0:
                    old_band = _pair_band(sp[i, 0], sp[i, 1], radius, old_speed, band_fraction, margin, dt)[1]
                    if gap < old_band - 1e-12:
                        ok = False
                if ok:
                    flag = 1
                    if tiers and not tight and gap > 0.0:
                        a = sp[i, 0]
                        b = sp[i, 1]
                        G = _reserve_gap(a, b, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, dq0, half_gap)
                        if (G > 0.0 and vn + G / dt > allow[a] + allow[b] + res_margin
                                and _find_key(warm_keys, a * S + b, 0, nw) < 0):
                            flag = 2
                            tmp_r[i, 0] = vn + G / dt  # σ (tmp_r is free after the ordering)
            keep[i] = flag
            if flag == 1:
                k += 1
            elif flag == 2:
                kr += 1
        counts[c + 1] = k
        rcounts[c + 1] = kr
    for c in range(n_chunks):
        counts[c + 1] += counts[c]
        rcounts[c + 1] += rcounts[c]
    for c in prange(n_chunks):
        k = counts[c]
        kr = rcounts[c]
        for i in range(c * step, min(P, (c + 1) * step)):
            if keep[i] == 0:
                continue
            if keep[i] == 2:
                res_idx[kr] = i
                res_sigma[kr] = tmp_r[i, 0]
                kr += 1
                continue
            _, tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, vn = _pair_geometry(
                i, sp, spar, x, d3, half, radius, speed, band_fraction, margin, dt, u, have_u, closing_factor,
                mark_tight, smooth, sep_allow, dq_half)
            a = sp[i, 0]
            b = sp[i, 1]
            _write_row(k, a, b, tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2,
                       a_out, b_out, n_out, la_out, lb_out, gap_out, tight_out)
            key_out[k] = a * S + b
            k += 1
    res_count[0] = rcounts[n_chunks]
    return counts[n_chunks]


detect_rows, detect_rows_parallel = serial_and_parallel(_detect_rows_impl)


def _reserve_suspects_impl(res_idx, res_sigma, sp, bound, margin, out):
    """out[j] = True where reserve pair j (position res_idx[j] in the sorted pairs sp, slack res_sigma[j] m/s;
    see :func:`_detect_rows_impl`) may be violated: σ_j ≤ bound_a + bound_b + margin, bound (S,) m/s each
    body's bound of its slack change (twist change and gap change, see
    :meth:`headsim.solvers.chains.ChainSolver._reserve_violations`)."""
    for j in prange(res_idx.shape[0]):
        i = res_idx[j]
        out[j] = res_sigma[j] <= bound[sp[i, 0]] + bound[sp[i, 1]] + margin


reserve_suspects, reserve_suspects_parallel = serial_and_parallel(_reserve_suspects_impl)


@njit(cache=True)
def reserve_rows(sel, sp, spar, x, d3, half, radius, speed, band_fraction, margin, dt, u, closing_factor, mark_tight,
                 smooth, sep_allow, dq_half, a_out, b_out, n_out, la_out, lb_out, gap_out, tight_out, key_out):
    """The rows of the pairs at positions sel of the sorted pairs sp, spar, written as :func:`_detect_rows_impl`
    writes its rows (same inputs: the same geometry), for reserve pairs that become candidates."""
    S = half.shape[0]
    have_u = u.shape[0] > 0
    for k in range(sel.shape[0]):
        i = sel[k]
        _, tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2, _ = _pair_geometry(
            i, sp, spar, x, d3, half, radius, speed, band_fraction, margin, dt, u, have_u, closing_factor,
            mark_tight, smooth, sep_allow, dq_half)
        _write_row(k, sp[i, 0], sp[i, 1], tight, gap, n0, n1, n2, la0, la1, la2, lb0, lb1, lb2,
                   a_out, b_out, n_out, la_out, lb_out, gap_out, tight_out)
        key_out[k] = sp[i, 0] * S + sp[i, 1]


@njit(cache=True, inline="always")
def _axes_closest(x, d3, half, a, b):
    """Parameters (s, t) ∈ [0, 1]² of the closest points of the axes of segments a and b (centres x, unit axes d3,
    half lengths half; Ericson's test, :func:`segment_segment_closest`)."""
    ha = half[a]
    hb = half[b]
    s, t, _ = segment_segment_closest(
        x[a, 0] - ha * d3[a, 0], x[a, 1] - ha * d3[a, 1], x[a, 2] - ha * d3[a, 2],
        x[a, 0] + ha * d3[a, 0], x[a, 1] + ha * d3[a, 1], x[a, 2] + ha * d3[a, 2],
        x[b, 0] - hb * d3[b, 0], x[b, 1] - hb * d3[b, 1], x[b, 2] - hb * d3[b, 2],
        x[b, 0] + hb * d3[b, 0], x[b, 1] + hb * d3[b, 1], x[b, 2] + hb * d3[b, 2])
    return s, t


def _end_state_pairs_impl(body, partner, x, d3, half, radius, n_out, la_out, lb_out, gap_out):
    """Fibre pairs (segments body[k], partner[k]) evaluated at a state x, d3 (post-stabilisation,
    :meth:`headsim.solvers.chains.ChainSolver._post_stabilise`): the closest points c_a, c_b of the two axes
    (Ericson's segment–segment test, :func:`headsim.collide._kernels_fibre_traverse.segment_segment_closest`), the
    normal n = (c_a − c_b)/‖c_a − c_b‖ (the axes' cross product where they touch, +y where they are also
    parallel, as :func:`fibre_pair_rows`), the gap ‖c_a − c_b‖ − r_a − r_b and the levers of the contact points
    c_a − r_a n − x_a, c_b + r_b n − x_b (m)."""
    for k in prange(body.shape[0]):
        a = body[k]
        b = partner[k]
        s, t = _axes_closest(x, d3, half, a, b)
        ta = (2.0 * s - 1.0) * half[a]
        tb = (2.0 * t - 1.0) * half[b]
        c0 = ta * d3[a, 0] - tb * d3[b, 0] + x[a, 0] - x[b, 0]
        c1 = ta * d3[a, 1] - tb * d3[b, 1] + x[a, 1] - x[b, 1]
        c2 = ta * d3[a, 2] - tb * d3[b, 2] + x[a, 2] - x[b, 2]
        dist = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        if dist > 1e-12:
            n0, n1, n2 = c0 / dist, c1 / dist, c2 / dist
        else:
            n0, n1, n2 = _touching_normal(d3, a, b)
        gap_out[k] = dist - radius[a] - radius[b]
        n_out[k, 0] = n0
        n_out[k, 1] = n1
        n_out[k, 2] = n2
        la_out[k, 0] = ta * d3[a, 0] - radius[a] * n0
        la_out[k, 1] = ta * d3[a, 1] - radius[a] * n1
        la_out[k, 2] = ta * d3[a, 2] - radius[a] * n2
        lb_out[k, 0] = tb * d3[b, 0] + radius[b] * n0
        lb_out[k, 1] = tb * d3[b, 1] + radius[b] * n1
        lb_out[k, 2] = tb * d3[b, 2] + radius[b] * n2


end_state_pairs, end_state_pairs_parallel = serial_and_parallel(_end_state_pairs_impl)


def _crossing_sides_impl(body, partner, x, d3, half, end_fraction, min_sin, cn_out, side_out):
    """The crossing side of fibre pairs (segments body[k], partner[k]) at a state x, d3 (``ChainOptions.
    restore_crossings``): cn_out[k] = e_a × e_b / ‖e_a × e_b‖ and side_out[k] = sign((e_a × e_b)·(c_a − c_b)) for the
    closest axis points c_a, c_b (Ericson's test, as :func:`_end_state_pairs_impl`); side 0 where a closest point is
    within ``end_fraction`` of its segment's length from an end or the axes cross at sin ≤ ``min_sin``."""
    for k in prange(body.shape[0]):
        a = body[k]
        b = partner[k]
        s, t = _axes_closest(x, d3, half, a, b)
        c0, c1, c2, sn = _axes_cross(d3, a, b)
        side_out[k] = 0.0
        if sn > min_sin:
            cn_out[k, 0] = c0 / sn
            cn_out[k, 1] = c1 / sn
            cn_out[k, 2] = c2 / sn
        else:
            cn_out[k, 0] = 0.0
            cn_out[k, 1] = 0.0
            cn_out[k, 2] = 0.0
            continue
        if s <= end_fraction or s >= 1.0 - end_fraction or t <= end_fraction or t >= 1.0 - end_fraction:
            continue
        ta = (2.0 * s - 1.0) * half[a]
        tb = (2.0 * t - 1.0) * half[b]
        dot = 0.0
        for i in range(3):
            dot += (ta * d3[a, i] - tb * d3[b, i] + x[a, i] - x[b, i]) * cn_out[k, i]
        side_out[k] = 1.0 if dot > 0.0 else -1.0 if dot < 0.0 else 0.0


crossing_sides, crossing_sides_parallel = serial_and_parallel(_crossing_sides_impl)


@njit(cache=True)
def joint_neighbour_pairs(body, partner, normal, lever, partner_lever, d3, half, radius, fibre, near, out_a, out_b):
    """Pairs next to fibre rows across a joint (``ChainOptions.restore_crossings``; ChainSolver._neighbour_crossings):
    for row k (segments a = body[k], b = partner[k]; unit normal, levers from the centres to the contact points, m)
    its closest axis points' parameters τ_a = (lever + r_a n)·e_a / h_a and τ_b = (partner lever − r_b n)·e_b / h_b
    in [−1, 1]; where |τ_a| ≥ ``near`` and the segment a' = a ± 1 across that end is of a's fibre, the pair (a', b),
    likewise (a, b'), and (a', b') where both exist. Pairs of one segment with itself or its joint neighbour are left
    out. Writes (min, max) segment pairs to out_a, out_b (3 × rows long) and returns their number (duplicates kept)."""
    S = half.shape[0]
    m = 0
    for k in range(body.shape[0]):
        a = body[k]
        b = partner[k]
        ta = 0.0
        tb = 0.0
        for i in range(3):
            ta += (lever[k, i] + radius[a] * normal[k, i]) * d3[a, i]
            tb += (partner_lever[k, i] - radius[b] * normal[k, i]) * d3[b, i]
        ta /= half[a]
        tb /= half[b]
        a1 = -1
        b1 = -1
        if abs(ta) >= near:
            c = a + 1 if ta >= 0.0 else a - 1
            if 0 <= c < S and fibre[c] == fibre[a]:
                a1 = c
        if abs(tb) >= near:
            c = b + 1 if tb >= 0.0 else b - 1
            if 0 <= c < S and fibre[c] == fibre[b]:
                b1 = c
        for p, q in ((a1, b), (a, b1), (a1, b1)):
            if p < 0 or q < 0:
                continue
            lo = min(p, q)
            hi = max(p, q)
            if fibre[lo] == fibre[hi] and hi - lo <= 1:
                continue
            out_a[m] = lo
            out_b[m] = hi
            m += 1
    return m
