"""Implicit Kirchhoff rod dynamics against beam theory, the elastica and the stability analysis."""

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.solvers.rods import (
    GeneralizedAlpha,
    ImplicitRodSolver,
    RodLoads,
    RodModel,
    RodSolverOptions,
    amplification_eigenvalues,
    initial_state,
    kinetic_energy,
    straight_frame,
)
from headsim.solvers.rods_analytic import cantilever_self_weight_elastica, euler_bernoulli_cantilever_frequencies

E, RADIUS, RHO, L = 3.89e9, 35e-6, 1300.0, 0.05
AREA, INERTIA = np.pi * RADIUS**2, np.pi * RADIUS**4 / 4
EI, RHOA = E * INERTIA, RHO * AREA
BETA_L = [1.8751040687, 4.6940911330]


def hair(N, n_fibres=1):
    return RodModel(N, np.full(n_fibres, L), RHOA, RHO * INERTIA * np.array([1, 1, 2]),
                    [EI, EI, 0.89e9 * 2 * INERTIA], np.zeros((N + 1, 3)), [0, 0, 0], straight_frame([1, 0, 0]))


def test_coefficients_from_rho_inf_are_second_order_and_validated():
    for r in (0.0, 0.3, 0.7, 1.0):
        c = GeneralizedAlpha.from_rho_inf(r)
        assert c.alpha_t - c.beta_t + c.gamma_t == pytest.approx(0.5)
        lam = amplification_eigenvalues(1e10j, c.alpha_t, c.beta_t, c.gamma_t)[0]
        assert np.abs(lam).max() == pytest.approx(r, abs=1e-4)  # rho_inf = 0: double root, ~|Omega|^-1/2
    with pytest.raises(ParameterError):
        GeneralizedAlpha.from_rho_inf(1.5)


def test_dynamic_steady_state_matches_self_weight_elastica_with_second_order():
    """Released under gravity and relaxed with backward Euler: the rest shape is the elastica."""
    q = RHOA * 9.81
    _, y_ref, _ = cantilever_self_weight_elastica(q, L, EI)
    errs, iters = [], []
    for N in (10, 20, 40):
        m = hair(N)
        st = initial_state(m)
        solver = ImplicitRodSolver(RodSolverOptions(coefficients=GeneralizedAlpha.backward_euler()))
        for dt in [0.01] * 20 + [0.1] * 20 + [1.0] * 10:
            st, rep = solver.step(m, st, dt, RodLoads(gravity=[0, 0, -9.81]))
            iters.append(rep.iterations[0])
        assert kinetic_energy(m, st)[0] < 1e-20
        errs.append(abs(-st.tip_position[0, 2] - y_ref) / y_ref)
    print("dynamic steady-state errors N=10,20,40:", errs, "mean Newton iterations:", np.mean(iters))
    assert errs[-1] < 0.001
    assert np.polyfit(np.log([10, 20, 40]), np.log(errs), 1)[0] == pytest.approx(-2.0, abs=0.2)


def _mode_start(m, mode, amplitude=1e-3):
    """Initial velocity in the clamped-free mode shape (transverse along d2, omega1 = -dv2/ds)."""
    N = m.n_segments
    b = BETA_L[mode] / L
    s = np.linspace(0, L, N + 1)
    sig = (np.cosh(b * L) + np.cos(b * L)) / (np.sinh(b * L) + np.sin(b * L))
    phi = np.cosh(b * s) - np.cos(b * s) - sig * (np.sinh(b * s) - np.sin(b * s))
    dphi = b * (np.sinh(b * s) + np.sin(b * s) - sig * (np.cosh(b * s) - np.cos(b * s)))
    x = np.zeros((1, N + 1, 12))
    x[0, :, 1] = amplitude * phi / phi[-1]
    x[0, :, 3] = -amplitude * dphi / phi[-1]
    return initial_state(m, x=x)


def _frequency(times, signal):
    i = np.where(np.sign(signal[1:-1]) != np.sign(signal[2:]))[0] + 1
    tc = times[i] - signal[i] * (times[i + 1] - times[i]) / (signal[i + 1] - signal[i])
    return 1.0 / (2 * np.mean(np.diff(tc)))


