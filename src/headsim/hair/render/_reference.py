"""Slow, plain-Python reference of the Marschner far field (Sobottka eq. 6.4–6.14) for the tests.

Independent of the kernels where it matters: cubic roots by ``numpy.roots``, the caustic energy by
adaptive ``scipy.integrate.quad_vec`` (the kernels tabulate it with a midpoint rule), the lobe
normalisation Z_p by ``quad`` (the kernels tabulate it on a θ_i grid).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import quad, quad_vec


def _bravais(eta, theta):
    s, c = math.sin(theta), math.cos(theta)
    root = math.sqrt(eta * eta - s * s)
    return root / c, eta * eta * c / root


def _fresnel(n1, n2, g):
    ci = math.cos(g)
    ct = math.sqrt(1 - (math.sin(g) / n1) ** 2)
    rs = (ci - n1 * ct) / (ci + n1 * ct)
    rp = (n2 * ci - ct) / (n2 * ci + ct)
    return 0.5 * (rs * rs + rp * rp)


def _g(s, x):
    return math.exp(-0.5 * (x / s) ** 2) / (s * math.sqrt(2 * math.pi))


def _gw(s, x):
    x = (x + math.pi) % (2 * math.pi) - math.pi
    return sum(_g(s, x + 2 * math.pi * k) for k in (-1, 0, 1))


def _coef(p, n1):
    c = math.asin(1 / n1)
    return -8 * p * c / math.pi**3, 6 * p * c / math.pi - 2, p * math.pi


def _density(p, n1, g):
    a3, a1, _ = _coef(p, n1)
    return math.cos(g) / abs(a1 + 3 * a3 * g * g)


def _at(p, n1, n2, sig, g, cos_tt):
    f = _fresnel(n1, n2, abs(g))
    a = f if p == 0 else (1 - f) ** 2 * f ** (p - 1)
    ct = math.sqrt(1 - (math.sin(g) / n1) ** 2)
    return np.array([a * math.exp(-p * s * 2 * ct / cos_tt) for s in sig])


def _roots_terms(p, dphi, n1, n2, sig, cos_tt):
    """[(½ A T (RGB), D)] over the real cubic roots γ ∈ [−π/2, π/2] of Δφ(p,γ) ≡ Δφ (mod 2π)."""
    a3, a1, a0 = _coef(p, n1)
    base = dphi % (2 * math.pi)
    terms = []
    for k in range(-1, 3):
        for r in np.roots([a3, 0.0, a1, a0 - base - 2 * math.pi * k]):
            if abs(r.imag) > 1e-9 or abs(r.real) > math.pi / 2:
                continue
            g = r.real
            terms.append((0.5 * _at(p, n1, n2, sig, g, cos_tt), _density(p, n1, g)))
    return terms


def lobe_n(p, dphi, n1, n2, sig, cos_tt, dmax=None, wc=None):
    """N_p(Δφ) RGB (6.11) by ``numpy.roots``; for TRT with ``dmax`` the total density is clamped at
    D_max and the removed energy (adaptive ``quad_vec`` over h) is put back as glints at ±φ_c."""
    if p == 0:
        g = -0.5 * ((dphi + math.pi) % (2 * math.pi) - math.pi)
        return 0.5 * _at(0, n1, n2, sig, g, cos_tt) * 0.5 * math.cos(g)
    terms = _roots_terms(p, dphi, n1, n2, sig, cos_tt)
    out = sum((t * d for t, d in terms), np.zeros(3))
    if dmax is not None and p == 2:
        dsum = sum(d for _, d in terms)
        if dsum > dmax:
            out = out * dmax / dsum
        a3, a1, a0 = _coef(p, n1)
        gc = math.sqrt(a1 / (-3 * a3)) if a1 > 0 else 0.0
        phic = a3 * gc**3 + a1 * gc + a0

        def removed(h):
            g = math.asin(h)
            ds = sum(d for _, d in _roots_terms(p, a3 * g**3 + a1 * g + a0, n1, n2, sig, cos_tt))
            if ds <= dmax:
                return np.zeros(3)
            return 0.5 * _at(p, n1, n2, sig, g, cos_tt) * (1 - dmax / ds)

        e = quad_vec(removed, -1.0, 1.0, epsrel=1e-5, limit=200)[0]
        out = out + e * 0.5 * (_gw(wc, dphi - phic) + _gw(wc, dphi + phic))
    return out


def z_norm(beta, alpha, theta_i):
    """Z_p(θ_i) = ∫ ½ g(β; θ_h − α) cos²θ_r / cos²θ_d dθ_r by adaptive quadrature."""
    def f(tr):
        th, td = 0.5 * (theta_i + tr), 0.5 * (tr - theta_i)
        return 0.5 * _g(beta, th - alpha) * math.cos(tr) ** 2 / max(math.cos(td) ** 2, 1e-12)
    c = 2 * alpha - theta_i
    pts = [x for x in (c,) if -math.pi / 2 < x < math.pi / 2]
    return quad(f, -math.pi / 2, math.pi / 2, points=pts, limit=200)[0]


def far_field_reference(params, theta_i, phi_i, theta_r, phi_r) -> np.ndarray:
    """(3, 3) lobes × RGB at one direction pair (same definitions as ``far_field``)."""
    p = params.packed
    eta = p[0]
    td = 0.5 * (theta_r - theta_i)
    th = 0.5 * (theta_i + theta_r)
    dphi = phi_r - phi_i
    a = p[10]
    n1s = 2 * (eta - 1) * a * a - eta + 2
    n2s = 2 * (eta - 1) / (a * a) - eta + 2
    eta_star = 0.5 * ((n1s + n2s) + math.cos(phi_i + phi_r) * (n1s - n2s))
    sig = p[7:10]
    out = np.zeros((3, 3))
    for lobe in range(3):
        e = eta_star if lobe == 2 else eta
        n1, n2 = _bravais(e, td)
        cos_tt = math.sqrt(1 - (math.sin(td) / e) ** 2)
        if lobe == 2 and p[14] > 0:
            n = lobe_n(2, dphi, n1, n2, sig, cos_tt, dmax=p[12] / p[11], wc=p[11])
        else:
            n = lobe_n(lobe, dphi, n1, n2, sig, cos_tt)
        z = z_norm(p[4 + lobe], p[1 + lobe], theta_i) if params.normalise_longitudinal else 1.0
        m = 0.5 * _g(p[4 + lobe], th - p[1 + lobe]) / z
        out[lobe] = m * n / math.cos(td) ** 2
    return out
