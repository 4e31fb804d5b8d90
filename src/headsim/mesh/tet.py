"""Tetrahedral meshes (SI metres)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from headsim.errors import MeshError
from headsim.mesh import geometry
from headsim.mesh.surface import _frozen_array

#: Region labels used across headsim (per tet or per vertex).
REGION_TISSUE = 0
REGION_BONE = 1
REGION_CUSHION = 2
REGION_SHELL = 3


@dataclass(frozen=True, eq=False)
class TetMesh:
    """Tetrahedral mesh.

    Attributes
    ----------
    vertices : (n, 3) float64, m
    tets : (m, 4) int64, positively oriented (det[b-a, c-a, d-a] > 0)
    tet_region : (m,) int32 region label per tet, or None
    vertex_region : (n,) int32 region label per vertex, or None
    fixed : (n,) bool, vertices held in place (bone side), or None
    name : origin, used in messages

    Construction refuses empty meshes, non-finite coordinates, out-of-range indices and inverted
    or degenerate (zero-volume) tets.
    """

    vertices: np.ndarray
    tets: np.ndarray
    tet_region: np.ndarray | None = None
    vertex_region: np.ndarray | None = None
    fixed: np.ndarray | None = None
    name: str = "tetmesh"

    def __post_init__(self):
        v = _frozen_array(self.vertices, np.float64, "vertices", 3, self.name)
        t = _frozen_array(self.tets, np.int64, "tets", 4, self.name)
        if len(v) == 0 or len(t) == 0:
            raise MeshError(f"{self.name}: empty tet mesh ({len(v)} vertices, {len(t)} tets)")
        if not np.isfinite(v).all():
            raise MeshError(f"{self.name}: NaN/inf vertex coordinates")
        if t.min() < 0 or t.max() >= len(v):
            raise MeshError(f"{self.name}: tet indices must lie in [0, {len(v) - 1}]")
        vol = geometry.tet_signed_volumes(v, t)
        scale = float(np.max(v.max(axis=0) - v.min(axis=0))) or 1.0
        bad = vol <= 1e-15 * scale**3
        if bad.any():
            raise MeshError(
                f"{self.name}: {int(bad.sum())} inverted or degenerate tets (first: tet {int(np.argmax(bad))}, "
                f"volume {vol[np.argmax(bad)]:.3g} m^3)"
            )
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "tets", t)
        for field, n, dtype in (("tet_region", len(t), np.int32), ("vertex_region", len(v), np.int32),
                                ("fixed", len(v), bool)):
            val = getattr(self, field)
            if val is None:
                continue
            arr = np.array(val, dtype=dtype)
            if arr.shape != (n,):
                raise MeshError(f"{self.name}: {field} must have shape ({n},), got {arr.shape}")
            arr.flags.writeable = False
            object.__setattr__(self, field, arr)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_tets(self) -> int:
        return len(self.tets)

    @cached_property
    def rest_volumes(self) -> np.ndarray:
        """(m,) float64, m^3, of the vertices given at construction."""
        return geometry.tet_signed_volumes(self.vertices, self.tets)

    @property
    def volume(self) -> float:
        return float(self.rest_volumes.sum())

    @cached_property
    def edges(self) -> np.ndarray:
        """(e, 2) int64 unique undirected tet edges, i < j."""
        t = self.tets
        pairs = np.concatenate([t[:, [a, b]] for a, b in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))])
        pairs.sort(axis=1)
        return np.unique(pairs, axis=0)

    @cached_property
    def boundary_triangles(self) -> np.ndarray:
        """(k, 3) int64 boundary faces, oriented outwards (normals point out of the body)."""
        t = self.tets
        # faces opposite vertex 0..3, each ordered so its normal points away from the opposite vertex
        faces = np.concatenate([t[:, [1, 2, 3]], t[:, [0, 3, 2]], t[:, [0, 1, 3]], t[:, [0, 2, 1]]])
        key = np.sort(faces, axis=1)
        _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        return faces[counts[inverse.ravel()] == 1]

    def with_vertices(self, vertices: np.ndarray) -> "TetMesh":
        """The same tets at new vertex positions; the topology-only caches (edges, boundary
        triangles) carry over, the position-dependent ones are recomputed."""
        out = replace(self, vertices=vertices)
        for name in ("edges", "boundary_triangles"):
            if name in self.__dict__:
                out.__dict__[name] = self.__dict__[name]
        return out

    def __repr__(self) -> str:
        return f"TetMesh({self.name!r}, {self.n_vertices} vertices, {self.n_tets} tets)"
