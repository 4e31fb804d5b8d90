"""Face regions from markers, and their closed models (Monkin 2016, seed 001, §5.3).

Markers (3-D points, m, or vertex ids) are snapped to the nearest mesh vertex and joined by shortest
paths on the mesh edge graph (Dijkstra, edge lengths as weights) into a closed loop. The loop cuts the
surface in two; the region is the side that does not contain the mesh boundary (the outer rim and the
eye, mouth and nostril openings of a face).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csg
from scipy.spatial import cKDTree

from headsim.errors import HeadsimError, RegionError
from headsim.mesh import geometry
from headsim.mesh.surface import SurfaceMesh
from headsim.mesh.units import parse_units

__all__ = [
    "Markers",
    "FaceRegion",
    "ClosedRegion",
    "load_markers",
    "save_markers",
    "region_from_markers",
    "region_from_loop",
    "snap_markers",
    "marker_loop",
    "transfer_region_to_midpoint_subdivision",
    "close_region",
]


@dataclass(frozen=True, eq=False)
class Markers:
    """Markers of one region, in order around it.

    points : (k, 3) float64, m, or None
    vertex_ids : (k,) int64, or None (exactly one of the two is given)
    name : region name
    """

    points: np.ndarray | None = None
    vertex_ids: np.ndarray | None = None
    name: str = "region"

    def __post_init__(self):
        if (self.points is None) == (self.vertex_ids is None):
            raise RegionError(f"markers {self.name!r}: give either 3-D points or vertex ids")
        if self.points is not None:
            p = np.array(self.points, dtype=np.float64)
            if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
                raise RegionError(f"markers {self.name!r}: points must be finite (k, 3), got shape {p.shape}")
            p.flags.writeable = False
            object.__setattr__(self, "points", p)
            k = len(p)
        else:
            ids = np.array(self.vertex_ids, dtype=np.int64).reshape(-1)
            ids.flags.writeable = False
            object.__setattr__(self, "vertex_ids", ids)
            k = len(ids)
        if k < 3:
            raise RegionError(f"markers {self.name!r}: a closed loop needs at least 3 markers, got {k}")

    def to_json(self) -> dict:
        """JSON-ready dict (points in metres)."""
        if self.points is not None:
            return {"points": self.points.tolist()}
        return {"vertex_ids": self.vertex_ids.tolist()}


def load_markers(path: str | Path, *, units: str | None = None) -> dict[str, Markers]:
    """Read a markers JSON file.

    Format: ``{"units": "m"|"cm"|"mm", "regions": {"left_cheek": {"points": [[x, y, z], ...]}, ...}}``;
    a region may give ``"vertex_ids": [...]`` instead of points. A file with top-level ``"points"`` or
    ``"vertex_ids"`` holds one region named after the file. ``units`` overrides the file's unit
    (default m). Returns markers with points in metres, by region name.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise RegionError(f"markers file not found: {path}") from None
    except (OSError, json.JSONDecodeError) as e:
        raise RegionError(f"{path}: cannot read markers JSON: {e}") from None
    if not isinstance(data, dict):
        raise RegionError(f"{path}: markers JSON must be an object")
    scale = parse_units(units or data.get("units", "m")).to_metres
    regions = data.get("regions")
    if regions is None:
        regions = {path.stem: data}
    if not isinstance(regions, dict) or not regions:
        raise RegionError(f"{path}: 'regions' must be a non-empty object")
    out = {}
    for name, spec in regions.items():
        if not isinstance(spec, dict):
            raise RegionError(f"{path}: region {name!r} must be an object with 'points' or 'vertex_ids'")
        try:
            if "points" in spec:
                out[name] = Markers(points=np.asarray(spec["points"], dtype=float) * scale, name=name)
            elif "vertex_ids" in spec:
                out[name] = Markers(vertex_ids=spec["vertex_ids"], name=name)
            else:
                raise RegionError(f"{path}: region {name!r} has neither 'points' nor 'vertex_ids'")
        except (TypeError, ValueError) as e:
            if isinstance(e, HeadsimError):
                raise
            raise RegionError(f"{path}: region {name!r}: {e}") from None
    return out


def save_markers(markers: dict[str, Markers], path: str | Path) -> None:
    """Write markers (points in metres) in the format of :func:`load_markers`."""
    data = {"units": "m", "regions": {name: m.to_json() for name, m in markers.items()}}
    Path(path).write_text(json.dumps(data, indent=1))


