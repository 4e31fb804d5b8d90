"""Volume injection (Monkin 2016 §4.3, §5.3) and measurements (ch. 6)."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.errors import MeshError, ParameterError
from headsim.graft import (GraftOptions, inject_volume, prepare_graft, signed_distances, surface_distances,
                           transfer_region_to_midpoint_subdivision, volume_between)
from headsim.graft.region import region_from_loop
from headsim.mesh.subdivide import subdivide_midpoint
from headsim.mesh.surface import SurfaceMesh


@pytest.fixture(scope="module")
def setup(left_cheek):
    return prepare_graft(left_cheek)


@pytest.mark.parametrize("volume_cm3", [1.0, 5.0, 12.0, 20.0])
def test_injected_volume_measured_on_the_output_surface(setup, face, volume_cm3):
    before = face.vertices.copy()
    result = inject_volume(setup, volume_cm3 * 1e-6)
    assert result.info.converged
    measured = volume_between(face, result.face_after, setup.region)
    assert measured == pytest.approx(volume_cm3 * 1e-6, rel=0.01)
    # the closed model's volume change equals the volume between the surfaces (loop and closure fixed)
    assert result.volume_after - result.volume_before == pytest.approx(measured, rel=1e-9)
    np.testing.assert_array_equal(face.vertices, before)  # input untouched
    moved = np.flatnonzero(np.any(result.face_after.vertices != face.vertices, axis=1))
    assert set(moved) <= set(setup.region.interior_vertex_ids.tolist())
    assert result.area_after > result.area_before
    assert np.all(result.displacement[setup.region.interior_vertex_ids] > -1e-4)  # bulges outwards


def test_mirror_closure_injects_the_same_volume(left_cheek, face):
    setup = prepare_graft(left_cheek, "mirror")
    assert setup.volume_before == pytest.approx(0.0, abs=1e-15)
    result = inject_volume(setup, 5e-6, GraftOptions(closure="mirror"))
    assert volume_between(face, result.face_after, left_cheek) == pytest.approx(5e-6, rel=0.01)


@pytest.fixture(scope="module")
def fine_cheek(face, left_cheek):
    return transfer_region_to_midpoint_subdivision(left_cheek, subdivide_midpoint(face))


def test_same_region_on_the_subdivided_face_gives_the_same_result(face, left_cheek, fine_cheek):
    """Seed ch. 6: the same region on the face and on its 1-to-4 subdivision, 10 cm³ → Hausdorff < 0.5 mm."""
    fine_region = fine_cheek
    assert fine_region.area == pytest.approx(left_cheek.area, rel=1e-12)
    assert len(fine_region.vertex_ids) > 3 * len(left_cheek.vertex_ids)
    coarse = inject_volume(prepare_graft(left_cheek), 10e-6)
    dense = inject_volume(prepare_graft(fine_region), 10e-6)
    d = surface_distances(coarse.face_after, dense.face_after)
    assert d.hausdorff < 0.5e-3
    assert np.max(np.abs(coarse.displacement)) > 5e-3  # a real bulge was compared


@pytest.mark.parametrize("density", ["face", "face x4"])
def test_anderson_path_reaches_the_rest_state_of_the_seeds_time_stepping(left_cheek, fine_cheek, density):
    """The default solve (Anderson acceleration of the step-from-rest map) against the seed's damped time
    stepping to its stop rule, 10 cm³: same surface within 0.05 mm (Hausdorff), fewer PBD steps, and the
    seed's loop started at the fast result stays there (it is a rest state of the same PBD model)."""
    from headsim.graft.plan import graft_problem
    from headsim.solvers.pbd import PBDSolver, PBDState

    setup = prepare_graft(left_cheek if density == "face" else fine_cheek)
    fast = inject_volume(setup, 10e-6)
    plain = inject_volume(setup, 10e-6, GraftOptions(acceleration="none"))
    assert fast.info.converged and plain.info.converged
    assert surface_distances(fast.face_after, plain.face_after).hausdorff < 0.05e-3
    assert fast.info.steps < plain.info.steps
    assert fast.volume_after - fast.volume_before == pytest.approx(10e-6, rel=1e-3)
    model, options = graft_problem(setup, 10e-6, GraftOptions(acceleration="none"))
    solver = PBDSolver(model, options)
    state = PBDState.at_rest(fast.closed_after)
    for _ in range(300):
        state = solver.step(state)
    assert np.abs(state.positions - fast.closed_after).max() < 0.01e-3


def test_injection_parameter_errors(setup):
    with pytest.raises(ParameterError):
        inject_volume(setup, 0.0)
    with pytest.raises(ParameterError, match="implausibly large"):
        inject_volume(setup, 12.0)  # 12 m³: forgot the cm³ → m³ conversion
    with pytest.raises(ParameterError):
        GraftOptions(closure="lid")
    with pytest.raises(ParameterError, match="compliance"):
        GraftOptions(gravity=True)


