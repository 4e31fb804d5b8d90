"""Fibre geometry: CSR layout, global segment indices, adjacency, the seed's total fibre, contacts."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.collide.fibres import FibreSet, capsule_contacts, fibres_from_arrays, fibres_from_rods
from headsim.errors import ParameterError


def three_fibres():
    nodes = np.arange(3 * 9, dtype=float).reshape(9, 3) * 0.01
    return FibreSet(nodes, [0, 3, 5, 9], 0.001)  # 2 + 1 + 3 segments


def test_segment_tables():
    f = three_fibres()
    assert (f.n_fibres, f.n_nodes, f.n_segments) == (3, 9, 6)
    np.testing.assert_array_equal(f.segment_offsets, [0, 2, 3, 6])
    np.testing.assert_array_equal(f.segment_fibre, [0, 0, 1, 2, 2, 2])
    np.testing.assert_array_equal(f.segment_start, [0, 1, 3, 5, 6, 7])
    np.testing.assert_array_equal(f.segment_local, [0, 1, 0, 0, 1, 2])
    np.testing.assert_array_equal(f.segment_previous, [-1, 0, -1, -1, 3, 4])
    np.testing.assert_array_equal(f.segment_next, [1, -1, -1, 4, 5, -1])
    p, q = f.segment_endpoints()
    np.testing.assert_array_equal(q[3], f.nodes[6])


def test_adjacency_is_same_fibre_neighbours_only():
    f = three_fibres()
    a = np.array([0, 0, 1, 2, 3, 3])
    b = np.array([0, 1, 2, 3, 5, 4])
    # 1–2 and 2–3 are consecutive global ids on different fibres: not adjacent
    np.testing.assert_array_equal(f.adjacent(a, b), [True, True, False, False, False, True])


def test_total_fibre_is_boustrophedon():
    f = three_fibres()  # 2, 1, 3 segments: root→tip, tip→root, root→tip
    np.testing.assert_array_equal(f.total_fibre_order(), [0, 1, 2, 3, 4, 5])
    np.testing.assert_array_equal(f.total_fibre_order([2, 0, 1]), [3, 4, 5, 1, 0, 2])
    g = FibreSet(np.zeros((9, 3)), [0, 3, 6, 9], 0.1)  # 2, 2, 2 segments
    np.testing.assert_array_equal(g.total_fibre_order(), [0, 1, 3, 2, 4, 5])
    with pytest.raises(ParameterError):
        f.total_fibre_order([0, 0, 1])


def test_per_node_radius_becomes_enclosing_segment_radius():
    nodes = np.zeros((5, 3))
    nodes[:, 0] = np.arange(5)
    f = fibres_from_arrays(nodes, [0, 2, 5], [1.0, 2.0, 3.0, 5.0, 4.0])
    np.testing.assert_array_equal(f.radius, [2.0, 5.0, 5.0])
    g = fibres_from_rods(nodes, [0, 2, 5], [1.0, 2.0, 3.0])  # per segment
    np.testing.assert_array_equal(g.radius, [1.0, 2.0, 3.0])


@pytest.mark.parametrize(
    "nodes, offsets, radius",
    [
        (np.zeros((4, 2)), [0, 4], 1.0),
        (np.full((4, 3), np.nan), [0, 4], 1.0),
        (np.zeros((4, 3)), [0, 1, 4], 1.0),  # a one-node fibre
        (np.zeros((4, 3)), [0, 3], 1.0),  # offsets do not end at N
        (np.zeros((4, 3)), [0, 4], -1.0),
        (np.zeros((4, 3)), [0, 4], [1.0, 1.0]),
    ],
)
def test_bad_input_is_refused(nodes, offsets, radius):
    with pytest.raises(ParameterError):
        FibreSet(nodes, offsets, radius)


def test_capsule_contact_record_of_crossing_capsules():
    # A along x at z = 0, B along y at z = 0.15; radii 0.1 → depth 0.05, normal from B to A = −z
    nodes = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0.15], [0, 1, 0.15]], float)
    f = FibreSet(nodes, [0, 2, 4], 0.1)
    c = capsule_contacts(f, [[0, 1]], [[0.5, 0.5]])
    np.testing.assert_allclose(c.normal[0], [0, 0, -1])
    assert c.depth[0] == pytest.approx(0.05)
    np.testing.assert_allclose(c.point_a[0], [0, 0, 0.1])
    np.testing.assert_allclose(c.point_b[0], [0, 0, 0.05])
    assert (c.body_a[0], c.body_b[0], c.obstacle[0]) == (0, 1, False)


def test_crossing_axes_get_a_perpendicular_normal():
    nodes = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0]], float)
    f = FibreSet(nodes, [0, 2, 4], 0.1)
    c = capsule_contacts(f, [[0, 1]], [[0.5, 0.5]])
    np.testing.assert_allclose(np.abs(c.normal[0]), [0, 0, 1])
    assert c.depth[0] == pytest.approx(0.2)


@pytest.fixture(scope="module")
def head_field():
    import trimesh

    from headsim.collide.distance_field import GridDistanceField
    from headsim.data import head_path

    m = trimesh.load(head_path(), process=False)
    return GridDistanceField.from_mesh(np.asarray(m.vertices), np.asarray(m.faces), 0.003, band=0.011)


def test_head_scene_fibres_are_inextensible_and_outside_the_head(head_field):
    from headsim.collide.fibre_scenes import head_field_band, head_scene

    f = head_scene(300, 12, length=0.06, layer_thickness=0.005, field=head_field, seed=2)
    p, q = f.segment_endpoints()
    np.testing.assert_allclose(np.linalg.norm(q - p, axis=1), 0.06 / 12, rtol=1e-12)
    phi = head_field.distance(f.nodes).reshape(300, 13)
    assert (phi[:, 1:] > 2 * 35e-6 * 0.5).all()  # off the skin (the target is 2 r + clearance)
    assert np.median(phi[:, -1]) > 0.004  # most tips reach their layer
    with pytest.raises(ParameterError, match="band"):
        head_scene(300, 12, layer_thickness=0.04, field=head_field)
    assert head_field_band(0.005) <= head_field.band


def test_numba_contact_records_equal_the_numpy_reference():
    from headsim.collide._reference_fibres import capsule_contacts_numpy

    rng = np.random.default_rng(3)
    nodes = rng.normal(size=(40, 3))
    nodes[10:12] = [[0, 0, 0], [1, 0, 0]]  # segment 9 (fibre 1): crosses segment 14 axis to axis
    nodes[15:17] = [[0.5, -1, 0], [0.5, 1, 0]]
    nodes[20:22] = [[0, 1, 0], [1, 1, 0]]  # segment 18: parallel to and on segment 9's axis line
    nodes[25:27] = [[0, 0, 0], [0.95, 0, 0.1]]
    f = FibreSet(nodes, [0, 10, 20, 30, 40], 0.1)
    pairs = np.array([[9, 14], [0, 30], [3, 33], [9, 18], [19, 23]])
    params = rng.uniform(size=(5, 2))
    params[0] = [0.5, 0.5]
    params[3] = [0.0, 0.0]
    nodes2 = nodes.copy()
    nodes2[20:22] = [[0, 0, 0], [1, 0, 0]]  # now segment 18 lies on segment 9: parallel, zero distance
    for x in (nodes, nodes2):
        got = capsule_contacts(f, pairs, params, nodes=x)
        want = capsule_contacts_numpy(f, pairs, params, nodes=x)
        for name in want.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    np.testing.assert_allclose(np.linalg.norm(got.normal, axis=1), 1.0)


def test_scalp_roots_keep_their_minimum_spacing():
    """Dart throwing on the scalp: with ``min_spacing`` no two roots are closer (the independent samples of
    the default put some of 300 roots within 14 µm of each other, closer than a 70 µm fibre); the default is
    unchanged; a spacing the scalp cannot hold and a non-finite one are refused."""
    import trimesh
    from scipy.spatial import cKDTree

    from headsim.collide.fibre_scenes import ROOT_DENSITY, scalp_roots
    from headsim.data import head_path

    m = trimesh.load(head_path(), process=False)
    v, t = np.asarray(m.vertices), np.asarray(m.faces)

    def nearest(p):
        return cKDTree(p).query(p, k=2)[0][:, 1]

    free, free_n = scalp_roots(v, t, 300, seed=0)
    again, _ = scalp_roots(v, t, 300, seed=0, min_spacing=0.0)
    np.testing.assert_array_equal(free, again)
    assert nearest(free).min() < 70e-6  # the defect the spacing removes
    s = 0.5 / np.sqrt(ROOT_DENSITY)  # 0.28 mm
    spaced, spaced_n = scalp_roots(v, t, 300, seed=0, min_spacing=s)
    assert spaced.shape == (300, 3) and spaced_n.shape == (300, 3)
    assert nearest(spaced).min() >= s
    np.testing.assert_allclose(np.linalg.norm(spaced_n, axis=1), 1.0, rtol=1e-12)
    # the same scalp band: the spaced roots span the heights of the independent ones
    assert abs(spaced[:, 1].min() - free[:, 1].min()) < 2e-3
    with pytest.raises(ParameterError, match="cannot hold"):
        scalp_roots(v, t, 300, min_spacing=3.0 / np.sqrt(ROOT_DENSITY))
    with pytest.raises(ParameterError, match="min_spacing"):
        scalp_roots(v, t, 30, min_spacing=float("nan"))
