"""Analytical reference solutions for rod validation (planar elastica, beam theory, helical springs).

All SI. These are the oracles of the rod tests and benchmark; they do not use the rod solver.
"""

from __future__ import annotations

import numpy as np
from dataclasses import dataclass

from scipy import integrate, optimize, special

from headsim.errors import ParameterError

__all__ = [
    "cantilever_tip_load_elastica",
    "cantilever_self_weight_elastica",
    "euler_bernoulli_cantilever_frequencies",
    "helical_spring_axial_stiffness",
    "helical_spring_fundamental_frequency",
    "cantilever_tip_load_linear",
    "cantilever_self_weight_linear",
    "LagrangeTop",
    "lagrange_top",
]


def cantilever_tip_load_linear(P: float, L: float, EI: float) -> float:
    """Euler-Bernoulli tip deflection P L^3 / (3 EI), m."""
    return P * L**3 / (3 * EI)


def cantilever_self_weight_linear(q: float, L: float, EI: float) -> float:
    """Euler-Bernoulli tip deflection q L^4 / (8 EI) under a uniform load q (N/m), m."""
    return q * L**4 / (8 * EI)


def cantilever_tip_load_elastica(P: float, L: float, EI: float) -> tuple[float, float, float]:
    """Large-deflection cantilever (horizontal clamp) under a vertical dead tip load P (N).

    First integral of EI phi'' = -P cos(phi): EI phi'^2 / 2 = P (sin phi_L - sin phi), with
    phi the tangent angle below the horizontal. With sin phi = sin phi_L - u^2 the integrals are
    regular:  L = int_0^a 2 du / (c cos phi(u)),  x = int 2 du / c,  y = int 2 (sin phi_L - u^2) du / (c cos phi),
    c = sqrt(2 P / EI), a = sqrt(sin phi_L). Returns (tip x, tip deflection y, tip angle phi_L).
    """
    if P <= 0 or L <= 0 or EI <= 0:
        raise ParameterError("P, L and EI must be positive")
    c = np.sqrt(2 * P / EI)

    def integrals(phiL):
        sL = np.sin(phiL)
        a = np.sqrt(sL)

        def cosphi(u):
            return np.sqrt(np.maximum(1.0 - (sL - u * u) ** 2, 1e-300))

        length = integrate.quad(lambda u: 2.0 / (c * cosphi(u)), 0.0, a, epsabs=1e-14, epsrel=1e-13)[0]
        x = 2.0 * a / c
        y = integrate.quad(lambda u: 2.0 * (sL - u * u) / (c * cosphi(u)), 0.0, a, epsabs=1e-14, epsrel=1e-13)[0]
        return length, x, y

    phiL = optimize.brentq(lambda p: integrals(p)[0] - L, 1e-12, np.pi / 2 - 1e-9, xtol=1e-15, rtol=1e-15)
    _, x, y = integrals(phiL)
    return x, y, phiL


def cantilever_self_weight_elastica(q: float, L: float, EI: float, n_mesh: int = 2001):
    """Large-deflection cantilever under its own weight q (N/m), horizontal clamp.

    EI phi'' = -q (L - s) cos(phi), phi(0) = 0, phi'(L) = 0, solved with scipy.integrate.solve_bvp
    to tolerance 1e-10. Returns (tip x, tip deflection y, tip angle), m, m, rad.
    """
    if q <= 0 or L <= 0 or EI <= 0:
        raise ParameterError("q, L and EI must be positive")
    s = np.linspace(0.0, L, n_mesh)

    def f(s, y):  # y = (phi, phi', x, z)
        return np.vstack([y[1], -q * (L - s) * np.cos(y[0]) / EI, np.cos(y[0]), np.sin(y[0])])

    def bc(ya, yb):
        return np.array([ya[0], yb[1], ya[2], ya[3]])

    y0 = np.zeros((4, s.size))
    y0[2] = s
    sol = integrate.solve_bvp(f, bc, s, y0, tol=1e-10, max_nodes=200000)
    if not sol.success:
        raise RuntimeError(f"elastica BVP failed: {sol.message}")
    end = sol.sol(L)
    return end[2], end[3], end[0]


def euler_bernoulli_cantilever_frequencies(L: float, EI: float, rho_area: float, n_modes: int = 3) -> np.ndarray:
    """Natural frequencies (Hz) of a clamped-free Euler-Bernoulli beam: cos(bL) cosh(bL) = -1,
    f = (bL)^2 / (2 pi L^2) sqrt(EI / rho A)."""
    roots = []
    for k in range(n_modes):
        guess = (k + 0.5) * np.pi
        roots.append(optimize.brentq(lambda b: np.cos(b) * np.cosh(b) + 1.0, guess - 1.0, guess + 1.0, xtol=1e-14))
    bl = np.array(roots)
    return bl**2 / (2 * np.pi * L**2) * np.sqrt(EI / rho_area)


