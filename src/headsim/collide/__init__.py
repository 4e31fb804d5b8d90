"""Collision queries: BVH over triangles, closest points, inside/outside, ray casts, heightmaps,
distance fields (grid, analytic, and exact-near-the-mesh :class:`MeshDistanceField`).

- :class:`TriangleBVH` — build once, :meth:`~TriangleBVH.refit` after deformation; closest points,
  winding number / ``contains``, signed distance, first-hit and all-hits ray and segment casts
  (Möller–Trumbore, Heinze §3.3.3).
- :class:`Heightmap` — the seed's approximate detector (Heinze §3.3.1), for comparison.
"""

from headsim.collide.bvh import ClosestPoints, RayHitList, RayHits, TriangleBVH
from headsim.collide.heightmap import Heightmap

__all__ = ["TriangleBVH", "ClosestPoints", "RayHits", "RayHitList", "Heightmap"]

# fibre collision detection (Sobottka 2008 ch. 7): fibres, bounding volumes, fibre BVHs, distance fields
from headsim.collide.bounding_volumes import AABB, KDOP, OBB, BoundingVolume, Sphere, kdop_directions
from headsim.collide.distance_field import (
    GridDistanceField,
    PlaneField,
    SphereField,
    mesh_distance_field,
    obstacle_contacts,
)
from headsim.collide.mesh_distance import MeshDistanceField
from headsim.collide.fibre_bvh import VARIANTS, FibreBVH, QueryStats, RebuildPolicy, fibre_self_contacts
from headsim.collide.fibres import FibreContacts, FibreSet, fibres_from_arrays, fibres_from_rods

__all__ += [
    "AABB", "KDOP", "OBB", "Sphere", "BoundingVolume", "kdop_directions",
    "GridDistanceField", "PlaneField", "SphereField", "mesh_distance_field", "obstacle_contacts", "MeshDistanceField",
    "FibreBVH", "VARIANTS", "QueryStats", "RebuildPolicy", "fibre_self_contacts",
    "FibreSet", "FibreContacts", "fibres_from_arrays", "fibres_from_rods",
]
