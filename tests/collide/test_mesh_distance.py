"""MeshDistanceField: exact signed distances to a triangle mesh within a coarse grid's band."""

import numpy as np
import pytest

from headsim.collide.distance_field import GridDistanceField
from headsim.collide.mesh_distance import MeshDistanceField
from headsim.errors import MeshError


def _box_mesh(half):
    """Closed cube [−half, half]³, 12 outward triangles."""
    import trimesh

    m = trimesh.creation.box(extents=(2 * half,) * 3)
    assert m.is_winding_consistent and m.volume > 0
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _box_sdf(p, half):
    """Exact signed distance of the cube and its gradient (analytic)."""
    q = np.abs(p) - half
    out = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = q.max(axis=1)
    d = np.where(inside > 0, out, inside)
    g = np.where(inside[:, None] > 0, np.maximum(q, 0.0) / np.maximum(out, 1e-300)[:, None], 0.0)
    k = np.argmax(q, axis=1)
    gi = np.zeros_like(p)
    gi[np.arange(len(p)), k] = 1.0
    g = np.where(inside[:, None] > 0, g, gi) * np.sign(p)
    return d, g


def test_cube_distances_and_normals_are_exact_at_faces_edges_and_corners():
    """A 2 cm cube on a 2 mm grid (band ε = 6 mm): points closer to it than ε − √3 Δs (every corner of their
    cell is a band node), inside and out, in the face, edge and corner regions, read the analytic signed
    distance and its gradient to rounding; the grid alone is off by a tenth of a millimetre and more there."""
    half = 0.01
    v, t = _box_mesh(half)
    f = MeshDistanceField(v, t, spacing=0.002, band=0.006)
    rng = np.random.default_rng(3)
    p = rng.uniform(-half - 0.003, half + 0.003, (40000, 3))
    d_ref, g_ref = _box_sdf(p, half)
    keep = (np.abs(d_ref) > 1e-6) & (np.abs(d_ref) < 0.006 - np.sqrt(3) * 0.002)
    p, d_ref, g_ref = p[keep], d_ref[keep], g_ref[keep]
    corner = (np.abs(p) > half).all(axis=1)
    edge = (np.abs(p) > half).sum(axis=1) == 2
    assert corner.sum() > 100 and edge.sum() > 1000 and (d_ref < 0).sum() > 1000
    d = f.distance(p)
    np.testing.assert_allclose(d, d_ref, rtol=0, atol=1e-15)
    # the gradient is undefined where two faces are equally close inside (the cube's medial planes)
    q = np.sort(np.abs(np.abs(p) - half), axis=1)
    clear = (d_ref > 0) | (q[:, 1] - q[:, 0] > 1e-9)
    np.testing.assert_allclose(f.normal(p)[clear], g_ref[clear], rtol=0, atol=1e-9)
    grid_err = np.abs(f.grid.distance(p) - d_ref).max()
    assert grid_err > 1e-4  # the corners and edges the exact query fixes


def test_head_distances_match_libigl_and_far_points_read_the_grid():
    """The bundled head (open at neck, eyes and mouth): 20,000 points within 6 mm of the skin read libigl's
    pseudo-normal signed distance (an independent implementation of the same definition) to rounding, signs
    included; a point beyond the band reads the coarse grid's value."""
    import igl
    import trimesh

    from headsim.data import head_path

    hm = trimesh.load(head_path(), process=False)
    v, t = np.asarray(hm.vertices, float), np.asarray(hm.faces, np.int64)
    f = MeshDistanceField(v, t, spacing=0.003, band=0.012)
    rng = np.random.default_rng(0)
    tri = rng.integers(0, len(t), 20000)
    w = rng.dirichlet([1.0, 1.0, 1.0], 20000)
    p = (v[t[tri]] * w[:, :, None]).sum(axis=1) + hm.face_normals[tri] * rng.uniform(-0.006, 0.006, (20000, 1))
    ref, *_ = igl.signed_distance(p, v, t, sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
    d = f.distance(p)
    np.testing.assert_allclose(d, ref, rtol=0, atol=1e-15)
    n = f.normal(p)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    assert np.abs(f.grid.distance(p) - ref).max() > 1e-3  # the 3 mm grid alone: mm off at ears, nose, lips
    far = np.array([[0.0, 0.0, 0.5], [0.0, 0.4, 0.0]])
    np.testing.assert_array_equal(f.distance(far), f.grid.distance(far))


def test_bad_meshes_are_refused():
    with pytest.raises(MeshError):
        MeshDistanceField(np.zeros((3, 3)), np.zeros((0, 3), np.int64))
    with pytest.raises(MeshError):
        MeshDistanceField(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))


def test_grid_is_the_from_mesh_grid():
    v, t = _box_mesh(0.01)
    f = MeshDistanceField(v, t, spacing=0.002)
    g = GridDistanceField.from_mesh(v, t, 0.002)
    np.testing.assert_array_equal(f.grid.values, g.values)
    assert f.band == g.band == pytest.approx(0.006)
