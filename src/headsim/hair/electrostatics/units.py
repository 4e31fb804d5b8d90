"""Electrostatic constants and the seed's cgs (Gaussian / esu) units, converted at this edge.

Inside headsim everything is SI: charges in coulomb (C), lengths in m, forces in N, fields in V/m.
Sobottka (2008) ch. 4 writes Coulomb's law with ``c0 = 1`` (Gaussian units, eq. 4.1) and quotes a
line charge density of -7.7e-4 without a unit; statC/cm is implied (digest §3.7). Conversions:

* 1 statC = 1 esu = 3.33564e-10 C (exactly 0.1 / c with c = 299 792 458 m/s);
* a line density in statC/cm is ``value * STATCOULOMB / 0.01`` C/m;
* the Gaussian ``c0 = 1`` becomes ``K_COULOMB = 1 / (4 pi eps0)`` = 8.98755e9 N m^2/C^2 in SI;
* a particle density per cm (the seed's rho_P = 330 /cm) is ``value * 100`` per m.
"""

from __future__ import annotations

import math

__all__ = [
    "EPSILON_0",
    "K_COULOMB",
    "STATCOULOMB",
    "SEED_LINE_CHARGE_STATC_PER_CM",
    "SEED_PARTICLES_PER_CM",
    "statc_to_coulomb",
    "statc_per_cm_to_c_per_m",
    "per_cm_to_per_m",
]

EPSILON_0 = 8.8541878128e-12  # F/m, vacuum permittivity (CODATA 2018)
K_COULOMB = 1.0 / (4.0 * math.pi * EPSILON_0)  # N m^2 / C^2
STATCOULOMB = 0.1 / 299_792_458.0  # C per statC (= 3.33564e-10)
SEED_LINE_CHARGE_STATC_PER_CM = -7.7e-4  # Sobottka §4.5: "Linienladungsdichte -7,7e-4" (statC/cm implied)
SEED_PARTICLES_PER_CM = 330.0  # Sobottka §4.5: rho_P = 330 particles/cm


def statc_to_coulomb(q_statc: float) -> float:
    """Charge in statC (esu) -> C."""
    return float(q_statc) * STATCOULOMB


def statc_per_cm_to_c_per_m(lam: float) -> float:
    """Line charge density statC/cm -> C/m."""
    return float(lam) * STATCOULOMB / 0.01


def per_cm_to_per_m(rho: float) -> float:
    """Particle density per cm -> per m."""
    return float(rho) * 100.0
