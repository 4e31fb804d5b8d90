"""Numba kernels of the Marschner far-field and near-field hair scattering functions.

Sobottka (2008) §6.3–6.4 (digest §5.2–5.3), which restates Marschner et al. (2003) with corrected
attenuation A(p,h) (6.7–6.8) and absorption T(p,h) (6.9). All angles in radians.

Packed parameter vector ``prm`` (float64, see :data:`N_PRM`; built by ``MarschnerParams.packed``):
    0 eta, 1–3 alpha_R/TT/TRT, 4–6 beta_R/TT/TRT, 7–9 sigma_a RGB (per fibre radius),
    10 eccentricity a, 11 glint width w_c, 12 dh_max (caustic clamp D_max = dh_max / w_c),
    13 near-field azimuthal width, 14 caustic flag (1: clamp + energy-preserving glint).
``gtab`` (NT, NC, 4) float64: tabulated TRT caustic energy and azimuth (:func:`glint_table`).
``ztab`` (3, NZ) float64: normalisation Z_p(θ_i) of the longitudinal lobes on a uniform θ_i grid over
[−π/2, π/2] (all ones for Marschner's plain Gaussians).

Frame: θ is the inclination from the fibre's normal plane (positive toward the tip, d₃), φ the azimuth.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

N_PRM = 15
_PI = math.pi
_TWO_PI = 2.0 * math.pi


@njit(cache=True)
def bravais(eta, theta):
    """Bravais indices (n', n'') for inclination θ: n' = √(n²−sin²θ)/cos θ, n'' = n² cos θ/√(n²−sin²θ)."""
    s = math.sin(theta)
    c = max(math.cos(theta), 1e-9)
    root = math.sqrt(eta * eta - s * s)
    return root / c, eta * eta * c / root


@njit(cache=True)
def fresnel(n1, n2, gamma):
    """Generalised Fresnel reflectance F(n', n'', γ) (Marschner 2003 App. B): s-polarisation with n',
    p-polarisation with n''; the refracted angle follows Snell in the normal plane with n'. γ in [0, π/2]."""
    ci = math.cos(gamma)
    st = math.sin(gamma) / n1
    ct = math.sqrt(max(0.0, 1.0 - st * st))
    rs = (ci - n1 * ct) / (ci + n1 * ct)
    rp = (n2 * ci - ct) / (n2 * ci + ct)
    return 0.5 * (rs * rs + rp * rp)


@njit(cache=True)
def gauss(sigma, x):
    """Unit-integral Gaussian g(σ; x)."""
    return math.exp(-0.5 * (x / sigma) ** 2) / (sigma * math.sqrt(_TWO_PI))


@njit(cache=True)
def gauss_wrapped(sigma, x):
    """Gaussian wrapped onto the circle (unit integral over one period)."""
    x = x - _TWO_PI * math.floor(x / _TWO_PI + 0.5)
    return gauss(sigma, x) + gauss(sigma, x - _TWO_PI) + gauss(sigma, x + _TWO_PI)


@njit(cache=True)
def wrap_pi(x):
    """Angle wrapped to [−π, π)."""
    return x - _TWO_PI * math.floor((x + _PI) / _TWO_PI)


@njit(cache=True)
def cubic_coefficients(p, n1):
    """Marschner's cubic Δφ(p, γ_i) ≈ a3 γ³ + a1 γ + a0 (fit of (6.4) with c = asin(1/n'))."""
    c = math.asin(1.0 / n1)
    return -8.0 * p * c / _PI ** 3, 6.0 * p * c / _PI - 2.0, p * _PI


@njit(cache=True)
def _cubic_roots(a3, a1, a0):
    """Real roots of a3 x³ + a1 x + a0 = 0 (a3 ≠ 0): (count, r0, r1, r2)."""
    P = a1 / a3
    Q = a0 / a3
    disc = 0.25 * Q * Q + P * P * P / 27.0
    if disc > 0.0:
        s = math.sqrt(disc)
        u = -0.5 * Q + s
        v = -0.5 * Q - s
        r = math.copysign(abs(u) ** (1.0 / 3.0), u) + math.copysign(abs(v) ** (1.0 / 3.0), v)
        return 1, r, 0.0, 0.0
    if P == 0.0:
        return 1, 0.0, 0.0, 0.0
    m = 2.0 * math.sqrt(-P / 3.0)
    arg = 3.0 * Q / (P * m)
    arg = min(1.0, max(-1.0, arg))
    t = math.acos(arg) / 3.0
    return 3, m * math.cos(t), m * math.cos(t - 2.0 * _PI / 3.0), m * math.cos(t - 4.0 * _PI / 3.0)


@njit(cache=True)
def delta_phi_exact(p, h, n1):
    """(6.4) Δφ(p,h) = 2pγ_t − 2γ_i + pπ with sin γ_i = h, n' sin γ_t = h."""
    return 2.0 * p * math.asin(h / n1) - 2.0 * math.asin(h) + p * _PI


@njit(cache=True, inline="always")
def _root_term(p, g, a3, a1, n1, n2, sig, cos_tt, out):
    """Add ½ A T D of the path with γ_i = g to ``out`` (RGB); return its ray density D (0 if |g| > π/2)."""
    if g < -0.5 * _PI or g > 0.5 * _PI:
        return 0.0
    h = math.sin(g)
    cg = math.cos(g)
    deriv = abs(a1 + 3.0 * a3 * g * g) / max(cg, 1e-12)
    d = 1.0 / max(deriv, 1e-12)
    f = fresnel(n1, n2, abs(g))
    a = (1.0 - f) * (1.0 - f) * f ** (p - 1)
    st = h / n1
    ct = math.sqrt(max(0.0, 1.0 - st * st))
    for ch in range(3):
        out[ch] += 0.5 * a * math.exp(-p * sig[ch] * 2.0 * ct / cos_tt) * d
    return d


@njit(cache=True)
def _lobe_roots_sum(p, dphi, n1, n2, sig, cos_tt, dmax, out):
    """Far-field azimuthal lobe N_p(Δφ) for p ∈ {1, 2} (6.11), RGB into ``out`` (added; ``out`` must
    hold only this lobe). Returns the total ray density ΣD over the roots.

    Roots of the cubic Δφ(p,γ) = Δφ + 2πk; D = |dΔφ/dh|⁻¹; A = (1−F)² F^{p−1} (6.8, F at entry = F at the
    internal interfaces by Fresnel symmetry); T = exp(−σ_a 2 cos γ_t / cos θ_t)^p (6.9 with s_M = 2R cos γ_t,
    σ_a per radius). Caustic clamp (dmax > 0): the lobe is scaled by min(1, D_max/ΣD), a clamp of the
    *total* density, which stays continuous where the two TRT caustics merge (n' → 2)."""
    a3, a1, a0 = cubic_coefficients(p, n1)
    base = dphi - _TWO_PI * math.floor(dphi / _TWO_PI)
    # the cubic's range: TT [2c, 2π − 2c]; TRT endpoints π + 4c (γ = π/2), 3π − 4c (γ = −π/2) and the
    # local extrema 2π ∓ φ_c' at ∓γ_c
    c = math.asin(1.0 / n1)
    if p == 1:
        lo = 2.0 * c
        hi = _TWO_PI - 2.0 * c
    else:
        ext = 0.0
        if a1 > 0.0:
            gc = math.sqrt(a1 / (-3.0 * a3))
            ext = abs(a3 * gc ** 3 + a1 * gc)
        lo = min(_PI + 4.0 * c, _TWO_PI - ext, 3.0 * _PI - 4.0 * c)
        hi = max(_PI + 4.0 * c, _TWO_PI + ext, 3.0 * _PI - 4.0 * c)
    k_lo = int(math.ceil((lo - base) / _TWO_PI - 1e-9))
    k_hi = int(math.floor((hi - base) / _TWO_PI + 1e-9))
    dsum = 0.0
    for k in range(k_lo, k_hi + 1):
        nr, r0, r1, r2 = _cubic_roots(a3, a1, a0 - (base + _TWO_PI * k))
        dsum += _root_term(p, r0, a3, a1, n1, n2, sig, cos_tt, out)
        if nr == 3:
            dsum += _root_term(p, r1, a3, a1, n1, n2, sig, cos_tt, out)
            dsum += _root_term(p, r2, a3, a1, n1, n2, sig, cos_tt, out)
    if dmax > 0.0 and dsum > dmax:
        f = dmax / dsum
        for ch in range(3):
            out[ch] *= f
    return dsum


@njit(cache=True)
def caustic_energy(n1, n2, sig, cos_tt, dmax, nq, out):
    """Energy the TRT density clamp removes, ½∫ A T (1 − min(1, D_max/ΣD(Δφ(h)))) dh over h ∈ (−1, 1)
    (midpoint rule with ``nq`` nodes, RGB into ``out``), and the caustic azimuth φ_c (returned; 0 ≡ 2π
    when n' ≥ 2). Digest §5.2 ("remove the caustic, replace by an energy-preserving function")."""
    p = 2
    a3, a1, a0 = cubic_coefficients(p, n1)
    gc = math.sqrt(a1 / (-3.0 * a3)) if a1 > 0.0 else 0.0
    phic = a3 * gc ** 3 + a1 * gc + a0
    for ch in range(3):
        out[ch] = 0.0
    scratch = np.zeros(3)
    for q in range(nq):
        h = -1.0 + (q + 0.5) * 2.0 / nq
        g = math.asin(h)
        dphi = a3 * g ** 3 + a1 * g + a0
        for ch in range(3):
            scratch[ch] = 0.0
        dsum = _lobe_roots_sum(p, dphi, n1, n2, sig, cos_tt, 0.0, scratch)
        if dsum <= dmax:
            continue
        f = fresnel(n1, n2, abs(g))
        a = (1.0 - f) * (1.0 - f) * f
        st = h / n1
        ct = math.sqrt(max(0.0, 1.0 - st * st))
        w = 0.5 * a * (1.0 - dmax / dsum) * (2.0 / nq)
        for ch in range(3):
            out[ch] += w * math.exp(-p * sig[ch] * 2.0 * ct / cos_tt)
    return phic


@njit(cache=True)
def _eta_star(eta, a, cos2phih):
    n1s = 2.0 * (eta - 1.0) * a * a - eta + 2.0
    n2s = 2.0 * (eta - 1.0) / (a * a) - eta + 2.0
    return 0.5 * ((n1s + n2s) + cos2phih * (n1s - n2s))


@njit(cache=True)
def glint_table(prm, nt, nc, nq, gtab):
    """Tabulate the caustic energy (both caustics together) and φ_c over |θ_d| ∈ [0, π/2] (nt) ×
    cos(φ_i + φ_r) ∈ [−1, 1] (nc;
    nc = 1 for circular fibres): ``gtab`` (nt, nc, 4) = (E_R, E_G, E_B, φ_c)."""
    e = np.zeros(3)
    dmax = prm[12] / prm[11]
    for i in range(nt):
        td = min(0.5 * _PI * i / (nt - 1), 0.5 * _PI - 1e-6)
        for j in range(nc):
            c2 = -1.0 + 2.0 * j / (nc - 1) if nc > 1 else 1.0
            es = _eta_star(prm[0], prm[10], c2)
            n1, n2 = bravais(es, td)
            st = math.sin(td) / es
            ctt = math.sqrt(max(1e-12, 1.0 - st * st))
            phic = caustic_energy(n1, n2, prm[7:10], ctt, dmax, nq, e)
            for ch in range(3):
                gtab[i, j, ch] = e[ch]
            gtab[i, j, 3] = phic


@njit(cache=True)
def _glint_from_table(gtab, td, cos2phih, dphi, wc, out):
    nt = gtab.shape[0]
    nc = gtab.shape[1]
    x = min(abs(td) / (0.5 * _PI), 1.0) * (nt - 1)
    i = min(int(x), nt - 2)
    tx = x - i
    if nc > 1:
        y = (min(1.0, max(-1.0, cos2phih)) + 1.0) * 0.5 * (nc - 1)
        j = min(int(y), nc - 2)
        ty = y - j
    else:
        j = 0
        ty = 0.0
    j1 = min(j + 1, nc - 1)
    w00 = (1 - tx) * (1 - ty)
    w10 = tx * (1 - ty)
    w01 = (1 - tx) * ty
    w11 = tx * ty
    phic = w00 * gtab[i, j, 3] + w10 * gtab[i + 1, j, 3] + w01 * gtab[i, j1, 3] + w11 * gtab[i + 1, j1, 3]
    shape = 0.5 * (gauss_wrapped(wc, dphi - phic) + gauss_wrapped(wc, dphi + phic))
    for ch in range(3):
        e = w00 * gtab[i, j, ch] + w10 * gtab[i + 1, j, ch] + w01 * gtab[i, j1, ch] + w11 * gtab[i + 1, j1, ch]
        out[ch] += e * shape


@njit(cache=True)
def z_lookup(ztab, p, theta_i):
    """Linear interpolation of the lobe normalisation Z_p(θ_i) on its uniform grid over [−π/2, π/2]."""
    nz = ztab.shape[1]
    x = (theta_i + 0.5 * _PI) / _PI * (nz - 1)
    if x <= 0.0:
        return ztab[p, 0]
    if x >= nz - 1:
        return ztab[p, nz - 1]
    i = int(x)
    t = x - i
    return (1.0 - t) * ztab[p, i] + t * ztab[p, i + 1]


@njit(cache=True)
def longitudinal(prm, ztab, p, theta_i, theta_r):
    """(6.13) M_p = ½ g(β_p; θ_h − α_p) / Z_p(θ_i).

    The ½ makes the ideal limit β → 0 equal to (6.3)'s δ(θ_r + θ_i) = ½δ(θ_h); Z_p (all ones unless the
    energy normalisation is on) makes ∫ M_p cos²θ_r/cos²θ_d dθ_r = 1 for every θ_i."""
    th = 0.5 * (theta_i + theta_r)
    return 0.5 * gauss(prm[4 + p], th - prm[1 + p]) / z_lookup(ztab, p, theta_i)


@njit(cache=True)
def _angles_common(prm, theta_i, phi_i, theta_r, phi_r):
    td = 0.5 * (theta_r - theta_i)
    eta = prm[0]
    sin_tt = math.sin(td) / eta
    cos_tt = math.sqrt(max(1e-12, 1.0 - sin_tt * sin_tt))
    cd2 = max(math.cos(td) ** 2, 1e-12)
    dphi = phi_r - phi_i
    # elliptic cross-section, TRT only (6.12): cos 2φ_h = cos(φ_i + φ_r)
    eta_star = _eta_star(eta, prm[10], math.cos(phi_i + phi_r))
    return td, cos_tt, cd2, dphi, eta_star


@njit(cache=True)
def far_field(prm, ztab, gtab, theta_i, phi_i, theta_r, phi_r, out):
    """Far-field S_p = M_p N_p / cos²θ_d (6.14) per lobe, ``out`` (3 lobes R/TT/TRT, 3 RGB), overwritten.

    ``gtab``: caustic table of :func:`glint_table` (used when prm[14] > 0)."""
    td, cos_tt, cd2, dphi, eta_star = _angles_common(prm, theta_i, phi_i, theta_r, phi_r)
    sig = prm[7:10]
    for i in range(3):
        for ch in range(3):
            out[i, ch] = 0.0
    n1, n2 = bravais(prm[0], td)
    # R: Δφ = −2γ_i exactly, one root
    g = -0.5 * wrap_pi(dphi)
    nr = 0.5 * fresnel(n1, n2, abs(g)) * 0.5 * math.cos(g)
    m = longitudinal(prm, ztab, 0, theta_i, theta_r) / cd2
    for ch in range(3):
        out[0, ch] = m * nr
    # TT
    _lobe_roots_sum(1, dphi, n1, n2, sig, cos_tt, 0.0, out[1])
    m = longitudinal(prm, ztab, 1, theta_i, theta_r) / cd2
    for ch in range(3):
        out[1, ch] *= m
    # TRT with n* and the caustic treatment
    s1, s2 = bravais(eta_star, td)
    sin_tt2 = math.sin(td) / eta_star
    cos_tt2 = math.sqrt(max(1e-12, 1.0 - sin_tt2 * sin_tt2))
    if prm[14] > 0.0:
        dmax = prm[12] / prm[11]
        _lobe_roots_sum(2, dphi, s1, s2, sig, cos_tt2, dmax, out[2])
        _glint_from_table(gtab, td, math.cos(phi_i + phi_r), dphi, prm[11], out[2])
    else:
        _lobe_roots_sum(2, dphi, s1, s2, sig, cos_tt2, 0.0, out[2])
    m = longitudinal(prm, ztab, 2, theta_i, theta_r) / cd2
    for ch in range(3):
        out[2, ch] *= m


@njit(cache=True)
def near_field(prm, ztab, h_r, theta_i, phi_i, theta_r, phi_r, out):
    """Near-field S_p at exit offset h_r ∈ (−1, 1) (6.20), lobes × RGB into ``out`` (overwritten).

    The entry offset is h_i = −h_r (δ(h_i + h_r)); δ(φ_r − φ_i − Δφ(p,h_i)) becomes a wrapped Gaussian of
    width prm[13]; the exact (6.4) Δφ is used. Averaging over h_r (½∫dh_r) gives the far-field lobe."""
    td, cos_tt, cd2, dphi, eta_star = _angles_common(prm, theta_i, phi_i, theta_r, phi_r)
    sig = prm[7:10]
    w = prm[13]
    h = -h_r
    g = math.asin(max(-1.0, min(1.0, h)))
    for p in range(3):
        eta_p = eta_star if p == 2 else prm[0]
        n1, n2 = bravais(eta_p, td)
        sin_t = math.sin(td) / eta_p
        ctt = math.sqrt(max(1e-12, 1.0 - sin_t * sin_t))
        f = fresnel(n1, n2, abs(g))
        if p == 0:
            a = f
        else:
            a = (1.0 - f) * (1.0 - f) * f ** (p - 1)
        st = h / n1
        ct = math.sqrt(max(0.0, 1.0 - st * st))
        shape = gauss_wrapped(w, dphi - delta_phi_exact(p, h, n1))
        m = longitudinal(prm, ztab, p, theta_i, theta_r) / cd2
        for ch in range(3):
            t = math.exp(-p * sig[ch] * 2.0 * ct / ctt) if p > 0 else 1.0
            out[p, ch] = m * a * t * shape


@njit(cache=True, parallel=True)
def far_field_batch(prm, ztab, gtab, theta_i, phi_i, theta_r, phi_r, out):
    """Vectorised :func:`far_field`; angle arrays (n,), ``out`` (n, 3, 3)."""
    for k in prange(theta_i.shape[0]):
        far_field(prm, ztab, gtab, theta_i[k], phi_i[k], theta_r[k], phi_r[k], out[k])


@njit(cache=True, parallel=True)
def near_field_batch(prm, ztab, h_r, theta_i, phi_i, theta_r, phi_r, out):
    """Vectorised :func:`near_field`; arrays (n,), ``out`` (n, 3, 3)."""
    for k in prange(theta_i.shape[0]):
        near_field(prm, ztab, h_r[k], theta_i[k], phi_i[k], theta_r[k], phi_r[k], out[k])
