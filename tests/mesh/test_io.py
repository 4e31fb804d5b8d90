"""Mesh I/O: round trips for every format, units, and clear errors for bad files."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from headsim.errors import MeshError, UnitsError
from headsim.mesh import REGION_BONE, REGION_TISSUE, TetMesh
from headsim.mesh.io import load_surface, load_tetmesh, read_surface, save_surface, save_tetmesh
from headsim.mesh.primitives import box, icosphere
from headsim.mesh.units import UnitsWarning


def _triangle_soup(mesh):
    """Order-independent description of a surface: sorted rows of its triangles' corner coordinates."""
    corners = mesh.vertices[mesh.triangles]                       # (m, 3, 3)
    # rotate each triangle so its lexicographically smallest corner comes first (keeps winding)
    keys = corners[:, :, 0] * 1e6 + corners[:, :, 1] * 1e3 + corners[:, :, 2]
    start = np.argmin(keys, axis=1)
    rolled = np.stack([np.roll(c, -s, axis=0) for c, s in zip(corners, start)])
    flat = rolled.reshape(len(rolled), -1)
    return flat[np.lexsort(flat.T[::-1])]


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply", ".msh", ".mesh", ".vtk", ".vtu", ".off"])
@pytest.mark.parametrize("units", ["m", "mm"])
def test_surface_round_trip(tmp_path, suffix, units):
    mesh = icosphere(0.05, 1, center=(0.01, -0.02, 0.03))
    path = save_surface(mesh, tmp_path / f"sphere{suffix}", units=units)
    back = load_surface(path, units=units, expect_head_sized=False)
    assert back.n_triangles == mesh.n_triangles
    assert back.n_vertices == mesh.n_vertices  # STL too: shared corners are merged on reading
    # STL/PLY store float32 coordinates
    atol = 1e-7 if suffix in (".stl", ".ply") else 1e-12
    np.testing.assert_allclose(_triangle_soup(back), _triangle_soup(mesh), atol=atol)
    assert back.signed_volume() == pytest.approx(mesh.signed_volume(), rel=1e-5)


def _labelled_tetmesh():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1.0]]) * 0.01
    t = np.array([[0, 1, 2, 3], [1, 4, 2, 3]])
    return TetMesh(v, t, tet_region=[REGION_TISSUE, REGION_BONE], vertex_region=[0, 1, 0, 1, 3],
                   fixed=[False, True, False, True, False], name="two")


@pytest.mark.parametrize("suffix", [".vtu", ".vtk", ".msh", ".mesh"])
def test_tetmesh_round_trip_keeps_labels(tmp_path, suffix):
    mesh = _labelled_tetmesh()
    back = load_tetmesh(save_tetmesh(mesh, tmp_path / f"t{suffix}", units="mm"), units="mm")
    np.testing.assert_allclose(back.vertices, mesh.vertices, atol=1e-15)
    np.testing.assert_array_equal(back.tets, mesh.tets)
    np.testing.assert_array_equal(back.tet_region, mesh.tet_region)
    np.testing.assert_array_equal(back.vertex_region, mesh.vertex_region)
    if suffix == ".mesh":
        assert back.fixed is None  # Medit has no place for it (documented)
    else:
        np.testing.assert_array_equal(back.fixed, mesh.fixed)


def test_msh_is_written_binary(tmp_path):
    path = save_tetmesh(_labelled_tetmesh(), tmp_path / "t.msh")
    head = path.read_bytes()[:200]
    assert b"$MeshFormat\n4.1 1 8" in head  # file-type 1 = binary


def test_units_convert_to_metres(tmp_path):
    mesh = box((0.1, 0.2, 0.3))
    path = save_surface(mesh, tmp_path / "box.obj", units="mm")
    text = path.read_text()
    assert "300" in text or "150" in text  # coordinates were written in mm
    back = load_surface(path, units="mm")
    np.testing.assert_allclose(back.extent, [0.1, 0.2, 0.3])
    cm = load_surface(path, units="cm", expect_head_sized=False)
    np.testing.assert_allclose(cm.extent, [1.0, 2.0, 3.0])


