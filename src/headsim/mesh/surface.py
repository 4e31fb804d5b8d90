"""Triangle surface meshes (SI metres)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from headsim.errors import MeshError
from headsim.mesh import geometry


def _frozen_array(a, dtype, what: str, ncols: int, source: str) -> np.ndarray:
    try:
        arr = np.array(a, dtype=dtype, order="C")
    except (TypeError, ValueError) as e:
        raise MeshError(f"{source}: {what} cannot be read as {np.dtype(dtype).name}: {e}") from None
    if arr.ndim != 2 or arr.shape[1] != ncols:
        raise MeshError(f"{source}: {what} must have shape (n, {ncols}), got {arr.shape}")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class SurfaceMesh:
    """Triangle surface mesh.

    Attributes
    ----------
    vertices : (n, 3) float64, m
    triangles : (m, 3) int64 vertex indices, counter-clockwise seen from the outside (normal side)
    name : where the mesh came from (file name), used in error messages

    Construction checks what every algorithm needs (non-empty, finite, indices in range). Topological
    defects (degenerate or non-manifold faces, inconsistent winding) are checked by
    :func:`headsim.mesh.validate_surface`, which the loaders call.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    name: str = "mesh"

    def __post_init__(self):
        v = _frozen_array(self.vertices, np.float64, "vertices", 3, self.name)
        t = _frozen_array(self.triangles, np.int64, "triangles", 3, self.name)
        if len(v) == 0 or len(t) == 0:
            raise MeshError(f"{self.name}: empty mesh ({len(v)} vertices, {len(t)} triangles)")
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any():
            raise MeshError(
                f"{self.name}: {int(bad.sum())} vertices have NaN/inf coordinates (first: vertex {int(np.argmax(bad))})"
            )
        if t.min() < 0 or t.max() >= len(v):
            raise MeshError(
                f"{self.name}: triangle indices must lie in [0, {len(v) - 1}], got [{t.min()}, {t.max()}]"
            )
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "triangles", t)

    # --- sizes -----------------------------------------------------------------------------------
    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64, m: min and max corner of the axis-aligned bounding box."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @property
    def extent(self) -> np.ndarray:
        """(3,) float64, m: bounding-box side lengths."""
        b = self.bounds
        return b[1] - b[0]

    # --- geometry --------------------------------------------------------------------------------
    @cached_property
    def face_normals(self) -> np.ndarray:
        """(m, 3) float64 unit normals (zero rows for degenerate triangles)."""
        return geometry.face_normals(self.vertices, self.triangles)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """(n, 3) float64 area-weighted unit vertex normals."""
        return geometry.vertex_normals(self.vertices, self.triangles)

    @cached_property
    def triangle_areas(self) -> np.ndarray:
        """(m,) float64, m^2."""
        return geometry.triangle_areas(self.vertices, self.triangles)

    @cached_property
    def vertex_areas(self) -> np.ndarray:
        """(n,) float64, m^2 (one third of each adjacent triangle)."""
        return geometry.vertex_areas(self.vertices, self.triangles)

    @property
    def area(self) -> float:
        """Total area, m^2."""
        return float(self.triangle_areas.sum())

    @cached_property
    def edges(self) -> np.ndarray:
        """(e, 2) int64 unique undirected edges, i < j."""
        return self._edges_and_counts[0]

    @cached_property
    def _edges_and_counts(self) -> tuple[np.ndarray, np.ndarray]:
        return geometry.unique_edges(self.triangles)

    @property
    def edge_face_count(self) -> np.ndarray:
        """(e,) int64 triangles per edge, aligned with :attr:`edges`."""
        return self._edges_and_counts[1]

    @cached_property
    def boundary_loops(self) -> list[np.ndarray]:
        """Closed boundary loops (vertex id arrays), longest first; empty for a closed surface."""
        return geometry.boundary_loops(self.triangles)

    @property
    def is_closed(self) -> bool:
        """True when every edge has exactly two triangles."""
        return bool(np.all(self.edge_face_count == 2))

    def signed_volume(self) -> float:
        """Enclosed volume, m^3 (positive for outward normals). Requires a closed surface."""
        if not self.is_closed:
            raise MeshError(f"{self.name}: volume needs a closed surface ({len(self.boundary_loops)} boundary loops)")
        return geometry.signed_volume(self.vertices, self.triangles)

    @cached_property
    def adjacency(self):
        """(n, n) scipy CSR vertex adjacency."""
        return geometry.vertex_adjacency(self.n_vertices, self.edges)

    # --- derived meshes --------------------------------------------------------------------------
    def with_vertices(self, vertices: np.ndarray) -> "SurfaceMesh":
        """Same connectivity, new positions (validated again)."""
        return replace(self, vertices=vertices)

    def submesh(self, vertex_ids: np.ndarray, *, name: str | None = None) -> tuple["SurfaceMesh", np.ndarray]:
        """Triangles whose three vertices are all in ``vertex_ids``, re-indexed.

        Returns
        -------
        SurfaceMesh, and (k,) int64 the original id of each new vertex.
        """
        keep = np.zeros(self.n_vertices, dtype=bool)
        keep[np.asarray(vertex_ids, dtype=np.int64)] = True
        tri = self.triangles[keep[self.triangles].all(axis=1)]
        if len(tri) == 0:
            raise MeshError(f"{self.name}: the vertex set spans no triangle")
        used = np.unique(tri)
        remap = -np.ones(self.n_vertices, dtype=np.int64)
        remap[used] = np.arange(len(used))
        return SurfaceMesh(self.vertices[used], remap[tri], name=name or f"{self.name}[sub]"), used

    def scaled(self, factor: float) -> "SurfaceMesh":
        return replace(self, vertices=self.vertices * factor)

    def __repr__(self) -> str:
        return f"SurfaceMesh({self.name!r}, {self.n_vertices} vertices, {self.n_triangles} triangles)"
