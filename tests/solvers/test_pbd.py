"""PBD / XPBD core (headsim.solvers.pbd): kernels against slow references, analytical checks, errors."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.errors import DivergenceError, MeshError, ParameterError
from headsim.mesh.primitives import box, icosphere
from headsim.solvers import _reference_pbd as ref
from headsim.solvers._kernels import pbd as K
from headsim.solvers.pbd import (PBDModel, PBDOptions, PBDSolver, PBDState, colour_edges, hydrostatic_forces,
                                 particle_masses)


@pytest.fixture(scope="module")
def sphere():
    return icosphere(0.1, 2)


def _perturbed(mesh, seed=0, scale=0.01):
    rng = np.random.default_rng(seed)
    return mesh.vertices + rng.normal(scale=scale, size=mesh.vertices.shape)


def test_particle_masses_follow_area_and_sum_to_object_mass(sphere):
    m = particle_masses(sphere.vertices, sphere.triangles, 2.0)
    assert m.sum() == pytest.approx(2.0, rel=1e-12)
    np.testing.assert_allclose(m / m.sum(), sphere.vertex_areas / sphere.vertex_areas.sum(), rtol=1e-12)


def test_edge_colouring_is_proper(sphere):
    order, offsets = colour_edges(sphere.edges, sphere.n_vertices)
    e = sphere.edges[order]
    for k in range(len(offsets) - 1):
        block = e[offsets[k]:offsets[k + 1]].ravel()
        assert len(np.unique(block)) == len(block)
    assert offsets[-1] == len(e)


@pytest.mark.parametrize("alpha_tilde,stiffness", [(0.0, 1.0), (0.0, 0.5), (3.0, 1.0)])
def test_coloured_gauss_seidel_matches_sequential_reference(sphere, alpha_tilde, stiffness):
    p0 = _perturbed(sphere)
    rest = np.linalg.norm(sphere.vertices[sphere.edges[:, 0]] - sphere.vertices[sphere.edges[:, 1]], axis=1)
    w = np.random.default_rng(1).uniform(0.5, 2.0, sphere.n_vertices)
    w[:5] = 0.0
    order, offsets = colour_edges(sphere.edges, sphere.n_vertices)
    edges, rest = np.ascontiguousarray(sphere.edges[order]), rest[order]
    for kernel in (K.project_distance_coloured, K.project_distance_coloured_parallel):
        p, lam = p0.copy(), np.zeros(len(edges))
        p_ref, lam_ref = p0.copy(), np.zeros(len(edges))
        for _ in range(3):
            kernel(edges, rest, offsets, w, alpha_tilde, stiffness, lam, p)
            ref.project_distance_sequential(edges, rest, w, alpha_tilde, stiffness, lam_ref, p_ref)
        np.testing.assert_allclose(p, p_ref, atol=1e-14)
        np.testing.assert_allclose(lam, lam_ref, atol=1e-12)


def test_jacobi_matches_numpy_reference(sphere):
    model = PBDModel.from_surface(_perturbed(sphere), sphere.triangles, total_mass=1.0)
    solver = PBDSolver(model, PBDOptions(method="jacobi", jacobi_omega=1.3))
    p0 = _perturbed(sphere, seed=3)
    w = model.inverse_mass
    rest = model.rest_length
    for kernel in (K.project_distance_jacobi, K.project_distance_jacobi_parallel):
        p, lam = p0.copy(), np.zeros(len(rest))
        p_ref, lam_ref = p0.copy(), np.zeros(len(rest))
        for _ in range(3):
            kernel(solver._edges, rest, solver._vertex_edge_offsets, solver._vertex_edges, w, 0.7, 1.0, 1.3,
                   lam, solver._dlam, solver._dir, p)
            ref.project_distance_jacobi_numpy(model.edges, rest, w, 0.7, 1.0, 1.3, lam_ref, p_ref)
        np.testing.assert_allclose(p, p_ref, atol=1e-14)


def test_volume_gradient_matches_finite_differences(sphere):
    p = _perturbed(sphere)
    _, grad = ref.volume_and_gradient(p, sphere.triangles)
    h = 1e-7
    for i in (0, 7, 40):
        for c in range(3):
            q = p.copy()
            q[i, c] += h
            vp, _ = ref.volume_and_gradient(q, sphere.triangles)
            q[i, c] -= 2 * h
            vm, _ = ref.volume_and_gradient(q, sphere.triangles)
            assert grad[i, c] == pytest.approx((vp - vm) / (2 * h), rel=1e-6, abs=1e-12)


def test_volume_projection_matches_reference_and_reaches_target(sphere):
    p0 = _perturbed(sphere)
    w = np.linspace(0.5, 1.5, sphere.n_vertices)
    vol0, _ = ref.volume_and_gradient(p0, sphere.triangles)
    target = vol0 * 1.2
    p, lam = p0.copy(), np.zeros(1)
    tb, vb = np.zeros(sphere.n_triangles, np.int64), np.zeros(sphere.n_vertices, np.int64)
    K.project_volume(sphere.triangles, tb, vb, np.array([target]), w, 0.0, 1.0, lam,
                     np.zeros_like(p), np.zeros(1), np.zeros(1), p)
    p_ref = p0.copy()
    ref.project_volume_numpy(sphere.triangles, target, w, 0.0, 0.0, p_ref)
    np.testing.assert_allclose(p, p_ref, atol=1e-14)
    for _ in range(3):
        K.project_volume(sphere.triangles, tb, vb, np.array([target]), w, 0.0, 1.0,
                         lam, np.zeros_like(p), np.zeros(1), np.zeros(1), p)
    vol, _ = ref.volume_and_gradient(p, sphere.triangles)
    assert vol == pytest.approx(target, rel=1e-12)


def test_free_fall_is_symplectic_euler():
    """No constraints: y_n = y_0 - g dt² n(n+1)/2 exactly (velocity first, then position)."""
    model = PBDModel(mass=[1.0, 2.0], fixed=[False, True], edges=np.zeros((0, 2)), rest_length=[])
    dt, g, n = 0.01, 9.81, 25
    solver = PBDSolver(model, PBDOptions(dt=dt, gravity=(0, -g, 0)))
    state = PBDState.at_rest([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    for _ in range(n):
        state = solver.step(state)
    assert state.positions[0, 1] == pytest.approx(1.0 - g * dt**2 * n * (n + 1) / 2, rel=1e-12)
    assert state.positions[1, 1] == 1.0  # fixed
    assert state.time == pytest.approx(n * dt)


@pytest.mark.parametrize("iterations", [2, 40])
def test_xpbd_hanging_mass_stretch_is_independent_of_iterations(iterations):
    """A mass m on a spring of compliance alpha under gravity rests at extension m g alpha (Hooke)."""
    m, g, alpha, L = 0.5, 9.81, 2e-3, 0.1
    model = PBDModel(mass=[1.0, m], fixed=[True, False], edges=[[0, 1]], rest_length=[L])
    opts = PBDOptions(dt=1e-2, iterations=iterations, gravity=(0, -g, 0), damping=0.2, xpbd=True,
                      edge_compliance=alpha, stop_tolerance=1e-13, max_steps=5000)
    state, info = PBDSolver(model, opts).solve(PBDState.at_rest([[0, 0, 0], [0, -L, 0]]))
    assert info.converged
    stretch = -state.positions[1, 1] - L
    assert stretch == pytest.approx(m * g * alpha, rel=1e-3)


def test_pbd_stiffness_depends_on_iterations_but_xpbd_does_not():
    """The reason for the XPBD option: with PBD stiffness < 1 the rest state changes with iterations."""
    def rest_stretch(xpbd, iterations):
        model = PBDModel(mass=[1.0, 0.5], fixed=[True, False], edges=[[0, 1]], rest_length=[0.1])
        opts = PBDOptions(dt=1e-2, iterations=iterations, gravity=(0, -9.81, 0), damping=0.2, xpbd=xpbd,
                          stiffness=0.5, edge_compliance=2e-3, stop_tolerance=1e-13, max_steps=5000)
        s, _ = PBDSolver(model, opts).solve(PBDState.at_rest([[0, 0, 0], [0, -0.1, 0]]))
        return -s.positions[1, 1] - 0.1

    assert rest_stretch(False, 2) > 2 * rest_stretch(False, 20)
    assert rest_stretch(True, 2) == pytest.approx(rest_stretch(True, 20), rel=1e-3)


def test_stabilisation_projects_without_velocity(sphere):
    model = PBDModel.from_surface(sphere.vertices, sphere.triangles, total_mass=1.0, closed_bodies=True)
    state = PBDState.at_rest(_perturbed(sphere, scale=0.003))
    out = PBDSolver(model, PBDOptions(stabilisation_iterations=20)).stabilise(state)
    assert np.all(out.velocities == 0)
    err = lambda p: np.abs(np.linalg.norm(p[model.edges[:, 0]] - p[model.edges[:, 1]], axis=1) - model.rest_length).max()
    assert err(out.positions) < 0.2 * err(state.positions)
    # the last projection is linearised: a second-order residual remains
    assert model.body_volumes(out.positions)[0] == pytest.approx(model.volume_target[0], rel=1e-5)


def test_solve_stop_rule_and_cancel(sphere):
    model = PBDModel.from_surface(sphere.vertices, sphere.triangles, total_mass=1.0, closed_bodies=True)
    start = PBDState.at_rest(_perturbed(sphere, scale=0.003))
    opts = PBDOptions(gravity=(0, 0, 0), damping=0.3, xpbd=True, edge_compliance=1e-3, stop_tolerance=1e-9,
                      max_steps=2000)
    state, info = PBDSolver(model, opts).solve(start)
    assert info.converged and not info.cancelled and info.last_change < 1e-9 * sphere.n_vertices
    _, info = PBDSolver(model, opts).solve(start, cancel=lambda: True)
    assert info.cancelled and info.steps == 0
    calls = []
    PBDSolver(model, PBDOptions(max_steps=3, min_steps=3, stop_tolerance=1.0)).solve(
        start, callback=lambda s, c: calls.append(s.steps))
    assert calls == [1, 2, 3]


def test_column_heights_of_a_box_and_hydrostatic_force():
    """Bottom vertices of a closed box see the whole height above them; top vertices see nothing."""
    b = box(size=(0.2, 0.3, 0.2), divisions=4)
    h = np.zeros(b.n_vertices)
    K.column_heights(np.ascontiguousarray(b.vertices), b.triangles, np.array([0.0, 1.0, 0.0]),
                     np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), 0.05, h)
    y = b.vertices[:, 1]
    inner = (np.abs(b.vertices[:, 0]) < 0.099) & (np.abs(b.vertices[:, 2]) < 0.099)
    bottom, top = inner & np.isclose(y, y.min()), inner & np.isclose(y, y.max())
    assert bottom.sum() > 0 and top.sum() > 0
    np.testing.assert_allclose(h[bottom], 0.3, rtol=1e-12)
    np.testing.assert_allclose(h[top], 0.0)
    f = hydrostatic_forces(b.vertices, b.triangles, 1000.0, (0, -9.81, 0))
    np.testing.assert_allclose(f[bottom, 1], -1000 * 9.81 * 0.3 * b.vertex_areas[bottom], rtol=1e-12)
    assert np.all(f[:, [0, 2]] == 0)


def test_dropped_ball_keeps_its_volume():
    """Seed fig. 3: volume constraint + gravity + hydrostatic pressure, resting on a plane: |ΔV|/V < 0.5 %."""
    from headsim.graft.scenes import run_ball_scene

    r = run_ball_scene()
    n = r.numbers
    assert n["stopped_by_rule"]
    assert abs(n["relative_volume_change"]) < 5e-3
    assert n["lowest_point_m"] >= -1e-9  # on, not through, the plane
    assert n["height_m"] < 0.2 * 0.95  # it did flatten on the plane


def test_bad_parameters_and_divergence(sphere):
    for kw in (dict(damping=1.5), dict(dt=0), dict(iterations=0), dict(method="sor"), dict(stiffness=0.0)):
        with pytest.raises(ParameterError):
            PBDOptions(**kw)
    with pytest.raises(ParameterError):
        PBDModel(mass=[1.0, -1.0], fixed=[False, False], edges=[[0, 1]], rest_length=[1.0])
    with pytest.raises(ParameterError):
        PBDModel(mass=[1.0, 1.0], fixed=[False, False], edges=[[0, 0]], rest_length=[1.0])
    with pytest.raises((ParameterError, MeshError)):
        particle_masses(sphere.vertices, sphere.triangles, 0.0)
    model = PBDModel(mass=[1.0], fixed=[False], edges=np.zeros((0, 2)), rest_length=[])
    with pytest.raises(DivergenceError):
        PBDSolver(model, PBDOptions(gravity=(0, -1e308, 0), dt=1e3)).step(PBDState.at_rest([[0.0, 0.0, 0.0]]))
