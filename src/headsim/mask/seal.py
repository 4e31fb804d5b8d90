"""Does the contact seal? Where does it leak?

**Seal rule** (issue 6): the mask seals when the skin–cushion contact whose pressure exceeds the
therapy air pressure forms a closed loop around the airway. On the face mesh: let
``S = {vertices with contact pressure > therapy pressure}``. Flood-fill from the airway vertices
over vertices *not* in ``S``, along mesh edges. The mask leaks iff the flood reaches an escape
vertex (by default the face mesh's outer boundary, its longest boundary loop). On a triangulated
surface a cycle of edges between ``S`` vertices cannot be crossed by any edge whose ends are both
outside ``S`` (edges do not cross), so this is exact for the vertex graph: the airway is sealed
iff ``S`` separates it from the outer boundary.

Inner holes of the mesh (eyes, mouth of the ICT faces) are body openings, not escapes: gas that
reaches them has not left the face. Pass ``escape_vertices`` to choose otherwise.

**Leak paths**: for each distinct break of the seal loop, a path from the airway to the escape
boundary through non-sealing vertices found by Dijkstra, with edge cost ``length × c`` where ``c``
prefers close contact: ``c = gap + 0.1 mm`` (m) when the per-vertex skin→cushion gap is given, else
``c = 1 / (0.05 + p / p_therapy)`` — so the path hugs the cushion and shows where it slips through.
Its **crossing point** is the path vertex where the passage between sealing vertices is narrowest
(for a path vertex ``q``: nearest sealing vertex ``s1``, nearest sealing vertex ``s2`` on the other
side, ``(s2 - q).(s1 - q) < 0``; passage width ``|s1 - q| + |s2 - q|``) — the middle of the break in
the loop; without any sealing vertex it is the path vertex of highest pressure, else of smallest
gap. Reported with the gap there and the **channel width** (that passage width). Further
breaks are found by closing the found one (vertices within ``channel width + 3 mm`` of the crossing
are added to ``S``) and searching again, up to ``max_paths``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, dijkstra
from scipy.spatial import cKDTree

from headsim.errors import ParameterError, RegionError
from headsim.mask.landmarks import Landmarks
from headsim.mask.pressure import THERAPY_PRESSURE_PA
from headsim.mesh import SurfaceMesh


@dataclass(frozen=True, eq=False)
class LeakPath:
    """One leak: a path from the airway to the escape boundary through the break in the seal loop.

    positions : (k, 3) float64, m, path vertex positions, airway first
    vertices : (k,) int64 face vertex ids
    crossing_vertex : int, face vertex id where the path passes the cushion footprint
    crossing_point : (3,) float64, m
    gap_width : float, m, skin→cushion gap at the crossing (None when no gap field was given)
    channel_width : float, m, width of the break in the seal loop at the crossing (distance between
        the sealing vertices on either side; inf when nothing seals)
    pressure_at_crossing : float, Pa
    """

    positions: np.ndarray
    vertices: np.ndarray
    crossing_vertex: int
    crossing_point: np.ndarray
    gap_width: float | None
    channel_width: float
    pressure_at_crossing: float

    def as_dict(self) -> dict:
        return {
            "crossing_point_m": self.crossing_point.tolist(),
            "crossing_vertex": int(self.crossing_vertex),
            "gap_width_mm": None if self.gap_width is None else self.gap_width * 1e3,
            "channel_width_mm": self.channel_width * 1e3 if np.isfinite(self.channel_width) else None,
            "pressure_at_crossing_kpa": self.pressure_at_crossing / 1e3,
            "path_m": self.positions.tolist(),
        }


@dataclass(frozen=True, eq=False)
class SealResult:
    """Outcome of :func:`analyse_seal`.

    sealed : bool
    sealing_vertices : (s,) int64, vertices with contact pressure > therapy pressure
    leak_region : (r,) int64, non-sealing vertices reachable from the airway (the pressurised region
        when sealed; reaches the escape boundary when not)
    leak_paths : list of LeakPath (empty when sealed)
    therapy_pressure : Pa
    """

    sealed: bool
    sealing_vertices: np.ndarray
    leak_region: np.ndarray
    leak_paths: list[LeakPath] = field(default_factory=list)
    therapy_pressure: float = THERAPY_PRESSURE_PA

    def as_dict(self) -> dict:
        return {
            "sealed": bool(self.sealed),
            "therapy_pressure_pa": self.therapy_pressure,
            "n_sealing_vertices": int(len(self.sealing_vertices)),
            "leak_paths": [p.as_dict() for p in self.leak_paths],
        }


def airway_vertices(face: SurfaceMesh, landmarks: Landmarks, kind: str = "nasal",
                    radius: float = 8e-3) -> np.ndarray:
    """(k,) int64 face vertices within ``radius`` (m) of the airway point of a ``kind`` mask.

    Nasal: around the midpoint of nose tip and subnasale (the nostrils); oronasal: around the
    midpoint of subnasale and stomion (upper lip and mouth).
    """
    from headsim.mask.placement import airway_point

    p = airway_point(landmarks, kind)
    ids = np.flatnonzero(np.linalg.norm(face.vertices - p, axis=1) <= radius)
    if len(ids) == 0:
        raise RegionError(f"{face.name}: no vertex within {radius * 1e3:.1f} mm of the {kind} airway point")
    return ids


def outer_boundary(face: SurfaceMesh) -> np.ndarray:
    """(b,) int64 vertices of the face's outer boundary (its longest boundary loop)."""
    loops = face.boundary_loops
    if not loops:
        raise RegionError(f"{face.name}: closed surface — a seal needs an open face with an outer boundary")
    return loops[0]


