"""Collision queries: BVH over triangles, closest points, inside/outside, ray casts, heightmaps,
distance fields.

- :class:`TriangleBVH` — build once, :meth:`~TriangleBVH.refit` after deformation; closest points,
  winding number / ``contains``, signed distance, first-hit and all-hits ray and segment casts
  (Möller–Trumbore, Heinze §3.3.3).
- :class:`Heightmap` — the seed's approximate detector (Heinze §3.3.1), for comparison.
"""

from headsim.collide.bvh import ClosestPoints, RayHitList, RayHits, TriangleBVH
from headsim.collide.heightmap import Heightmap

__all__ = ["TriangleBVH", "ClosestPoints", "RayHits", "RayHitList", "Heightmap"]
