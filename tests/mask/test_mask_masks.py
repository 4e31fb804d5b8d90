"""Built-in parametric masks: watertight, positive, conforming, deterministic, ordered sizes."""

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.mask import (CUSHION_SILICONE, SILICONE_MEMBRANE, build_parametric_mask,
                          effective_cushion_modulus, make_mask, mask_catalogue)
from headsim.mask.geometry import grid_triangles, split_prisms, sweep_ring
from headsim.mask.masks import _DESIGNS
from headsim.mesh import REGION_CUSHION, REGION_SHELL, SurfaceMesh
from headsim.mesh.geometry import boundary_edges_directed, tet_signed_volumes, unique_edges


@pytest.fixture(scope="module")
def masks():
    return {name: make_mask(name) for name in mask_catalogue()}


def test_catalogue():
    assert mask_catalogue() == ["nasal-S", "nasal-M", "nasal-L", "oronasal-S", "oronasal-M", "oronasal-L"]
    with pytest.raises(ParameterError, match="unknown mask"):
        make_mask("nasal-XL")


@pytest.mark.parametrize("name", ["nasal-S", "nasal-M", "nasal-L", "oronasal-S", "oronasal-M", "oronasal-L"])
def test_mask_is_a_watertight_positive_solid(name, masks):
    m = masks[name]
    tm = m.tetmesh
    assert (tet_signed_volumes(tm.vertices, tm.tets) > 0).all()
    # conforming: every tet face is shared by at most two tets
    faces = np.concatenate([tm.tets[:, [1, 2, 3]], tm.tets[:, [0, 3, 2]], tm.tets[:, [0, 1, 3]], tm.tets[:, [0, 2, 1]]])
    _, counts = np.unique(np.sort(faces, axis=1), axis=0, return_counts=True)
    assert counts.max() == 2
    # the boundary is a closed, consistently oriented surface enclosing the tets' volume
    boundary = tm.boundary_triangles
    surf = SurfaceMesh(tm.vertices, boundary)
    assert surf.is_closed
    assert len(boundary_edges_directed(boundary)) == 0
    half = np.concatenate([boundary[:, [0, 1]], boundary[:, [1, 2]], boundary[:, [2, 0]]])
    assert len(np.unique(half, axis=0)) == len(half)  # each directed edge once: consistent winding
    assert surf.signed_volume() == pytest.approx(tm.volume, rel=1e-9)
    # a ring: a torus (genus 1), V - E + F = 0
    edges, _ = unique_edges(boundary)
    used = np.unique(boundary)
    assert len(used) - len(edges) + len(boundary) == 0


@pytest.mark.parametrize("name", ["nasal-M", "oronasal-M"])
def test_regions_and_contact_surface(name, masks):
    m = masks[name]
    tm = m.tetmesh
    assert set(np.unique(tm.tet_region)) == {REGION_CUSHION, REGION_SHELL}
    np.testing.assert_array_equal(tm.fixed, tm.vertex_region == REGION_SHELL)
    assert 0 < tm.fixed.sum() < tm.n_vertices
    # the shell is the back (largest z); the skin side faces -z
    z = tm.vertices[:, 2]
    assert z[tm.fixed].min() > np.median(z[~tm.fixed])
    contact = m.contact_triangles
    assert not tm.fixed[contact].any()
    n = np.cross(tm.vertices[contact[:, 1]] - tm.vertices[contact[:, 0]], tm.vertices[contact[:, 2]] - tm.vertices[contact[:, 0]])
    # the skin-most faces of the contact surface point towards the face (-z)
    lowest = z[contact].mean(axis=1) < np.percentile(z[contact].mean(axis=1), 5)
    assert (n[lowest, 2] < 0).mean() > 0.9
    np.testing.assert_allclose(m.airway_axis, [0, 0, -1])
    np.testing.assert_allclose(m.up, [0, 1, 0])


def test_generation_is_deterministic():
    a, b = make_mask("nasal-M"), make_mask("nasal-M")
    np.testing.assert_array_equal(a.tetmesh.vertices, b.tetmesh.vertices)
    np.testing.assert_array_equal(a.tetmesh.tets, b.tetmesh.tets)
    np.testing.assert_array_equal(a.contact_triangles, b.contact_triangles)


@pytest.mark.parametrize("kind", ["nasal", "oronasal"])
def test_sizes_are_ordered(kind, masks):
    ext = [np.ptp(masks[f"{kind}-{s}"].tetmesh.vertices, axis=0) for s in "SML"]
    vol = [masks[f"{kind}-{s}"].tetmesh.volume for s in "SML"]
    assert (ext[0] < ext[1]).all() and (ext[1] < ext[2]).all()
    assert vol[0] < vol[1] < vol[2]


