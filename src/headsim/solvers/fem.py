"""Tetrahedral finite elements with the stable neo-Hookean material (Smith, de Goes & Kim 2018).

Linear (4-node) tets; energy, gradient and a sparse Hessian (element Hessians assembled with a
precomputed CSR pattern, each projected to positive semi-definite for Newton's method); lumped
mass (tet volume x density / 4 per vertex). Pressures and stresses are in Pa: the energy density
linearises to Hooke's law with the given E and nu (tests: uniaxial stress E eps, patch test).

Energy density (Smith et al. 2018, eq. 14): Psi = mu/2 (I_C - 3) + lam/2 (J - alpha)^2, alpha =
1 + mu/lam, shifted by a constant so Psi(I) = 0. Expanding near F = I gives mu/2 (I_C - 3) - mu (J - 1)
+ lam/2 (J - 1)^2, the classical neo-Hookean mu/2 (I_C - 3) - mu ln J + lam_L/2 (ln J)^2 to second
order when lam = lam_L + mu; so mu = mu_Lame, lam = lambda_Lame + mu_Lame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
import scipy.sparse as sp

from headsim.errors import MeshError, ParameterError
from headsim.mesh.tet import TetMesh
from headsim.solvers._assembly import ElementAssembler
from headsim.solvers._kernels import fem as _k
from headsim.solvers.compaction import CompactionBarrier
from headsim.solvers.materials import Material


def shape_gradients(vertices: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shape-function gradients (m, 4, 3), 1/m, and signed volumes (m,), m^3, of linear tets.

    F = sum_a x_a grad_a^T maps rest to current edge vectors (F = Ds Dm^-1).
    """
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(tets, dtype=np.int64)
    dm = np.stack([v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]], v[t[:, 3]] - v[t[:, 0]]], axis=2)
    vol = np.linalg.det(dm) / 6.0
    if (vol <= 0).any():
        raise MeshError(f"{int((vol <= 0).sum())} inverted or degenerate tets")
    bm = np.linalg.inv(dm)  # (m, 3, 3): rows are gradients of barycentric coords 1..3
    grads = np.empty((len(t), 4, 3))
    grads[:, 1:, :] = bm
    grads[:, 0, :] = -bm.sum(axis=1)
    return grads, vol


