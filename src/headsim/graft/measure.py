"""Measurements between aligned face models (Monkin 2016, seed 001, ch. 6).

- :func:`volume_between`: volume between two aligned face surfaces inside a region of the first.
- :func:`surface_distances`: Hausdorff and mean surface distance (vertex-to-surface, both ways).
- :func:`signed_distances`: per-vertex signed distance of one surface from another (for colour maps).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.collide import TriangleBVH
from headsim.errors import MeshError
from headsim.graft.region import FaceRegion
from headsim.mesh import geometry
from headsim.mesh.surface import SurfaceMesh

__all__ = ["volume_between", "surface_distances", "SurfaceDistances", "signed_distances", "same_connectivity"]


def same_connectivity(a: SurfaceMesh, b: SurfaceMesh) -> bool:
    """True when ``b`` is ``a`` with moved vertices (same vertex count and triangles)."""
    return a.n_vertices == b.n_vertices and a.triangles.shape == b.triangles.shape and bool(
        np.array_equal(a.triangles, b.triangles))


def volume_between(reference: SurfaceMesh, other: SurfaceMesh, region: FaceRegion) -> float:
    """Signed volume, m³, between ``other`` and ``reference`` inside ``region`` (of ``reference``).

    Positive where ``other`` lies outside ``reference`` (on the side of its normals), as after an injection.

    With the same connectivity the volume is exact: the divergence theorem over the closed surface made of
    the region on ``other``, the region on ``reference`` reversed, and the strip of quads between the two
    copies of the loop. Otherwise (two scans) it integrates heights: from the centroid of every region
    triangle a line along the triangle's normal is cast both ways onto ``other``; the nearer hit gives the
    signed height h_t and V = Σ h_t A_t (exact for parallel surfaces, first order in the slope between them).
    """
    if region.mesh is not reference and not np.array_equal(region.mesh.vertices, reference.vertices):
        raise MeshError("the region must be a region of the reference mesh")
    tri = reference.triangles[region.triangle_ids]
    if same_connectivity(reference, other):
        a, b = reference.vertices, other.vertices
        vol = geometry.signed_volume(b, tri) - geometry.signed_volume(a, tri)
        loop = region.loop
        # side strip between the loop on `reference` (a) and on `other` (b), oriented consistently with
        # the region's winding: the loop runs with the region's boundary half-edges.
        half = geometry.boundary_edges_directed(tri)
        directed = {(int(i), int(j)) for i, j in half}
        nxt = np.roll(loop, -1)
        forward = (int(loop[0]), int(nxt[0])) in directed
        i, j = (loop, nxt) if forward else (nxt, loop)
        stacked = np.vstack([a, b])
        n = len(a)
        # quad (i_a, j_a, j_b, i_b) closes the solid b-cap + reversed a-cap
        q1 = np.column_stack([i, j, j + n])
        q2 = np.column_stack([i, j + n, i + n])
        vol += geometry.signed_volume(stacked, np.vstack([q1, q2]))
        return float(vol)
    v = reference.vertices
    centroid = v[tri].mean(axis=1)
    normal = geometry.face_normals(v, tri)
    area = geometry.triangle_areas(v, tri)
    bvh = TriangleBVH(other.vertices, other.triangles)
    reach = float(np.max(reference.extent))
    fwd = bvh.intersect_rays(centroid, normal, reach)
    bwd = bvh.intersect_rays(centroid, -normal, reach)
    h = np.where(fwd.distance <= bwd.distance, fwd.distance, -bwd.distance)
    missed = ~(fwd.hit | bwd.hit)
    if missed.any():
        raise MeshError(f"{int(missed.sum())} of {len(tri)} region triangles have no counterpart on "
                        f"{other.name}; are the models aligned and in the same unit?")
    return float(np.sum(h * area))


@dataclass(frozen=True)
class SurfaceDistances:
    """Vertex-to-surface distances both ways, m.

    hausdorff : max of both directed maxima; mean : mean over all sampled vertices of both directions;
    a_to_b, b_to_a : maxima of each direction.
    """

    hausdorff: float
    mean: float
    a_to_b: float
    b_to_a: float


def surface_distances(a: SurfaceMesh, b: SurfaceMesh, region: FaceRegion | None = None) -> SurfaceDistances:
    """Hausdorff and mean surface distance between ``a`` and ``b`` (vertex samples to exact closest points).

    With ``region`` (a region of ``a``) only the region's vertices of ``a`` and the vertices of ``b`` whose
    closest point on ``a`` lies in the region are compared. Only vertices that belong to a triangle are
    samples: a stray unused vertex is not part of either surface.
    """
    bvh_a = TriangleBVH(a.vertices, a.triangles)
    bvh_b = TriangleBVH(b.vertices, b.triangles)
    ids_a = np.unique(a.triangles) if region is None else np.intersect1d(region.vertex_ids, a.triangles)
    va = a.vertices[ids_a]
    d_ab = bvh_b.closest_points(va).distance
    cp_ba = bvh_a.closest_points(b.vertices[np.unique(b.triangles)])
    d_ba = cp_ba.distance
    if region is not None:
        in_region = np.zeros(a.n_triangles, bool)
        in_region[region.triangle_ids] = True
        d_ba = d_ba[in_region[cp_ba.triangle]]
    both = np.concatenate([d_ab, d_ba])
    return SurfaceDistances(float(both.max()), float(both.mean()), float(d_ab.max()),
                            float(d_ba.max()) if len(d_ba) else 0.0)


def signed_distances(reference: SurfaceMesh, other: SurfaceMesh) -> np.ndarray:
    """(n_other,) float64, m: distance of every vertex of ``other`` from ``reference``, positive on the
    side of ``reference``'s normals."""
    bvh = TriangleBVH(reference.vertices, reference.triangles)
    cp = bvh.closest_points(other.vertices)
    normal = bvh.triangle_normals(cp.triangle)
    side = np.einsum("ij,ij->i", other.vertices - cp.point, normal)
    return np.where(side >= 0, cp.distance, -cp.distance)
