"""Integrators: the seed's stability analysis (Heinze eqs. 3.3-3.6), divergence detection, implicit Euler."""

import numpy as np
import pytest

from headsim.errors import DivergenceError, ParameterError
from headsim.solvers._kernels.massspring import explicit_euler_step
from headsim.solvers.grids import block_tetmesh
from headsim.solvers.integrators import (ExplicitEuler, ImplicitEuler, SymplecticEuler, critical_time_step,
                                        lowest_angular_frequency, simulate)
from headsim.solvers.massspring import MassSpringModel, mass_spring_from_tetmesh
from headsim.solvers.state import BodyState


def _decay_model(k: float) -> MassSpringModel:
    """One unit mass tied by a pure damper (c = k) to a fixed point: v' = -k v along the axis.

    This is the seed's test equation x' = -k x (eq. 3.3) for the velocity, integrated by eq. 3.1.
    """
    return MassSpringModel([[-1.0, 0, 0], [0.0, 0, 0]], [1.0, 1.0], [[0, 1]], [1.0], [0.0], [k],
                           [True, False], np.zeros((2, 3)), [0, 0])


def _velocity_history(integrator, k, dt, steps=40, v0=1e-6):
    model = _decay_model(k)
    state = BodyState(model.rest_positions, [[0, 0, 0], [v0, 0, 0]])
    states = simulate(integrator, model, state, dt, steps)
    return np.array([s.velocities[1, 0] for s in states])


@pytest.mark.parametrize("k", [0.5, 5.0])
def test_explicit_euler_on_linear_decay_follows_eqs_3_3_to_3_6(k):
    # dt < 1/k: monotone decay with factor (1 - k dt)
    v = _velocity_history(ExplicitEuler(), k, 0.5 / k)
    assert np.all(v[1:] > 0) and np.all(np.diff(v) < 0)
    assert v[1:] / v[:-1] == pytest.approx(1 - 0.5, rel=1e-12)
    # 1/k < dt < 2/k: oscillating sign, still decaying
    v = _velocity_history(ExplicitEuler(), k, 1.5 / k)
    assert np.all(v[1:] * v[:-1] < 0)
    assert abs(v[-1]) < abs(v[0])
    # dt > 2/k: oscillating and growing (diverges)
    v = _velocity_history(ExplicitEuler(), k, 2.5 / k, steps=20)
    assert np.all(v[1:] * v[:-1] < 0)
    assert np.all(np.abs(v[1:]) > np.abs(v[:-1]))
    assert abs(v[-1]) / abs(v[0]) == pytest.approx(1.5**20, rel=1e-9)


@pytest.mark.parametrize("factor", [0.5, 1.5, 2.5, 50.0])
def test_implicit_euler_is_stable_for_every_dt(factor):
    k = 2.0
    v = _velocity_history(ImplicitEuler(), k, factor / k, steps=4, v0=1e-2)
    assert np.all(v[1:] > 0) and np.all(np.diff(v) < 0)  # no oscillation, monotone decay
    assert v[1:] / v[:-1] == pytest.approx(1 / (1 + factor), rel=1e-6)


def test_explicit_euler_is_exactly_eqs_3_1_and_3_2():
    mesh = block_tetmesh((0.1, 0.1, 0.1), (2, 1, 1))
    model = mass_spring_from_tetmesh(mesh, stiffness=5.0, damping=0.1, total_mass=0.5)
    rng = np.random.default_rng(0)
    state = BodyState(model.rest_positions + 1e-3 * rng.standard_normal((model.n_vertices, 3)),
                      1e-3 * rng.standard_normal((model.n_vertices, 3)))
    new = ExplicitEuler().step(model, state, 0.01)
    f = model.forces(state.positions, state.velocities)
    assert np.allclose(new.velocities, state.velocities + 0.01 * f / model.mass[:, None], rtol=1e-14)  # eq. 3.1
    assert np.allclose(new.positions, state.positions + 0.01 * state.velocities, rtol=1e-14)  # eq. 3.2
    xo, vo = np.empty_like(f), np.empty_like(f)
    explicit_euler_step(state.positions, state.velocities, model.mass, model.fixed, f, 0.01, xo, vo)
    assert np.allclose(xo, new.positions) and np.allclose(vo, new.velocities)
    assert state.step == 0 and new.step == 1 and new.time == pytest.approx(0.01)


