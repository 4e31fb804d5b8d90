"""Barrier contact (headsim.solvers.barrier): the pressure law against the potential's own force,
and a force-driven solve that must stop at the barrier without the surfaces crossing."""

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.solvers.barrier import BarrierContact, barrier_distance, barrier_pressure


def _vertex_over_plate(d):
    # a large plate triangle (area 50 m^2 about its vertices) and a small triangle whose vertex 3
    # hangs d above the plate's interior
    v = np.array([[-5, -5, 0], [5, -5, 0], [0, 5, 0], [0.2, 0.3, d], [0.3, 0.3, d + 0.05], [0.2, 0.4, d + 0.05]], float)
    return v, np.array([[0, 1, 2], [3, 4, 5]])


@pytest.mark.parametrize("t", [0.05, 0.3, 0.5, 0.9])
def test_force_over_area_is_the_documented_pressure_law(t):
    dhat, kappa = 1e-2, 3e4
    v, tri = _vertex_over_plate(t * dhat)
    bc = BarrierContact(v, tri, dhat, kappa)
    f = bc.vertex_forces(v, np.zeros(0))
    area = bc.areas[list(bc.ids).index(3)]
    # only vertex 3 is near the plate: its force is normal, magnitude p(d) x its area
    assert f[3, :2] == pytest.approx([0, 0], abs=1e-12)
    assert f[3, 2] / area == pytest.approx(barrier_pressure(t * dhat, dhat, kappa), rel=1e-9)
    # equal and opposite on the plate
    assert f.sum(axis=0) == pytest.approx([0, 0, 0], abs=1e-9 * abs(f[3, 2]))
    assert barrier_distance(barrier_pressure(t * dhat, dhat, kappa), dhat, kappa) == pytest.approx(t * dhat, rel=1e-9)


def test_no_force_beyond_dhat_and_infinite_energy_at_contact():
    dhat = 1e-2
    v, tri = _vertex_over_plate(1.5 * dhat)
    bc = BarrierContact(v, tri, dhat, 1.0)
    assert bc.energy(v, np.zeros(0)) == 0.0 and not bc.vertex_forces(v, np.zeros(0)).any()
    v0, _ = _vertex_over_plate(0.0)
    assert bc.energy(v0, np.zeros(0)) == np.inf


def test_step_fraction_stops_a_step_through_the_plate():
    dhat = 1e-3
    v, tri = _vertex_over_plate(0.01)
    bc = BarrierContact(v, tri, dhat, 1.0)
    v1 = v.copy()
    v1[3:, 2] -= 0.02  # would pass 1 cm through the plate
    frac = bc.step_fraction(v, np.zeros(0), v1, np.zeros(0))
    assert 0 < frac < 0.5  # the crossing happens at half the step
    assert not bc.intersecting(v + frac * (v1 - v))


def test_vertices_within_names_the_primitives_closer_than_the_distance():
    # vertex 3 hangs 0.1 above the plate; the small triangle's other two vertices 0.15
    v, tri = _vertex_over_plate(0.1)
    bc = BarrierContact(v, tri, 1e-3, 1.0)
    assert not bc.vertices_within(v, 0.09).any()
    near = bc.vertices_within(v, 0.12)
    # the point-triangle pair of vertex 3 loads vertex 3 and the plate's three vertices
    assert near.tolist() == [True, True, True, True, False, False]
    assert bc.vertices_within(v, 0.2).all()


# -- lagged friction on the barrier (BarrierContact(friction=mu, friction_slip=eps)) ----------------------
# A block rests on a fixed slab of the same model under a normal pressure p_n, then gets a tangential
# traction p_t on its top: the same experiment as tests/solvers/test_friction.py for the lagged planes.

H = 0.01
MU = 0.5
EPS = 1e-7  # m


def _block_on_slab():
    from headsim.mesh import TetMesh
    from headsim.solvers.fem import fem_from_tetmesh
    from headsim.solvers.grids import block_tetmesh
    from headsim.solvers.materials import Material

    mat = Material.from_kpa(10.0, 0.3, 1000.0)
    dhat = 1e-3 * H
    # the block off the slab's grid lines: no bottom vertex above a slab edge or vertex (degenerate pairs)
    block = block_tetmesh((H, H, H), (3, 3, 3), origin=(0.17 * H, 0.23 * H, 0.5 * dhat))
    slab = block_tetmesh((3 * H, 3 * H, 0.5 * H), (3, 3, 1), origin=(-H, -H, -0.5 * H))
    nb = block.n_vertices
    mesh = TetMesh(np.vstack([block.vertices, slab.vertices]), np.vstack([block.tets, slab.tets + nb]),
                   fixed=np.r_[np.zeros(nb, bool), np.ones(slab.n_vertices, bool)], name="block on slab")
    tri = mesh.boundary_triangles
    model = fem_from_tetmesh(mesh, mat)
    bottom = tri[np.all(np.isclose(mesh.vertices[tri][:, :, 2], 0.5 * dhat), axis=1)]
    top_slab = tri[np.all(np.isclose(mesh.vertices[tri][:, :, 2], 0.0), axis=1)]
    from headsim.solvers.contact import surface_vertex_areas

    top_areas = surface_vertex_areas(mesh.n_vertices, tri[np.all(np.isclose(mesh.vertices[tri][:, :, 2],
                                                                             H + 0.5 * dhat), axis=1)], mesh.vertices)
    contact = BarrierContact(mesh.vertices, np.vstack([bottom, top_slab]), dhat, mat.young_modulus,
                             friction=MU, friction_slip=EPS)
    return model, contact, top_areas, mat