def helical_spring_axial_stiffness(coil_radius: float, pitch_angle: float, wire_length: float,
                                   EI: float, GJ: float) -> float:
    """Axial stiffness (N/m) of an open-coiled helical spring whose ends may rotate freely about
    the axis (Wahl 1963): 1/k = L R^2 (cos^2 a / GJ + sin^2 a / EI) for wire length L, coil radius R,
    pitch angle a."""
    a = pitch_angle
    return 1.0 / (wire_length * coil_radius**2 * (np.cos(a) ** 2 / GJ + np.sin(a) ** 2 / EI))


def helical_spring_fundamental_frequency(k: float, spring_mass: float) -> float:
    """Fundamental axial frequency (Hz) of a clamped-free spring with distributed mass and no end
    mass, treated as a uniform 1-D continuum: f = sqrt(k / m) / 4."""
    return 0.25 * np.sqrt(k / spring_mass)


@dataclass(frozen=True)
class LagrangeTop:
    """Closed-form static Kirchhoff rod with a circular section and end loads only (the Lagrange
    top of Kirchhoff's kinetic analogy; Sobottka 2008 §3.3.1.1, eqs. 3.77-3.118, with the digest's
    corrections). Scaled units: EI = 1, so forces are F / EI (1/m^2), moments M / EI (1/m).

    n : the constant contact force n e_z (the tip force), > 0; m3 : twisting moment b kappa3;
    mz : e_z . m; H : the Hamiltonian 1/2 m.kappa + n d3.e_z (eq. 3.82); b = GJ / EI;
    z1 <= z2 <= z3 : roots of the cubic (eqs. 3.91-3.94); k, lam : modulus and rate of eq. 3.96;
    s0 : phase with z(0) = z0 (eqs. 3.98/3.99, eta^2 = (z0 - z1) / (z2 - z1)).
    """

    n: float
    m3: float
    mz: float
    H: float
    b: float
    z1: float
    z2: float
    z3: float
    k: float
    lam: float
    s0: float

    def z(self, s):
        """cos theta(s) = d3(s) . e_z (eq. 3.96): z1 + (z2 - z1) sn^2(lam (s + s0), k)."""
        sn, _, _, _ = special.ellipj(self.lam * (np.asarray(s, float) + self.s0), self.k**2)
        return self.z1 + (self.z2 - self.z1) * sn**2

    def height(self, s):
        """Z(s) - Z(0) = int_0^s z (eq. 3.118, reconstructed): z3 s - (z3 - z1) / lam [E(am u) - E(am u0)]
        with u = lam (s + s0), using int sn^2 = (u - E(am u, k)) / k^2."""
        s = np.asarray(s, float)
        m = self.k**2

        def Eam(u):
            return special.ellipeinc(special.ellipj(u, m)[3], m)

        u, u0 = self.lam * (s + self.s0), self.lam * self.s0
        return self.z3 * s - (self.z3 - self.z1) / self.lam * (Eam(u) - Eam(u0))

    def dphi(self, s):
        """phi'(s) = (mz - m3 z) / (1 - z^2) (eq. 3.87): precession rate of the tangent about e_z."""
        z = self.z(s)
        return (self.mz - self.m3 * z) / (1.0 - z**2)


def lagrange_top(n: float, m3: float, mz: float, H: float, b: float, z0: float, rising: bool) -> LagrangeTop:
    """The Lagrange-top solution through z(0) = z0 with first integrals (n, m3, mz, H) (scaled, EI = 1);
    ``rising``: z'(0) >= 0. Roots by the monic trigonometric Cardano formula (Appendix A.3, corrected)."""
    if not n > 0:
        raise ParameterError("the Lagrange-top solution needs n > 0 (force along +e_z)")
    h = (H - m3**2 / (2 * b)) / n  # eq. 3.90
    c = np.array([2 * n, -2 * n * h - m3**2, -2 * n + 2 * mz * m3, 2 * n * h - mz**2])  # eq. 3.93
    a1, a2, a3 = c[1] / c[0], c[2] / c[0], c[3] / c[0]
    Q = (a1**2 - 3 * a2) / 9
    R = (2 * a1**3 - 9 * a1 * a2 + 27 * a3) / 54
    if not (Q > 0 and R**2 <= Q**3 * (1 + 1e-12)):
        raise ParameterError("the cubic of eq. 3.91 has complex roots for these integrals")
    zeta = np.arccos(np.clip(R / np.sqrt(Q**3), -1.0, 1.0))
    roots = np.sort(-2 * np.sqrt(Q) * np.cos((zeta + np.array([0.0, 2 * np.pi, -2 * np.pi])) / 3) - a1 / 3)
    z1, z2, z3 = (float(r) for r in roots)
    if not (z1 - 1e-9 <= z0 <= z2 + 1e-9):
        raise ParameterError(f"z0 = {z0} lies outside [z1, z2] = [{z1}, {z2}]")
    k = np.sqrt((z2 - z1) / (z3 - z1))
    lam = np.sqrt(n * (z3 - z1) / 2)
    eta = np.sqrt(np.clip((z0 - z1) / (z2 - z1), 0.0, 1.0))
    s0 = special.ellipkinc(np.arcsin(eta), k**2) / lam
    return LagrangeTop(n, m3, mz, H, b, z1, z2, z3, float(k), float(lam), float(s0 if rising else -s0))
