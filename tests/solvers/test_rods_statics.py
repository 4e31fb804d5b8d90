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


def _clamped_twisted_buckled_equilibrium(n_segments, dt=4e-3, t_hold=0.5):
    """A rod clamped at both ends, its tip turned by 4 pi EI / GJ and moved 17 % towards the root
    (as in the buckling scene, tip mode "clamped-position"), then held and relaxed to rest by
    backward Euler: a spatial static equilibrium with end loads only."""
    from headsim.hair.scenes import build_scene
    from headsim.solvers.rods import GeneralizedAlpha, ImplicitRodSolver, RodBoundary, RodLoads, RodSolverOptions

    sc = build_scene("buckling", n_segments=n_segments, dt=dt)
    m = sc.model
    L, ds = m.length[0], m.segment_length[0]
    EI, GJ = m.stiffness[0, 0], m.stiffness[0, 2]
    phi = 4 * np.pi * EI / GJ
    kick = np.zeros((1, m.n_nodes, 3))
    kick[0, m.n_nodes // 2, 2] = 1e-2 * EI / L**2 / ds
    solver = ImplicitRodSolver(sc.options)
    st = sc.state
    while st.time < t_hold - 1e-9:
        t, tm = st.time + dt, st.time + 0.5 * dt
        spin = phi / 0.2 * (1 - np.cos(2 * np.pi * tm / 0.2)) if tm < 0.2 else 0.0
        bo = RodBoundary(tip="clamped-position", tip_position=sc.info["tip_path"](t),
                         tip_angular_velocity=np.array([spin, 0.0, 0.0]))
        st, _ = solver.step(m, st, dt, RodLoads(distributed_force=kick if t <= 0.1 else None), bo)
    relax = ImplicitRodSolver(RodSolverOptions(coefficients=GeneralizedAlpha.backward_euler()))
    hold = RodBoundary(tip="clamped-position", tip_position=sc.info["tip_path"](t_hold))
    for h in [0.01] * 30 + [0.1] * 30:
        st, _ = relax.step(m, st, h, RodLoads(), hold)
    return m, st


def test_clamped_twisted_rod_matches_the_lagrange_top_solution():
    """Kirchhoff's kinetic analogy (Sobottka §3.3.1.1): a circular rod loaded only at its ends is a
    Lagrange top. Its first integrals (contact force n, twisting moment m3, m . e_n, H) are constant
    along the rod, and with them z(s) = d3 . e_n is the Jacobi-elliptic closed form (eq. 3.96) and the
    height along e_n the elliptic-integral form (eq. 3.118). Both converge at second order in ds."""
    from headsim.solvers.rods_analytic import lagrange_top

    errs = []
    for n_seg in (40, 80):
        m, st = _clamped_twisted_buckled_equilibrium(n_seg)
        L = m.length[0]
        EI, GJ = m.stiffness[0, 0], m.stiffness[0, 2]
        b = GJ / EI
        R, x = st.frames[0], st.x[0]
        assert np.abs(x[:, 0:6]).max() < 1e-6  # at rest
        n_glob = np.einsum("jab,jb->ja", R, x[:, 9:12]) / EI  # scaled: EI = 1
        n_vec = n_glob.mean(0)
        n = np.linalg.norm(n_vec)
        e_n = n_vec / n
        kap = x[:, 6:9]
        m_loc = kap * np.array([1.0, 1.0, b])
        m_n = np.einsum("jab,jb->ja", R, m_loc) @ e_n
        z = R[:, :, 2] @ e_n
        H = 0.5 * (m_loc * kap).sum(1) + n * z
        spreads = (np.ptp(n_glob, axis=0).max() / n, np.ptp(m_loc[:, 2]) / abs(m_loc[:, 2]).mean(),
                   np.ptp(m_n) / abs(m_n).mean(), np.ptp(H) / abs(H).mean())
        dz0 = (R[0] @ np.array([kap[0, 1], -kap[0, 0], 0.0])) @ e_n
        top = lagrange_top(n, m_loc[:, 2].mean(), m_n.mean(), H.mean(), b, z[0], dz0 >= 0)
        s = m.arc_length[0]
        ez = np.abs(top.z(s) - z).max()
        eh = np.abs(top.height(s) - (st.positions[0] - st.positions[0, 0]) @ e_n).max() / L
        print(f"N={n_seg}: n L^2 = {n * L**2:.2f}, m3 L = {m_loc[0, 2] * L:.2f}, k = {top.k:.3f}, z in "
              f"[{z.min():.3f}, {z.max():.3f}]; spreads of n, m3, m.e_n, H: {np.round(spreads, 6)}; "
              f"max |z - z_top| {ez:.2e}, max |height - top| / L {eh:.2e}")
        assert z.max() - z.min() > 0.3 and abs(m_loc[0, 2]) * L > 1 and abs(m_n.mean()) * L > 1  # truly spatial
        errs.append((ez, eh, max(spreads)))
    (ez1, eh1, sp1), (ez2, eh2, sp2) = errs
    print("orders z, height, integrals:", np.log2(ez1 / ez2), np.log2(eh1 / eh2), np.log2(sp1 / sp2))
    assert ez2 < 0.02 and eh2 < 0.005
    assert np.log2(ez1 / ez2) > 1.7 and np.log2(eh1 / eh2) > 1.7 and np.log2(sp1 / sp2) > 1.7
