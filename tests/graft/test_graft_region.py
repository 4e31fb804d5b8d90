"""Markers → closed loop → region, closed region models (Monkin 2016 §5.3), marker files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from headsim.errors import RegionError
from headsim.graft import (Markers, close_region, load_markers, region_from_loop, region_from_markers,
                           save_markers)
from headsim.mesh.primitives import icosphere
from headsim.mesh.surface import SurfaceMesh


def test_bundled_cheeks_are_closed_regions_without_mesh_boundary(face, cheek_markers):
    boundary = np.unique(np.concatenate(face.boundary_loops))
    for name, markers in cheek_markers.items():
        r = region_from_markers(face, markers)
        assert 100 < len(r.vertex_ids) < 1000, name
        assert not np.isin(r.vertex_ids, boundary).any()
        # the loop is a closed chain of mesh edges
        e = {tuple(x) for x in face.edges.tolist()}
        for a, b in zip(r.loop, np.roll(r.loop, -1)):
            assert (min(a, b), max(a, b)) in e
        # region triangles' own boundary is exactly the loop
        sub, ids = face.submesh(r.vertex_ids)
        assert set(ids[np.concatenate(sub.boundary_loops)]) == set(r.loop.tolist())
        assert 15e-4 < r.area < 30e-4  # 15–30 cm²


def test_left_and_right_cheeks_are_mirror_images(face, cheek_markers):
    left = region_from_markers(face, cheek_markers["left_cheek"])
    right = region_from_markers(face, cheek_markers["right_cheek"])
    assert left.area == pytest.approx(right.area, rel=0.05)
    assert face.vertices[left.vertex_ids, 0].min() > 0 > face.vertices[right.vertex_ids, 0].max()


def test_vertex_id_markers_give_the_same_region(face, left_cheek):
    again = region_from_markers(face, Markers(vertex_ids=left_cheek.marker_vertices, name="ids"))
    np.testing.assert_array_equal(again.triangle_ids, left_cheek.triangle_ids)


def test_region_errors(face, left_cheek):
    v = face.vertices
    with pytest.raises(RegionError, match="at least 3"):
        Markers(points=v[:2])
    ids = left_cheek.marker_vertices
    with pytest.raises(RegionError, match="fewer than 3"):
        region_from_markers(face, Markers(vertex_ids=[ids[0], ids[1], ids[0]]))
    # figure-eight order: the loop crosses itself
    crossing = Markers(vertex_ids=[ids[0], ids[3], ids[1], ids[4]], name="cross")
    with pytest.raises(RegionError, match="crosses|touches"):
        region_from_markers(face, crossing)
    # markers in millimetres on a metre mesh are far from the surface
    with pytest.raises(RegionError, match="from the surface"):
        region_from_markers(face, Markers(points=v[ids] * 1000.0))
    # a loop around the left eye encloses an opening of the mesh
    eye = face.boundary_loops
    eye_loop = min((l for l in eye if face.vertices[l, 0].mean() > 0.02 and face.vertices[l, 1].mean() > 0.02),
                   key=len)
    c = face.vertices[eye_loop].mean(axis=0)
    around = c + 0.022 * np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    around[:, 2] = c[2] + 0.01
    with pytest.raises(RegionError, match="opening|boundary"):
        region_from_markers(face, Markers(points=around, name="eye"))


def test_empty_region_is_refused():
    """A loop around a single triangle encloses no vertex."""
    s = icosphere(1.0, 2)
    t = s.triangles[0]
    with pytest.raises(RegionError, match="empty|no vertex"):
        region_from_loop(s, t)


def test_closed_mesh_takes_the_smaller_side():
    s = icosphere(1.0, 3)
    ring = np.flatnonzero(np.abs(s.vertices[:, 2] - 0.7) < 0.2)
    # markers around the cap z > 0.7
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    pts = np.column_stack([0.7 * np.cos(ang), 0.7 * np.sin(ang), np.full(8, 0.71)])
    r = region_from_markers(s, Markers(points=pts))
    assert len(ring) > 0
    assert r.area < 0.5 * s.area
    assert s.vertices[r.interior_vertex_ids, 2].min() > 0.5


@pytest.mark.parametrize("method", ["centroid", "mirror"])
def test_closed_models_are_closed_and_consistently_oriented(left_cheek, method):
    c = close_region(left_cheek, method)
    m = SurfaceMesh(c.vertices, c.triangles)
    assert m.is_closed
    # consistent orientation: every directed half-edge appears once
    half = np.concatenate([c.triangles[:, [0, 1]], c.triangles[:, [1, 2]], c.triangles[:, [2, 0]]])
    assert len(np.unique(half, axis=0)) == len(half)
    assert c.fixed[np.isin(c.face_ids, left_cheek.loop)].all()
    assert c.fixed[c.face_ids < 0].all()
    assert not c.fixed[np.isin(c.face_ids, left_cheek.interior_vertex_ids)].any()
    if method == "mirror":
        assert c.volume == pytest.approx(0.0, abs=1e-15)
    else:
        assert c.volume > 0  # a cheek bulges outwards


def test_markers_file_round_trip_and_units(tmp_path, cheek_markers):
    path = tmp_path / "m.json"
    save_markers(cheek_markers, path)
    again = load_markers(path)
    np.testing.assert_allclose(again["left_cheek"].points, cheek_markers["left_cheek"].points)
    mm = {"units": "mm", "points": (cheek_markers["left_cheek"].points * 1000).tolist()}
    (tmp_path / "one.json").write_text(json.dumps(mm))
    one = load_markers(tmp_path / "one.json")
    np.testing.assert_allclose(one["one"].points, cheek_markers["left_cheek"].points, rtol=1e-12)
    (tmp_path / "bad.json").write_text("{nope")
    with pytest.raises(RegionError):
        load_markers(tmp_path / "bad.json")
    with pytest.raises(RegionError):
        load_markers(tmp_path / "missing.json")
