"""Contact as an energy for the quasi-static solver: rigid driven plate, two deformable bodies, drivers."""

from dataclasses import replace

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.mesh.primitives import box
from headsim.solvers.contact import PlaneContact, RigidDriver, SphereObstacle, solve_quasi_static, \
    surface_vertex_areas
from headsim.solvers.fem import fem_from_tetmesh
from headsim.solvers.grids import block_tetmesh
from headsim.solvers.materials import Material
from headsim.solvers.massspring import mass_spring_from_tetmesh

MAT = Material.from_kpa(10.0, 0.3, 1000.0)
H = 0.01


def _rollers(x, bottom=0.0):
    return np.column_stack([np.isclose(x[:, 0], 0.0), np.isclose(x[:, 1], 0.0), np.isclose(x[:, 2], bottom)])


def _top(mesh, z):
    tri = mesh.boundary_triangles
    face = tri[np.all(np.isclose(mesh.vertices[tri][:, :, 2], z), axis=1)]
    return face


@pytest.mark.parametrize("direction", ["consistent", "naive"])
def test_rigid_plate_driven_by_force_compresses_block_uniaxially(direction):
    mesh = block_tetmesh((H, H, H), (2, 2, 2))
    model = fem_from_tetmesh(mesh, MAT)
    x = mesh.vertices
    face = _top(mesh, H)
    areas = surface_vertex_areas(len(x), face, x)
    top = np.flatnonzero(areas > 0)
    plate = box((3 * H, 3 * H, 0.5 * H), center=(0.5 * H, 0.5 * H, 1.25 * H))
    kappa = 1e3 * MAT.young_modulus / H
    p = 1e-3 * MAT.young_modulus
    force = p * H * H
    contact = PlaneContact(top, areas[top], plate.triangles, kappa, rigid_vertices=plate.vertices, driver=0,
                           direction=direction, slave_edges=mesh.edges)
    res = solve_quasi_static(model, [contact], [RigidDriver((0, 0, -1), force=force)], fixed_dofs=_rollers(x))
    strain = p / MAT.young_modulus
    assert res.driver_displacement[0] == pytest.approx(strain * H + p / kappa, rel=2e-3)
    assert res.contact_pressure[top] == pytest.approx(np.full(len(top), p), rel=2e-3)
    assert res.contact_forces[:, 2].sum() == pytest.approx(-force, rel=1e-6)
    assert res.driver_forces[0] == pytest.approx(-force, rel=1e-6)  # contact on the plate balances the strap
    assert res.reaction_forces[:, 2].sum() == pytest.approx(force, rel=1e-6)
    assert 0 < res.gradient_norm <= res.tolerance  # the residual is reported and met


def test_two_deformable_blocks_in_contact_share_the_load():
    """A small block pressed onto the middle of a larger one (quarter symmetry through the centres).

    Checks: the contact transmits the whole load (equal and opposite contact forces, support
    reaction = load), every contact direction is the lower block's top normal, penetration stays
    at the penalty level, and the stack shortens by more than the upper block alone would.
    """
    from headsim.mesh.tet import TetMesh

    lower = block_tetmesh((H, H, H), (4, 4, 2), name="lower")  # quarter of a 2H x 2H x H block
    upper = block_tetmesh((H / 2, H / 2, H), (2, 2, 2), origin=(0, 0, H), name="upper")  # quarter of H x H x H
    n0 = lower.n_vertices
    both = TetMesh(np.vstack([lower.vertices, upper.vertices]), np.vstack([lower.tets, upper.tets + n0]))
    x = both.vertices
    p = 1e-3 * MAT.young_modulus
    face = _top(upper, 2 * H) + n0
    ext = np.zeros_like(x)
    ext[:, 2] = -p * surface_vertex_areas(len(x), face, x)
    model = replace(fem_from_tetmesh(both, MAT), external_force=ext)
    kappa = 1e3 * MAT.young_modulus / H
    up_v, lo_v = np.arange(n0, len(x)), np.arange(n0)
    a_up = surface_vertex_areas(len(x), upper.boundary_triangles + n0, x)
    a_lo = surface_vertex_areas(len(x), lower.boundary_triangles, x)
    contacts = [
        PlaneContact(up_v, a_up[up_v], lower.boundary_triangles, kappa, slave_edges=both.edges),
        PlaneContact(lo_v, a_lo[lo_v], upper.boundary_triangles + n0, kappa, slave_edges=both.edges),
    ]
    res = solve_quasi_static(model, contacts, fixed_dofs=_rollers(x))
    load = p * (H / 2) ** 2
    assert res.reaction_forces[:, 2].sum() == pytest.approx(load, rel=1e-6)
    assert res.contact_forces[up_v, 2].sum() == pytest.approx(load, rel=1e-6)
    assert res.contact_forces[lo_v, 2].sum() == pytest.approx(-load, rel=1e-6)
    c = contacts[0]
    interior = x[up_v[c.active], 0] > 1e-9  # off the symmetry planes (cut faces, not real surfaces)
    interior &= x[up_v[c.active], 1] > 1e-9
    assert np.allclose(c.normals[interior], [0, 0, 1])
    u = res.positions - x
    top = np.isclose(x[:, 2], 2 * H) & (np.arange(len(x)) >= n0)
    assert -u[top, 2].mean() > p * H / MAT.young_modulus  # more than the upper block's own shortening
    assert res.contact_pressure.max() / kappa < 1e-2 * -u[top, 2].mean()  # penetration << displacement