def test_divergence_is_raised_within_one_step_with_step_and_cause():
    mesh = block_tetmesh((0.1, 0.1, 0.1), (1, 1, 1))
    model = mass_spring_from_tetmesh(mesh, stiffness=5e4, total_mass=0.01)
    state = BodyState(model.rest_positions * 1.05, np.zeros((model.n_vertices, 3)))
    dt = 1.0
    assert critical_time_step(model) < dt
    with pytest.raises(DivergenceError, match=r"step 1 .*dt = 1 s.*stability limit"):
        ExplicitEuler().step(model, state, dt)
    nan_state = BodyState(np.where(np.arange(model.n_vertices)[:, None] == 0, np.nan, model.rest_positions),
                          np.zeros((model.n_vertices, 3)))
    with pytest.raises(DivergenceError, match="non-finite"):
        SymplecticEuler().step(model, nan_state, 1e-3)
    with pytest.raises(ParameterError):
        ExplicitEuler().step(model, state, -1.0)


def test_critical_time_step_matches_single_spring():
    # two unit masses, one spring k, one end fixed: omega^2 = k/m -> limit 2 / sqrt(k) from the bound 2k row sum
    k = 4.0
    m = MassSpringModel([[0, 0, 0], [1.0, 0, 0]], [1.0, 1.0], [[0, 1]], [1.0], [k], [0.0], [True, False],
                        np.zeros((2, 3)), [0, 0])
    assert critical_time_step(m) == pytest.approx(2 / np.sqrt(k))


def test_lowest_angular_frequency_of_a_mass_on_three_orthogonal_springs():
    # free mass m at the origin held by springs k_x, k_y, k_z to fixed points on the axes: at rest the
    # stiffness is diag(k_x, k_y, k_z), so the lowest angular frequency is sqrt(min k / m)
    m, ks = 0.5, [8.0, 2.0, 5.0]
    v = [[0, 0, 0], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]
    model = MassSpringModel(v, [m, 1, 1, 1], [[0, 1], [0, 2], [0, 3]], [1.0, 1.0, 1.0], ks, [0.0] * 3,
                            [False, True, True, True], np.zeros((4, 3)), [0] * 4)
    assert lowest_angular_frequency(model) == pytest.approx(np.sqrt(min(ks) / m), rel=1e-9)


def test_symplectic_euler_keeps_oscillator_energy_bounded_explicit_does_not():
    k, mass = 4.0, 1.0
    model = MassSpringModel([[0, 0, 0], [1.0, 0, 0]], [1.0, mass], [[0, 1]], [1.0], [k], [0.0], [True, False],
                            np.zeros((2, 3)), [0, 0])
    state = BodyState([[0, 0, 0], [1.1, 0, 0]], np.zeros((2, 3)))

    def energy(s):
        return 0.5 * mass * np.sum(s.velocities[1] ** 2) + 0.5 * k * (s.positions[1, 0] - 1.0) ** 2

    dt = 0.05
    sym = simulate(SymplecticEuler(), model, state, dt, 400)
    exp = simulate(ExplicitEuler(), model, state, dt, 400)
    assert max(energy(s) for s in sym) < 1.1 * energy(state)
    assert energy(exp[-1]) > 2.0 * energy(state)  # forward Euler pumps energy into an undamped oscillator


def test_implicit_euler_settles_a_hanging_block_under_gravity():
    from dataclasses import replace

    from headsim.solvers.massspring import STANDARD_GRAVITY
    from headsim.solvers.materials import Material

    mesh = block_tetmesh((0.02, 0.06, 0.02), (1, 3, 1), origin=(0, -0.06, 0))
    mesh = replace(mesh, fixed=mesh.vertices[:, 1] == 0.0)
    model = mass_spring_from_tetmesh(mesh, material=Material.from_kpa(1.0, 0.25, 1000.0), gravity=STANDARD_GRAVITY,
                                     damping_ratio=0.1)
    dt = 100 * critical_time_step(model)
    states = simulate(ImplicitEuler(), model, BodyState.at_rest(model.rest_positions), dt, 30)
    # at rest the spring forces balance gravity: the support carries the whole weight
    from headsim.solvers.contact import solve_quasi_static

    eq = solve_quasi_static(model)
    assert np.abs(states[-1].positions - eq.positions).max() < 1e-3 * np.abs(eq.positions - model.rest_positions).max() + 1e-9
    assert eq.reaction_forces[:, 1].sum() == pytest.approx(-model.external_force[:, 1].sum(), rel=1e-9)


def test_inverted_tets_are_detected_as_divergence():
    from headsim.solvers.fem import fem_from_tetmesh
    from headsim.solvers.materials import Material

    mesh = block_tetmesh((0.01, 0.01, 0.01), (1, 1, 1))
    model = fem_from_tetmesh(mesh, Material.from_kpa(10.0, 0.3, 1000.0))
    v = np.zeros((model.n_vertices, 3))
    v[:, 2] = -(mesh.vertices[:, 2] - 0.005) * 40.0  # flips the block through itself within the step
    state = BodyState(model.rest_positions, v)
    with pytest.raises(DivergenceError, match="inverted"):
        SymplecticEuler(max_jump=10.0).step(model, state, 0.001 * 25 * 2.5)