def _flood(adjacency: sp.csr_matrix, open_vertices: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """(n,) bool: vertices reachable from ``seeds`` through ``open_vertices`` (both (n,) bool / ids)."""
    n = adjacency.shape[0]
    keep = sp.diags(open_vertices.astype(np.float64))
    graph = (keep @ adjacency @ keep).tocsr()
    reached = np.zeros(n, dtype=bool)
    seeds = seeds[open_vertices[seeds]]
    if len(seeds) == 0:
        return reached
    # a virtual super-source would need a bigger matrix; seeds are few, so add edges between them
    order = breadth_first_order(graph + _clique(seeds, n), int(seeds[0]), directed=False,
                                return_predecessors=False)
    reached[order] = True
    return reached


def _clique(ids: np.ndarray, n: int) -> sp.csr_matrix:
    """Chain adjacency joining ``ids`` (so one BFS reaches every seed)."""
    if len(ids) < 2:
        return sp.csr_matrix((n, n))
    a, b = ids[:-1], ids[1:]
    return sp.csr_matrix((np.ones(2 * len(a)), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n))


def _passage_width(points: np.ndarray, sealing_points: np.ndarray, k: int = 64) -> np.ndarray:
    """(q,) m: width of the passage between sealing vertices at each point (inf if open on one side).

    For each point, the nearest sealing vertex ``s1`` and the nearest sealing vertex ``s2`` on the
    opposite side (``(s2 - q) . (s1 - q) < 0``) among its ``k`` nearest; width = ``|s1 - q| + |s2 - q|``.
    """
    tree = cKDTree(sealing_points)
    kk = min(k, len(sealing_points))
    dist, idx = tree.query(points, k=kk)
    dist = dist.reshape(len(points), kk)
    idx = idx.reshape(len(points), kk)
    first = sealing_points[idx[:, 0]] - points
    rel = sealing_points[idx] - points[:, None, :]
    opposite = np.einsum("qkd,qd->qk", rel, first) < 0
    d2 = np.where(opposite, dist, np.inf).min(axis=1)
    return dist[:, 0] + d2


def analyse_seal(face: SurfaceMesh, pressure_pa: np.ndarray, airway_vertices: np.ndarray,
                 therapy_pressure_pa: float = THERAPY_PRESSURE_PA, gap: np.ndarray | None = None,
                 escape_vertices: np.ndarray | None = None, max_paths: int = 8) -> SealResult:
    """Decide whether the contact seals the airway; report leak paths otherwise (module doc).

    Parameters
    ----------
    face : SurfaceMesh, m (open, with an outer boundary)
    pressure_pa : (n,) float64, Pa, contact pressure at every face vertex (≥ 0)
    airway_vertices : (k,) int64 face vertices inside the mask's airway (e.g. :func:`airway_vertices`)
    therapy_pressure_pa : Pa, > 0 (default 10 cmH2O)
    gap : (n,) float64, m, skin→cushion distance per face vertex (optional; inf/NaN where no cushion
        lies over the vertex)
    escape_vertices : (b,) int64 (default: the outer boundary)
    max_paths : most leak paths reported

    Returns
    -------
    SealResult
    """
    n = face.n_vertices
    p = np.asarray(pressure_pa, dtype=np.float64)
    if p.shape != (n,) or not np.isfinite(p).all() or np.any(p < 0):
        raise ParameterError(f"pressure_pa must be a finite, non-negative ({n},) array, got shape {p.shape}")
    if not (np.isfinite(therapy_pressure_pa) and therapy_pressure_pa > 0):
        raise ParameterError(f"therapy_pressure_pa must be > 0, got {therapy_pressure_pa}")
    seeds = np.unique(np.asarray(airway_vertices, dtype=np.int64).ravel())
    if len(seeds) == 0:
        raise RegionError("airway_vertices is empty")
    if seeds.min() < 0 or seeds.max() >= n:
        raise RegionError(f"airway_vertices must be vertex ids in [0, {n - 1}]")
    g = None
    if gap is not None:
        g = np.asarray(gap, dtype=np.float64)
        if g.shape != (n,):
            raise ParameterError(f"gap must have shape ({n},), got {g.shape}")
        g = np.where(np.isfinite(g), g, np.inf)
    escape = outer_boundary(face) if escape_vertices is None else np.unique(np.asarray(escape_vertices, np.int64))
    if len(escape) == 0:
        raise RegionError("escape_vertices is empty")
    is_escape = np.zeros(n, dtype=bool)
    is_escape[escape] = True

    sealing = p > therapy_pressure_pa
    adjacency = face.adjacency
    reached = _flood(adjacency, ~sealing, seeds)
    leaking = bool((reached & is_escape).any())
    result_region = np.flatnonzero(reached)
    if not leaking:
        return SealResult(True, np.flatnonzero(sealing), result_region, [], float(therapy_pressure_pa))

    # --- leak paths ---------------------------------------------------------------------------------
    v = face.vertices
    edges = face.edges
    length = np.linalg.norm(v[edges[:, 1]] - v[edges[:, 0]], axis=1)
    if g is not None:
        cost_v = np.where(np.isfinite(g), np.maximum(g, 0.0), 0.05) + 1e-4
    else:
        cost_v = 1.0 / (0.05 + p / therapy_pressure_pa)
    paths: list[LeakPath] = []
    blocked = sealing.copy()
    for _ in range(max_paths):
        open_v = ~blocked
        reach = _flood(adjacency, open_v, seeds)
        if not (reach & is_escape).any():
            break
        ok = open_v[edges[:, 0]] & open_v[edges[:, 1]]
        e = edges[ok]
        w = length[ok] * 0.5 * (cost_v[e[:, 0]] + cost_v[e[:, 1]])
        graph = sp.csr_matrix((np.concatenate([w, w]), (np.concatenate([e[:, 0], e[:, 1]]),
                                                        np.concatenate([e[:, 1], e[:, 0]]))), shape=(n, n))
        src = seeds[open_v[seeds]]
        dist, pred, _ = dijkstra(graph, directed=False, indices=src, min_only=True, return_predecessors=True)
        targets = np.flatnonzero(is_escape & np.isfinite(dist))
        end = int(targets[np.argmin(dist[targets])])
        path = [end]
        while pred[path[-1]] >= 0:
            path.append(int(pred[path[-1]]))
        path = np.array(path[::-1], dtype=np.int64)

        seal_ids = np.flatnonzero(sealing)
        if len(seal_ids):
            width = _passage_width(v[path], v[seal_ids])
            k = int(np.argmin(width))
            channel = float(width[k])
        else:
            if p[path].max() > 0 or g is None:
                k = int(np.argmax(p[path]))
            else:
                k = int(np.argmin(g[path]))
            channel = float("inf")
        c = int(path[k])
        paths.append(LeakPath(
            positions=v[path].copy(), vertices=path, crossing_vertex=c, crossing_point=v[c].copy(),
            gap_width=None if g is None else float(g[c]), channel_width=channel,
            pressure_at_crossing=float(p[c]),
        ))
        if not np.isfinite(channel):
            break  # nothing seals: one path says it all
        close = np.linalg.norm(v - v[c], axis=1) <= channel + 3e-3
        blocked |= close & ~np.isin(np.arange(n), seeds)
    return SealResult(False, np.flatnonzero(sealing), result_region, paths, float(therapy_pressure_pa))
