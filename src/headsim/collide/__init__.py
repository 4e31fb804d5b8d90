"""Collision queries: BVH over triangles, closest points, inside/outside, ray casts, heightmaps,
distance fields."""
