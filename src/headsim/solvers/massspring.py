"""Mass-spring-damper model on tetrahedral meshes (Heinze 2023, ch. 2, eqs. 2.1-2.8).

Mass points carry a mass (eq. 2.1: total mass / N as in the seed, or lumped tet volume x density);
every tet edge is a Hooke spring (eqs. 2.4-2.6) with a parallel damper (eqs. 2.7-2.8); bone vertices
are fixed; gravity and constant external forces on vertex sets are added (eq. 2.2). Spring constants
come either from material data (:func:`headsim.solvers.materials.spring_stiffness_from_young`, per
region) or, to reproduce the seed's experiments, from a constant in N/m.

The model also exposes energy, gradient and a (projected) sparse Hessian so the implicit and
quasi-static solvers of :mod:`headsim.solvers.integrators` can use it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping

import numpy as np
import scipy.sparse as sp

from headsim.errors import ParameterError
from headsim.mesh.tet import TetMesh
from headsim.solvers._arrays import frozen_array
from headsim.solvers._assembly import ElementAssembler
from headsim.solvers._kernels import massspring as _k
from headsim.solvers.materials import Material, damping_from_ratio, spring_stiffness_from_young

STANDARD_GRAVITY = np.array([0.0, -9.81, 0.0])  # m/s^2, y up as in the seed and the bundled faces


@dataclass(frozen=True, eq=False)
class MassSpringModel:
    """What a mass-spring-damper solve never changes (Heinze eqs. 2.1-2.8).

    Attributes
    ----------
    rest_positions : (n, 3) float64, m
    mass : (n,) float64, kg (> 0)
    edges : (s, 2) int64 spring end points
    rest_length : (s,) float64, m (> 0)
    stiffness : (s,) float64, N/m (>= 0)
    damping : (s,) float64, N s/m (>= 0)
    fixed : (n,) bool, vertices held in place (bone)
    external_force : (n, 3) float64, N, constant load (gravity included)
    body : (n,) int32 body id of each vertex (several bodies can share one model)
    """

    rest_positions: np.ndarray
    mass: np.ndarray
    edges: np.ndarray
    rest_length: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    fixed: np.ndarray
    external_force: np.ndarray
    body: np.ndarray
    _assembler: ElementAssembler | None = field(default=None, repr=False)

    def __post_init__(self):
        x = frozen_array(self.rest_positions, name="rest_positions")
        if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
            raise ParameterError(f"rest_positions must be (n, 3), got {x.shape}")
        n = len(x)
        e = np.array(self.edges, dtype=np.int64)
        if e.ndim != 2 or e.shape[1] != 2 or (e.size and (e.min() < 0 or e.max() >= n)):
            raise ParameterError(f"edges must be (s, 2) indices below {n}")
        e.flags.writeable = False
        s = len(e)
        vals = {
            "rest_positions": x,
            "edges": e,
            "mass": frozen_array(self.mass, np.float64, (n,), "mass"),
            "rest_length": frozen_array(self.rest_length, np.float64, (s,), "rest_length"),
            "stiffness": frozen_array(self.stiffness, np.float64, (s,), "stiffness"),
            "damping": frozen_array(self.damping, np.float64, (s,), "damping"),
            "fixed": frozen_array(self.fixed, bool, (n,), "fixed"),
            "external_force": frozen_array(self.external_force, np.float64, (n, 3), "external_force"),
            "body": frozen_array(self.body, np.int32, (n,), "body"),
        }
        if (vals["mass"] <= 0).any():
            raise ParameterError("every mass must be > 0 kg")
        if (vals["rest_length"] <= 0).any():
            raise ParameterError("zero-length springs (duplicate vertices?)")
        if (vals["stiffness"] < 0).any() or (vals["damping"] < 0).any():
            raise ParameterError("spring and damper constants must be >= 0")
        for k, v in vals.items():
            object.__setattr__(self, k, v)
        object.__setattr__(self, "_assembler", ElementAssembler(e, n) if s else None)

    @property
    def n_vertices(self) -> int:
        return len(self.rest_positions)

    # -- forces (explicit integration) ---------------------------------------------------------
    def forces(self, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        """Total force on every mass point (n, 3), N: springs, dampers, external load (eq. 2.2)."""
        out = np.array(self.external_force)
        _k.spring_damper_forces(np.ascontiguousarray(positions), np.ascontiguousarray(velocities), self.edges,
                                self.rest_length, self.stiffness, self.damping, out)
        return out

    # -- energy interface (implicit / quasi-static) -------------------------------------------------
    def energy(self, positions: np.ndarray) -> float:
        """Spring energy minus the work of the constant external load, J."""
        x = np.ascontiguousarray(positions)
        return float(_k.spring_energy(x, self.edges, self.rest_length, self.stiffness)
                     - np.sum(self.external_force * (x - self.rest_positions)))

    def gradient(self, positions: np.ndarray) -> np.ndarray:
        """dE/dx (n, 3), N (= minus the static force)."""
        springs = np.zeros_like(positions, dtype=np.float64)
        _k.spring_damper_forces(np.ascontiguousarray(positions), np.zeros_like(springs), self.edges,
                                self.rest_length, self.stiffness, np.zeros(len(self.damping)), springs)
        return -springs - self.external_force

    def hessian(self, positions: np.ndarray, project: bool = True) -> sp.csr_matrix:
        """Sparse (3n, 3n) Hessian of :meth:`energy`, N/m; PSD when ``project``."""
        if self._assembler is None:
            return sp.csr_matrix((3 * self.n_vertices,) * 2)
        blocks = np.empty((len(self.edges), 3, 3))
        _k.spring_hessian_blocks(np.ascontiguousarray(positions), self.edges, self.rest_length, self.stiffness,
                                 project, blocks)
        local = np.empty((len(self.edges), 6, 6))
        local[:, :3, :3] = blocks
        local[:, 3:, 3:] = blocks
        local[:, :3, 3:] = -blocks
        local[:, 3:, :3] = -blocks
        return self._assembler.assemble(local)

    def damping_matrix(self, positions: np.ndarray) -> sp.csr_matrix:
        """Sparse (3n, 3n) matrix D of the dampers at ``positions`` (force = -D v), N s/m (eq. 2.7)."""
        if self._assembler is None:
            return sp.csr_matrix((3 * self.n_vertices,) * 2)
        d = positions[self.edges[:, 1]] - positions[self.edges[:, 0]]
        r = d / np.linalg.norm(d, axis=1, keepdims=True)
        blocks = self.damping[:, None, None] * r[:, :, None] * r[:, None, :]
        local = np.empty((len(self.edges), 6, 6))
        local[:, :3, :3] = blocks
        local[:, 3:, 3:] = blocks
        local[:, :3, 3:] = -blocks
        local[:, 3:, :3] = -blocks
        return self._assembler.assemble(local)

    def check_state(self, positions: np.ndarray) -> str | None:
        """Return a reason if ``positions`` is unusable (springs have no inversion test), else None."""
        return None

    def with_external_force(self, external_force: np.ndarray) -> "MassSpringModel":
        """Copy with another constant load (n, 3), N."""
        return replace(self, external_force=external_force, _assembler=None)


def combine_mass_spring(models: list[MassSpringModel]) -> tuple[MassSpringModel, np.ndarray]:
    """Concatenate several bodies into one model; returns (model, vertex offsets (k + 1,)).

    Body ids are renumbered 0..k-1 in the given order.
    """
    offsets = np.cumsum([0] + [m.n_vertices for m in models])
    cat = np.concatenate
    model = MassSpringModel(
        cat([m.rest_positions for m in models]), cat([m.mass for m in models]),
        cat([m.edges + o for m, o in zip(models, offsets)]), cat([m.rest_length for m in models]),
        cat([m.stiffness for m in models]), cat([m.damping for m in models]), cat([m.fixed for m in models]),
        cat([m.external_force for m in models]),
        cat([np.full(m.n_vertices, b, dtype=np.int32) for b, m in enumerate(models)]),
    )
    return model, offsets


def mass_spring_from_tetmesh(
    mesh: TetMesh,
    *,
    material: Material | Mapping[int, Material] | None = None,
    stiffness: float | Mapping[int, float] | None = None,
    damping: float = 0.0,
    damping_ratio: float | None = None,
    total_mass: float | None = None,
    gravity: np.ndarray | None = None,
    body: int = 0,
) -> MassSpringModel:
    """Build a mass-spring-damper model on the edges of a tet mesh (Heinze ch. 2).

    Parameters
    ----------
    mesh : TetMesh (m); ``mesh.fixed`` marks bone vertices.
    material : Material or {region: Material}; gives the spring constants (Van Gelder-type rule, see
        :func:`spring_stiffness_from_young`) and the lumped masses (tet volume x density / 4 per
        vertex). Per-region materials use ``mesh.tet_region``.
    stiffness : N/m, constant or {region: N/m} (the seed's hand-set constants). Exactly one of
        ``material`` and ``stiffness`` must be given. A spring between two regions takes the mean.
    damping : N s/m, parallel damper constant of every spring (eq. 2.7), or
    damping_ratio : fraction of critical damping per spring (overrides ``damping``).
    total_mass : kg; if given the mass is total / N per vertex (eq. 2.1, as in the seed).
    gravity : (3,) m/s^2, e.g. ``STANDARD_GRAVITY``; None for none (the seed's mask study).
    body : body id written into ``MassSpringModel.body``.
    """
    if (material is None) == (stiffness is None):
        raise ParameterError("give exactly one of material= (physical data) and stiffness= (N/m)")
    x = mesh.vertices
    n = mesh.n_vertices
    edges = mesh.edges
    region = mesh.tet_region if mesh.tet_region is not None else np.zeros(mesh.n_tets, dtype=np.int32)
    density = None
    if material is not None:
        mats = {int(r): material for r in np.unique(region)} if isinstance(material, Material) else dict(material)
        missing = set(np.unique(region).tolist()) - set(mats)
        if missing:
            raise ParameterError(f"no material for tet regions {sorted(missing)}")
        young = np.array([mats[int(r)].young_modulus for r in region])
        density = np.array([mats[int(r)].density for r in region])
        k = spring_stiffness_from_young(x, mesh.tets, edges, young)
    else:
        if isinstance(stiffness, Mapping):
            missing = set(np.unique(region).tolist()) - set(int(r) for r in stiffness)
            if missing:
                raise ParameterError(f"no spring constant for tet regions {sorted(missing)}")
            kt = np.array([float(stiffness[int(r)]) for r in region])
            # vertex stiffness = mean over its tets; spring = mean of its two end vertices
            kv = np.zeros(n)
            cnt = np.zeros(n)
            np.add.at(kv, mesh.tets.ravel(), np.repeat(kt, 4))
            np.add.at(cnt, mesh.tets.ravel(), 1.0)
            kv /= np.maximum(cnt, 1)
            k = 0.5 * (kv[edges[:, 0]] + kv[edges[:, 1]])
        else:
            k = np.full(len(edges), float(stiffness))
    if total_mass is not None:
        if total_mass <= 0:
            raise ParameterError(f"total mass must be > 0 kg, got {total_mass}")
        mass = np.full(n, total_mass / n)  # eq. 2.1 with equal masses
    else:
        if density is None:
            raise ParameterError("with stiffness= in N/m give total_mass= (the seed's masses are total / N)")
        mass = np.zeros(n)
        np.add.at(mass, mesh.tets.ravel(), np.repeat(mesh.rest_volumes * density / 4.0, 4))
    fixed = mesh.fixed if mesh.fixed is not None else np.zeros(n, dtype=bool)
    ext = np.zeros((n, 3))
    if gravity is not None:
        ext += mass[:, None] * np.asarray(gravity, dtype=np.float64)[None, :]
    ext[fixed] = 0.0
    c = damping_from_ratio(k, edges, mass, damping_ratio) if damping_ratio is not None else np.full(len(edges), damping)
    rest = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    return MassSpringModel(x, mass, edges, rest, k, c, fixed, ext, np.full(n, body, dtype=np.int32))