def test_oronasal_is_larger_than_nasal(masks):
    assert np.ptp(masks["oronasal-M"].tetmesh.vertices[:, 1]) > np.ptp(masks["nasal-M"].tetmesh.vertices[:, 1]) + 0.02


def test_saddle_is_deeper_at_the_cheeks(masks):
    """The skin-side edge reaches further towards the face (-z) at the cheeks than at the bridge."""
    m = masks["nasal-M"]
    v = m.tetmesh.vertices[m.contact_vertices]
    top = v[:, 1] > np.percentile(v[:, 1], 95)
    side = np.abs(v[:, 0]) > np.percentile(np.abs(v[:, 0]), 95)
    assert v[side, 2].min() < v[top, 2].min() - 5e-3


@pytest.mark.parametrize("name", ["nasal-M", "oronasal-M"])
def test_size_m_cushion_follows_the_mean_face(masks, name, neutral_face, neutral_landmarks):
    """Designed on the population mean face: placed automatically on it, the smallest skin gap of each
    30-degree sector of the outline varies by less than 5 mm, well within what the cushion can
    compress (it is 8 mm tall at the bridge and more elsewhere). The first design varied by 10-11 mm."""
    from headsim.mask.placement import place_mask

    m = masks[name]
    gaps = place_mask(m, neutral_face, neutral_landmarks).gaps
    p = m.tetmesh.vertices[m.contact_vertices]
    angle = np.degrees(np.arctan2(p[:, 1] - p[:, 1].mean(), p[:, 0]))
    sector_min = [gaps[(angle >= a) & (angle < a + 30) & np.isfinite(gaps)].min() for a in range(-180, 180, 30)]
    assert max(sector_min) - min(sector_min) < 5e-3


def test_split_prisms_is_conforming_for_any_numbering():
    """A random relabelling of a swept ring still gives matching shared faces (Dompierre rule)."""
    rng = np.random.default_rng(3)
    n_rows, n_cols, n_samples = 3, 3, 12
    tri = grid_triangles(n_rows, n_cols)
    prisms = sweep_ring(tri, n_rows * n_cols, n_samples)
    t = np.linspace(0, 2 * np.pi, n_samples, endpoint=False)
    r, h = np.meshgrid(np.linspace(-1, 1, n_cols), np.linspace(0, 1, n_rows))
    v = np.concatenate([np.column_stack([(3 + r.ravel()) * np.cos(a), (3 + r.ravel()) * np.sin(a), h.ravel()]) for a in t])
    perm = rng.permutation(len(v))
    inv = np.argsort(perm)
    tets = split_prisms(inv[prisms], v[perm])
    assert (tet_signed_volumes(v[perm], tets) > 0).all()
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    _, counts = np.unique(np.sort(faces, axis=1), axis=0, return_counts=True)
    n_boundary = (counts == 1).sum()
    # boundary of the ring: 2 triangles per boundary quad of the section, per sample
    n_section_boundary_edges = 2 * (n_rows - 1) + 2 * (n_cols - 1)
    assert n_boundary == 2 * n_section_boundary_edges * n_samples
    assert counts.max() == 2


def test_materials():
    lam, mu = SILICONE_MEMBRANE.lame
    assert mu == pytest.approx(1.11e6 / (2 * 1.49))
    assert 10e3 <= CUSHION_SILICONE.youngs_modulus <= 100e3
    # E_eff = E_m t^3 / (2 w H^2): 1.11 MPa, 3 mm, 10 mm, 15 mm -> 1.11e6 * 27e-9 / (2 * 0.01 * 2.25e-4)
    assert effective_cushion_modulus(1.11e6, 3e-3, 10e-3, 15e-3) == pytest.approx(6660.0)
    with pytest.raises(ParameterError):
        effective_cushion_modulus(1.11e6, -1e-3, 10e-3, 15e-3)


def test_too_tight_outline_is_refused():
    from dataclasses import replace

    with pytest.raises(ParameterError, match="lower the taper"):
        build_parametric_mask(replace(_DESIGNS["nasal"], taper=0.8))


