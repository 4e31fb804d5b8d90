"""Anderson acceleration of the PBD rest state (headsim.solvers.pbd_anderson): same fixed points as the
seed's damped time stepping, reached in fewer steps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.mesh.primitives import icosphere
from headsim.solvers.pbd import PBDModel, PBDOptions, PBDSolver, PBDState


def _inflated_sphere():
    """Icosphere (r = 0.1 m) with springs at their lengths, 3 particles fixed (no rigid motion), target
    volume raised by 30 %: a stretched balloon, whose rest state is unique."""
    s = icosphere(0.1, 2)
    fixed = np.zeros(s.n_vertices, bool)
    fixed[[0, 5, 11]] = True
    model = PBDModel.from_surface(s.vertices, s.triangles, total_mass=1.0, fixed=fixed, closed_bodies=True)
    return model.with_volume_target(1.3 * model.volume_target), s.vertices


def _hanging_sheet(n=8, size=0.1):
    """A vertical square sheet (XPBD springs, gravity -y) held at its two top corners: gravity stretches it in
    its plane. (Held horizontally it would have two mirror rest states, sagging to +z or -z.)"""
    g = np.linspace(0, size, n + 1)
    x, z = np.meshgrid(g, g, indexing="ij")
    v = np.column_stack([x.ravel(), -z.ravel(), np.zeros(x.size)])
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    fixed = np.zeros(len(v), bool)
    fixed[[idx[0, 0], idx[n, 0]]] = True
    return PBDModel.from_surface(v, tri, total_mass=0.05, fixed=fixed), v


CASES = {
    "inflated sphere": (_inflated_sphere, PBDOptions(dt=1e-2, iterations=2, gravity=(0, 0, 0), damping=0.05, xpbd=True,
                                                     edge_compliance=1e-3, stop_tolerance=1e-12, max_steps=100_000,
                                                     stop_patience=50)),
    "hanging sheet": (_hanging_sheet, PBDOptions(dt=1e-2, iterations=4, damping=0.05, xpbd=True, edge_compliance=1e-4,
                                                 stop_tolerance=1e-12, max_steps=100_000, stop_patience=50)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_anderson_reaches_the_rest_state_of_time_stepping_in_fewer_steps(case):
    build, options = CASES[case]
    model, x0 = build()
    plain_state, plain = PBDSolver(model, options).solve(PBDState.at_rest(x0))
    fast_options = replace(options, acceleration="anderson", anderson_history=6, stop_patience=1)
    fast_state, fast = PBDSolver(model, fast_options).solve(PBDState.at_rest(x0))
    assert plain.converged and fast.converged
    size = np.ptp(x0, axis=0).max()
    displacement = np.abs(plain_state.positions - x0).max()
    assert displacement > 0.02 * size  # the rest state is far from the start
    np.testing.assert_allclose(fast_state.positions, plain_state.positions, rtol=0, atol=1e-6 * size)
    assert fast.steps < plain.steps / 2
    np.testing.assert_array_equal(fast_state.positions[model.fixed], x0[model.fixed])
    np.testing.assert_array_equal(fast_state.velocities, 0.0)


def test_anderson_result_is_a_fixed_point_of_the_step_from_rest():
    model, x0 = _inflated_sphere()
    options = replace(CASES["inflated sphere"][1], acceleration="anderson", stop_patience=1)
    solver = PBDSolver(model, options)
    state, info = solver.solve(PBDState.at_rest(x0))
    after = solver.step(PBDState.at_rest(state.positions)).positions
    np.testing.assert_array_equal(solver.rest_step(state.positions), after)  # rest_step is that step
    assert np.abs(after - state.positions).sum() < options.stop_tolerance * model.n_particles


def test_anderson_callback_cancel_and_options():
    model, x0 = _inflated_sphere()
    options = replace(CASES["inflated sphere"][1], acceleration="anderson")
    seen = []
    state0 = PBDState.at_rest(x0)
    state, info = PBDSolver(model, options).solve(state0, callback=lambda s, r: seen.append(r),
                                                  cancel=lambda: len(seen) >= 3)
    assert info.cancelled and not info.converged and state is state0 and len(seen) == 3
    _, info = PBDSolver(model, replace(options, max_steps=4)).solve(state0)
    assert not info.converged and info.steps >= 4
    with pytest.raises(ParameterError):
        PBDOptions(acceleration="chebyshev")
    with pytest.raises(ParameterError):
        PBDOptions(anderson_history=0)
