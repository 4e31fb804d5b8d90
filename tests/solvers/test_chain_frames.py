"""The chain solver's per-segment frame kernels (headsim.solvers._kernels.chains_frames) against the NumPy
formulas they replace, both builds."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.solvers._kernels import chains_frames as FK


def _rotations(rng, n):
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    return np.ascontiguousarray(q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :])


@pytest.mark.parametrize("build", ["serial", "parallel"])
def test_frame_products_and_point_speeds_match_numpy(build):
    rng = np.random.default_rng(3)
    n = 257
    R = _rotations(rng, n)
    d = rng.uniform(1e-12, 1e-10, (n, 3))
    w = rng.normal(size=(n, 3))
    u = rng.normal(size=(n, 6))
    lever = rng.uniform(0.0, 2e-3, n)
    par = build == "parallel"
    out = np.empty((n, 3))
    (FK.apply_scaled_parallel if par else FK.apply_scaled)(R, d, w, out)
    ref = np.einsum("sij,sj,skj,sk->si", R, d, R, w)
    np.testing.assert_allclose(out, ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())
    frames = np.empty((n, 3, 3))
    (FK.scaled_frames_parallel if par else FK.scaled_frames)(R, d, frames)
    ref = np.einsum("sik,sk,sjk->sij", R, d, R)
    np.testing.assert_allclose(frames, ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())
    speed = np.empty(n)
    (FK.point_speed_parallel if par else FK.point_speed)(u, lever, speed)
    np.testing.assert_array_equal(speed, np.linalg.norm(u[:, :3], axis=1) + lever * np.linalg.norm(u[:, 3:], axis=1))
    (FK.point_speed_parallel if par else FK.point_speed)(u, np.array([0.3]), speed)
    np.testing.assert_array_equal(speed, np.linalg.norm(u[:, :3], axis=1) + 0.3 * np.linalg.norm(u[:, 3:], axis=1))


@pytest.mark.parametrize("build", ["serial", "parallel"])
@pytest.mark.parametrize("with_u", [True, False])
def test_joint_rows_match_the_numpy_formulas(build, with_u):
    """Joint rows of two 6-segment fibres (the first anchored at a root frame): bodies, levers, gap targets,
    spring/damper blocks C = s R_k diag(K) R_kᵀ + c_d c E and relative spins, as written out in NumPy."""
    rng = np.random.default_rng(5)
    S, F = 12, 2
    fib_all = np.repeat(np.arange(F), 6)
    x = rng.normal(scale=1e-3, size=(S, 3))
    R = _rotations(rng, S)
    half = rng.uniform(1e-3, 2e-3, S)
    root_point = rng.normal(size=(F, 3))
    root_frame = _rotations(rng, F)
    K = rng.uniform(1e-9, 1e-8, (S, 3))
    c = rng.uniform(1e-10, 1e-9, S)
    u = rng.normal(size=(S, 6)) if with_u else np.zeros((0, 6))
    seg = np.array([0, 1, 2, 5, 7, 9], np.int64)
    is_root = np.array([True, False, False, False, False, False])
    fib = fib_all[seg]
    ts, ss, ds = -3.0, 0.7e-6, 1e-3
    n = len(seg)
    k, rk, rl, tg, C, w0 = (np.empty(n, np.int64), np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)),
                            np.empty((n, 3, 3)), np.empty((n, 3)))
    (FK.joint_rows_parallel if build == "parallel" else FK.joint_rows)(
        seg, is_root, fib, x, R, half, root_point, root_frame, K, c, u, ts, ss, ds, k, rk, rl, tg, C, w0)
    kk = np.maximum(seg - 1, 0)
    np.testing.assert_array_equal(k, np.where(is_root, -1, seg - 1))
    np.testing.assert_array_equal(rl, -half[seg, None] * R[seg, :, 2])
    np.testing.assert_array_equal(rk, np.where(is_root[:, None], 0.0, half[kk, None] * R[kk, :, 2]))
    pk = np.where(is_root[:, None], root_point[fib], x[kk] + rk)
    np.testing.assert_allclose(tg, ts * (pk - (x[seg] + rl)), rtol=1e-14, atol=1e-18)
    Rk = np.where(is_root[:, None, None], root_frame[fib], R[kk])
    ref = ss * np.einsum("sik,sk,sjk->sij", Rk, K[seg], Rk) + ds * c[seg, None, None] * np.eye(3)
    np.testing.assert_allclose(C, ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())
    if with_u:
        np.testing.assert_array_equal(w0, u[seg, 3:] - np.where(is_root[:, None], 0.0, u[kk, 3:]))
    else:
        np.testing.assert_array_equal(w0, 0.0)


def test_joint_spring_moment_is_the_gradient_of_the_spring_energy():
    """The joint stage's spring moment (kernels.chains._spring_moment, expressed in the first body's frame R_k)
    against a central-difference gradient of E = ½ Σ_c K_c (θ_c − θ°_c)², θ = log(R_kᵀ R_l) (Sobottka eq. 8.83),
    for rotations of the second body, at joint angles up to 1.5 rad with unequal bending and torsion stiffnesses
    (K₃/K₁ = 2G/E of keratin ≈ 0.46): the moment is the energy's exact gradient (a conservative spring), where K(θ −
    θ°) alone, exact only as θ → 0, is off by up to 20 % here (its first-order error ½ θ × K(θ − θ°) is circulatory)."""
    from scipy.spatial.transform import Rotation

    from headsim.solvers._kernels.chains import _log_so3_parts, _spring_moment

    rng = np.random.default_rng(7)
    K = np.array([1.0, 1.0, 0.46])
    rest = np.array([0.1, -0.05, 0.02])

    def energy(Rk, Rl):
        t = np.array(_log_so3_parts(Rk.T @ Rl))
        return 0.5 * float((K * (t - rest) ** 2).sum()), t

    worst_linear = 0.0
    for _ in range(20):
        Rk = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        Rl = Rk @ Rotation.from_rotvec(rng.normal(size=3) * rng.uniform(0.1, 1.5) / np.sqrt(3)).as_matrix()
        _, t = energy(Rk, Rl)
        grad = np.zeros(3)
        for i in range(3):
            d = np.zeros(3)
            d[i] = 1e-6
            grad[i] = (energy(Rk, Rotation.from_rotvec(d).as_matrix() @ Rl)[0]
                       - energy(Rk, Rotation.from_rotvec(-d).as_matrix() @ Rl)[0]) / 2e-6
        e = K * (t - rest)
        moment = Rk @ np.array(_spring_moment(*t, *e))
        np.testing.assert_allclose(moment, grad, atol=1e-7 * np.linalg.norm(grad) + 1e-12)
        worst_linear = max(worst_linear, np.linalg.norm(Rk @ e - grad) / np.linalg.norm(grad))
    assert worst_linear > 0.05  # the test tells the exact moment from the small-angle one


def _thin_segment_inertia():
    """A 3 mm × 70 µm keratin segment's principal inertias (kg m²) with the true axial moment
    (``spherical_inertia=False``): I₁ = I₂ ≈ 1,225 I₃."""
    from headsim.solvers.chains_model import chain_model_from_polylines

    model, _ = chain_model_from_polylines(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 3e-3]]), [0, 2], radius=35e-6,
                                          spherical_inertia=False)
    inertia = model.inertia[0]
    assert inertia[0] == inertia[1] and 1200 < inertia[0] / inertia[2] < 1250
    return inertia


def _euler_flow(R0, w0, inertia, h):
    """R and world ω after h s of torque-free motion (Euler's equations, body frame), integrated to 1e-12."""
    from scipy.integrate import solve_ivp

    def rhs(_, y):
        R = y[:9].reshape(3, 3)
        wb = y[9:]
        dR = R @ np.array([[0.0, -wb[2], wb[1]], [wb[2], 0.0, -wb[0]], [-wb[1], wb[0], 0.0]])
        return np.r_[dR.ravel(), np.cross(inertia * wb, wb) / inertia]

    y = solve_ivp(rhs, (0.0, h), np.r_[R0.ravel(), R0.T @ w0], rtol=1e-12, atol=1e-14, method="DOP853").y[:, -1]
    R = y[:9].reshape(3, 3)
    return R, R @ y[9:]


@pytest.mark.parametrize("build", ["serial", "parallel"])
def test_half_step_is_the_torque_free_motion_of_an_axisymmetric_segment(build):
    """The rotation update of the chain solver's half steps: for an axisymmetric body it is the exact torque-free
    motion (precession about the fixed angular momentum, spin about the axis), so a thin segment turning end
    over end at 100 rad/s keeps its axial spin (1 rad/s) and its kinetic energy over 10 half steps of 0.5 ms
    and matches Euler's equations. The former update, exp(h ω̃) R with ω re-derived from the kept angular
    momentum, multiplied the axial spin by 8,400 and the kinetic energy by 6.8 here (issue 10, thirty-fifth
    session). (With the models' default spherical inertia, I₃ = I₁, the two updates coincide.)"""
    from headsim.solvers._kernels.chains import half_step, half_step_serial

    step = half_step if build == "parallel" else half_step_serial
    inertia = _thin_segment_inertia()[None]
    R0 = _rotations(np.random.default_rng(5), 1)
    R0[0, :, 0] *= np.linalg.det(R0[0])  # a rotation (det +1), not a reflection
    w0 = R0[0] @ np.array([100.0, 0.0, 1.0])  # end over end, slow spin about the axis R0[:, 2]
    R, w = R0.copy(), w0[None].copy()
    zeros = np.zeros((1, 3))
    for _ in range(10):
        x_out, R_out, w_out = np.empty((1, 3)), np.empty((1, 3, 3)), np.empty((1, 3))
        step(zeros, R, zeros, w, inertia, 0.5e-3, x_out, R_out, w_out)
        R, w = R_out, w_out

    def kinetic(Rs, ws):
        wb = Rs[0].T @ ws[0]
        return 0.5 * float(wb @ (inertia[0] * wb))

    # (round-off: the axial spin is L·e₃/I₃, read from a momentum I₁/I₃ · |ω⊥|/ω₃ ≈ 1.2e5 times larger)
    assert w[0] @ R[0][:, 2] == pytest.approx(1.0, rel=1e-8)
    assert kinetic(R, w) == pytest.approx(kinetic(R0, w0[None]), rel=1e-12)
    R_ref, w_ref = _euler_flow(R0[0], w0, inertia[0], 5e-3)
    np.testing.assert_allclose(R[0], R_ref, atol=1e-9)
    np.testing.assert_allclose(w[0], w_ref, rtol=1e-8, atol=1e-8 * np.abs(w0).max())


def test_selected_fibres_carry_their_share_of_energy_and_joint_gaps():
    """select_fibres (the diagnostics' part of a scene): split into two complementary fibre sets, a bent, moving,
    partly unanchored three-fibre model keeps every energy as the sum of the parts' and every joint gap, and each
    part keeps its own roots (a wrong root or offset would move spring or gap terms between fibres)."""
    from scipy.spatial.transform import Rotation

    from headsim.errors import ParameterError
    from headsim.solvers.chains_model import (ChainState, chain_model_from_polylines, joint_gaps, kinetic_energy,
                                              potential_energy, select_fibres, spring_energy)

    rng = np.random.default_rng(3)
    nodes, offsets = [], [0]
    for f, n in enumerate((5, 3, 7)):
        s = np.linspace(0.0, 1.0, n)[:, None]
        nodes.append(np.hstack([f * 1e-3 + 2e-3 * np.sin(3 * s), -1e-2 * s, 1e-3 * s**2]))
        offsets.append(offsets[-1] + n)
    model, state = chain_model_from_polylines(np.vstack(nodes), offsets, anchored=[True, False, True],
                                              rest_shape="initial")
    S = model.n_segments
    state = ChainState(state.position + 1e-5 * rng.normal(size=(S, 3)),
                       Rotation.from_rotvec(0.05 * rng.normal(size=(S, 3))).as_matrix() @ state.rotation,
                       rng.normal(size=(S, 3)) * 1e-2, rng.normal(size=(S, 3)), 0.25)
    energies = (kinetic_energy, potential_energy, spring_energy)
    gaps = joint_gaps(model, state)
    parts = [select_fibres(model, state, sel) for sel in ([0, 2], np.array([False, True, False]))]
    np.testing.assert_allclose([sum(e(m, s) for m, s in parts) for e in energies],
                               [e(model, state) for e in energies], rtol=1e-12)
    assert spring_energy(model, state) > 0.0
    assert all(s.time == 0.25 for _, s in parts)
    assert parts[0][0].n_fibres == 2 and parts[1][0].n_segments == 2 and not parts[1][0].anchored[0]
    np.testing.assert_allclose(np.sort(np.concatenate([joint_gaps(m, s) for m, s in parts])), np.sort(gaps))
    assert gaps.max() > 1e-6  # the perturbation opened the joints: the comparison sees them
    for bad in ([], [3], [-1], [0.5], np.ones(2, bool)):
        with pytest.raises(ParameterError):
            select_fibres(model, state, bad)
