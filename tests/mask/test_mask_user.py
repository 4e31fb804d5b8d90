"""User masks: open membranes with a wall thickness, closed bodies, rigid regions, clear errors."""

import numpy as np
import pytest

from headsim.errors import MeshError, ParameterError, RegionError, UnitsError
from headsim.mask import extrude_shell, load_user_mask, place_mask
from headsim.mesh import REGION_SHELL, SurfaceMesh
from headsim.mesh.geometry import tet_signed_volumes
from headsim.mesh.io import save_surface
from headsim.mesh.primitives import icosphere


def cushion_band(n_around=48, n_up=6, r_skin=0.03, r_back=0.025, depth=0.02) -> SurfaceMesh:
    """An open conical band (two boundary loops), like a cushion membrane: the skin side at z = 0,
    the back (shell side) at z = depth; normals point outwards (away from the axis)."""
    t = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    s = np.linspace(0, 1, n_up)
    r = r_skin + (r_back - r_skin) * s
    v = np.concatenate([np.column_stack([rr * np.cos(t), rr * np.sin(t), np.full(n_around, ss * depth)])
                        for rr, ss in zip(r, s)])
    tri = []
    for j in range(n_up - 1):
        for i in range(n_around):
            a, b = j * n_around + i, j * n_around + (i + 1) % n_around
            c, d = b + n_around, a + n_around
            tri += [[a, b, c], [a, c, d]]
    return SurfaceMesh(v, np.array(tri), name="band")


def test_band_fixture_is_open_and_outward():
    band = cushion_band()
    assert len(band.boundary_loops) == 2
    # normals point away from the axis
    c = band.vertices[band.triangles].mean(axis=1)
    assert (np.einsum("ij,ij->i", band.face_normals[:, :2], c[:, :2]) > 0).all()


def test_extrude_shell_gives_a_wall_of_the_given_thickness():
    band = cushion_band()
    tm = extrude_shell(band, 2e-3, layers=2)
    assert (tet_signed_volumes(tm.vertices, tm.tets) > 0).all()
    assert tm.n_vertices == 3 * band.n_vertices and tm.n_tets == 3 * 2 * band.n_triangles
    # volume of a thin wall: area x thickness, to the curvature correction t / (2 R) ~ 4 %
    assert tm.volume == pytest.approx(band.area * 2e-3, rel=0.06)
    inner = tm.vertices[2 * band.n_vertices:]
    shrink = np.hypot(band.vertices[:, 0], band.vertices[:, 1]) - np.hypot(inner[:, 0], inner[:, 1])
    assert np.median(shrink) == pytest.approx(2e-3, rel=0.05)


def test_open_mask_file_with_a_plane_cut(tmp_path):
    band = cushion_band()
    path = save_surface(band.scaled(1e3), tmp_path / "cushion.stl", units="m")     # written in mm
    mask = load_user_mask(path, "mm", rigid=((0, 0, 17.0e-3), (0, 0, -1.0)), thickness=1.5e-3)
    tm = mask.tetmesh
    z = tm.vertices[:, 2]
    np.testing.assert_array_equal(tm.fixed, z > 17e-3)          # behind the plane (normal towards the face: -z)
    assert (tm.vertex_region[tm.fixed] == REGION_SHELL).all()
    assert not tm.fixed[mask.contact_triangles].any()
    np.testing.assert_allclose(mask.airway_axis, [0, 0, -1])
    assert mask.kind == "nasal" and mask.size is None


def test_open_mask_with_a_vertex_set(tmp_path):
    band = cushion_band()
    back_loop = np.flatnonzero(band.vertices[:, 2] > 0.0199)
    mask = load_user_mask(band, rigid=back_loop, thickness=1e-3, layers=1)
    tm = mask.tetmesh
    assert tm.fixed.sum() == 2 * len(back_loop)                  # the loop on both faces of the wall
    # default axis: from the rigid part to the soft part, here -z (towards the skin side)
    assert mask.airway_axis[2] < -0.99


def test_user_mask_errors(tmp_path):
    band = cushion_band()
    with pytest.raises(MeshError, match="wall thickness"):
        load_user_mask(band, rigid=((0, 0, 0.017), (0, 0, -1.0)))
    with pytest.raises(RegionError, match="empty"):
        load_user_mask(band, rigid=((0, 0, 1.0), (0, 0, -1.0)), thickness=1e-3)
    with pytest.raises(RegionError, match="whole mask"):
        load_user_mask(band, rigid=((0, 0, -1.0), (0, 0, -1.0)), thickness=1e-3)
    with pytest.raises(RegionError, match="rigid region"):
        load_user_mask(band, thickness=1e-3)
    with pytest.raises(RegionError):
        load_user_mask(band, rigid=np.array([band.n_vertices + 5]), thickness=1e-3)
    with pytest.raises(UnitsError):
        load_user_mask(band.scaled(100.0), rigid=((0, 0, 1.7), (0, 0, -1.0)), thickness=1e-3)
    with pytest.raises(MeshError, match="folds"):
        extrude_shell(icosphere(0.004, 2), 6e-3)


def test_closed_mask_body_is_tetrahedralised(tmp_path):
    pytest.importorskip("pytetwild")
    pytest.importorskip("pyvista")
    body = icosphere(0.025, 2)
    path = save_surface(body.scaled(1e3), tmp_path / "body.obj", units="m")
    mask = load_user_mask(path, "mm", rigid=((0, 0, 0.01), (0, 0, -1.0)), target_edge=8e-3)
    tm = mask.tetmesh
    np.testing.assert_array_equal(tm.fixed, tm.vertices[:, 2] > 0.01)
    assert 0 < tm.fixed.sum() < tm.n_vertices
    with pytest.raises(ParameterError, match="no wall thickness"):
        load_user_mask(body, rigid=((0, 0, 0.01), (0, 0, -1.0)), thickness=1e-3)
    # a vertex set is carried over to the remeshed body by proximity
    fine = icosphere(0.025, 3)                                     # edges ~4 mm: reach ~6 mm
    top = np.flatnonzero(fine.vertices[:, 2] > 0.015)
    m2 = load_user_mask(fine, rigid=top, target_edge=8e-3)
    z = m2.tetmesh.vertices[:, 2]
    assert (z[m2.tetmesh.fixed] > 0.015 - 6.5e-3).all()
    assert m2.tetmesh.fixed[np.argmax(z)]


def test_user_mask_can_be_placed(neutral_face, neutral_landmarks):
    """A user cushion (band, 60 mm wide) placed automatically 2 cm in front of the nose."""
    band = cushion_band(r_skin=0.03, r_back=0.026)
    mask = load_user_mask(band, rigid=((0, 0, 0.017), (0, 0, -1.0)), thickness=1.5e-3,
                          airway_center=(0, 0, 0.0), up=(0, 1, 0))
    pl = place_mask(mask, neutral_face, neutral_landmarks)
    assert pl.min_gap == pytest.approx(0.02, abs=1e-9)
