"""Repulsion of the charged fibres by the charged scalp (Sobottka eq. 4.13, Alg. 2 line 10).

    f_i = K q_i Q_S / max(d_i, d_min)^2 * grad Phi_S(x_i) / |grad Phi_S(x_i)|      [N]

with d_i = Phi_S(x_i) the (signed) distance to the scalp S and K = 1/(4 pi eps0) (the seed writes the
cgs form |q||Q_S|/d^2 with q Q_S > 0, i.e. like charges that repel; with the signed product used
here unlike charges attract). Q_S is the scalp charge in C, treated as a point-like charge at the
closest scalp point, as in the seed.

Clamp: the force is singular at d -> 0 and undefined inside the head. We use d_eff = max(d, d_min)
(default d_min = 1 mm), so the force magnitude is capped at K |q Q_S| / d_min^2 and points along the
outward gradient also for particles at or behind the surface (a soft collision response). Particles
where the gradient vanishes (e.g. outside a narrow-band field) get no scalp force.

Any object with ``distance(points) -> (n,)`` and ``gradient(points) -> (n, 3)`` serves as Phi_S:
``headsim.collide.distance_field`` fields (analytic sphere/plane, grid SDF of a mesh) or
:class:`MeshDistance`, which queries the triangle BVH exactly.
"""

from __future__ import annotations

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.electrostatics.units import K_COULOMB

__all__ = ["MeshDistance", "scalp_forces", "DEFAULT_CLAMP"]

DEFAULT_CLAMP = 1e-3  # m


class MeshDistance:
    """Exact distance to a triangle mesh via :class:`headsim.collide.TriangleBVH`; the sign is that of
    (p - q) . n(q) with q the closest point and n the face normal (works on open meshes such as the
    bundled head); gradient = sign * (p - q)/|p - q|, the face normal on the surface."""

    def __init__(self, vertices, triangles):
        from headsim.collide import TriangleBVH

        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self.bvh = TriangleBVH(self.vertices, self.triangles)
        a, b, c = (self.vertices[self.triangles[:, i]] for i in range(3))
        n = np.cross(b - a, c - a)
        self.face_normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    def _query(self, points):
        p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        cp = self.bvh.closest_points(p)
        d = p - cp.point
        nf = self.face_normals[cp.triangle]
        s = np.where(np.einsum("ij,ij->i", d, nf) < 0, -1.0, 1.0)
        return p, cp, d, nf, s

    def distance(self, points) -> np.ndarray:
        _, cp, _, _, s = self._query(points)
        return s * cp.distance

    def gradient(self, points, scheme: str = "exact") -> np.ndarray:
        _, cp, d, nf, s = self._query(points)
        g = nf.copy()
        ok = cp.distance > 1e-12
        g[ok] = s[ok, None] * d[ok] / cp.distance[ok, None]
        return g


def scalp_forces(points, charges, field, scalp_charge: float, clamp: float = DEFAULT_CLAMP) -> np.ndarray:
    """(n, 3) N: eq. 4.13 with the clamp above. points (n, 3) m; charges (n,) C; scalp_charge C."""
    x = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    q = np.asarray(charges, dtype=np.float64)
    if q.shape != (x.shape[0],):
        raise ParameterError("charges must be (n,) for points (n, 3)")
    if not (np.isfinite(scalp_charge) and clamp > 0):
        raise ParameterError(f"scalp charge must be finite and the clamp distance > 0 m, got {scalp_charge}, {clamp}")
    if scalp_charge == 0.0 or field is None or x.shape[0] == 0:
        return np.zeros_like(x)
    d = np.asarray(field.distance(x), dtype=np.float64)
    g = np.asarray(field.gradient(x), dtype=np.float64)
    gn = np.linalg.norm(g, axis=1)
    u = np.divide(g, gn[:, None], out=np.zeros_like(g), where=gn[:, None] > 0)
    deff = np.maximum(d, clamp)
    mag = K_COULOMB * q * float(scalp_charge) / deff**2
    return mag[:, None] * u