def test_with_vertices_and_transformed_keep_labels(masks):
    m = masks["nasal-S"]
    moved = m.with_vertices(m.tetmesh.vertices + [0.0, 0.0, 0.01])
    np.testing.assert_array_equal(moved.tetmesh.fixed, m.tetmesh.fixed)
    np.testing.assert_array_equal(moved.contact_triangles, m.contact_triangles)
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    turned = m.transformed(rot, [1.0, 2.0, 3.0])
    np.testing.assert_allclose(turned.up, [-1.0, 0.0, 0.0])
    np.testing.assert_allclose(turned.airway_center, [1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match="rotation"):
        m.transformed(np.diag([1.0, 1.0, -1.0]), np.zeros(3))


def test_describe(masks):
    d = masks["nasal-M"].describe()
    assert d["name"] == "nasal-M" and d["size"] == "M" and d["kind"] == "nasal"
    # outline 50 mm wide plus the 10 mm cushion; 55 mm tall plus the cushion
    assert d["width_mm"] == pytest.approx(60.0, abs=1.0)
    assert d["height_mm"] == pytest.approx(65.0, abs=1.5)
    assert d["n_tets"] == masks["nasal-M"].tetmesh.n_tets


def test_membrane_cushion_modulus_follows_section_height():
    """The membrane homogenisation: E_eff = E_m t^3 / (2 w H^2) per section; a tall section is softer."""
    from headsim.mask.masks import MEMBRANE_CUSHION, PAP_MEMBRANE, MembraneWall, membrane_cushion_modulus

    e = membrane_cushion_modulus(PAP_MEMBRANE, 10e-3, np.array([8e-3, 15e-3, 27e-3]))
    np.testing.assert_allclose(e, [effective_cushion_modulus(1.11e6, 3e-3, 10e-3, h) for h in (8e-3, 15e-3, 27e-3)])
    assert e[0] > e[1] > e[2]
    assert MEMBRANE_CUSHION.youngs_modulus == pytest.approx(e[1])
    m = make_mask("nasal-M", edge_length=5e-3, cushion="membrane")
    assert m.tet_modulus is not None and m.tet_modulus.shape == (m.tetmesh.n_tets,)
    # bounded by the shortest (bridge, 8 mm + rounding) and tallest (cheek) sections of nasal-M
    assert 1.5e3 < m.tet_modulus.min() < m.tet_modulus.max() < 60e3
    assert make_mask("nasal-M", edge_length=5e-3).tet_modulus is None          # the solid default
    with pytest.raises(ParameterError):
        make_mask("nasal-M", cushion="foam")
    with pytest.raises(ParameterError):
        MembraneWall(thickness=-1e-3)


@pytest.mark.parametrize("segments", [2, 4, 6])
def test_rounded_corner_rows_lie_on_the_arc_at_equal_angles(segments):
    """corner_segments = n: the outer vertices of the corner rows lie on the corner's circle (radius
    r, centred r above the edge and r inside the section's side) at angles k pi / (2 n)."""
    from headsim.mask.masks import design_of

    design = design_of("nasal")
    m = make_mask("nasal-M", edge_length=4e-3, corner_segments=segments)
    n_samples, n_rows, n_cols = m.section_grid
    v = m.tetmesh.vertices.reshape(n_samples, n_rows, n_cols, 3)
    r, half_w = design.corner_radius, 0.5 * design.cushion_width
    rows = v[:, : segments + 1]
    half = 0.5 * np.linalg.norm(rows[:, :, -1, :2] - rows[:, :, 0, :2], axis=2)     # (samples, rows)
    height = rows[:, :, 0, 2] - rows[:, :1, 0, 2]
    np.testing.assert_allclose(np.hypot(half - (half_w - r), r - height), r, rtol=1e-9)
    angle = np.arctan2(half - (half_w - r), r - height)
    np.testing.assert_allclose(angle, np.broadcast_to(np.linspace(0, np.pi / 2, segments + 1), angle.shape),
                               atol=1e-9)
    assert v[:, segments + 1:, 0, 2].min() > v[:, segments, 0, 2].min()           # rows above the corner


def test_section_edge_refines_the_cross_section_only():
    coarse = make_mask("nasal-M", edge_length=2e-3, section_edge=4e-3)
    fine = make_mask("nasal-M", edge_length=2e-3)
    assert coarse.section_grid[0] == fine.section_grid[0]                     # same outline sampling
    assert coarse.section_grid[2] < fine.section_grid[2] and coarse.section_grid[1] < fine.section_grid[1]
    with pytest.raises(ParameterError):
        make_mask("nasal-M", section_edge=0.1e-3)
    with pytest.raises(ParameterError):
        make_mask("nasal-M", corner_segments=12)
