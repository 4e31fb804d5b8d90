"""Ray and segment casts (Möller–Trumbore over the BVH) against brute-force plane intersection."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from headsim.collide import TriangleBVH
from headsim.collide._reference import (
    icosphere,
    intersect_rays_all_bruteforce,
    intersect_rays_bruteforce,
    random_star_shape,
)
from headsim.errors import ParameterError

# coordinates on a 2^-16 grid: hypothesis still finds exact ties (rays through edges and vertices,
# rays in a triangle's plane) but no denormal-scale triangles whose hit test is ill-conditioned
_GRID = 2.0**16


def grid_points(shape, scale=1.0):
    """Strategy: float64 array of ``shape`` with entries k / 2^16 * scale, |k| <= 2^16."""
    ints = arrays(np.int64, shape, elements=st.integers(-(2**16), 2**16))
    return ints.map(lambda a: a * (scale / _GRID))


def _well_shaped(vertices, triangles):
    """(m,) bool: area not tiny compared with the longest edge (hit test well posed)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    longest = np.max([np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
                      np.linalg.norm(a - c, axis=1)], axis=0)
    return area2 > 1e-3 * longest**2


@st.composite
def soup_and_rays(draw):
    m = draw(st.integers(1, 40))
    vertices = draw(grid_points((3 * m, 3)))
    triangles = np.arange(3 * m).reshape(m, 3)
    triangles = triangles[_well_shaped(vertices, triangles)]  # drop slivers and degenerate ones
    assume(len(triangles) > 0)
    q = draw(st.integers(1, 20))
    origins = draw(grid_points((q, 3), scale=2.0))
    directions = draw(grid_points((q, 3)))
    directions[np.linalg.norm(directions, axis=1) < 1e-3] = (0.0, 0.0, 1.0)
    max_distance = draw(st.sampled_from([np.inf, 0.5, 2.0]))
    return vertices, triangles, origins, directions, max_distance


