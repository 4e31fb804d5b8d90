"""Barrier contact (headsim.solvers.barrier): the pressure law against the potential's own force,
and a force-driven solve that must stop at the barrier without the surfaces crossing."""

import numpy as np
import pytest

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