@pytest.mark.parametrize("mode,startup", [(0, "backward_euler"), (1, "backward_euler"), (0, "seed")])
def test_small_amplitude_frequencies_match_euler_bernoulli(mode, startup):
    """Both start-up rules: a backward-Euler first step, or the seed's d_t x = M^-1 (P d_s x + g)."""
    f_ref = euler_bernoulli_cantilever_frequencies(L, EI, RHOA, 2)[mode]
    m = hair(24)
    st = _mode_start(m, mode)
    solver = ImplicitRodSolver(RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(1.0), startup=startup))
    dt = 1 / (40 * f_ref)
    t, z = [0.0], [0.0]
    for _ in range(120):
        st, _ = solver.step(m, st, dt)
        t.append(st.time)
        z.append(st.tip_position[0, 2])
    f = _frequency(np.array(t), np.array(z))
    print(f"mode {mode + 1} ({startup} start-up): {f:.4f} Hz vs Euler-Bernoulli {f_ref:.4f} Hz, rel. error {(f - f_ref) / f_ref:+.2e}")
    assert f == pytest.approx(f_ref, rel=0.02)


@pytest.mark.parametrize("rho_inf,steps_per_period", [(0.0, 8), (0.5, 8), (0.3, 4)])
def test_numerical_damping_follows_the_amplification_factor(rho_inf, steps_per_period):
    """Energy decay per step of the first mode = |lambda(i w dt)|^2 of eqs. 3.144/3.145; the period
    error = arg(lambda) / (w dt) - 1."""
    f_ref = euler_bernoulli_cantilever_frequencies(L, EI, RHOA, 1)[0]
    m = hair(20)
    st = _mode_start(m, 0)
    c = GeneralizedAlpha.from_rho_inf(rho_inf, 1.0)
    solver = ImplicitRodSolver(RodSolverOptions(coefficients=c))
    dt = 1 / (steps_per_period * f_ref)
    w = np.ones(m.n_nodes)
    w[0] = w[-1] = 0.5

    def energy(s):
        return kinetic_energy(m, s)[0] + 0.5 * (w[:, None] * s.curvature[0] ** 2 * m.stiffness[0]).sum() * m.segment_length[0]

    e = [energy(st)]
    for _ in range(6 * steps_per_period):
        st, _ = solver.step(m, st, dt)
        e.append(energy(st))
    n = np.arange(len(e))
    measured = np.polyfit(n[steps_per_period:], np.log(e[steps_per_period:]), 1)[0]  # skip the start-up step
    lam = amplification_eigenvalues(2j * np.pi * f_ref * dt, c.alpha_t, c.beta_t, c.gamma_t)[0, 0]
    predicted = 2 * np.log(abs(lam))
    print(f"rho_inf={rho_inf}: log energy decay per step {measured:.5f}, predicted {predicted:.5f}")
    assert measured == pytest.approx(predicted, rel=0.05)


@pytest.mark.parametrize("N", [6, 12, 25, 50, 100])
def test_stable_over_segments_and_time_steps(N):
    """Seed §3.4.9: stable for 6..100 segments and dt = 1e-5..1e-2 s (hair under gravity)."""
    report = []
    for dt in (1e-5, 1e-4, 1e-3, 1e-2):
        m = hair(N)
        st = initial_state(m)
        solver = ImplicitRodSolver(RodSolverOptions(coefficients=GeneralizedAlpha.from_rho_inf(0.5)))
        its = []
        for _ in range(15):
            st, rep = solver.step(m, st, dt, RodLoads(gravity=[0, 0, -9.81]))
            its.append(rep.iterations[0])
        assert np.isfinite(st.positions).all()
        seg = np.linalg.norm(np.diff(st.positions[0], axis=0), axis=1)
        np.testing.assert_allclose(seg, L / N, rtol=1e-3)  # inextensible
        assert st.tip_position[0, 2] < 0  # falls
        report.append((dt, float(np.mean(its))))
    print(f"N={N}: (dt, mean Newton iterations per step):", report)


def test_batched_fibres_match_single_fibre():
    m1, m4 = hair(10), hair(10, n_fibres=9)
    s1, s4 = initial_state(m1), initial_state(m4)
    solver = ImplicitRodSolver()
    for _ in range(5):
        s1, _ = solver.step(m1, s1, 1e-3, RodLoads(gravity=[0, 0, -9.81]))
        s4, _ = solver.step(m4, s4, 1e-3, RodLoads(gravity=[0, 0, -9.81]))
    np.testing.assert_allclose(s4.positions, np.broadcast_to(s1.positions, s4.positions.shape), atol=1e-14)
