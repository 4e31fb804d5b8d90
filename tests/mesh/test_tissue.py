"""Tissue layer (Heinze §2.3, §2.3.1): conforming, positive, volume and depth as geometry predicts."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.errors import MeshError, ParameterError
from headsim.mesh import REGION_BONE, REGION_TISSUE, SurfaceMesh
from headsim.mesh.primitives import icosphere
from headsim.mesh.quality import tet_quality
from headsim.mesh.tissue import TissueOptions, build_tissue_layer, extrude_tissue_layer


def _boundary_face_count(tets: np.ndarray) -> int:
    faces = np.sort(np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]], tets[:, [0, 1, 2]]]), axis=1)
    _, counts = np.unique(faces, axis=0, return_counts=True)
    assert counts.max() <= 2  # no face shared by three tets
    return int((counts == 1).sum())


def _check_structure(layer, face_n_boundary_edges: int):
    mesh, n, k = layer.mesh, layer.n_skin, layer.layers
    m = len(layer.skin_triangles)
    assert mesh.n_vertices == (k + 1) * n and mesh.n_tets == 3 * k * m
    assert np.all(mesh.rest_volumes > 0)
    np.testing.assert_array_equal(mesh.fixed, np.arange(mesh.n_vertices) >= k * n)
    np.testing.assert_array_equal(mesh.vertex_region == REGION_BONE, mesh.fixed)
    assert np.all(mesh.tet_region == REGION_TISSUE)
    # conforming: the only boundary faces are skin + bone triangles + two per side-wall quad per layer
    assert _boundary_face_count(mesh.tets) == 2 * m + 2 * k * face_n_boundary_edges
    # the bone vertex of each skin vertex lies exactly `thickness` along the inward direction
    depth = mesh.vertices[layer.bone_vertex_ids] - mesh.vertices[layer.skin_vertex_ids]
    np.testing.assert_allclose(np.linalg.norm(depth, axis=1), layer.thickness, rtol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", depth, layer.inward), layer.thickness, rtol=1e-12)



def test_flat_grid_gives_exact_slab(make_grid):
    g = make_grid(8, 6, spacing=0.005)
    layer = extrude_tissue_layer(g, thickness=0.004, layers=2, use_cache=False)
    _check_structure(layer, face_n_boundary_edges=2 * (8 + 6))
    assert layer.mesh.volume == pytest.approx(g.area * 0.004, rel=1e-12)
    np.testing.assert_allclose(layer.mesh.vertices[layer.bone_vertex_ids, 2], -0.004)  # normals +z: bone below
    assert not layer.reduced.any() and len(layer.trimmed_triangles) == 0
    np.testing.assert_array_equal(layer.face_vertex_ids, np.arange(g.n_vertices))
    np.testing.assert_array_equal(layer.mesh.vertices[: g.n_vertices], g.vertices)


def test_per_vertex_thickness(make_grid):
    g = make_grid(6, 6, spacing=0.005)
    h = 0.003 + 0.02 * g.vertices[:, 0]   # 3 mm .. 3.6 mm, slope 0.02 < limit
    layer = extrude_tissue_layer(g, thickness=h, layers=3, use_cache=False)
    np.testing.assert_allclose(layer.thickness, h)
    # straight prisms over a flat grid: volume = sum of triangle area x mean corner thickness
    expect = np.sum(g.triangle_areas * h[g.triangles].mean(axis=1))
    assert layer.mesh.volume == pytest.approx(expect, rel=1e-12)


def test_sphere_shell_volume_matches_the_offset_formula():
    r, h = 0.05, 0.01
    s = icosphere(r, 3)
    layer = extrude_tissue_layer(s, thickness=h, layers=2, use_cache=False)
    _check_structure(layer, face_n_boundary_edges=0)
    assert not layer.reduced.any()
    # directions are radial up to the discretisation; the discrete shell is the icosphere minus its
    # copy scaled by (r - h) / r, so V = V_ico (1 - ((r - h) / r)^3) to the angle error of the normals
    expect = s.signed_volume() * (1 - ((r - h) / r) ** 3)
    radial = s.vertices / np.linalg.norm(s.vertices, axis=1, keepdims=True)
    cos_err = 1 - np.einsum("ij,ij->i", -layer.inward, radial).min()
    assert cos_err < 1e-3
    assert layer.mesh.volume == pytest.approx(expect, rel=2 * cos_err + 1e-9)


def test_bad_arguments(make_grid):
    g = make_grid(2, 2)
    with pytest.raises(ParameterError, match="thickness"):
        extrude_tissue_layer(g, thickness=-0.01)
    with pytest.raises(ParameterError, match="thickness"):
        extrude_tissue_layer(g, thickness=np.ones(3))
    with pytest.raises(ParameterError, match="layers"):
        extrude_tissue_layer(g, layers=0)
    with pytest.raises(ParameterError):
        TissueOptions(min_volume_ratio=0.5, min_direction_cosine=0.2)


def _bump(grid_surface, height: float, width: float = 0.004, n: int = 24, size: float = 0.06) -> SurfaceMesh:
    """Flat square with a sharp Gaussian bump (a 'nose'): strongly convex at its top."""
    g = grid_surface(n, n, spacing=size / n)
    c = g.vertices[:, :2] - size / 2
    z = height * np.exp(-np.sum(c**2, axis=1) / (2 * width**2))
    return g.with_vertices(np.column_stack([g.vertices[:, :2], z]))


def test_sharp_convex_bump_gets_thinner_tissue_not_inverted_tets(make_grid):
    face = _bump(make_grid, height=0.012)
    layer = extrude_tissue_layer(face, thickness=0.01, layers=3, use_cache=False)
    _check_structure(layer, face_n_boundary_edges=len(face.boundary_loops[0]) if not len(layer.trimmed_triangles) else
                     len(SurfaceMesh(face.vertices, layer.skin_triangles).boundary_loops[0]))
    top = np.argmax(face.vertices[:, 2])
    assert layer.reduced_by_shape.any() and layer.thickness[top] < 0.01
    assert layer.thickness.min() >= 0.1 * 0.01  # never below the floor
    far = np.linalg.norm(face.vertices[:, :2] - 0.03, axis=1) > 0.025
    np.testing.assert_allclose(layer.thickness[far], 0.01)  # far from the bump nothing changes
    assert tet_quality(layer.mesh).radius_ratio.min() > 0


def test_folded_sheet_is_trimmed_or_refused(make_grid):
    # a sheet folded back on itself (a 'lip'): two layers 2 mm apart joined at one edge
    g = make_grid(10, 4, spacing=0.002)
    v, t = g.vertices, g.triangles
    n = len(v)
    upper = v + [0, 0, 0.002]
    verts = np.vstack([v, upper])
    # lower sheet faces -z (flip), upper faces +z; share the x = 0 column by a strip
    col = np.flatnonzero(v[:, 0] == 0)
    strip = []
    for a, b in zip(col[:-1], col[1:]):
        strip += [[a, b, n + b], [a, n + b, n + a]]
    tri = np.vstack([t[:, ::-1], t + n, np.array(strip)[:, ::-1]])
    face = SurfaceMesh(verts, tri, name="lip")
    layer = extrude_tissue_layer(face, thickness=0.01, layers=2, use_cache=False)
    # the sheets are 2 mm apart: where both are flat (away from the fold and the rims) each side gets
    # at most half of the gap, and no bone point comes closer to the skin than half its thickness
    skin = layer.skin_surface()
    xs = skin.vertices
    flat = (xs[:, 0] > 0.006) & (xs[:, 0] < 0.016) & (xs[:, 1] > 0.002) & (xs[:, 1] < 0.006)
    assert flat.sum() == 8  # 4 interior points on each sheet
    assert layer.thickness[flat].max() <= 0.001 * 1.001  # rays slightly oblique near the fold
    assert layer.reduced_by_clearance[flat].all()
    import igl

    d2, _, _ = igl.point_mesh_squared_distance(layer.mesh.vertices[layer.bone_vertex_ids], xs, skin.triangles)
    assert np.all(np.sqrt(d2) >= 0.5 * layer.thickness * (1 - 1e-9))
    with pytest.raises(MeshError, match="lip: "):
        extrude_tissue_layer(face, thickness=0.01, layers=2, use_cache=False,
                             options=TissueOptions(trim_folds=False, min_thickness_fraction=0.2))


def test_bundled_face(bundled_face):
    face = bundled_face
    layer = extrude_tissue_layer(face, thickness=0.01, layers=3)
    assert extrude_tissue_layer(face, thickness=0.01, layers=3) is layer  # cached
    assert build_tissue_layer(face) is layer.mesh
    skin = layer.skin_surface()
    _check_structure(layer, face_n_boundary_edges=sum(len(lp) for lp in skin.boundary_loops))
    np.testing.assert_array_equal(layer.mesh.vertices[: layer.n_skin], face.vertices[layer.face_vertex_ids])
    back = layer.skin_id_of_face_vertex(face.n_vertices)
    np.testing.assert_array_equal(back[layer.face_vertex_ids], np.arange(layer.n_skin))
    assert (back >= 0).sum() == layer.n_skin > 0.95 * face.n_vertices
    # only small folds (eyelid margins, inner lips) may be trimmed
    assert skin.area > 0.98 * face.area
    h = layer.thickness
    assert h.max() == pytest.approx(0.01) and h.min() >= 0.001 - 1e-15
    # volume against the Steiner offset formula V = sum A_i (h_i - H_i h_i^2 + K_i h_i^3 / 3), with the
    # discrete (cotangent) mean curvature H and the angle-defect Gaussian curvature K; what remains is
    # from the smoothed (not exactly normal) directions and the varying thickness
    import igl

    a = skin.vertex_areas
    lap = igl.cotmatrix(skin.vertices, skin.triangles)
    hn = -(lap @ skin.vertices) / (2 * a[:, None])
    mean_curv = np.einsum("ij,ij->i", hn, skin.vertex_normals)     # > 0 where convex seen from outside
    gauss = igl.gaussian_curvature(skin.vertices, skin.triangles) / a
    boundary = np.zeros(layer.n_skin, dtype=bool)
    boundary[np.concatenate(skin.boundary_loops)] = True
    mean_curv[boundary] = 0.0
    gauss[boundary] = 0.0
    first = np.sum(a * h)
    steiner = first - np.sum(a * mean_curv * h**2) + np.sum(a * gauss * h**3) / 3
    assert abs(layer.mesh.volume - steiner) < 0.015 * first
    assert abs(layer.mesh.volume - first) > 0.03 * first   # the curvature terms matter (face is convex)
    # bone vertices lie at depth ~ thickness below the skin (closest distance to the skin surface)
    d2, _, _ = igl.point_mesh_squared_distance(layer.mesh.vertices[layer.bone_vertex_ids], skin.vertices,
                                               skin.triangles)
    ratio = np.sqrt(d2) / h
    assert ratio.max() <= 1 + 1e-9
    assert np.median(ratio[~layer.reduced]) > 0.98
    q = tet_quality(layer.mesh)
    assert q.radius_ratio.min() > 0 and np.median(q.radius_ratio) > 0.5
