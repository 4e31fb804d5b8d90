"""Closed-surface tetrahedralisation (fTetWild default, gmsh optional) and tet quality measures."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from headsim.errors import MeshError, ParameterError
from headsim.mesh import SurfaceMesh
from headsim.mesh.primitives import box, icosphere
from headsim.mesh.quality import tet_dihedral_angles, tet_quality, tet_radius_ratio
from headsim.mesh.tetra import tetrahedralize_surface


def _has_gmsh() -> bool:
    if importlib.util.find_spec("gmsh") is None:
        return False
    try:
        import gmsh  # noqa: F401  (needs the system GL/X libraries)
    except OSError:
        return False
    return True


def test_quality_of_reference_tets():
    regular = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1.0]])
    t = np.array([[0, 2, 1, 3]])
    np.testing.assert_allclose(np.degrees(tet_dihedral_angles(regular, t)), np.degrees(np.arccos(1 / 3)))
    np.testing.assert_allclose(tet_radius_ratio(regular, t), 1.0)
    corner = np.eye(4)[[3, 0, 1, 2], :3]          # (0,0,0), e_x, e_y, e_z
    ang = np.sort(np.degrees(tet_dihedral_angles(corner, np.array([[0, 1, 2, 3]]))[0]))
    np.testing.assert_allclose(ang, [54.7356103] * 3 + [90] * 3)
    np.testing.assert_allclose(tet_radius_ratio(corner, np.array([[0, 1, 2, 3]])), np.sqrt(3) - 1)


def test_tetwild_sphere_volume_within_its_envelope():
    r = 0.05
    s = icosphere(r, 2)
    mesh = tetrahedralize_surface(s, target_edge=0.02)
    assert np.all(mesh.rest_volumes > 0)
    # fTetWild keeps its boundary within eps * diagonal (eps = 1e-3) of the input, so the volume may
    # differ by at most area * eps * diagonal
    envelope = 1e-3 * np.linalg.norm(s.extent)
    assert abs(mesh.volume - s.signed_volume()) <= s.area * envelope
    # ... and against the true sphere, by at most that plus the surface's own discretisation error
    exact = 4 / 3 * np.pi * r**3
    assert abs(mesh.volume - exact) <= abs(s.signed_volume() - exact) + s.area * envelope
    # the boundary of the tet mesh is closed and encloses the same volume
    boundary = SurfaceMesh(mesh.vertices, mesh.boundary_triangles)
    assert boundary.is_closed and boundary.signed_volume() == pytest.approx(mesh.volume, rel=1e-12)
    assert tet_quality(mesh).min_dihedral_deg > 5.0


@pytest.mark.skipif(not _has_gmsh(), reason="optional gmsh extra not installed")
def test_gmsh_keeps_the_surface_exactly():
    s = box((0.04, 0.03, 0.02), 3)
    mesh = tetrahedralize_surface(s, target_edge=0.01, method="gmsh")
    np.testing.assert_array_equal(mesh.vertices[: s.n_vertices], s.vertices)
    assert mesh.volume == pytest.approx(0.04 * 0.03 * 0.02, rel=1e-12)
    assert np.all(mesh.rest_volumes > 0)


def test_open_or_inward_or_broken_surfaces_are_refused(make_grid):
    with pytest.raises(MeshError, match="grid: tetrahedralisation needs a closed surface"):
        tetrahedralize_surface(make_grid(2, 2))
    s = icosphere(0.05, 1)
    with pytest.raises(MeshError, match="inward"):
        tetrahedralize_surface(SurfaceMesh(s.vertices, s.triangles[:, ::-1], name="inv"))
    with pytest.raises(ParameterError, match="unknown tetrahedralisation method"):
        tetrahedralize_surface(s, method="tetgen")
    with pytest.raises(ParameterError, match="target_edge"):
        tetrahedralize_surface(s, target_edge=-1.0)