def test_warm_start_converges_immediately():
    mesh = block_tetmesh((H, H, H), (2, 2, 2))
    model = fem_from_tetmesh(mesh, MAT)
    x = mesh.vertices
    areas = surface_vertex_areas(len(x), _top(mesh, H), x)
    top = np.flatnonzero(areas > 0)
    sphere = SphereObstacle(np.array([0.5 * H, 0.5 * H, 3 * H]), 2 * H, 1e3 * MAT.young_modulus / H, top, areas[top],
                            driver=0)
    driver = RigidDriver((0, 0, -1), force=1e-3)
    first = solve_quasi_static(model, [sphere], [driver], fixed_dofs=_rollers(x))
    again = solve_quasi_static(model, [sphere], [driver], fixed_dofs=_rollers(x),
                               initial_positions=first.positions, initial_drivers=first.driver_displacement)
    assert again.newton_iterations <= 1 < first.newton_iterations
    assert np.allclose(again.positions, first.positions, atol=1e-12)


def test_inexact_updates_option_is_validated_and_keeps_the_uniaxial_answer():
    from headsim.solvers.contact import QuasiStaticOptions

    for bad in (0.0, 1.0, -1e-3):
        with pytest.raises(ParameterError):
            QuasiStaticOptions(inexact_updates=bad)
    mesh = block_tetmesh((H, H, H), (2, 2, 2))
    model = fem_from_tetmesh(mesh, MAT)
    x = mesh.vertices
    areas = surface_vertex_areas(len(x), _top(mesh, H), x)
    top = np.flatnonzero(areas > 0)
    plate = box((3 * H, 3 * H, 0.5 * H), center=(0.5 * H, 0.5 * H, 1.25 * H))
    kappa = 1e3 * MAT.young_modulus / H
    p = 1e-3 * MAT.young_modulus
    contact = PlaneContact(top, areas[top], plate.triangles, kappa, rigid_vertices=plate.vertices, driver=0,
                           slave_edges=mesh.edges)
    res = solve_quasi_static(model, [contact], [RigidDriver((0, 0, -1), force=p * H * H)], fixed_dofs=_rollers(x),
                             options=QuasiStaticOptions(inexact_updates=1e-3))
    assert res.driver_displacement[0] == pytest.approx(p / MAT.young_modulus * H + p / kappa, rel=2e-3)
    assert res.driver_forces[0] == pytest.approx(-p * H * H, rel=1e-6)  # finished to the full tolerance


def test_mass_spring_model_works_with_quasi_static_contact():
    mesh = block_tetmesh((H, H, H), (2, 2, 2))
    mesh = replace(mesh, fixed=np.isclose(mesh.vertices[:, 2], 0.0))
    model = mass_spring_from_tetmesh(mesh, material=Material.from_kpa(10.0, 0.25))
    x = mesh.vertices
    areas = surface_vertex_areas(len(x), _top(mesh, H), x)
    top = np.flatnonzero(areas > 0)
    sphere = SphereObstacle(np.array([0.5 * H, 0.5 * H, 2 * H]), H, 1e3 * 1e4 / H, top, areas[top], driver=0)
    res = solve_quasi_static(model, [sphere], [RigidDriver((0, 0, -1), force=1e-3)])
    assert res.contact_forces[:, 2].sum() == pytest.approx(-1e-3, rel=1e-6)
    assert res.reaction_forces[:, 2].sum() == pytest.approx(1e-3, rel=1e-6)


def test_bad_drivers_and_contacts_are_refused():
    with pytest.raises(ParameterError):
        RigidDriver((0, 0, 0), force=1.0)
    with pytest.raises(ParameterError):
        RigidDriver((0, 0, 1))
    with pytest.raises(ParameterError):
        PlaneContact(np.arange(3), np.ones(3), np.zeros((1, 3), int), 1.0, direction="consistent")
    mesh = block_tetmesh((H, H, H), (1, 1, 1))
    model = fem_from_tetmesh(mesh, MAT)
    s = SphereObstacle(np.zeros(3), H, 1.0, np.arange(2), np.ones(2), driver=3)
    with pytest.raises(ParameterError):
        solve_quasi_static(model, [s], [])


def test_driver_attachment_transmits_strap_force():
    """A block glued on top to a force-driven rigid part, rollers below: uniaxial compression."""
    from headsim.solvers.contact import DriverAttachment

    mesh = block_tetmesh((H, H, H), (2, 2, 2))
    model = fem_from_tetmesh(mesh, MAT)
    x = mesh.vertices
    top = np.flatnonzero(np.isclose(x[:, 2], H))
    p = 1e-3 * MAT.young_modulus
    force = p * H * H
    glue = DriverAttachment(top, x[top], driver=0, stiffness=1e6 * MAT.young_modulus * H)
    fixed = _rollers(x)
    res = solve_quasi_static(model, [glue], [RigidDriver((0, 0, -1), force=force)], fixed_dofs=fixed)
    # the glued face cannot expand laterally, so compare with a monolithic solve of the same constraint
    ref_fixed = fixed.copy()
    ref_fixed[top] = True
    start = x.copy()
    start[top, 2] -= res.driver_displacement[0]
    ref = solve_quasi_static(model, initial_positions=start, fixed_dofs=ref_fixed)
    assert np.allclose(res.positions, ref.positions, atol=1e-6 * res.driver_displacement[0])
    assert -ref.reaction_forces[top, 2].sum() == pytest.approx(force, rel=1e-4)
    assert res.reaction_forces[:, 2].sum() == pytest.approx(force, rel=1e-6)