def _solve_on_slab(model, contact, top_areas, p_n, p_t, x0=None):
    from dataclasses import replace

    from headsim.solvers.contact import QuasiStaticOptions, solve_quasi_static
    from headsim.solvers.newton import NewtonOptions

    ext = np.zeros((model.n_vertices, 3))
    ext[:, 2] = -p_n * top_areas
    ext[:, 0] = p_t * top_areas
    contact.tolerance = 1e-9 * p_n * H * H
    opts = QuasiStaticOptions(force_tolerance=1e-10 * p_n * H * H, max_contact_updates=30,
                              newton=NewtonOptions(max_iterations=200, try_exact_hessian=True,
                                                   exact_after_full_step=True))
    return solve_quasi_static(replace(model, external_force=ext), [contact], initial_positions=x0, options=opts)


def test_barrier_friction_below_the_coulomb_limit_sticks_and_balances_the_load():
    """p_t = mu p_n / 2: the contact forces on the block (barrier + friction) balance both loads
    exactly; friction carries the tangential load (all but the tangential part of the barrier's pair
    forces, which tilt with the block: 1.6e-4 of it measured), inside the Coulomb cone summed over the
    block (|F_t| <= mu N); the lagged normal forces were refreshed to their fixed point."""
    model, contact, top_areas, mat = _block_on_slab()
    p_n = 1e-2 * mat.young_modulus
    first = _solve_on_slab(model, contact, top_areas, p_n, 0.0)
    p_t = 0.5 * MU * p_n
    res = _solve_on_slab(model, contact, top_areas, p_n, p_t, x0=first.positions)
    n_total, t_total = p_n * H * H, p_t * H * H
    block = ~np.asarray(model.fixed)
    total = res.contact_forces[block].sum(axis=0)
    assert total == pytest.approx([-t_total, 0.0, n_total], abs=1e-6 * n_total)
    friction = contact.friction_forces(res.positions)[block].sum(axis=0)
    assert -friction[0] / t_total > 0.99
    normal = total - friction
    assert np.linalg.norm(friction[:2]) <= MU * normal[2] * (1 + 1e-9)
    assert res.contact_updates >= 2  # the lagged normal forces were refreshed


def test_barrier_friction_above_the_coulomb_limit_has_no_static_equilibrium():
    from headsim.errors import ConvergenceError

    model, contact, top_areas, mat = _block_on_slab()
    p_n = 1e-2 * mat.young_modulus
    first = _solve_on_slab(model, contact, top_areas, p_n, 0.0)
    with pytest.raises(ConvergenceError):
        _solve_on_slab(model, contact, top_areas, p_n, 1.5 * MU * p_n, x0=first.positions)


def test_barrier_friction_needs_a_slip_length():
    v, tri = _vertex_over_plate(0.1)
    with pytest.raises(ParameterError, match="friction_slip"):
        BarrierContact(v, tri, 1e-3, 1.0, friction=0.3)


def test_barrier_friction_counts_slip_from_where_a_vertex_first_touched():
    """A vertex that touches only during the solve (it starts 2 dhat above the plate and lands 0.2 m
    aside) has its slip counted from the first accepted iterate at which it touched: moved on by
    delta = eps / 10, it sticks with IPC's mollified force mu lambda f1(delta), f1(y) = 2y/eps - y^2/eps^2
    (Li et al. 2020 eq. 15), where counting from the start (0.2 m of 'slip') would make it slide with
    mu lambda."""
    dhat, kappa, mu, eps = 1e-2, 3e4, 0.5, 1e-3
    v, tri = _vertex_over_plate(2 * dhat)
    bc = BarrierContact(v, tri, dhat, kappa, friction=mu, friction_slip=eps)
    u = np.zeros(0)
    bc.start(v, u)
    landed = v.copy()
    landed[3:, 2] -= 1.5 * dhat
    landed[3:, 0] += 0.2
    bc.hessian(landed, u)  # an accepted Newton iterate (its Hessian is asked for): vertex 3 within dhat
    moved = landed.copy()
    moved[3:, 0] += 0.1 * eps
    assert bc.update(moved, u)  # friction appears: the lagged data changed
    f = bc.friction_forces(moved)
    lam = bc.vertex_forces(moved, u)[3, 2] - f[3, 2]  # the barrier's normal force on vertex 3
    y = 0.1 * eps
    assert f[3, 0] == pytest.approx(-mu * lam * (2 * y / eps - (y / eps) ** 2), rel=1e-6)
    assert f[3, 1] == pytest.approx(0.0, abs=1e-12 * lam)


