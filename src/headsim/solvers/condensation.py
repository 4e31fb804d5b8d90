"""Static condensation of a linear-elastic body onto its contact-candidate surface nodes.

For a linear-elastic body with stiffness ``K`` (N/m, the FEM Hessian at rest; fixed dofs removed),
a load that acts only at ``m`` candidate nodes, each along its own unit direction ``d_i``, is
``f = D lam`` with ``D`` the (3n, m) matrix whose column i holds ``d_i`` at node i's dofs and
``lam`` the (m,) nodal forces (N). The displacement of the whole body is ``u = K^-1 D lam`` and the
displacements of the candidates along their directions are ``D^T u = W lam`` with the condensed
compliance

    W = D^T K^-1 D          (m, m), m/N, symmetric positive definite,

the inverse of the Schur complement ``S = K_cc - K_ci K_ii^-1 K_ic`` of the stiffness onto the
candidate dofs (projected on the directions). This is the static condensation of the interactive
mask-fitting approach of Kwon et al. (PLOS ONE 2022, as cited in issue 6: a linear-elastic face
condensed onto its surface nodes, contact by Lagrange multipliers): the interior is solved once per body
(one sparse LU factorisation and ``m`` back substitutions), after which every contact problem on
those nodes is an ``m``-sized dense problem (:mod:`headsim.solvers.contact_qp`).

Small strains only (linear elasticity about the rest state); no dependence on the load.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from headsim.errors import ParameterError


@dataclass(frozen=True, eq=False)
class CondensedBody:
    """A linear-elastic body condensed onto contact-candidate nodes (module doc).

    nodes : (m,) int64 candidate node ids; directions : (m, 3) unit vectors;
    compliance : (m, m) float64 W, m/N; free : (3n,) bool dofs that are not fixed;
    n_vertices : n; seconds : time of the condensation. ``displacements(lam)`` gives the (n, 3)
    displacement field (m) of the whole body under candidate forces ``lam`` (N).
    """

    nodes: np.ndarray
    directions: np.ndarray
    compliance: np.ndarray
    free: np.ndarray
    n_vertices: int
    seconds: float
    _lu: object

    def load_matrix(self) -> sp.csr_matrix:
        """(3n, m) sparse D: column i is direction i at node i's three dofs."""
        m = len(self.nodes)
        rows = (3 * self.nodes[:, None] + np.arange(3)).ravel()
        cols = np.repeat(np.arange(m), 3)
        return sp.csr_matrix((self.directions.ravel(), (rows, cols)), shape=(3 * self.n_vertices, m))

    def displacements(self, lam: np.ndarray) -> np.ndarray:
        """(n, 3) m: displacement of every node under forces ``lam`` (N) at the candidates."""
        f = self.load_matrix() @ np.asarray(lam, dtype=np.float64)
        u = np.zeros(3 * self.n_vertices)
        u[self.free] = self._lu.solve(f[self.free])
        return u.reshape(-1, 3)


def condense(stiffness: sp.spmatrix, fixed_dofs: np.ndarray, nodes: np.ndarray, directions: np.ndarray,
             block: int = 256) -> CondensedBody:
    """Condense ``stiffness`` (3n, 3n) onto ``nodes`` along ``directions`` (module doc).

    stiffness : N/m, symmetric, positive definite on the free dofs; fixed_dofs : (3n,) bool
    nodes : (m,) int node ids (not fixed along their direction); directions : (m, 3)
    block : right-hand sides per back substitution
    """
    import time

    t0 = time.perf_counter()
    k = sp.csc_matrix(stiffness)
    n3 = k.shape[0]
    if k.shape != (n3, n3) or n3 % 3:
        raise ParameterError(f"stiffness must be (3n, 3n), got {k.shape}")
    fixed = np.asarray(fixed_dofs, dtype=bool).reshape(-1)
    if fixed.shape != (n3,):
        raise ParameterError(f"fixed_dofs must have {n3} entries, got {fixed.shape}")
    nodes = np.asarray(nodes, dtype=np.int64)
    d = np.asarray(directions, dtype=np.float64).reshape(len(nodes), 3)
    norm = np.linalg.norm(d, axis=1)
    if len(nodes) == 0 or nodes.min() < 0 or nodes.max() >= n3 // 3 or (norm < 1e-12).any():
        raise ParameterError("condense: need >= 1 candidate node with non-zero directions, ids in range")
    d = d / norm[:, None]
    free = ~fixed
    kff = k[free][:, free].tocsc()
    lu = spla.splu(kff)
    body = CondensedBody(nodes, d, np.empty((0, 0)), free, n3 // 3, 0.0, lu)
    dm = body.load_matrix().tocsc()[free]
    m = len(nodes)
    w = np.empty((m, m))
    for s in range(0, m, block):
        rhs = dm[:, s:s + block].toarray()
        w[:, s:s + block] = dm.T @ lu.solve(rhs)
    w = 0.5 * (w + w.T)   # exact symmetry (round-off of the back substitution)
    if not np.isfinite(w).all() or (np.diag(w) <= 0).any():
        raise ParameterError("condense: the stiffness is singular on the candidates (a free body, or a "
                             "candidate whose direction is fixed)")
    return CondensedBody(nodes, d, w, free, n3 // 3, time.perf_counter() - t0, lu)
