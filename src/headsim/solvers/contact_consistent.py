"""The seed's collision response for two deformable bodies (Heinze 2023, §3.3-3.4, eqs. 3.7-3.13).

Detection: the vertices of body A inside the closed surface of body B (generalised winding number,
:class:`headsim.collide.bvh.TriangleBVH`), and vice versa.

Direction r and depth d of each colliding vertex:

- ``"naive"``: the shortest way out -- towards the closest point of B's surface (§3.4.1). Neighbours
  near opposite faces of a thin part of B get opposite directions and tear A apart (fig. 3.1).
- ``"consistent"`` (§3.4.2): *border points* (colliding, with at least one spring to a non-colliding
  point) intersect each such spring with B's surface (Möller-Trumbore, §3.3.3), x_i the hit and n_i
  the outward normal there; d = sum w (x_i - p) . n_i / sum w (eq. 3.9), w = 1/|x_i - p| (eq. 3.10),
  r = sum w n_i / sum w (eq. 3.11). The other colliding points get d and r from one breadth-first
  traversal seeded by all border points (variant 1), eqs. 3.12-3.13 over already visited neighbours.
  Points not reachable from any border point fall back to the naive direction. We normalise r after
  each weighted mean (the seed uses it as a direction).

  Variant 2 (one traversal per "collision group", §3.4.2, figs. 3.2-3.4) is not implemented: the
  thesis does not define how the groups are found (they are not the connected components of the
  colliding points -- a traversal never leaves its component, so per-component traversals would equal
  variant 1 -- but adjacent regions, e.g. points 0, 1, 3 vs point 2 in fig. 3.4), and it rules the
  variant out itself: several traversals can reintroduce the fig. 3.1 failure ("schließt sich der
  mehrfache Breitendurchlauf komplett aus").

Force (eq. 3.8 with 3.7): F = k_coll d r + c_coll ((v_body - v_point) . r) r, v_body the mean velocity of
the other body; r points out of the other body, so the force pushes the point out. The seed's eq. 3.8
writes both terms with a minus sign for the opposite orientation of r and d.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from headsim.errors import ParameterError
from headsim.solvers._kernels.contact import bfs_propagate


def _bvh(vertices, triangles):
    from headsim.collide.bvh import TriangleBVH

    return TriangleBVH(vertices, triangles)


@dataclass(frozen=True, eq=False)
class ExitPoints:
    """Collision data of k slave vertices against a closed surface.

    inside : (k,) bool colliding
    valid : (k,) bool a direction was found (colliding points only)
    depth : (k,) m penetration depth d
    direction : (k, 3) unit r, pointing out of the other body
    point : (k, 3) m exit point (first hit of the ray p + t r), NaN where none
    triangle : (k,) int64 index into the master triangles of the exit point, -1 where none
    barycentric : (k, 3) weights of the exit point in that triangle
    border : (k,) bool border points (consistent method)
    """

    inside: np.ndarray
    valid: np.ndarray
    depth: np.ndarray
    direction: np.ndarray
    point: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    border: np.ndarray


def _local_adjacency(slave_vertices: np.ndarray, edges: np.ndarray, n: int):
    local = np.full(n, -1, dtype=np.int64)
    local[slave_vertices] = np.arange(len(slave_vertices))
    e = np.asarray(edges, dtype=np.int64)
    e = e[(local[e[:, 0]] >= 0) & (local[e[:, 1]] >= 0)]
    k = len(slave_vertices)
    a = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[local[e[:, 0]], local[e[:, 1]]],
                                             np.r_[local[e[:, 1]], local[e[:, 0]]])), shape=(k, k))
    return local, a.indptr.astype(np.int64), a.indices.astype(np.int64)


def exit_points(positions: np.ndarray, slave_vertices: np.ndarray, master_positions: np.ndarray,
                master_triangles: np.ndarray, method: str = "consistent",
                edges: np.ndarray | None = None, bvh=None) -> ExitPoints:
    """Depth and direction of the slave vertices that are inside the master surface.

    positions : (n, 3) m, all vertices (springs may lead to non-slave vertices)
    slave_vertices : (k,) int64 the vertices tested (all mass points of body A in the seed)
    master_positions : (p, 3) m and master_triangles : (t, 3) int64 -- body B's closed, outward surface
    method : "consistent" (eqs. 3.9-3.13) or "naive" (shortest way out)
    edges : (s, 2) int64 springs of body A (needed for "consistent"); a spring to a vertex outside
        ``slave_vertices`` counts as a spring to a non-colliding point
    bvh : an existing TriangleBVH over (master_positions, master_triangles) to reuse
    """
    if method not in ("consistent", "naive"):
        raise ParameterError(f"method must be 'consistent' or 'naive', got {method!r}")
    x = np.asarray(positions, dtype=np.float64)
    sv = np.asarray(slave_vertices, dtype=np.int64)
    k = len(sv)
    tree = bvh if bvh is not None else _bvh(master_positions, master_triangles)
    p = x[sv]
    inside = tree.contains(p)
    depth = np.zeros(k)
    direction = np.zeros((k, 3))
    border = np.zeros(k, dtype=bool)
    assigned = np.zeros(k, dtype=bool)
    if inside.any() and method == "consistent":
        if edges is None:
            raise ParameterError("the consistent method needs the springs (edges) of the body")
        e = np.asarray(edges, dtype=np.int64)
        local, ptr, idx = _local_adjacency(sv, e, len(x))
        coll_global = np.zeros(len(x), dtype=bool)
        coll_global[sv[inside]] = True
        # springs from a colliding point to a non-colliding point (either orientation)
        both = np.concatenate([e, e[:, ::-1]])
        cross = both[coll_global[both[:, 0]] & ~coll_global[both[:, 1]] & (local[both[:, 0]] >= 0)]
        if len(cross):
            hits = tree.intersect_segments(x[cross[:, 0]], x[cross[:, 1]])
            h = hits.hit
            src = local[cross[h, 0]]
            xi = hits.point[h]
            ni = hits.normal[h]
            w = 1.0 / np.maximum(np.linalg.norm(xi - x[cross[h, 0]], axis=1), 1e-300)  # eq. 3.10
            wsum = np.bincount(src, weights=w, minlength=k)
            dnum = np.bincount(src, weights=w * np.einsum("ij,ij->i", xi - x[cross[h, 0]], ni), minlength=k)
            rnum = np.stack([np.bincount(src, weights=w * ni[:, c], minlength=k) for c in range(3)], axis=1)
            border = wsum > 0
            depth[border] = dnum[border] / wsum[border]  # eq. 3.9
            r = rnum[border] / wsum[border, None]  # eq. 3.11
            norm = np.linalg.norm(r, axis=1)
            good = norm > 1e-12
            bidx = np.flatnonzero(border)
            direction[bidx[good]] = r[good] / norm[good, None]
            border[bidx[~good]] = False
            assigned = border.copy()
        bfs_propagate(x, sv, inside, assigned, depth, direction, ptr, idx)  # eqs. 3.12-3.13
    # naive (and fallback for colliding points the traversal did not reach)
    need = inside & ~assigned
    if need.any():
        cp = tree.closest_points(p[need])
        vec = cp.point - p[need]
        dist = np.linalg.norm(vec, axis=1)
        # on (or within round-off of) the surface the direction to the closest point is noise: use the
        # outward normal of the closest triangle there
        tiny = 1e-9 * float(np.linalg.norm(np.ptp(np.asarray(master_positions)[np.unique(master_triangles)], axis=0)))
        r = np.where(dist[:, None] > tiny, vec / np.maximum(dist, 1e-300)[:, None],
                     tree.triangle_normals(cp.triangle))
        depth[need] = dist
        direction[need] = r
        assigned = assigned | need
    valid = inside & assigned & (np.linalg.norm(direction, axis=1) > 0)
    point = np.full((k, 3), np.nan)
    tri = np.full(k, -1, dtype=np.int64)
    bary = np.full((k, 3), np.nan)
    if valid.any():
        vi = np.flatnonzero(valid)
        hits = tree.intersect_rays(p[vi], direction[vi])
        ok = hits.hit
        point[vi[ok]] = hits.point[ok]
        tri[vi[ok]] = hits.triangle[ok]
        bary[vi[ok]] = hits.barycentric[ok]
        if (~ok).any():  # numerically grazing: snap the seed's exit estimate p + d r to the surface
            miss = vi[~ok]
            cp = tree.closest_points(p[miss] + depth[miss, None] * direction[miss])
            point[miss], tri[miss], bary[miss] = cp.point, cp.triangle, cp.barycentric
    return ExitPoints(inside, valid, depth, direction, point, tri, bary, border)


class SeedCollisionForce:
    """Collision force between deformable bodies for explicit integration (Heinze eqs. 3.7-3.13).

    Parameters
    ----------
    body : (n,) int body id of every vertex (e.g. ``MassSpringModel.body``)
    surfaces : per body, (t, 3) int64 boundary triangles (global vertex ids, outward)
    edges : (s, 2) int64 springs (``MassSpringModel.edges``)
    stiffness : k_coll, N/m (eq. 3.8)
    damping : c_coll, N s/m (eq. 3.8)
    method : "consistent" (eqs. 3.9-3.13) or "naive" (shortest way out)
    bodies : which bodies collide with each other (all pairs of the given ids)

    Calling it with (positions, velocities) returns the (n, 3) collision forces, N; ``last`` keeps the
    per-body :class:`ExitPoints` of the last call for inspection.
    """

    def __init__(self, body: np.ndarray, surfaces: Sequence[np.ndarray], edges: np.ndarray, stiffness: float,
                 damping: float = 0.0, method: str = "consistent", bodies: Sequence[int] | None = None):
        if stiffness < 0 or damping < 0:
            raise ParameterError("collision stiffness and damping must be >= 0")
        if method not in ("consistent", "naive"):
            raise ParameterError(f"method must be 'consistent' or 'naive', got {method!r}")
        self.body = np.asarray(body)
        self.surfaces = [np.asarray(s, dtype=np.int64) for s in surfaces]
        self.edges = np.asarray(edges, dtype=np.int64)
        self.stiffness = float(stiffness)
        self.damping = float(damping)
        self.method = method
        self.bodies = list(range(len(self.surfaces))) if bodies is None else list(bodies)
        self.vertices_of = [np.flatnonzero(self.body == b) for b in range(len(self.surfaces))]
        self._trees: dict[int, object] = {}
        self.last: dict[tuple[int, int], ExitPoints] = {}

    def _tree(self, b: int, x: np.ndarray):
        t = self._trees.get(b)
        if t is None:
            t = _bvh(x, self.surfaces[b])
            self._trees[b] = t
        else:
            t.refit(x)
        return t

    def __call__(self, positions: np.ndarray, velocities: np.ndarray) -> np.ndarray:
        x = np.asarray(positions, dtype=np.float64)
        v = np.asarray(velocities, dtype=np.float64)
        f = np.zeros_like(x)
        for a in self.bodies:
            for b in self.bodies:
                if a == b:
                    continue
                sv = self.vertices_of[a]
                res = exit_points(x, sv, x, self.surfaces[b], self.method, self.edges, bvh=self._tree(b, x))
                self.last[(a, b)] = res
                c = res.valid
                if not c.any():
                    continue
                r = res.direction[c]
                v_body = v[self.vertices_of[b]].mean(axis=0)  # eq. 3.7: mean velocity of the other body
                v_rel = v_body[None, :] - v[sv[c]]
                mag = self.stiffness * res.depth[c] + self.damping * np.einsum("ij,ij->i", r, v_rel)  # eq. 3.8
                np.add.at(f, sv[c], mag[:, None] * r)
        return f
