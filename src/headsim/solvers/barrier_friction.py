"""Lagged smoothed Coulomb friction over the barrier's contact pairs, with a smoothed contact normal.

IPC's friction (Li et al., "Incremental Potential Contact", ACM TOG 39(4) 2020, sec. 5) is a
dissipation potential over the *tangential collisions* k built from the barrier's contact pairs at a
lagged configuration:

    D(u) = sum_k w_k mu lambda_k f0(|P_k r_k(u)|),   r_k = sum_i gamma_ki u_i     (Li et al. eq. 14)

with u the surface vertices' displacement (here: the slip since they first touched, see
:mod:`headsim.solvers.barrier`), gamma_ki the closest-point coefficients of the pair's stencil
(+1 for a point, -b_i for the barycentric weights of the triangle it faces; edge parameters for an
edge-edge pair), w_k the pair's area weight, lambda_k its lagged normal force, P_k the projection on
the pair's tangent plane and

    f0(s) = -s^3 / (3 eps^2) + s^2 / eps + eps / 3  (s < eps),  s  (s >= eps),
    f1(s) = f0'(s) = 2 s / eps - s^2 / eps^2        (s < eps),  1  (s >= eps)          (Li et al. eq. 15)

so that the friction force of a pair is mu lambda_k f1(s) along the slip: the Coulomb force where
the tangential slip s exceeds eps, a smooth rise from zero below it.

**The contact normal.** ipctk takes P_k from the pair's own geometry: the plane of the triangle of a
point-triangle pair, the plane normal to the distance of a point-edge pair and, for an edge-edge pair,
the plane spanned by edge a and (e_a x e_b) x e_a. For two nearly parallel edges -- the usual case
where a cushion lies on skin -- e_a x e_b points anywhere in the plane normal to e_a, so that pair's
"tangent" plane can contain the surfaces' normal (two sheets 1e-3 rad apart: up to 65 deg off,
``tests/solvers/test_barrier_friction.py``) and sliding is partly taken as approach.
``normals="smooth"`` (the default) takes the tangent plane normal to a *smoothed* contact normal
instead, as smoothing methods for contact on faceted surfaces do (Puso & Laursen, "A 3D contact
smoothing method using Gregory patches", IJNME 54 (2002); Wriggers, "Computational Contact
Mechanics", 2nd ed. 2006, ch. 9, the normal of the master surface at the projection point): one of
the two surfaces is the master -- the contact surface component listed first (the lower connected-
component label; the skin in the mask fit, whose triangles come first) -- and every pair's normal is
that surface's area-weighted vertex normals interpolated, with the pair's closest-point weights
|gamma_k|, at the pair's closest point on it. One smooth normal field for all pairs: continuous
where a pair moves across an edge, and the same for the pairs of the improved-max set that correct
each other (a point lying on an edge has a point-edge pair of negative weight and edge-edge pairs
with the edges at that point, and they must have the same normal for their friction to cancel).
On a flat master face it is the face normal, i.e. ipctk's point-triangle plane. ``normals="pair"``
keeps ipctk's planes (for comparison and for the test that checks this implementation against
ipctk's FrictionPotential). Where a point crosses an edge between two faces of a creased surface,
ipctk's friction is continuous as well (the improved-max set blends the two faces' pairs through the
edge's; measured on a 22.6 deg fold).

Measured (outer loop of the mask fit's barrier friction relaxed, :mod:`headsim.solvers.barrier`;
coarse test problem, mu = 0.5, cold fits at 10 / 20 / 25 / 30 N; ``benchmarks/bench_mask_friction.py
--problem coarse --forces 10,20,25,30 --compare``): this rule converged at all four;
ipctk's planes stalled at 10 and 30 N; per-kind rules stalled where correcting pairs got different
normals: a point's pair with the normal of the side it projects on and edge-edge pairs with the
mean of both sides stalled at 25 and 30 N (at 25 N on a skin vertex lying on a cushion edge), the
two sides' combination n_a + (n_a . n_b) n_b for every pair at 10 N.

The potential depends on the slip only through |P_k r_k|, so no tangent basis is needed. Its Hessian
in the tangential slip y = P r is f1(s)/s P + (f1'(s) - f1(s)/s) y y^T / s^2, positive semi-definite
for IPC's f0 (eigenvalues f1' >= 0 along y and f1/s > 0 across). The pair's weight w_k can be
negative: the "improved max" collision set (Li, Kaufman & Jiang 2023) subtracts the pairs that two
neighbouring pairs count twice (an edge-vertex pair between two point-triangle pairs). The projected
Hessian (``project=True``) leaves those out, which is what clamping each pair's eigenvalues at zero
does (ipctk's ``PSDProjectionMethod.CLAMP``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from headsim.errors import ParameterError
from headsim.mesh.geometry import vertex_components, vertex_normals

_KINDS = ("vv_collisions", "ev_collisions", "ee_collisions", "fv_collisions")


class LaggedFriction:
    """The friction potential D(u) of the module doc over ipctk ``TangentialCollisions`` taken at the
    surface positions ``positions`` (k, 3) m of ``mesh`` (an ipctk CollisionMesh).

    eps : m, the slip below which a pair sticks (the Coulomb coefficient is the collisions' own, set
    when ipctk built them); normals : "smooth" (module doc) or "pair" (ipctk's tangent planes); body :
    (k,) int body label per surface vertex (default: the connected components of the mesh's faces). :meth:`energy`, :meth:`gradient` and :meth:`hessian` take
    the surface displacement u (k, 3) m; the gradient is (k, 3) N, the Hessian a (3k, 3k) sparse
    matrix in N/m over the surface dofs (x, y, z per vertex).
    """

    def __init__(self, collisions, mesh, positions: np.ndarray, eps: float, normals: str = "smooth",
                 body: np.ndarray | None = None):
        if normals not in ("smooth", "pair"):
            raise ParameterError(f"friction normals must be 'smooth' or 'pair', got {normals!r}")
        if not eps > 0:
            raise ParameterError(f"friction needs a slip length eps > 0, got {eps}")
        self.eps = float(eps)
        self.n_vertices = len(positions)
        edges, faces = mesh.edges, mesh.faces
        stencils, gammas, coeff, pair_normal = [], [], [], []
        for kind in _KINDS:
            for col in getattr(collisions, kind):
                ids = np.full(4, -1, dtype=np.int64)
                vid = [int(i) for i in col.vertex_ids(edges, faces)]
                ids[: len(vid)] = vid
                m = np.asarray(col.relative_velocity_jacobian())  # (3, 3 n_stencil): blocks gamma_i I_3
                g = np.zeros(4)
                g[: m.shape[1] // 3] = m[0, 0::3]
                basis = np.asarray(col.tangent_basis)  # (3, 2)
                stencils.append(ids)
                gammas.append(g)
                coeff.append(col.weight * col.mu_k * col.normal_force_magnitude)
                pair_normal.append(np.cross(basis[:, 0], basis[:, 1]))
        k = len(stencils)
        self.ids = np.array(stencils, dtype=np.int64).reshape(k, 4)
        self.gamma = np.array(gammas, dtype=np.float64).reshape(k, 4)
        self.gamma[self.ids < 0] = 0.0
        self.ids[self.ids < 0] = 0
        self.coeff = np.array(coeff, dtype=np.float64).reshape(k)  # w mu lambda, N
        own = np.array(pair_normal, dtype=np.float64).reshape(k, 3)
        own /= np.maximum(np.linalg.norm(own, axis=1, keepdims=True), 1e-300)
        if normals == "smooth" and k:
            n = self._smoothed_normals(np.asarray(positions, dtype=np.float64), np.asarray(faces), own, body)
        else:
            n = own
        self.normals = n
        self.projector = np.eye(3)[None] - n[:, :, None] * n[:, None, :]  # (k, 3, 3)
        # sparsity of the Hessian: 4 x 4 blocks of 3 x 3 per pair
        dof = 3 * self.ids[:, :, None] + np.arange(3)  # (k, 4, 3)
        flat = dof.reshape(k, 12)
        self._rows = np.repeat(flat, 12, axis=1).ravel()
        self._cols = np.tile(flat, (1, 12)).ravel()

    def __len__(self) -> int:
        return len(self.coeff)

    def _smoothed_normals(self, x, faces, own, body=None) -> np.ndarray:
        """(k, 3) smoothed contact normals (module doc): the vertex normals of the pair's side on the
        first body (the lower label of ``body``, per surface vertex; default: the connected components
        of ``faces``) interpolated at its closest point; the pair's own normal ``own`` where that side
        has no normal."""
        f = np.asarray(faces, dtype=np.int64)
        label = vertex_components(len(x), f) if body is None else np.asarray(body, dtype=np.int64)
        vn = vertex_normals(x, f)[self.ids]  # (k, 4, 3)
        big = np.iinfo(np.int64).max
        lab = label[self.ids]
        side_a = np.where(self.gamma > 0, lab, big).min(axis=1)
        side_b = np.where(self.gamma < 0, lab, big).min(axis=1)
        on_master = np.where((side_a <= side_b)[:, None], self.gamma > 0, self.gamma < 0)
        w = np.where(on_master, np.abs(self.gamma), 0.0)
        n = np.einsum("ki,kij->kj", w, vn)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(length > 1e-12, n / np.maximum(length, 1e-300), own)

    # -- the slip of each pair -------------------------------------------------------------------
    def _tangential_slip(self, u):
        r = np.einsum("ki,kij->kj", self.gamma, np.asarray(u, dtype=np.float64)[self.ids])  # (k, 3)
        y = np.einsum("kab,kb->ka", self.projector, r)
        return y, np.linalg.norm(y, axis=1)

    def _f1_over_s(self, s):
        e = self.eps
        return np.where(s < e, 2.0 / e - s / (e * e), 1.0 / np.maximum(s, 1e-300))

    def energy(self, u) -> float:
        """D(u), J."""
        if not len(self):
            return 0.0
        _, s = self._tangential_slip(u)
        e = self.eps
        f0 = np.where(s < e, -s**3 / (3 * e * e) + s * s / e + e / 3.0, s)
        return float(self.coeff @ f0)

    def gradient(self, u) -> np.ndarray:
        """dD/du, (k_vertices, 3) N."""
        g = np.zeros((self.n_vertices, 3))
        if not len(self):
            return g
        y, s = self._tangential_slip(u)
        t = (self.coeff * self._f1_over_s(s))[:, None] * y  # (k, 3): the pair's gradient w.r.t. its slip r
        np.add.at(g, self.ids, self.gamma[:, :, None] * t[:, None, :])
        return g

    def hessian(self, u, project: bool = False) -> sp.csr_matrix:
        """d2D/du2 at fixed lagged data, (3k, 3k) sparse. ``project``: positive semi-definite, the
        pairs of negative weight left out (module doc)."""
        size = 3 * self.n_vertices
        if not len(self):
            return sp.csr_matrix((size, size))
        y, s = self._tangential_slip(u)
        e = self.eps
        a = self._f1_over_s(s)
        # (f1' - f1/s) / s^2 = -1 / (eps^2 s) below eps, -1 / s^3 above (its y y^T term vanishes at s = 0)
        b = np.zeros_like(s)
        small = (s > 0) & (s < e)
        b[small] = -1.0 / (e * e * s[small])
        b[s >= e] = -1.0 / s[s >= e] ** 3
        h3 = a[:, None, None] * self.projector + b[:, None, None] * y[:, :, None] * y[:, None, :]
        h3 *= (np.maximum(self.coeff, 0.0) if project else self.coeff)[:, None, None]
        blocks = np.einsum("ki,kj,kab->kiajb", self.gamma, self.gamma, h3)  # (k, 4, 3, 4, 3)
        h = sp.coo_matrix((blocks.reshape(-1), (self._rows, self._cols)), shape=(size, size))
        return h.tocsr()