def _plane(n=6, size=0.04, z=0.0):
    s = np.linspace(-size / 2, size / 2, n + 1)
    x, y = np.meshgrid(s, s, indexing="ij")
    v = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return SurfaceMesh(v, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])]))


def _square_region(plane, n=6):
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    ring = np.concatenate([idx[1, 1:n], idx[1:n, n - 1][1:], idx[n - 1, 1:n - 1][::-1], idx[2:n - 1, 1][::-1]])
    return region_from_loop(plane, ring)


def test_volume_between_offset_planes_is_height_times_area():
    plane = _plane()
    region = _square_region(plane)
    h = 0.003
    # same connectivity, the whole sheet lifted (loop moves too: the side strip matters)
    lifted = plane.with_vertices(plane.vertices + [0, 0, h])
    assert volume_between(plane, lifted, region) == pytest.approx(h * region.area, rel=1e-12)
    lowered = plane.with_vertices(plane.vertices - [0, 0, h])
    assert volume_between(plane, lowered, region) == pytest.approx(-h * region.area, rel=1e-12)
    # different connectivity (another scan): height integration
    other = subdivide_midpoint(_plane(z=h))
    assert volume_between(plane, other, region) == pytest.approx(h * region.area, rel=1e-9)
    far = _plane(z=0.0).with_vertices(_plane().vertices + [1.0, 0, 0])
    with pytest.raises(MeshError, match="aligned"):
        volume_between(plane, subdivide_midpoint(far), region)


def test_surface_distances_of_offset_planes_and_signed_distances():
    plane = _plane()
    up = _plane(n=9, z=0.002)
    d = surface_distances(plane, up)
    assert d.hausdorff == pytest.approx(0.002, rel=1e-12)
    assert d.mean == pytest.approx(0.002, rel=1e-12)
    s = signed_distances(plane, up)
    np.testing.assert_allclose(s, 0.002, rtol=1e-12)
    np.testing.assert_allclose(signed_distances(up, plane), -0.002, rtol=1e-12)


def test_surface_distances_match_brute_force(face, setup):
    """Hausdorff via the BVH against a brute-force point-to-triangle search on a small patch."""
    from headsim.collide._reference import closest_points_bruteforce

    result = inject_volume(setup, 3e-6)
    sub_a, ids = face.submesh(setup.region.vertex_ids)
    sub_b = SurfaceMesh(result.face_after.vertices[ids], sub_a.triangles)
    d = surface_distances(sub_a, sub_b)
    ab = closest_points_bruteforce(sub_a.vertices, sub_b.vertices, sub_b.triangles)
    ba = closest_points_bruteforce(sub_b.vertices, sub_a.vertices, sub_a.triangles)
    ab = ab[0] if isinstance(ab, tuple) else ab.distance
    ba = ba[0] if isinstance(ba, tuple) else ba.distance
    assert d.hausdorff == pytest.approx(max(np.max(ab), np.max(ba)), rel=1e-9)


def test_hydrostatic_pressure_settles_independently_of_the_sweep_count(setup, face):
    """Gravity + hydrostatic pressure of the fat (Monkin §4.3, 900 kg/m³) on the cheek: the solve settles,
    keeps the injected volume, sags downwards (−y) and, once the sweeps of a step converge, does not depend
    on their number (the rest state is then the force balance, not an artefact of the iteration)."""
    no_load = inject_volume(setup, 5e-6)
    loaded = {}
    for sweeps in (200, 400):
        opts = GraftOptions(gravity=True, fluid_density=900.0, edge_compliance=0.1, loaded_iterations=sweeps)
        loaded[sweeps] = inject_volume(setup, 5e-6, opts)
        assert loaded[sweeps].info.converged
        assert volume_between(face, loaded[sweeps].face_after, setup.region) == pytest.approx(5e-6, rel=0.01)
    assert surface_distances(loaded[200].face_after, loaded[400].face_after).hausdorff < 0.01e-3
    ids = setup.region.interior_vertex_ids
    shift = loaded[200].face_after.vertices[ids] - no_load.face_after.vertices[ids]
    assert surface_distances(no_load.face_after, loaded[200].face_after).hausdorff > 1e-3  # a real load
    assert shift[:, 1].mean() < 0  # it sags along gravity


def test_surface_distances_ignore_vertices_outside_every_triangle():
    """A stray vertex (in no triangle) is not part of the surface: two unit squares 1 mm apart stay 1 mm
    apart when one of them carries an unused vertex 1 m away."""
    quad = np.array([[0, 1, 2], [0, 2, 3]])
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float) * 0.01
    a = SurfaceMesh(sq, quad)
    b = SurfaceMesh(np.vstack([sq + [0, 0, 1e-3], [[1.0, 1.0, 1.0]]]), quad)
    for d in (surface_distances(a, b), surface_distances(b, a)):
        assert d.hausdorff == pytest.approx(1e-3, rel=1e-9) and d.mean == pytest.approx(1e-3, rel=1e-9)
