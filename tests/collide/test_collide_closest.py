"""TriangleBVH.closest_points against the brute-force reference (Ericson's regions vs projection + edges)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from headsim.collide import TriangleBVH
from headsim.collide._reference import closest_points_bruteforce, icosphere
from headsim.errors import MeshError, ParameterError

# coordinates on a 2^-16 grid: exact ties and degenerate (collinear, repeated-vertex) triangles
# still occur, but no denormal-scale triangles on which the reference's projection is meaningless
_GRID = 2.0**16


def grid_points(shape, scale=1.0):
    """Strategy: float64 array of ``shape`` with entries k / 2^16 * scale, |k| <= 2^16."""
    ints = arrays(np.int64, shape, elements=st.integers(-(2**16), 2**16))
    return ints.map(lambda a: a * (scale / _GRID))


@st.composite
def soup_and_points(draw):
    m = draw(st.integers(1, 40))
    vertices = draw(grid_points((3 * m, 3)))
    triangles = np.arange(3 * m).reshape(m, 3)
    points = draw(grid_points((draw(st.integers(1, 20)), 3), scale=2.0))
    leaf = draw(st.integers(1, 6))
    return vertices, triangles, points, leaf


def _check_consistent(result, vertices, triangles, points):
    """The point is the barycentric combination of its triangle and lies at the stated distance."""
    corners = vertices[triangles[result.triangle]]
    np.testing.assert_allclose(result.barycentric.sum(axis=1), 1.0, atol=1e-12)
    assert (result.barycentric >= -1e-12).all()
    np.testing.assert_allclose(np.einsum("qi,qik->qk", result.barycentric, corners), result.point, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(result.point - points, axis=1), result.distance, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(soup_and_points())
def test_closest_points_match_bruteforce_on_triangle_soups(case):
    vertices, triangles, points, leaf = case
    got = TriangleBVH(vertices, triangles, leaf_size=leaf).closest_points(points)
    want = closest_points_bruteforce(points, vertices, triangles)
    np.testing.assert_allclose(got.distance, want.distance, rtol=0, atol=1e-12)
    _check_consistent(got, vertices, triangles, points)


def test_points_on_the_surface_vertices_and_edges_have_zero_distance():
    v, t = icosphere(2)
    bvh = TriangleBVH(v, t)
    rng = np.random.default_rng(1)
    w = rng.dirichlet([1, 1, 1], size=len(t))
    on_faces = np.einsum("mi,mik->mk", w, v[t])
    edge_mid = 0.5 * (v[t[:, 0]] + v[t[:, 1]])
    for pts in (v, on_faces, edge_mid):
        got = bvh.closest_points(pts)
        assert got.distance.max() < 1e-15
        np.testing.assert_allclose(got.point, pts, atol=1e-15)
    # a point on a face maps to that face (no other triangle is that close)
    got = bvh.closest_points(on_faces)
    assert (got.triangle == np.arange(len(t))).mean() > 0.999
    # a vertex query returns weight 1 on that vertex
    got = bvh.closest_points(v)
    tri_vertices = t[got.triangle]
    k = np.argmax(got.barycentric, axis=1)
    assert (tri_vertices[np.arange(len(v)), k] == np.arange(len(v))).all()


def test_sphere_distance_is_analytic_up_to_the_faceting():
    # Points on rays from the centre of a unit icosphere: the distance to the polyhedron lies
    # between |p| - 1 (circumscribed sphere) and |p| - r_in (inscribed sphere).
    v, t = icosphere(3)
    bvh = TriangleBVH(v, t)
    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    r_in = np.min(np.einsum("mk,mk->m", n / np.linalg.norm(n, axis=1, keepdims=True), v[t[:, 0]]))
    rng = np.random.default_rng(2)
    dirs = rng.normal(size=(500, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    r = rng.uniform(1.2, 3.0, 500)
    d = bvh.closest_points(dirs * r[:, None]).distance
    assert (d >= r - 1 - 1e-12).all() and (d <= r - r_in + 1e-12).all()


def test_max_distance_limits_the_search():
    v, t = icosphere(1)
    bvh = TriangleBVH(v, t)
    p = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 1.05]])
    got = bvh.closest_points(p, max_distance=0.5)
    assert got.triangle[0] == -1 and np.isinf(got.distance[0])
    assert got.triangle[1] >= 0 and got.distance[1] == pytest.approx(0.05, abs=0.05)


def test_bad_input_raises_typed_errors():
    v, t = icosphere(0)
    with pytest.raises(MeshError):
        TriangleBVH(v, t + len(v))
    with pytest.raises(MeshError):
        TriangleBVH(np.full_like(v, np.nan), t)
    with pytest.raises(MeshError):
        TriangleBVH(v, np.zeros((0, 3), int))
    bvh = TriangleBVH(v, t)
    with pytest.raises(ParameterError):
        bvh.closest_points(np.array([[np.nan, 0, 0]]))
    with pytest.raises(ParameterError):
        bvh.closest_points(np.zeros((4, 2)))
    with pytest.raises(MeshError):
        bvh.refit(v[:-1])
