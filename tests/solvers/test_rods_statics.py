"""Static rods: energy minimisation against the elastica, its convergence order, Pai's follower loads."""

import numpy as np
import pytest

from headsim.solvers.rods import RodModel, straight_frame
from headsim.solvers.rods_analytic import (
    cantilever_self_weight_elastica,
    cantilever_tip_load_elastica,
    cantilever_tip_load_linear,
)
from headsim.solvers.rods_statics import pai_static, solve_static_energy, static_energy, static_nodal_loads

E, RADIUS, RHO, L = 3.89e9, 35e-6, 1300.0, 0.05
AREA, INERTIA = np.pi * RADIUS**2, np.pi * RADIUS**4 / 4
EI = E * INERTIA


def hair(N, k0=None):
    """5 cm hair along +x, d2 = +z (gravity -z bends about d1)."""
    k0 = np.zeros((N + 1, 3)) if k0 is None else k0
    return RodModel(N, [L], RHO * AREA, RHO * INERTIA * np.array([1, 1, 2]), [EI, EI, 0.89e9 * 2 * INERTIA],
                    k0, [0, 0, 0], straight_frame([1, 0, 0]))


def test_energy_gradient_matches_finite_differences():
    m = hair(8, k0=np.tile([5.0, -3.0, 1.0], (9, 1)))
    kap = np.random.default_rng(0).normal(size=(8, 3)) * 20
    loads = static_nodal_loads(m, gravity=[1, -3, -9.81], tip_force=[1e-6, 2e-6, -3e-6])
    _, g, _, _ = static_energy(m, kap, loads)
    gf = np.zeros_like(kap)
    h = 1e-6
    for k in range(8):
        for c in range(3):
            kp, km = kap.copy(), kap.copy()
            kp[k, c] += h
            km[k, c] -= h
            gf[k, c] = (static_energy(m, kp, loads)[0] - static_energy(m, km, loads)[0]) / (2 * h)
    np.testing.assert_allclose(g, gf, rtol=1e-6, atol=1e-6 * np.abs(g).max())


def test_tip_load_elastica_within_1_percent_and_second_order():
    P = 3 * EI / L**2  # large deflection: tip angle ~ 56 degrees
    _, y_ref, _ = cantilever_tip_load_elastica(P, L, EI)
    errs = []
    for N in (10, 20, 40, 100):
        sol = solve_static_energy(hair(N), tip_force=[0, 0, -P])
        errs.append(abs(-sol.positions[-1, 2] - y_ref) / y_ref)
    print("tip-load elastica relative errors N=10,20,40,100:", errs)
    assert errs[-1] < 0.01
    order = np.polyfit(np.log([10, 20, 40]), np.log(errs[:3]), 1)[0]
    assert order == pytest.approx(-2.0, abs=0.2)


def test_self_weight_elastica_within_1_percent():
    q = RHO * AREA * 9.81
    _, y_ref, _ = cantilever_self_weight_elastica(q, L, EI)
    sol = solve_static_energy(hair(100), gravity=[0, 0, -9.81])
    err = abs(-sol.positions[-1, 2] - y_ref) / y_ref
    print("self-weight elastica relative error N=100:", err, "tip sag / L:", y_ref / L)
    assert err < 0.01


def test_pai_integration_agrees_for_small_loads_and_shows_follower_effect_for_large():
    m = hair(200)
    small = 0.01 * EI / L**2
    _, _, r, _ = pai_static(m, tip_force_local=[0, -small, 0])  # -d2 = -z at the start
    lin = cantilever_tip_load_linear(small, L, EI)
    assert -r[-1, 2] == pytest.approx(lin, rel=0.02)
    P = 2 * EI / L**2
    _, n, r_pai, R_pai = pai_static(m, tip_force_local=[0, -P, 0])
    dead = solve_static_energy(hair(100), tip_force=[0, 0, -P])
    # Pai's tip load stays perpendicular to the tip tangent (follower load) ...
    f_global = R_pai[-1] @ n[-1]
    assert abs(f_global @ R_pai[-1][:, 2]) < 1e-9 * P
    # ... whereas the dead-load solution's tip tangent is far from perpendicular to -z
    assert abs(dead.frames[-1][:, 2] @ np.array([0, 0, -1.0])) > 0.5
    # and the follower load rotates the tip further than the dead load does
    tip_angle = lambda Rm: np.arctan2(-Rm[-1][2, 2], Rm[-1][0, 2])
    print("tip angle dead vs follower (deg):", np.degrees(tip_angle(dead.frames)), np.degrees(tip_angle(R_pai)))
    assert tip_angle(R_pai) > tip_angle(dead.frames) + np.radians(10)
