"""Material data (SI) and the spring constants a mass-spring network derives from it.

A user states a tissue by its Young's modulus (kPa at the edges, Pa inside), Poisson ratio and
density; nothing in headsim asks for a spring constant in N/m by hand (Heinze ch. 6: "every parameter
had to be tuned by hand").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError


@dataclass(frozen=True)
class Material:
    """Isotropic elastic material.

    Attributes
    ----------
    young_modulus : float, Pa (> 0)
    poisson_ratio : float, in (-1, 0.5)
    density : float, kg/m^3 (> 0)
    name : label used in messages
    """

    young_modulus: float
    poisson_ratio: float = 0.45
    density: float = 1000.0
    name: str = "material"

    def __post_init__(self):
        if not np.isfinite(self.young_modulus) or self.young_modulus <= 0:
            raise ParameterError(f"{self.name}: Young's modulus must be > 0 Pa, got {self.young_modulus}")
        if not -1.0 < self.poisson_ratio < 0.5:
            raise ParameterError(f"{self.name}: Poisson ratio must lie in (-1, 0.5), got {self.poisson_ratio}")
        if not np.isfinite(self.density) or self.density <= 0:
            raise ParameterError(f"{self.name}: density must be > 0 kg/m^3, got {self.density}")

    @classmethod
    def from_kpa(cls, young_modulus_kpa: float, poisson_ratio: float = 0.45, density: float = 1000.0,
                 name: str = "material") -> "Material":
        """Build from a Young's modulus in kPa (the unit tissue data is published in)."""
        return cls(float(young_modulus_kpa) * 1e3, poisson_ratio, density, name)

    @property
    def shear_modulus(self) -> float:
        """Lamé mu, Pa."""
        return self.young_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def lame_lambda(self) -> float:
        """Lamé lambda, Pa."""
        e, nu = self.young_modulus, self.poisson_ratio
        return e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    @property
    def plane_strain_modulus(self) -> float:
        """E* = E / (1 - nu^2), Pa (Hertz contact with a rigid indenter)."""
        return self.young_modulus / (1.0 - self.poisson_ratio**2)

    def wave_speed(self) -> float:
        """Dilatational (P-)wave speed, m/s: the explicit stability limit is dt < h / c."""
        return float(np.sqrt((self.lame_lambda + 2.0 * self.shear_modulus) / self.density))


#: Typical soft-tissue values (order of magnitude; in-vivo facial tissue is 5-30 kPa, nearly incompressible).
SOFT_TISSUE = Material.from_kpa(15.0, 0.45, 1050.0, name="soft tissue")
#: Silicone mask cushion (Shore 5-20 A silicones are ~ 100-500 kPa).
CUSHION_SILICONE = Material.from_kpa(200.0, 0.45, 1100.0, name="cushion silicone")
#: Rigid mask shell (polycarbonate ~ 2.4 GPa).
SHELL_POLYCARBONATE = Material.from_kpa(2.4e6, 0.37, 1200.0, name="polycarbonate shell")


def spring_stiffness_from_young(vertices: np.ndarray, tets: np.ndarray, edges: np.ndarray,
                                tet_young_modulus: np.ndarray) -> np.ndarray:
    """Spring constants of a tetrahedral spring network from Young's modulus.

    k_ij = sum_{t containing edge ij} E_t V_t / l_ij^2

    Parameters
    ----------
    vertices : (n, 3) float64, m (rest positions)
    tets : (m, 4) int64
    edges : (s, 2) int64, the unique tet edges (i < j)
    tet_young_modulus : (m,) float64, Pa

    Returns
    -------
    (s,) float64, N/m

    Notes
    -----
    This is the three-dimensional form of Van Gelder's rule (A. Van Gelder, "Approximate simulation
    of elastic membranes by triangulated spring meshes", J. Graphics Tools 3(2), 1998: k = E sum A_t
    / |c|^2 for triangles); Lloyd, Székely & Harders (2007, "Identification of spring parameters for
    deformable object simulation", IEEE TVCG 13(5)) derive the same E-proportional scaling.
    Derivation: a tet whose six springs carry k = c E V / l^2 stores, under a small homogeneous strain
    eps, W = c E V sum_e (r_e^T eps r_e)^2 / 2. Averaged over orientations,
    <(r^T eps r)^2> = (2 eps:eps + tr(eps)^2) / 15, so W / V = (6c/15)(eps:eps + tr(eps)^2 / 2), a
    linear-elastic energy with mu = lambda = 6c/15 E, i.e. Young's modulus 5 mu / 2 = c E and
    nu = 1/4. Hence c = 1 reproduces E on average. A central-force network cannot represent other
    Poisson ratios (Cauchy relation), so ``nu`` only enters the FEM material; use FEM where the
    Poisson ratio or pressures in kPa matter.
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(tets, dtype=np.int64)
    e = np.asarray(edges, dtype=np.int64)
    young = np.broadcast_to(np.asarray(tet_young_modulus, dtype=np.float64), (len(t),))
    vol = np.abs(np.einsum("ij,ij->i", np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]]),
                           v[t[:, 3]] - v[t[:, 0]])) / 6.0
    n = len(v)
    pairs = np.concatenate([t[:, [a, b]] for a, b in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))])
    pairs.sort(axis=1)
    weight = np.tile(young * vol, 6)
    key_tet = pairs[:, 0] * n + pairs[:, 1]
    key_edge = e[:, 0] * n + e[:, 1]
    order = np.argsort(key_edge)
    pos = np.searchsorted(key_edge[order], key_tet)
    if np.any(pos >= len(e)) or np.any(key_edge[order][np.minimum(pos, len(e) - 1)] != key_tet):
        raise ParameterError("edges do not contain every tet edge; pass TetMesh.edges")
    ev = np.zeros(len(e))
    np.add.at(ev, order[pos], weight)
    length2 = np.sum((v[e[:, 1]] - v[e[:, 0]]) ** 2, axis=1)
    return ev / length2


def damping_from_ratio(stiffness: np.ndarray, edges: np.ndarray, mass: np.ndarray, damping_ratio: float) -> np.ndarray:
    """Dashpot constants c_ij = 2 zeta sqrt(k_ij m_ij), m_ij = m_i m_j / (m_i + m_j), N s/m.

    ``damping_ratio`` zeta is the fraction of critical damping of the two-mass oscillator formed by
    one spring; 0 gives no damping (Heinze eq. 2.7 with k_d = 0).
    """
    if damping_ratio < 0 or not np.isfinite(damping_ratio):
        raise ParameterError(f"damping ratio must be >= 0, got {damping_ratio}")
    m = np.asarray(mass, dtype=np.float64)
    mi, mj = m[edges[:, 0]], m[edges[:, 1]]
    reduced = mi * mj / (mi + mj)
    return 2.0 * damping_ratio * np.sqrt(np.asarray(stiffness) * reduced)