@dataclass(frozen=True, eq=False)
class FaceRegion:
    """A region of a face surface bounded by a closed loop of mesh edges.

    mesh : the whole face
    loop : (b,) int64 vertex ids of the boundary loop, in order
    triangle_ids : (t,) int64 triangles of the region
    markers : the markers it was built from (or None)
    """

    mesh: SurfaceMesh
    loop: np.ndarray
    triangle_ids: np.ndarray
    markers: Markers | None = None
    marker_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @cached_property
    def vertex_ids(self) -> np.ndarray:
        """(k,) int64 vertices of the region triangles (boundary loop included), sorted."""
        return np.unique(self.mesh.triangles[self.triangle_ids])

    @cached_property
    def interior_vertex_ids(self) -> np.ndarray:
        """(k - b,) int64 region vertices not on the loop (the ones the simulation moves)."""
        return np.setdiff1d(self.vertex_ids, self.loop)

    @property
    def area(self) -> float:
        """Region area, m²."""
        return float(self.mesh.triangle_areas[self.triangle_ids].sum())

    def area_on(self, vertices: np.ndarray) -> float:
        """Area, m², of the region's triangles on other vertex positions (same connectivity)."""
        return float(geometry.triangle_areas(np.asarray(vertices), self.mesh.triangles[self.triangle_ids]).sum())

    def vertex_mask(self) -> np.ndarray:
        """(n,) bool, True on region vertices."""
        m = np.zeros(self.mesh.n_vertices, bool)
        m[self.vertex_ids] = True
        return m

    def __repr__(self) -> str:
        return (f"FaceRegion({self.mesh.name!r}, {len(self.vertex_ids)} vertices, {len(self.triangle_ids)} "
                f"triangles, loop of {len(self.loop)}, area {self.area * 1e4:.2f} cm²)")


def _edge_graph(mesh: SurfaceMesh) -> sp.csr_matrix:
    e = mesh.edges
    length = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
    length = np.maximum(length, 1e-15)
    rows = np.concatenate([e[:, 0], e[:, 1]])
    cols = np.concatenate([e[:, 1], e[:, 0]])
    return sp.csr_matrix((np.concatenate([length, length]), (rows, cols)), shape=(mesh.n_vertices,) * 2)


def snap_markers(mesh: SurfaceMesh, markers: Markers, *, max_distance: float | None = None) -> np.ndarray:
    """(k,) int64 nearest mesh vertex of every marker (vertex ids are checked and kept).

    max_distance (m): refuse markers farther than this from every vertex (default: 5 % of the mesh's
    largest extent), which catches markers given in the wrong unit.
    """
    if markers.vertex_ids is not None:
        ids = markers.vertex_ids
        if ids.min() < 0 or ids.max() >= mesh.n_vertices:
            raise RegionError(f"markers {markers.name!r}: vertex ids must lie in [0, {mesh.n_vertices - 1}]")
        return ids.copy()
    dist, ids = cKDTree(mesh.vertices).query(markers.points)
    limit = 0.05 * float(mesh.extent.max()) if max_distance is None else max_distance
    far = dist > limit
    if far.any():
        k = int(np.argmax(far))
        raise RegionError(
            f"markers {markers.name!r}: marker {k} is {dist[k]:.4g} m from the surface of {mesh.name} "
            f"(limit {limit:.3g} m); are the markers in the mesh's unit and aligned with it?"
        )
    return ids.astype(np.int64)


def marker_loop(mesh: SurfaceMesh, marker_vertices: np.ndarray, name: str = "region") -> np.ndarray:
    """(b,) int64 closed loop of vertex ids joining the marker vertices by shortest edge paths."""
    ids = [int(v) for v in marker_vertices]
    ids = [v for k, v in enumerate(ids) if v != ids[k - 1]] if len(ids) > 1 else ids  # drop repeats
    if len(set(ids)) < 3:
        raise RegionError(f"markers {name!r} snap to fewer than 3 distinct vertices; the loop is open")
    graph = _edge_graph(mesh)
    unique = np.unique(ids)
    dist, pred = csg.dijkstra(graph, directed=False, indices=unique, return_predecessors=True)
    row = {v: r for r, v in enumerate(unique)}
    loop: list[int] = []
    for k, a in enumerate(ids):
        b = ids[(k + 1) % len(ids)]
        r = row[a]
        if not np.isfinite(dist[r, b]):
            raise RegionError(f"markers {name!r}: markers {k} and {(k + 1) % len(ids)} lie on unconnected "
                              "parts of the mesh; the loop is open")
        path = [b]
        while path[-1] != a:
            path.append(int(pred[r, path[-1]]))
        loop.extend(path[::-1][:-1])  # a … (before b)
    if len(set(loop)) != len(loop):
        seen, dup = set(), None
        for v in loop:
            if v in seen:
                dup = v
                break
            seen.add(v)
        raise RegionError(f"markers {name!r}: the marker loop crosses or touches itself at vertex {dup}; "
                          "place the markers in order around the region")
    return np.asarray(loop, dtype=np.int64)