def test_face_in_mm_read_as_metres_is_flagged(tmp_path, bundled_face):
    path = save_surface(bundled_face, tmp_path / "face_mm.obj", units="mm")
    with pytest.warns(UnitsWarning, match=r"scaled by 0\.001.*m vs mm"):
        wrong = load_surface(path, units="m")
    assert np.max(wrong.extent) == pytest.approx(1000 * np.max(bundled_face.extent), rel=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitsWarning)
        right = load_surface(path, units="mm")
        load_surface(path, units="m", expect_head_sized=False)  # opted out: no warning
    np.testing.assert_allclose(right.vertices, bundled_face.vertices, atol=1e-9)


@pytest.mark.parametrize("factor,hint", [(10.0, "cm vs mm"), (100.0, "m vs cm")])
def test_plausibility_hint_names_the_factor(factor, hint, bundled_face):
    from headsim.mesh.units import check_head_scale

    with pytest.warns(UnitsWarning, match=hint):
        check_head_scale(bundled_face.vertices * factor, source="x")


def test_unknown_unit_is_a_units_error(tmp_path):
    path = save_surface(box(0.2), tmp_path / "b.obj")
    with pytest.raises(UnitsError, match="inch"):
        load_surface(path, units="inch")


def test_missing_file(tmp_path):
    with pytest.raises(MeshError, match=r"nothere\.obj: file not found"):
        load_surface(tmp_path / "nothere.obj")


def test_unknown_format(tmp_path):
    p = tmp_path / "face.xyz"
    p.write_text("1 2 3\n")
    with pytest.raises(MeshError, match=r"face\.xyz: unknown surface mesh format '\.xyz'"):
        load_surface(p)


def test_garbage_file(tmp_path):
    p = tmp_path / "garbage.ply"
    p.write_bytes(b"this is not a ply file\x00\x01")
    with pytest.raises(MeshError, match=r"garbage\.ply: cannot read"):
        load_surface(p)


def test_file_without_triangles(tmp_path):
    p = save_tetmesh(_labelled_tetmesh(), tmp_path / "tets.vtu")
    with pytest.raises(MeshError, match=r"tets\.vtu: no triangles in the file \(cell types: tetra\)"):
        load_surface(p)
    q = save_surface(box(0.1), tmp_path / "surf.vtu")
    with pytest.raises(MeshError, match=r"surf\.vtu: no tetrahedra"):
        load_tetmesh(q)


def test_empty_obj(tmp_path):
    p = tmp_path / "empty.obj"
    p.write_text("# nothing\n")
    with pytest.raises(MeshError, match=r"empty\.obj"):
        load_surface(p)


def test_nan_and_out_of_range_in_files(tmp_path):
    p = tmp_path / "nan.obj"
    p.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match=r"nan\.obj: 1 vertices have NaN/inf coordinates \(first: vertex 1\)"):
        load_surface(p, expect_head_sized=False)
    q = tmp_path / "range.obj"
    q.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    with pytest.raises(MeshError, match=r"range\.obj"):
        load_surface(q, expect_head_sized=False)


def test_quads_are_split(tmp_path):
    p = tmp_path / "quad.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    mesh = load_surface(p, expect_head_sized=False)
    assert mesh.n_triangles == 2
    assert mesh.area == pytest.approx(1.0)
    np.testing.assert_allclose(mesh.face_normals, [[0, 0, 1], [0, 0, 1]])


def test_inverted_tets_in_file_are_refused(tmp_path):
    import meshio

    v = np.eye(4)[:, :3]
    meshio.Mesh(v, [("tetra", np.array([[0, 1, 2, 3]]))]).write(tmp_path / "inv.vtu")
    with pytest.raises(MeshError, match=r"inv\.vtu: 1 inverted or degenerate tets"):
        load_tetmesh(tmp_path / "inv.vtu")


def test_read_surface_reports_repairs(tmp_path):
    mesh = icosphere(0.1, 1)
    flipped = mesh.triangles.copy()
    flipped[:5] = flipped[:5, ::-1]
    from headsim.mesh import SurfaceMesh

    path = save_surface(SurfaceMesh(mesh.vertices, flipped), tmp_path / "f.ply")
    with pytest.raises(MeshError, match=r"f\.ply: invalid mesh: inconsistent winding.*repair=True"):
        load_surface(path)
    loaded = read_surface(path, repair=True)
    assert loaded.repair.flipped_triangles == 5
    assert "inconsistent_winding" in loaded.original_validation.kinds
    assert loaded.validation.ok
