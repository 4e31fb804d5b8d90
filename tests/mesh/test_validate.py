"""Validation finds every defect class on small handmade meshes; repairs fix exactly the safe ones."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from headsim.errors import MeshError
from headsim.mesh import SurfaceMesh
from headsim.mesh.primitives import box, icosphere
from headsim.mesh.validate import MeshDefectError, check_surface, repair_surface, validate_surface

SQUARE_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
SQUARE_T = np.array([[0, 1, 2], [0, 2, 3]])


def _defect(mesh, kind):
    report = validate_surface(mesh)
    assert kind in report.kinds, report.summary()
    with pytest.raises(MeshDefectError, match=mesh.name) as info:
        check_surface(mesh)
    assert kind in info.value.report.kinds
    return info.value


def test_valid_meshes_pass(bundled_face, make_grid):
    for mesh in (SurfaceMesh(SQUARE_V, SQUARE_T), icosphere(1.0, 2), box((1, 2, 3), 3), make_grid(), bundled_face):
        report = check_surface(mesh)
        assert report.ok and not report.defects, report.summary()
    assert validate_surface(bundled_face).n_boundary_loops == 4  # outline, mouth, two eyes
    assert validate_surface(icosphere(1.0, 1)).is_closed


def test_empty_nan_out_of_range_are_refused_at_construction():
    with pytest.raises(MeshError, match=r"sq: empty mesh"):
        SurfaceMesh(np.zeros((0, 3)), np.zeros((0, 3), int), name="sq")
    bad = SQUARE_V.copy()
    bad[2, 1] = np.inf
    with pytest.raises(MeshError, match=r"sq: 1 vertices have NaN/inf coordinates \(first: vertex 2\)"):
        SurfaceMesh(bad, SQUARE_T, name="sq")
    with pytest.raises(MeshError, match=r"sq: triangle indices must lie in \[0, 3\], got \[0, 4\]"):
        SurfaceMesh(SQUARE_V, [[0, 1, 4]], name="sq")
    with pytest.raises(MeshError, match=r"sq: triangles must have shape"):
        SurfaceMesh(SQUARE_V, [[0, 1, 2, 3]], name="sq")


def test_degenerate_triangles():
    v = np.vstack([SQUARE_V, [[2, 0, 0]]])
    # collinear (0, 1, 4) and repeated index (2, 2, 3)
    err = _defect(SurfaceMesh(v, [[0, 1, 2], [0, 2, 3], [0, 1, 4], [2, 2, 3]], name="deg.obj"), "degenerate_triangles")
    assert "2 degenerate (zero-area) triangles (first: 2, 3)" in str(err)
    assert "repairable" in str(err)


def test_duplicate_triangles():
    err = _defect(SurfaceMesh(SQUARE_V, [[0, 1, 2], [0, 2, 3], [2, 0, 1]], name="dup"), "duplicate_triangles")
    assert "1 duplicate triangles (first: 2)" in str(err)


def test_duplicate_vertices():
    # two triangles meeting along an edge whose vertices are stored twice
    v = np.vstack([SQUARE_V, SQUARE_V[[0, 2]] + 1e-13])
    err = _defect(SurfaceMesh(v, [[0, 1, 2], [4, 5, 3]], name="dupv"), "duplicate_vertices")
    assert "2 duplicate vertices" in str(err)


def test_unused_vertices_are_only_a_note():
    v = np.vstack([SQUARE_V, [[5, 5, 5]]])
    report = check_surface(SurfaceMesh(v, SQUARE_T))
    assert report.ok and report.kinds == {"unreferenced_vertices"}


def test_non_manifold_edge():
    v = np.vstack([SQUARE_V, [[0.5, 0.5, 1.0]]])
    mesh = SurfaceMesh(v, [[0, 1, 2], [0, 2, 3], [2, 0, 4]], name="fin.stl")
    err = _defect(mesh, "non_manifold_edges")
    assert "1 non-manifold edges shared by more than 2 triangles (first: 0-2)" in str(err)
    assert "no safe automatic repair" in str(err) or "mesh editor" in str(err)


def test_non_manifold_vertex():
    # two triangles touching at one vertex (bow tie)
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]], dtype=float)
    err = _defect(SurfaceMesh(v, [[0, 1, 2], [0, 3, 4]], name="bowtie"), "non_manifold_vertices")
    assert "first: 0" in str(err)


def test_inconsistent_winding(make_grid):
    g = make_grid(3, 3)
    tri = g.triangles.copy()
    tri[4] = tri[4, ::-1]
    err = _defect(SurfaceMesh(g.vertices, tri, name="w"), "inconsistent_winding")
    assert "1 triangles would need flipping" in str(err)


def test_inward_closed_surface():
    s = icosphere(1.0, 1)
    _defect(SurfaceMesh(s.vertices, s.triangles[:, ::-1], name="inv"), "inward_orientation")


def test_moebius_strip_is_non_orientable():
    k = 12
    ang = np.linspace(0, 2 * np.pi, k, endpoint=False)
    centre = np.stack([np.cos(ang), np.sin(ang), np.zeros(k)], 1)
    half = 0.5 * ang
    w = 0.2 * np.stack([np.cos(half) * np.cos(ang), np.cos(half) * np.sin(ang), np.sin(half)], 1)
    v = np.concatenate([centre - w, centre + w])  # i: lower, k + i: upper
    tris = []
    for i in range(k - 1):
        tris += [[i, i + 1, k + i + 1], [i, k + i + 1, k + i]]
    # the last quad closes the strip with a half twist: lower(k-1) -> upper(0), upper(k-1) -> lower(0)
    tris += [[k - 1, k, 0], [k - 1, 0, 2 * k - 1]]
    mesh = SurfaceMesh(v, tris, name="moebius")
    report = validate_surface(mesh)
    assert "non_orientable" in report.kinds
    with pytest.raises(MeshDefectError, match="non-orientable"):
        check_surface(mesh)


def test_repair_fixes_everything_safe_and_reports_it():
    s = icosphere(1.0, 1)
    v = np.vstack([s.vertices, s.vertices[:3] + 1e-12, [[9.0, 9, 9]]])   # 3 duplicates + 1 unused
    n = s.n_vertices
    tri = s.triangles.copy()
    tri[tri == 0] = n                     # use the duplicate of vertex 0 in some triangles
    tri[::7] = tri[::7, ::-1]             # flip every 7th triangle
    tri = np.vstack([tri, [[1, 1, 2]], tri[:2]])  # one degenerate, two duplicate triangles
    broken = SurfaceMesh(v, tri, name="broken")
    before = validate_surface(broken)
    assert {"duplicate_vertices", "degenerate_triangles", "duplicate_triangles", "inconsistent_winding",
            "unreferenced_vertices"} <= before.kinds
    fixed, rep = repair_surface(broken)
    assert check_surface(fixed).defects == ()
    assert rep.merged_vertices == 3
    assert rep.dropped_degenerate_triangles == 1
    assert rep.dropped_duplicate_triangles == 2
    assert rep.dropped_unreferenced_vertices == 1
    assert rep.flipped_triangles == len(tri[::7][: len(s.triangles[::7])])
    assert fixed.n_vertices == s.n_vertices and fixed.n_triangles == s.n_triangles
    assert fixed.signed_volume() == pytest.approx(s.signed_volume())
    np.testing.assert_array_equal(rep.vertex_map[: n], np.arange(n))
    assert "merged 3 duplicate vertices" in rep.summary()


def test_repair_turns_inward_closed_surface_outwards():
    s = box((1, 2, 3), 2)
    fixed, rep = repair_surface(SurfaceMesh(s.vertices, s.triangles[:, ::-1]))
    assert rep.flipped_triangles == s.n_triangles
    np.testing.assert_array_equal(fixed.triangles, s.triangles)


def test_repair_leaves_non_manifold_edges():
    v = np.vstack([SQUARE_V, [[0.5, 0.5, 1.0]]])
    fixed, _ = repair_surface(SurfaceMesh(v, [[0, 1, 2], [0, 2, 3], [2, 0, 4]]))
    assert "non_manifold_edges" in validate_surface(fixed).kinds


@settings(max_examples=25, deadline=None)
@given(flips=st.lists(st.booleans(), min_size=80, max_size=80), root_flipped=st.booleans())
def test_repair_undoes_random_flips_of_a_closed_surface(flips, root_flipped):
    s = icosphere(1.0, 1)   # 80 triangles
    mask = np.array(flips)
    mask[0] = root_flipped
    tri = np.where(mask[:, None], s.triangles[:, ::-1], s.triangles)
    fixed, rep = repair_surface(SurfaceMesh(s.vertices, tri))
    np.testing.assert_array_equal(fixed.triangles, s.triangles)
    assert rep.flipped_triangles == int(mask.sum())


@settings(max_examples=25, deadline=None)
@given(flips=st.lists(st.booleans(), min_size=24, max_size=24))
def test_repair_of_open_surface_keeps_majority_winding(make_grid, flips):
    g = make_grid(3, 4)  # 24 triangles
    mask = np.array(flips)
    tri = np.where(mask[:, None], g.triangles[:, ::-1], g.triangles)
    fixed, rep = repair_surface(SurfaceMesh(g.vertices, tri))
    assert validate_surface(fixed).ok
    normals_z = fixed.face_normals[:, 2]
    assert np.all(np.abs(normals_z) == 1) and len(set(normals_z)) == 1
    expect_up = mask.sum() <= len(mask) / 2   # fewer flipped than kept: keep the original (up)
    if mask.sum() != len(mask) / 2:
        assert (normals_z[0] > 0) == expect_up
    assert rep.flipped_triangles == min(mask.sum(), len(mask) - mask.sum())