def region_from_loop(mesh: SurfaceMesh, loop: np.ndarray, *, markers: Markers | None = None,
                     marker_vertices: np.ndarray | None = None) -> FaceRegion:
    """The region bounded by ``loop``: the side of the cut that does not contain the mesh boundary.

    On a closed mesh the side with the smaller area is taken.
    """
    name = markers.name if markers is not None else "region"
    loop = np.asarray(loop, dtype=np.int64)
    tri = mesh.triangles
    cut = set()
    for a, b in zip(loop, np.roll(loop, -1)):
        cut.add((min(a, b), max(a, b)))
    # triangle adjacency across edges that are not cut
    half = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    half.sort(axis=1)
    tri_of_half = np.tile(np.arange(len(tri)), 3)
    key = half[:, 0] * mesh.n_vertices + half[:, 1]
    cut_keys = np.array([a * mesh.n_vertices + b for a, b in cut], dtype=np.int64)
    missing = ~np.isin(cut_keys, key)
    if missing.any():
        raise RegionError(f"markers {name!r}: the loop uses a pair of vertices that is not a mesh edge")
    order = np.argsort(key, kind="stable")
    ks, ts = key[order], tri_of_half[order]
    same = ks[1:] == ks[:-1]
    a_t, b_t, k_pair = ts[:-1][same], ts[1:][same], ks[:-1][same]
    keep = ~np.isin(k_pair, cut_keys)
    adj = sp.coo_matrix((np.ones(int(keep.sum())), (a_t[keep], b_t[keep])), shape=(len(tri), len(tri)))
    n_comp, label = csg.connected_components(adj, directed=False)
    if n_comp < 2:
        raise RegionError(f"markers {name!r}: the loop does not separate the surface; the loop is open")
    uniq, n_face = np.unique(ks, return_counts=True)
    boundary_keys = uniq[n_face == 1]
    boundary_tris = ts[np.isin(ks, boundary_keys)]
    touches_boundary = np.zeros(n_comp, bool)
    touches_boundary[label[boundary_tris]] = True
    # the two sides of the loop: components that have a triangle on a cut edge
    loop_tris = ts[np.isin(ks, cut_keys)]
    sides = np.unique(label[loop_tris])
    inside = [c for c in sides if not touches_boundary[c]]
    if len(boundary_keys) == 0:
        areas = np.bincount(label, weights=mesh.triangle_areas, minlength=n_comp)
        inside = [min(sides, key=lambda c: areas[c])]
    if not inside:
        raise RegionError(f"markers {name!r}: both sides of the loop reach the mesh boundary; the loop encloses "
                          "an opening of the mesh (eye, mouth, nostril) — mark a region without holes")
    region_tris = np.flatnonzero(np.isin(label, inside))
    if len(region_tris) == 0:
        raise RegionError(f"markers {name!r}: the region is empty")
    if len(region_tris) == len(tri):
        raise RegionError(f"markers {name!r}: the region is the whole surface")
    interior = np.setdiff1d(np.unique(tri[region_tris]), loop)
    if len(interior) == 0:
        raise RegionError(f"markers {name!r}: the region has no vertex inside its loop (it is empty)")
    return FaceRegion(mesh, loop, region_tris, markers,
                      np.zeros(0, np.int64) if marker_vertices is None else np.asarray(marker_vertices, np.int64))