def test_friction_lag_is_relaxed_when_the_outer_residual_stops_falling():
    """friction_lag="adaptive": the lagged data are taken at the last solution while the outer loop's
    residual falls; where it does not (a 2-cycle of the plain lagged iteration), halfway between the
    last lag configuration and the solution, then a quarter of the way, ..., growing back by 1.5 when
    the residual falls again ("plain": always at the solution)."""
    v, tri = _vertex_over_plate(0.5e-3)
    x0 = v.copy()
    steps = [x0 + [0, 0, -5e-5 * k] for k in range(1, 6)]
    for lag, expected in (("adaptive", [1.0, 1.0, 0.5, 0.25, 0.375]), ("plain", [1.0] * 5)):
        bc = BarrierContact(v, tri, 1e-3, 1.0, friction=0.5, friction_slip=1e-6, friction_lag=lag)
        bc.start(x0, np.zeros(0))
        at_prev = x0
        for x, residual, omega in zip(steps, [1.0, 0.5, 0.6, 0.7, 0.1], expected):
            at = bc._relaxed_lag_configuration(x, residual)
            assert np.allclose(at, at_prev + omega * (x - at_prev), rtol=0, atol=1e-15)
            at_prev = at
    with pytest.raises(ParameterError, match="friction_lag"):
        BarrierContact(v, tri, 1e-3, 1.0, friction=0.5, friction_slip=1e-6, friction_lag="aitken")


def test_pieces_of_one_body_do_not_repel_each_other():
    """Two triangles 0.3 dhat apart that do not share a vertex: as separate connected components (the
    default) they are two bodies and the barrier pushes them apart; labelled as one body (``bodies``,
    e.g. a cropped skin that fell into pieces) they do not interact at all."""
    dhat = 1e-3
    v, tri = _vertex_over_plate(0.3 * dhat)
    apart = BarrierContact(v, tri, dhat, 1.0)
    assert apart.energy(v, np.zeros(0)) > 0 and apart.vertex_forces(v, np.zeros(0))[3, 2] > 0
    one = BarrierContact(v, tri, dhat, 1.0, bodies=np.zeros(len(v), dtype=int))
    assert one.energy(v, np.zeros(0)) == 0.0 and not one.vertex_forces(v, np.zeros(0)).any()
    assert one.minimum_distance(v) == np.inf and not one.vertices_within(v, dhat).any()
    with pytest.raises(ParameterError, match="bodies"):
        BarrierContact(v, tri, dhat, 1.0, bodies=np.zeros(3, dtype=int))


@pytest.mark.parametrize("ccd", ["additive", "tight-inclusion"])
def test_both_ccd_methods_stop_a_point_falling_through_a_plate_short_of_it(ccd):
    """A vertex 1 cm above the plate moved 2 cm straight down: the additive CCD stops where its gap is
    10 % of the start (fraction (1 - 0.1) x 0.5 = 0.45), the inclusion method closer; both short of 0.5."""
    v, tri = _vertex_over_plate(0.01)
    bc = BarrierContact(v, tri, 1e-3, 1.0, ccd=ccd)
    v1 = v.copy()
    v1[3:, 2] -= 0.02
    frac = bc.step_fraction(v, np.zeros(0), v1, np.zeros(0))
    if ccd == "additive":
        assert frac == pytest.approx(0.45, rel=1e-6)
    else:
        assert 0.45 < frac < 0.5
    assert bc.ccd_fallbacks == 0


def test_an_additive_step_that_crosses_is_recomputed_by_tight_inclusion(monkeypatch):
    """Where the surfaces stepped by the additive CCD's fraction cross (its floating-point hazard), the
    fraction of the provably conservative inclusion method is returned instead."""
    v, tri = _vertex_over_plate(0.01)
    bc = BarrierContact(v, tri, 1e-3, 1.0)
    v1 = v.copy()
    v1[3:, 2] -= 0.02
    inclusion = BarrierContact(v, tri, 1e-3, 1.0, ccd="tight-inclusion").step_fraction(v, None, v1, None)
    monkeypatch.setattr(bc._ipc, "has_intersections", lambda mesh, vertices: True)
    assert bc.step_fraction(v, None, v1, None) == inclusion
    assert bc.ccd_fallbacks == 1


def test_unknown_ccd_method_is_refused():
    v, tri = _vertex_over_plate(0.01)
    with pytest.raises(ParameterError, match="ccd"):
        BarrierContact(v, tri, 1e-3, 1.0, ccd="exact")
