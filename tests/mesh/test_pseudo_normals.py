"""The pseudo-normals of the exact mesh distance (edge pseudo-normals of mesh.geometry, angle-weighted vertex
normals of MeshDistanceField), on a cube where both are known."""

import numpy as np
import trimesh

from headsim.collide import MeshDistanceField
from headsim.mesh.geometry import edge_pseudo_normals, face_normals, vertex_normals


def _cube():
    m = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def test_cube_corner_normals_are_the_diagonals_whatever_the_triangulation():
    """At a cube corner the three faces meet at right angles: their angle weights are equal (π/2 each, split
    between one or two triangles as the faces' diagonals fall), so the pseudo-normal is the corner's diagonal.
    The area-weighted normal of the same corner is not (a corner touched by two triangles of one face and
    one of another weighs them 2:1)."""
    v, t = _cube()
    n = MeshDistanceField(v, t, spacing=0.5)._vertex_normal
    np.testing.assert_allclose(n, v / np.sqrt(3.0), atol=1e-14)
    assert np.abs(vertex_normals(v, t) - v / np.sqrt(3.0)).max() > 0.2


def test_cube_edge_pseudo_normals():
    """A cube edge (two faces at right angles): the bisector (n₁ + n₂)/√2; a face diagonal (two triangles of one
    face): the face normal."""
    v, t = _cube()
    e = edge_pseudo_normals(v, t)
    fn = face_normals(v, t)
    for i in range(len(t)):
        for k in range(3):
            a, b = v[t[i, k]], v[t[i, (k + 1) % 3]]
            mid = 0.5 * (a + b)
            if np.count_nonzero(np.isclose(np.abs(mid), 1.0)) == 2:  # on a cube edge
                expect = np.where(np.isclose(np.abs(mid), 1.0), np.sign(mid), 0.0) / np.sqrt(2.0)
            else:  # a face diagonal
                expect = fn[i]
            np.testing.assert_allclose(e[i, k], expect, atol=1e-14)


def test_open_mesh_boundary_edge_takes_its_one_face():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]])
    t = np.array([[0, 1, 2], [1, 3, 2]])
    e = edge_pseudo_normals(v, t)
    fn = face_normals(v, t)
    np.testing.assert_allclose(e[0, 0], fn[0], atol=1e-15)  # edge 0–1: boundary
    shared = (fn[0] + fn[1]) / np.linalg.norm(fn[0] + fn[1])
    np.testing.assert_allclose(e[0, 1], shared, atol=1e-15)  # edge 1–2: shared
    np.testing.assert_allclose(e[1, 2], shared, atol=1e-15)  # the same edge seen from triangle 1 (2–1)
