"""The seed's qualitative rod examples (Sobottka §3.4.9) as assertions with numbers."""

import numpy as np
import pytest

from headsim.hair.fibres import helix_axis
from headsim.hair.scenes import build_scene, run_scene
from headsim.solvers.rods import GeneralizedAlpha, ImplicitRodSolver, RodLoads, RodSolverOptions
from headsim.solvers.rods_geometry import min_self_distance, writhe
from headsim.solvers.rods_analytic import helical_spring_axial_stiffness, helical_spring_fundamental_frequency
from headsim.solvers.rods_statics import solve_static_energy


def test_precurvature_preserved_under_gravity():
    """Fig. 3.15: a sinusoidally pre-curved fibre released under gravity bends only in its plane
    (kappa2 = kappa3 = 0) and relaxes to the minimum-energy shape of the static solver."""
    sc = build_scene("precurved", n_segments=80, dt=2e-3, duration=0.2)
    traj = run_scene(sc, interpolate=False)
    k = traj.curvature[:, 0]
    assert np.abs(k[:, :, 1:]).max() < 1e-9 * np.abs(k[:, :, 0]).max()
    # relax with backward Euler and compare with the energy minimiser (same kappa0(s), same load)
    st = traj.final_state
    solver = ImplicitRodSolver(RodSolverOptions(coefficients=GeneralizedAlpha.backward_euler()))
    for dt in [0.02] * 20 + [0.1] * 60:
        st, _ = solver.step(sc.model, st, dt, RodLoads(gravity=[0, 0, -9.81]))
    fine = build_scene("precurved", n_segments=320).model  # converged reference (2nd order in ds)
    static = solve_static_energy(fine, gravity=[0, 0, -9.81])
    L = sc.model.length[0]
    diff = np.abs(st.positions[0] - static.positions[::4]).max() / L
    print("dynamic rest shape (N = 80) vs static energy minimum (N = 320), max distance / L:", diff)
    assert diff < 0.01
    # the waves survive: the bent curvature still correlates with kappa0
    kk, k0 = st.curvature[0, :, 0], sc.model.natural_curvature[0, :, 0]
    assert np.corrcoef(kk, k0)[0, 1] > 0.9


@pytest.mark.parametrize("load", ["force", "torque"])
def test_axial_tip_load_on_helix_produces_torsion(load):
    """Fig. 3.16: an axial tip force or torque on a helix changes its torsion kappa3."""
    sc = build_scene("helix", n_segments=60, dt=5e-3, duration=0.3, load=load)
    traj = run_scene(sc, interpolate=False)
    k0 = sc.model.natural_curvature[0]
    dk = traj.curvature[-1, 0] - k0
    print(f"{load}: max |d kappa3| = {np.abs(dk[:, 2]).max():.3g} 1/m (kappa0 = {k0[0]})")
    assert np.abs(dk[:, 2]).max() > 0.05 * np.linalg.norm(k0[0])


def test_tip_torque_on_straight_rod_forms_a_closed_loop():
    """Fig. 3.17: a tip torque 2 pi EI / L bends a straight rod into a full circle (the static
    answer: uniform kappa1 = 2 pi / L, tip back at the root)."""
    sc = build_scene("loop", n_segments=40, length=0.1, dt=0.02, duration=8.0)
    traj = run_scene(sc, record_every=100, interpolate=False)
    p = traj.positions[-1, 0]
    L = sc.model.length[0]
    gap = np.linalg.norm(p[-1] - p[0]) / L
    k1 = traj.curvature[-1, 0, :, 0]
    print("tip-root gap / L:", gap, "kappa1 range:", k1.min(), k1.max(), "target", 2 * np.pi / L)
    assert gap < 0.01
    np.testing.assert_allclose(k1, 2 * np.pi / L, rtol=0.01)


def test_spiral_spring_frequency_matches_helical_spring_theory():
    """Fig. 3.18: a helical keratin spring (8 turns, coil radius 2 mm) excited by an axial tip force
    that is switched off: the tip oscillates at f = sqrt(k / m) / 4 with Wahl's stiffness k."""
    sc = build_scene("spiral", n_segments=64, turns=8, duration=0.35, dt=5e-4)
    traj = run_scene(sc, interpolate=False)
    m = sc.model
    axis = helix_axis(m.root_frame[0], m.natural_curvature[0, 0])
    z = (traj.positions[:, 0, -1] - traj.positions[0, 0, -1]) @ axis
    t = traj.times
    R, pitch = 2e-3, 1e-3
    k = helical_spring_axial_stiffness(R, np.arctan2(pitch / (2 * np.pi), R), m.length[0], m.stiffness[0, 0], m.stiffness[0, 2])
    f_ref = helical_spring_fundamental_frequency(k, m.rho_area[0] * m.length[0])
    after = t > 0.05
    zz, tt = z[after], t[after]
    i = np.where(np.sign(zz[:-1]) != np.sign(zz[1:]))[0]
    tc = tt[i] - zz[i] * (tt[i + 1] - tt[i]) / (zz[i + 1] - zz[i])
    f = 1 / (2 * np.mean(np.diff(tc)))
    print(f"spiral spring: {f:.3f} Hz vs theory {f_ref:.3f} Hz ({(f - f_ref) / f_ref:+.2%}), "
          f"mean Newton iterations {traj.iterations.mean():.2f}")
    assert f == pytest.approx(f_ref, rel=0.02)