def _assert_hits_match(got, want, all_want):
    np.testing.assert_array_equal(got.hit, want.hit)
    np.testing.assert_allclose(got.distance[got.hit], want.distance[want.hit], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(got.point[got.hit], want.point[want.hit], atol=1e-9)
    # the triangle must match wherever the first hit is unambiguous
    for i in np.nonzero(got.hit)[0]:
        d, ids = all_want[i]
        if len(d) == 1 or d[1] - d[0] > 1e-9:
            assert got.triangle[i] == ids[0]
            np.testing.assert_allclose(got.normal[i], want.normal[i], atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(soup_and_rays())
def test_first_hits_match_bruteforce_on_triangle_soups(case):
    v, t, o, d, md = case
    bvh = TriangleBVH(v, t, leaf_size=2)
    got = bvh.intersect_rays(o, d, max_distance=md)
    want = intersect_rays_bruteforce(o, d, v, t, max_distance=md)
    _assert_hits_match(got, want, intersect_rays_all_bruteforce(o, d, v, t, max_distance=md))


@settings(max_examples=100, deadline=None)
@given(soup_and_rays())
def test_all_hits_match_bruteforce_on_triangle_soups(case):
    v, t, o, d, md = case
    got = TriangleBVH(v, t).intersect_rays_all(o, d, max_distance=md)
    want = intersect_rays_all_bruteforce(o, d, v, t, max_distance=md)
    np.testing.assert_array_equal(got.count, [len(w[0]) for w in want])
    for i, (dist, ids) in enumerate(want):
        s = slice(got.offsets[i], got.offsets[i + 1])
        np.testing.assert_allclose(got.distance[s], dist, rtol=1e-9, atol=1e-12)
        assert set(got.triangle[s]) == set(ids)
        assert (np.diff(got.distance[s]) >= 0).all()
        assert (got.ray[s] == i).all()


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_segments_match_bruteforce_on_closed_meshes(seed):
    v, t = random_star_shape(seed, 2)
    rng = np.random.default_rng(seed)
    a = rng.uniform(-2.5, 2.5, (100, 3))
    b = rng.uniform(-2.5, 2.5, (100, 3))
    length = np.linalg.norm(b - a, axis=1)
    got = TriangleBVH(v, t).intersect_segments(a, b)
    want = intersect_rays_bruteforce(a, b - a, v, t, max_distance=length)
    _assert_hits_match(got, want, intersect_rays_all_bruteforce(a, b - a, v, t, max_distance=length))
    assert (got.distance[got.hit] <= length[got.hit] + 1e-12).all()
    every = TriangleBVH(v, t).intersect_segments_all(a, b)
    want_all = intersect_rays_all_bruteforce(a, b - a, v, t, max_distance=length)
    np.testing.assert_array_equal(every.count, [len(w[0]) for w in want_all])
    np.testing.assert_allclose(every.distance, np.concatenate([w[0] for w in want_all]), rtol=1e-9, atol=1e-12)
    # a closed surface is crossed an even number of times between two outside points
    outside = ~TriangleBVH(v, t).contains(np.vstack([a, b]))
    both_out = outside[: len(a)] & outside[len(a):]
    assert (every.count[both_out] % 2 == 0).all()


def _grid_patch(n=4):
    """n × n unit squares in the plane z = 0, each split along a diagonal (alternating)."""
    xs = np.arange(n + 1, dtype=float)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    v = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    idx = lambda i, j: i * (n + 1) + j  # noqa: E731
    tris = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            tris += [(a, b, c), (a, c, d)] if (i + j) % 2 == 0 else [(a, b, d), (b, c, d)]
    return v, np.array(tris)


@pytest.mark.parametrize("rotated", [False, True])
def test_rays_through_vertices_and_edges_never_miss(rotated):
    # Rays perpendicular to a triangulated patch, on a grid that passes exactly through every vertex,
    # every edge and every diagonal: each must hit (watertight), at the right distance, once in the
    # first-hit query.
    v, t = _grid_patch(4)
    s = np.linspace(0.0, 4.0, 33)
    gx, gy = np.meshgrid(s, s, indexing="ij")
    o = np.column_stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    d = np.tile([0.0, 0.0, -1.0], (len(o), 1))
    if rotated:  # inexact coordinates: rounding decides which side of an edge a ray falls on
        rng = np.random.default_rng(5)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        shift = rng.normal(size=3)
        v, o, d = v @ q.T + shift, o @ q.T + shift, d @ q.T
    got = TriangleBVH(v, t).intersect_rays(o, d)
    assert got.hit.all()
    np.testing.assert_allclose(got.distance, 1.0, atol=1e-12)
    # the reported triangle contains the hit point
    corners = v[t[got.triangle]]
    np.testing.assert_allclose(np.einsum("qi,qik->qk", got.barycentric, corners), got.point, atol=1e-12)
    assert (got.barycentric >= -1e-9).all()


def test_ray_through_a_shared_vertex_of_a_closed_mesh():
    v, t = icosphere(2)
    bvh = TriangleBVH(v, t)
    o = 3.0 * v  # from outside straight through each vertex to the centre
    got = bvh.intersect_rays(o, -v)
    assert got.hit.all()
    np.testing.assert_allclose(got.distance, 2.0, atol=1e-12)
    np.testing.assert_allclose(got.point, v, atol=1e-12)
    # the hit triangle is one of the vertex's triangles
    assert all(i in t[tri] for i, tri in enumerate(got.triangle))
    # the outward normal is met head-on
    assert (np.einsum("qk,qk->q", got.normal, v) > 0).all()
    # every hit: first at the vertex (each adjacent triangle), last at the antipodal vertex
    all_hits = bvh.intersect_rays_all(o, -v)
    valence = np.bincount(t.ravel(), minlength=len(v))
    for i in range(len(v)):
        d = all_hits.distance[all_hits.offsets[i]:all_hits.offsets[i + 1]]
        assert np.sum(np.abs(d - 2.0) < 1e-12) == valence[i]
        np.testing.assert_allclose(d[-1], 4.0, atol=1e-12)


def test_ray_parallel_to_a_triangle_or_along_an_edge_misses_that_triangle():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]])
    t = np.array([[0, 1, 2], [1, 3, 2]])  # a tent: edge 1-2 shared, second triangle tilted
    bvh = TriangleBVH(v, t)
    o = np.array([
        [-1.0, 0.2, 0.0],   # in the plane of triangle 0, crossing it: parallel → no hit on 0
        [-1.0, 0.2, -0.1],  # parallel to triangle 0, below it; passes under the tilted one
        [1.5, -0.5, 0.0],   # along the shared edge 1→2 (in the plane of triangle 0), starting beyond 1
    ])
    d = np.array([[1.0, 0, 0], [1.0, 0, 0], [-1.0, 1.0, 0.0]])
    got = bvh.intersect_rays(o, d)
    want = intersect_rays_bruteforce(o, d, v, t)
    np.testing.assert_array_equal(got.hit, want.hit)
    # ray 0 enters the tilted triangle through the shared edge (x + y = 1 at z = 0); ray 1 misses;
    # ray 2 lies in both planes (along the edge): parallel to both, no hit
    np.testing.assert_array_equal(got.hit, [True, False, False])
    assert got.triangle[0] == 1
    np.testing.assert_allclose(got.point[0], [0.8, 0.2, 0.0], atol=1e-15)
    # the tilted triangle is entered through its edge 1-2 by the first ray
    np.testing.assert_allclose(got.distance[got.hit], want.distance[want.hit], atol=1e-12)


def test_bad_rays_raise():
    v, t = icosphere(0)
    bvh = TriangleBVH(v, t)
    with pytest.raises(ParameterError):
        bvh.intersect_rays(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ParameterError):
        bvh.intersect_rays(np.zeros((2, 3)), np.ones((3, 3)))
    with pytest.raises(ParameterError):
        bvh.intersect_rays(np.zeros((1, 3)), np.ones((1, 3)), max_distance=-1.0)
