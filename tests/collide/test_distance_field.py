"""Signed distance fields (Sobottka §7.2): analytic fields, trilinear grid, exact narrow band from meshes."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.collide._reference_fibres import point_mesh_distance_bruteforce
from headsim.collide.distance_field import (
    GridDistanceField,
    PlaneField,
    SphereField,
    mesh_distance_field,
    obstacle_contacts,
)
from headsim.collide.fibres import FibreSet
from headsim.errors import MeshError, ParameterError

L_POLYGON = np.array([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], float)  # CCW, reflex at (1, 1)


def l_prism():
    """Closed L-shaped prism (z in [0, 1]) with outward triangles: it has convex and concave edges."""
    n = len(L_POLYGON)
    v = np.vstack([np.c_[L_POLYGON, np.zeros(n)], np.c_[L_POLYGON, np.ones(n)]])
    tris = []
    for i in range(n):
        j = (i + 1) % n
        tris += [[i, j, n + j], [i, n + j, n + i]]
    fan = [(3, 4, 5), (3, 5, 0), (3, 0, 1), (3, 1, 2)]  # from the reflex vertex
    tris += [[n + a, n + b, n + c] for a, b, c in fan] + [[a, c, b] for a, b, c in fan]
    return v, np.array(tris)


def inside_l_prism(p):
    x, y, z = p.T
    in_l = (x > 0) & (y > 0) & (x < 2) & (y < 2) & ((x < 1) | (y < 1))
    return in_l & (z > 0) & (z < 1)


def test_l_prism_is_closed_and_outward():
    import trimesh

    v, t = l_prism()
    m = trimesh.Trimesh(v, t, process=False)
    assert m.is_watertight and m.volume == pytest.approx(3.0)


@pytest.fixture(scope="module")
def l_field():
    v, t = l_prism()
    return v, t, GridDistanceField.from_mesh(v, t, spacing=0.05, band=0.15)


def test_band_nodes_equal_brute_force_distance(l_field):
    v, t, f = l_field
    ijk = np.argwhere(np.abs(f.values) < f.band)
    sel = ijk[np.random.default_rng(0).choice(len(ijk), 300, replace=False)]
    want, _ = point_mesh_distance_bruteforce(f.node_positions(sel), v, t)
    np.testing.assert_allclose(np.abs(f.values[tuple(sel.T)]), want, rtol=0, atol=1e-12)


def test_band_is_complete(l_field):
    """Every node whose true distance is within the band got its value (none left at ±far)."""
    v, t, f = l_field
    ijk = np.argwhere(np.ones(f.shape, bool))
    sel = ijk[np.random.default_rng(1).choice(len(ijk), 400, replace=False)]
    d, _ = point_mesh_distance_bruteforce(f.node_positions(sel), v, t)
    vals = f.values[tuple(sel.T)]
    near = d < f.band
    np.testing.assert_allclose(np.abs(vals[near]), d[near], atol=1e-12)
    assert (np.abs(vals[~near]) == f.far).all()


def test_signs_at_convex_and_concave_edges(l_field):
    v, t, f = l_field
    ijk = np.argwhere(np.abs(f.values) < f.band)
    p = f.node_positions(ijk)
    vals = f.values[tuple(ijk.T)]
    off_surface = np.abs(vals) > 1e-9
    truth = inside_l_prism(p)
    np.testing.assert_array_equal(vals[off_surface] < 0, truth[off_surface])
    # nodes whose closest feature is the concave vertical edge through (1, 1) and convex edges
    concave = (np.hypot(p[:, 0] - 1, p[:, 1] - 1) < 0.15) & (p[:, 2] > 0.2) & (p[:, 2] < 0.8)
    convex = (np.hypot(p[:, 0] - 2, p[:, 1]) < 0.15) & (p[:, 2] > 0.2) & (p[:, 2] < 0.8)
    for sel in (concave & off_surface, convex & off_surface):
        assert (vals[sel] < 0).any() and (vals[sel] > 0).any()
        np.testing.assert_array_equal(vals[sel] < 0, truth[sel])
    # and through the interpolated field between nodes
    q = np.array([[1.05, 1.05, 0.5], [0.95, 0.95, 0.5], [2.05, -0.05, 0.5], [1.95, 0.05, 0.5]])
    np.testing.assert_array_equal(f.distance(q) < 0, [False, True, False, True])


def test_interpolated_distance_within_the_lipschitz_bound(l_field):
    """Trilinear interpolation of a 1-Lipschitz function errs by at most √3 Δs; typically far less."""
    v, t, f = l_field
    rng = np.random.default_rng(2)
    p = rng.uniform(-0.05, 2.05, size=(300, 3)) * [1, 1, 0.55]
    d, _ = point_mesh_distance_bruteforce(p, v, t)
    keep = d < f.band - np.sqrt(3) * f.spacing  # whole cell inside the band
    sign = np.where(inside_l_prism(p), -1.0, 1.0)
    err = np.abs(f.distance(p[keep]) - sign[keep] * d[keep])
    assert keep.sum() > 50
    assert err.max() <= np.sqrt(3) * f.spacing
    assert np.median(err) < 0.1 * f.spacing


def test_trilinear_is_exact_for_linear_fields_and_gradient_converges():
    plane = PlaneField((0.1, 0.2, 0.3), (1.0, 2.0, 2.0))
    grid = GridDistanceField.from_function(plane.distance, [-1, -1, -1], [1, 1, 1], 0.1)
    p = np.random.default_rng(3).uniform(-0.9, 0.9, size=(100, 3))
    np.testing.assert_allclose(grid.distance(p), plane.distance(p), atol=1e-13)
    np.testing.assert_allclose(grid.gradient(p), plane.gradient(p), atol=1e-10)
    sphere = SphereField((0, 0, 0), 0.5)
    q = np.random.default_rng(4).normal(size=(200, 3))
    q = 0.5 * q / np.linalg.norm(q, axis=1, keepdims=True) * 1.2
    errs = []
    for h in (0.04, 0.02):
        g = GridDistanceField.from_function(sphere.distance, [-1, -1, -1], [1, 1, 1], h)
        errs.append(np.abs(g.normal(q, "forward") - sphere.normal(q)).max())
        assert np.abs(g.normal(q, "central") - sphere.normal(q)).max() < errs[-1]
    assert errs[1] < 0.7 * errs[0]  # forward differences: first order in Δs


def test_outside_the_grid_reads_far():
    g = GridDistanceField.from_function(SphereField().distance, [-2, -2, -2], [2, 2, 2], 0.5)
    assert g.distance([[5.0, 0, 0]])[0] == g.far


def test_obstacle_contacts_against_a_plane():
    # one fibre dipping below the floor y = 0, radius 0.01
    nodes = np.array([[0, 0.05, 0], [0.1, 0.005, 0], [0.2, -0.02, 0], [0.3, 0.05, 0]], float)
    f = FibreSet(nodes, [0, 4], 0.01)
    floor = PlaneField((0, 0, 0), (0, 1, 0))
    c = obstacle_contacts(f, floor)
    np.testing.assert_array_equal(c.segment_a, [1, 2])  # nodes 1 and 2 (start of segments 1, 2)
    np.testing.assert_allclose(c.depth, [0.005, 0.03])
    np.testing.assert_allclose(c.normal, [[0, 1, 0], [0, 1, 0]])
    np.testing.assert_allclose(c.point_b[:, 1], 0.0, atol=1e-15)
    np.testing.assert_allclose(c.point_a[:, 1], nodes[1:3, 1] - 0.01)
    assert c.obstacle.all() and (c.segment_b == -1).all()
    # finer sampling finds the same deepest contact; a level lifts the floor
    assert obstacle_contacts(f, floor, samples_per_segment=4).depth.max() == pytest.approx(0.03)
    assert len(obstacle_contacts(f, floor, level=0.06)) == 4


def test_grid_field_of_a_sphere_mesh_gives_the_same_contacts_as_the_analytic_sphere():
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=0.1)
    field = mesh_distance_field(m, spacing=0.004, band=0.02)
    rng = np.random.default_rng(5)
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    nodes = np.repeat(d, 2, axis=0) * np.tile([0.095, 0.15], 50)[:, None]
    f = FibreSet(nodes, np.arange(51) * 2, 0.001)
    c = obstacle_contacts(f, field)
    np.testing.assert_array_equal(c.segment_a, np.arange(50))
    np.testing.assert_allclose(c.normal, d, atol=0.05)
    np.testing.assert_allclose(c.depth, 0.006, atol=0.002)  # mesh chord error ≲ 0.5 mm


def test_bundled_head_field():
    import trimesh

    from headsim.data import head_path

    m = trimesh.load(head_path(), process=False)
    v, t = np.asarray(m.vertices), np.asarray(m.faces, np.int64)
    f = GridDistanceField.from_mesh(v, t, spacing=0.006, band=0.018)
    ijk = np.argwhere(np.abs(f.values) < f.band)
    sel = ijk[np.random.default_rng(6).choice(len(ijk), 20, replace=False)]
    want, _ = point_mesh_distance_bruteforce(f.node_positions(sel), v, t)
    np.testing.assert_allclose(np.abs(f.values[tuple(sel.T)]), want, atol=1e-12)
    # the scalp: 3 mm outside is positive, 3 mm inside negative; the skull centre is inside
    top = np.argsort(v[:, 1])[-200:]
    n = m.vertex_normals[top]
    assert (f.distance(v[top] + 0.003 * n) > 0).all()
    assert (f.distance(v[top] - 0.003 * n) < 0).all()
    assert f.distance([[0.0, 0.05, 0.0]])[0] < 0


def test_bad_input():
    with pytest.raises(MeshError):
        GridDistanceField.from_mesh(np.zeros((3, 3)), np.zeros((0, 3), int), 0.1)
    with pytest.raises(ParameterError):
        GridDistanceField.from_mesh(*l_prism(), spacing=-1.0)
    with pytest.raises(ParameterError):
        SphereField(radius=0.0)
    with pytest.raises(ParameterError):
        PlaneField().distance([[np.nan, 0, 0]])