def test_stretched_curly_strand_snaps_back_and_settles():
    """Fig. 3.21: pull the tip until the end-to-end distance is 130 %, release: the strand snaps
    back past its hanging length and settles (kinetic energy decays)."""
    sc = build_scene("strand-stretch", n_segments=100, dt=4e-3, pull_time=1.0, duration=3.0, n_interpolated=20)
    traj = run_scene(sc, record_every=5)
    p = traj.positions[:, 0]
    d = np.linalg.norm(p[:, -1] - p[:, 0], axis=1) / np.linalg.norm(p[0, -1] - p[0, 0])
    t = traj.times
    release = np.argmin(np.abs(t - 1.0))
    print("end-to-end / initial: at release", d[release], "min after", d[release:].min(),
          "final", d[-1], "kinetic: max", traj.kinetic.max(), "final", traj.kinetic[-1, 0])
    assert d[release] == pytest.approx(1.3, abs=0.01)
    assert d[release:].min() < 1.0  # snaps back beyond the start (overshoot)
    assert traj.kinetic[-1, 0] < 0.01 * traj.kinetic.max()
    assert traj.interpolated.shape[1:] == (20, 101, 3)


def test_moving_support_along_arc_is_stable_and_followed():
    """Fig. 3.24: the strand hangs from a support moving along a 45 degree arc of radius 30 cm."""
    sc = build_scene("moving-support", n_segments=100, dt=4e-3, duration=1.0, n_interpolated=10)
    traj = run_scene(sc, record_every=25)
    rate = 2 * (np.pi / 4) / 1.0
    for k, t in enumerate(traj.times):
        root = traj.positions[k, 0, 0]
        assert np.linalg.norm(root) == pytest.approx(0.30, rel=1e-4)  # stays on the arc
        angle = np.arctan2(root[2], root[0])
        # the support starts with a velocity jump at t = 0; the trapezoidal root update of the first
        # step lags by half a step, everything after follows the arc exactly
        assert abs(angle - sc.info["support_angle"](t)) <= 0.5 * rate * sc.dt + 1e-6
    assert np.isfinite(traj.positions).all()
    print("moving support: max kinetic energy", traj.kinetic.max(), "mean Newton iterations", traj.iterations.mean())


def test_end_shortening_with_axial_torque_buckles_into_a_loop():
    """Fig. 3.20: a twisted rod (torque 4 pi EI / L, above Greenhill's moment) whose guided tip is
    moved towards the root first buckles into a gently writhed spatial shape, then snaps into a loop:
    the writhe (Gauss integral, tails closed along the axis) jumps from below 0.5 to 0.8 and more,
    and part of the rod runs backwards. The run stops there (no rod self-contact, see the scene)."""
    sc = build_scene("buckling", n_segments=40, dt=4e-3, duration=1.0)
    traj = run_scene(sc, interpolate=False)
    L = sc.model.length[0]
    x0 = traj.positions[0, 0, -1, 0]
    short = (x0 - traj.positions[:, 0, -1, 0]) / L
    wr = np.array([writhe(p, axis=(1, 0, 0)) for p in traj.positions[:, 0]])
    print("end-shortening at the loop:", short[-1], "writhe before / at:", wr[-2], wr[-1], "t:", traj.times[-1],
          "min self-distance / d:", min_self_distance(traj.positions[-1, 0]) / 70e-6)
    assert traj.times[-1] < 1.0 - 1e-9  # stopped: the loop formed before the end of the shortening
    assert wr[-1] >= 0.8
    # only buckled until shortly before: at 30 % end-shortening the writhe is still small
    k30 = np.searchsorted(short, 0.3)
    assert short[k30] < 0.31 and abs(wr[k30]) < 0.5
    assert 0.3 < short[-1] < 0.45
    # the tip follows its prescribed path exactly (position BC inside Newton: no drift)
    tips = traj.positions[:, 0, -1]
    goal = np.array([sc.info["tip_path"](t) for t in traj.times])
    assert np.abs(tips - goal).max() < 1e-8 * L
    # a loop: part of the centreline runs against the axis, and the rod has not passed through itself
    t1 = np.diff(traj.positions[-1, 0], axis=0)
    assert (t1[:, 0] / np.linalg.norm(t1, axis=1)).min() < -0.5
    assert min_self_distance(traj.positions[-1, 0]) > 70e-6
    # while only buckled the rod is in quasi-static equilibrium: the axial moment m3 is a first
    # integral (uniform twist) and equals the applied torque (N = 40: -2.0 %, N = 80: -0.17 %)
    kap3 = traj.curvature[k30, 0, :, 2]
    M = 4 * np.pi * sc.model.stiffness[0, 0] / L
    assert np.ptp(kap3) < 1e-4 * kap3.mean()
    assert kap3.mean() == pytest.approx(M / sc.model.stiffness[0, 2], rel=0.05)