def transfer_region_to_midpoint_subdivision(region: FaceRegion, fine: SurfaceMesh) -> FaceRegion:
    """The same region on the 1-to-4 midpoint subdivision ``fine`` of ``region.mesh``.

    The coarse vertices keep their ids in ``fine`` (``headsim.mesh.subdivide.subdivide_midpoint``); each
    loop edge (a, b) becomes a, m_ab, b with m_ab the new vertex adjacent to both. Unlike re-running the
    marker paths on ``fine`` (whose shortest paths cut the corners of the coarse zig-zag loop and so
    change the region's area), this keeps the region's outline exactly.
    """
    n = region.mesh.n_vertices
    if fine.n_vertices <= n or not np.allclose(fine.vertices[:n], region.mesh.vertices):
        raise RegionError("the fine mesh is not a midpoint subdivision of the region's mesh")
    adj = fine.adjacency
    loop = []
    for a, b in zip(region.loop, np.roll(region.loop, -1)):
        na = adj.indices[adj.indptr[a]:adj.indptr[a + 1]]
        nb = adj.indices[adj.indptr[b]:adj.indptr[b + 1]]
        common = np.intersect1d(na, nb)
        common = common[common >= n]
        mid = 0.5 * (fine.vertices[a] + fine.vertices[b])
        if len(common) == 0:
            raise RegionError("the fine mesh is not a midpoint subdivision of the region's mesh")
        m = common[np.argmin(np.linalg.norm(fine.vertices[common] - mid, axis=1))]
        loop.extend([int(a), int(m)])
    return region_from_loop(fine, np.asarray(loop, np.int64), markers=region.markers,
                            marker_vertices=region.marker_vertices)


def region_from_markers(mesh: SurfaceMesh, markers: Markers) -> FaceRegion:
    """Snap ``markers`` to ``mesh``, join them into a closed loop and return the enclosed region."""
    ids = snap_markers(mesh, markers)
    loop = marker_loop(mesh, ids, markers.name)
    return region_from_loop(mesh, loop, markers=markers, marker_vertices=ids)


@dataclass(frozen=True, eq=False)
class ClosedRegion:
    """Closed model of a region (Monkin 2016 §5.3).

    vertices : (k, 3) float64, m
    triangles : (t, 3) int64, a closed, consistently oriented surface
    face_ids : (k,) int64 face vertex of every model vertex, -1 for added ones (centroid, mirror copy)
    fixed : (k,) bool, loop vertices and the added closure (they do not move)
    surface_triangles : (r,) int64 rows of ``triangles`` that are the region's own surface
    method : "centroid" or "mirror"
    """

    vertices: np.ndarray
    triangles: np.ndarray
    face_ids: np.ndarray
    fixed: np.ndarray
    surface_triangles: np.ndarray
    method: str

    @property
    def volume(self) -> float:
        """Signed volume of the closed model, m³."""
        return geometry.signed_volume(self.vertices, self.triangles)

    def volume_on(self, vertices: np.ndarray) -> float:
        return geometry.signed_volume(np.asarray(vertices), self.triangles)


def close_region(region: FaceRegion, method: str = "centroid") -> ClosedRegion:
    """Build the closed model of ``region`` (Monkin 2016 §5.3).

    ``"centroid"``: add one vertex at the area-weighted centroid of the region and a fan of triangles
    joining it to the boundary edges. ``"mirror"``: the region plus a copy with reversed triangles; the
    copy shares the loop vertices, so the model is a closed surface of volume zero at the start. Every
    added vertex is fixed (the closure stands for the tissue underneath), as are the loop vertices.
    """
    mesh = region.mesh
    sub_tri_face = mesh.triangles[region.triangle_ids]
    face_ids = region.vertex_ids
    remap = -np.ones(mesh.n_vertices, dtype=np.int64)
    remap[face_ids] = np.arange(len(face_ids))
    tri = remap[sub_tri_face]
    verts = mesh.vertices[face_ids]
    on_loop = np.isin(face_ids, region.loop)
    k = len(face_ids)
    if method == "centroid":
        areas = geometry.triangle_areas(verts, tri)
        centroid = (verts[tri].mean(axis=1) * areas[:, None]).sum(axis=0) / areas.sum()
        half = geometry.boundary_edges_directed(tri)
        fan = np.column_stack([half[:, 1], half[:, 0], np.full(len(half), k)])
        vertices = np.vstack([verts, centroid])
        triangles = np.vstack([tri, fan])
        ids = np.append(face_ids, -1)
        fixed = np.append(on_loop, True)
    elif method == "mirror":
        interior = np.flatnonzero(~on_loop)
        copy_of = np.arange(k)
        copy_of[interior] = k + np.arange(len(interior))
        vertices = np.vstack([verts, verts[interior]])
        triangles = np.vstack([tri, copy_of[tri][:, ::-1]])
        ids = np.concatenate([face_ids, -np.ones(len(interior), np.int64)])
        fixed = np.concatenate([on_loop, np.ones(len(interior), bool)])
    else:
        raise RegionError(f"unknown closure method {method!r}; use 'centroid' or 'mirror'")
    return ClosedRegion(np.ascontiguousarray(vertices), np.ascontiguousarray(triangles, dtype=np.int64),
                        ids, fixed, np.arange(len(tri)), method)