@dataclass(frozen=True, eq=False)
class FemModel:
    """What a FEM solve never changes.

    Attributes
    ----------
    rest_positions : (n, 3) float64, m
    tets : (m, 4) int64, positively oriented
    mass : (n,) float64, kg, lumped
    shear_modulus : (m,) float64, Pa (Lamé mu)
    lame_lambda : (m,) float64, Pa
    fixed : (n,) bool, vertices held in place
    external_force : (n, 3) float64, N, constant load
    body : (n,) int32 body id
    rayleigh_stiffness : float, s, stiffness-proportional damping (D = beta K at rest) for dynamics
    compaction : optional :class:`headsim.solvers.compaction.CompactionBarrier`, a volume floor of the
        tets it selects (homogenised hollow solids that must not be crushed through J = 0)
    """

    rest_positions: np.ndarray
    tets: np.ndarray
    mass: np.ndarray
    shear_modulus: np.ndarray
    lame_lambda: np.ndarray
    fixed: np.ndarray
    external_force: np.ndarray
    body: np.ndarray
    rayleigh_stiffness: float = 0.0
    compaction: CompactionBarrier | None = None
    grads: np.ndarray = field(init=False, repr=False)
    volumes: np.ndarray = field(init=False, repr=False)
    _assembler: ElementAssembler = field(init=False, repr=False)

    def __post_init__(self):
        x = np.array(self.rest_positions, dtype=np.float64)
        t = np.array(self.tets, dtype=np.int64)
        n, m = len(x), len(t)
        if x.ndim != 2 or x.shape[1] != 3 or t.ndim != 2 or t.shape[1] != 4 or m == 0:
            raise ParameterError(f"need (n, 3) positions and (m, 4) tets, got {x.shape}, {t.shape}")
        if t.min() < 0 or t.max() >= n:
            raise ParameterError(f"tet indices must lie below {n}")
        grads, vol = shape_gradients(x, t)
        arrays = {
            "rest_positions": x, "tets": t,
            "mass": np.broadcast_to(np.asarray(self.mass, dtype=np.float64), (n,)).copy(),
            "shear_modulus": np.broadcast_to(np.asarray(self.shear_modulus, dtype=np.float64), (m,)).copy(),
            "lame_lambda": np.broadcast_to(np.asarray(self.lame_lambda, dtype=np.float64), (m,)).copy(),
            "fixed": np.broadcast_to(np.asarray(self.fixed, dtype=bool), (n,)).copy(),
            "external_force": np.broadcast_to(np.asarray(self.external_force, dtype=np.float64), (n, 3)).copy(),
            "body": np.broadcast_to(np.asarray(self.body, dtype=np.int32), (n,)).copy(),
            "grads": grads, "volumes": vol,
        }
        if (arrays["mass"] <= 0).any():
            raise ParameterError("every vertex mass must be > 0 kg (unreferenced vertices?)")
        if (arrays["shear_modulus"] <= 0).any() or (arrays["lame_lambda"] <= 0).any():
            raise ParameterError("Lamé parameters must be > 0 Pa (Poisson ratio in (0, 0.5))")
        if not np.isfinite(arrays["external_force"]).all():
            raise ParameterError("external_force contains NaN/inf")
        if self.compaction is not None and self.compaction.tets.shape != (m,):
            raise ParameterError(f"compaction barrier selects {self.compaction.tets.shape} tets, the model has {m}")
        for k, v in arrays.items():
            v.flags.writeable = False
            object.__setattr__(self, k, v)
        object.__setattr__(self, "_assembler", ElementAssembler(t, n))

    @property
    def n_vertices(self) -> int:
        return len(self.rest_positions)

    @property
    def _snh_lambda(self) -> np.ndarray:
        return self.lame_lambda + self.shear_modulus

    def elastic_energy(self, positions: np.ndarray) -> float:
        """Stored elastic energy, J (inf where the compaction barrier's floor is reached)."""
        x = np.ascontiguousarray(positions, dtype=np.float64)
        e = float(_k.snh_energy(x, self.tets, self.grads, self.volumes, self.shear_modulus, self._snh_lambda))
        if self.compaction is not None:
            e += self.compaction.energy(x, self.tets, self.grads, self.volumes, self.shear_modulus)
        return e

    def energy(self, positions: np.ndarray) -> float:
        """Elastic energy minus the work of the constant external load, J."""
        return self.elastic_energy(positions) - float(np.sum(self.external_force * (positions - self.rest_positions)))

    def elastic_gradient(self, positions: np.ndarray) -> np.ndarray:
        """dE_elastic/dx (n, 3), N (minus the internal elastic forces)."""
        out = np.zeros((self.n_vertices, 3))
        x = np.ascontiguousarray(positions, dtype=np.float64)
        _k.snh_gradient(x, self.tets, self.grads, self.volumes, self.shear_modulus, self._snh_lambda, out)
        if self.compaction is not None:
            self.compaction.add_gradient(x, self.tets, self.grads, self.volumes, self.shear_modulus, out)
        return out

    def gradient(self, positions: np.ndarray) -> np.ndarray:
        """dE/dx (n, 3), N."""
        return self.elastic_gradient(positions) - self.external_force

    def hessian(self, positions: np.ndarray, project: bool = True) -> sp.csr_matrix:
        """Sparse (3n, 3n) Hessian, N/m; element-wise projected to PSD when ``project``."""
        return self._assembler.assemble(self.element_hessians(positions, project))

    def element_hessians(self, positions: np.ndarray, project: bool = True) -> np.ndarray:
        """Element Hessians (m, 12, 12), N/m; projected to PSD through the analytic eigensystem of the
        stable neo-Hookean energy (Smith et al. 2018/2019, no 9 x 9 eigensolve) when ``project``."""
        vals = np.empty((len(self.tets), 12, 12))
        x = np.ascontiguousarray(positions, dtype=np.float64)
        if project:
            _k.snh_hessian_values_projected(x, self.tets, self.grads, self.volumes, self.shear_modulus,
                                            self._snh_lambda, vals)
        else:
            _k.snh_hessian_values(x, self.tets, self.grads, self.volumes, self.shear_modulus, self._snh_lambda,
                                  False, vals)
        if self.compaction is not None:
            self.compaction.add_element_hessians(x, self.tets, self.grads, self.volumes, self.shear_modulus, project,
                                                 vals)
        return vals

    def forces(self, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """Total force (n, 3), N: elastic + external (+ Rayleigh damping -beta K0 v)."""
        f = -self.gradient(positions)
        if self.rayleigh_stiffness > 0:
            f -= self.rayleigh_stiffness * (self.rest_hessian @ np.asarray(velocities).ravel()).reshape(-1, 3)
        return f

    def damping_matrix(self, positions: np.ndarray) -> sp.csr_matrix:
        """Rayleigh damping matrix beta K(rest), N s/m."""
        return self.rayleigh_stiffness * self.rest_hessian

    @property
    def rest_hessian(self) -> sp.csr_matrix:
        cache = self.__dict__.get("_rest_hessian")
        if cache is None:
            cache = self.hessian(self.rest_positions)
            object.__setattr__(self, "_rest_hessian", cache)
        return cache

    def min_jacobian(self, positions: np.ndarray) -> float:
        return float(_k.snh_min_jacobian(np.ascontiguousarray(positions, dtype=np.float64), self.tets, self.grads))

    def check_state(self, positions: np.ndarray) -> str | None:
        """Reason why ``positions`` is unusable (inverted tets), or None."""
        j = self.min_jacobian(positions)
        if not np.isfinite(j):
            return "non-finite positions"
        if j <= 0.0:
            return f"inverted tetrahedra (min det F = {j:.3g})"
        return None

    def cauchy_stress(self, positions: np.ndarray) -> np.ndarray:
        """Cauchy stress per tet (m, 3, 3), Pa: sigma = P F^T / J."""
        x = np.asarray(positions)
        f = np.einsum("tai,taj->tij", x[self.tets], self.grads)
        jac = np.linalg.det(f)
        cof = jac[:, None, None] * np.linalg.inv(f).transpose(0, 2, 1)
        lam = self._snh_lambda
        p = self.shear_modulus[:, None, None] * f + (lam * (jac - 1.0) - self.shear_modulus)[:, None, None] * cof
        return np.einsum("tij,tkj->tik", p, f) / jac[:, None, None]


def fem_from_tetmesh(mesh: TetMesh, material: Material | Mapping[int, Material], *,
                     gravity: np.ndarray | None = None, rayleigh_stiffness: float = 0.0, body: int = 0,
                     compaction: CompactionBarrier | None = None) -> FemModel:
    """Build a stable neo-Hookean FEM model; per-region materials use ``mesh.tet_region``
    (``compaction``: :attr:`FemModel.compaction`).

    Lumped mass: each tet gives density x volume / 4 to each of its vertices.
    """
    region = mesh.tet_region if mesh.tet_region is not None else np.zeros(mesh.n_tets, dtype=np.int32)
    mats = {int(r): material for r in np.unique(region)} if isinstance(material, Material) else dict(material)
    missing = set(np.unique(region).tolist()) - set(mats)
    if missing:
        raise ParameterError(f"no material for tet regions {sorted(missing)}")
    mu = np.array([mats[int(r)].shear_modulus for r in region])
    lam = np.array([mats[int(r)].lame_lambda for r in region])
    rho = np.array([mats[int(r)].density for r in region])
    n = mesh.n_vertices
    mass = np.zeros(n)
    np.add.at(mass, mesh.tets.ravel(), np.repeat(mesh.rest_volumes * rho / 4.0, 4))
    fixed = mesh.fixed if mesh.fixed is not None else np.zeros(n, dtype=bool)
    ext = np.zeros((n, 3))
    if gravity is not None:
        ext += mass[:, None] * np.asarray(gravity, dtype=np.float64)
    ext[fixed] = 0.0
    return FemModel(mesh.vertices, mesh.tets, mass, mu, lam, fixed, ext, np.full(n, body, np.int32),
                    rayleigh_stiffness, compaction)
