"""The chain-solver benchmarks run (issue 10): the replay of captured coupled contact solves, the exact final
solve's comparison, the root-region experiment, the drape benchmark's saved states, the terrain spin diagnostic and
the joint stage's root diagnostic.

``benchmarks/bench_contact_convergence.py`` (and ``bench_contact_domains.py``, which reads the captured calls
through the same ``iterate_args``) rerun :func:`headsim.solvers._kernels.chains_coupled.coupled_iterate` from
argument lists captured during a step. When the kernel gained two arguments (issue 10, twentieth session) both
scripts kept addressing the list by position and stopped running, and nothing noticed: this test runs the
convergence benchmark on a small drape (8 fibres × 30 segments, serial kernels) and checks that it replays the
solve (the 20-sweep reference is 0 off itself, 5 sweeps are not)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_contact_convergence_benchmark_replays_a_captured_solve():
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_contact_convergence.py"), "--fibres", "8",
                          "--segments", "30", "--settle", "10", "--sweeps", "5", "20"],
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    errors = {m.group(1): float(m.group(2))
              for m in re.finditer(r"^\s*(\d+ \w+) \(\d+ sweeps\).*?rel\. M-error ([0-9.e+-]+)", out.stdout, re.M)}
    assert set(errors) == {"20 nesterov", "5 nesterov", "20 plain", "5 plain"}, out.stdout
    assert errors["20 nesterov"] == 0.0
    assert errors["5 plain"] > 0.0


def test_exact_solve_benchmark_compares_both_modes():
    """``benchmarks/bench_exact_solve.py`` runs both modes on its scenes (the clamped fibre through
    ``bench_energy_ledger.py``'s scene) and reports a ratio per scene; on the stack the exact mode uses the exact
    solve in every step and the Gauss–Seidel mode in none."""
    steps = 20
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_exact_solve.py"), "--steps", str(steps),
                          "--stack-sweeps", "30"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert len(re.findall(r"time exact / GS only: [0-9.]+$", out.stdout, re.M)) == 2, out.stdout
    used = re.findall(r"^stack, qp_iterations 30 +(GS only|exact) .*exact solves used (\d+)", out.stdout, re.M)
    assert dict(used) == {"GS only": "0", "exact": str(steps)}, out.stdout


def test_root_solve_experiment_runs():
    """``benchmarks/bench_root_solve.py`` (the root-region exact solve between sweeps) replays a captured solve of a
    small ringlet and reports the plain continuation and the root-region solve for every depth asked."""
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_root_solve.py"), "--fibres", "8",
                          "--segments", "20", "--settle", "10", "--reference", "300", "--more", "5",
                          "--depth", "8"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert re.search(r"^GS 30 \+ warm 5 +CPU", out.stdout, re.M), out.stdout
    assert re.search(r"root region of depth 8: \d+ bodies", out.stdout), out.stdout


def test_drape_benchmark_saves_a_state_and_starts_from_it(tmp_path):
    """``benchmarks/bench_drape.py --save-state`` writes the state reached after its warm-up and settle steps, and
    ``--state`` starts a run from it (at its time; ``--floor`` adds the one-sweep run); ``drape_states.load_state``
    refuses a file made for another number of segments or another strand (its roots elsewhere:
    ``--fibre-spacing``), and a loaded state is the saved one to float32 rounding with orthonormal rotations."""
    saved = tmp_path / "state.npz"
    common = [sys.executable, str(ROOT / "benchmarks" / "bench_drape.py"), "--fibres", "4", "--segments", "10",
              "--steps", "1", "--coupled-only"]
    out = subprocess.run(common + ["--settle", "3", "--save-state", str(saved)], capture_output=True, text=True,
                         timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert re.search(r"state at t = 0\.005 s saved to", out.stdout), out.stdout  # 2 warm-up + 3 settle steps
    out = subprocess.run(common + ["--settle", "0", "--state", str(saved), "--floor"], capture_output=True, text=True,
                         timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert re.search(r"^\[floor\] one sweep per contact solve \(qp_iterations=1, .*\): [\d.]+ s/step wall", out.stdout,
                     re.M), out.stdout
    for run in ("coupled", "floor"):  # the end states' overlap counts (none on this strand: "none" or counts)
        assert re.search(rf"^\[{run}\] fibre overlaps at the end: next to the roots \(segments < 5\) (none|\d+ > 1 µm"
                         rf".*); elsewhere (none|\d+ > 1 µm.*)$", out.stdout, re.M), out.stdout
    # the time printed is the one before the timed step: the saved 5 ms + 2 warm-up steps
    assert re.search(r"40 segments, t = 0\.007 s", out.stdout), out.stdout
    out = subprocess.run(common + ["--settle", "0", "--save-state", str(tmp_path / "no" / "state.npz")],
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 2 and "--save-state: no directory" in out.stderr and "warm-up" not in out.stdout

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from drape_states import load_state, save_state
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    from headsim.hair.drape import build_drape_scene

    scene = build_drape_scene("sphere-helical", "aniso", n_fibres=4, segments=10)
    state = load_state(saved, scene.model)
    again = load_state(save_state(tmp_path / "again.npz", state), scene.model)
    np.testing.assert_allclose(again.position, state.position, rtol=0, atol=1e-8)
    np.testing.assert_allclose(np.einsum("sab,sac->sbc", again.rotation, again.rotation), np.broadcast_to(np.eye(3),
                               again.rotation.shape), atol=1e-12)
    np.testing.assert_allclose(again.rotation, state.rotation, atol=1e-6)
    assert again.time == state.time == pytest.approx(0.005)
    other = build_drape_scene("sphere-helical", "aniso", n_fibres=4, segments=12)
    with pytest.raises(SystemExit, match="holds 40 segments, the scene has 48"):
        load_state(saved, other.model)
    with pytest.raises(SystemExit, match="no saved state"):
        load_state(tmp_path / "missing.npz", other.model)
    # a state of the same size from a strand of another fibre spacing: its roots are not this scene's
    wide = build_drape_scene("sphere-helical", "aniso", n_fibres=4, segments=10, fibre_spacing=210e-6)
    with pytest.raises(SystemExit, match="from this scene's roots"):
        load_state(saved, wide.model)
    out = subprocess.run(common + ["--settle", "0", "--state", str(saved), "--fibre-spacing", "210e-6"],
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode != 0 and "from this scene's roots" in out.stderr, out.stderr[-2000:]
    out = subprocess.run(common + ["--settle", "0", "--fibre-spacing", "50e-6"], capture_output=True, text=True,
                         timeout=600, cwd=ROOT)  # closer than a diameter: a usage error, nothing run
    assert out.returncode == 2 and "fibre_spacing must exceed the fibre diameter" in out.stderr, out.stderr[-2000:]
    assert "warm-up" not in out.stdout


def test_terrain_spin_diagnostic_loads_its_state_and_steps():
    """``benchmarks/bench_terrain_spin.py`` (the terrain drape's open spin-up, issue 10) loads its bundled state
    (t = 69 ms of the 355 × 100 scene) and steps the 30 fibres around fibre 316 (``--fibres 300:330``; the whole
    scene takes 6–25 s per step there): two steps print the time after them, a finite spin on one of those fibres
    (numbered as in the full scene), joint gap and energy. (The spin-up itself takes 6–7 steps of the whole scene;
    see the script.)"""
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_terrain_spin.py"), "--steps", "2",
                          "--fibres", "300:330"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("terrain 30 × 100, from t = 0.069 s"), out.stdout
    found = re.findall(r"^t (0\.07[01]) s: max ω\s+([0-9.]+) rad/s \(fibre (\d+), .*max joint gap\s+([0-9.]+) µm, "
                       r"total energy ([0-9.e+-]+) J", out.stdout, re.M)
    assert [f[0] for f in found] == ["0.070", "0.071"], out.stdout
    for _, w, fibre, gap, energy in found:
        assert 300 <= int(fibre) < 330
        assert all(np.isfinite(float(v)) for v in (w, gap, energy))
    bad = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_terrain_spin.py"), "--fibres", "350:360"],
                         capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert bad.returncode == 2 and "fibre indices must be within 0 … 354" in bad.stderr, bad.stderr[-2000:]


def _joint_stage_module():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import bench_joint_stage_root
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return bench_joint_stage_root


def _moving_coil(B, seed):
    """The 5 mm released coil of ``bench_joint_stage_root`` (module B) with random twists (0.05 m/s, 300 rad/s):
    (model, state, the generator for more random numbers)."""
    from headsim.solvers.chains_model import ChainState

    model, rest = B.released_coil(5e-3)
    rng = np.random.default_rng(seed)
    n = model.n_segments
    state = ChainState(rest.position, rest.rotation, rng.normal(0, 0.05, (n, 3)), rng.normal(0, 300.0, (n, 3)))
    return model, state, rng


def test_joint_stage_diagnostic_has_the_kernels_equations():
    """``bench_joint_stage_root.JointStage`` with the start levers is Method I's joint stage as the solver's kernel
    has it: for a moving, bent chain (the 5 mm released coil with random twists) and random joint impulses P, the
    kernel's trial integration (``_kernels.chains._fibre_trial``) gives twists u'(P) and gap and spring residuals;
    at (u'(P), P) the script's body rows vanish and its gap and spring rows are the kernel's (scaled to impulses:
    gaps × m/Δt, springs / h), to round-off. With the mean levers the body rows no longer vanish there (the
    impulses' moment changes)."""
    from headsim.solvers._kernels import chains as K

    B = _joint_stage_module()
    model, state, rng = _moving_coil(B, 7)
    n, dt = model.n_segments, 1e-3
    m, inertia = model.mass[0], model.inertia[0, 0]
    P = np.concatenate([rng.normal(0, 0.05 * m, (n, 3)), rng.normal(0, 100.0 * inertia, (n, 3))], axis=1)
    res, x_end, R_end, w_new = np.zeros((n, 6)), np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3))
    zero = np.zeros((n, 3))
    K._fibre_trial(0, n, 0, P, state.position, state.rotation, state.velocity, state.angular_velocity, model.mass,
                   model.inertia, model.half_length, model.root_point, model.root_frame, 0, dt, np.zeros(3), zero, zero,
                   model.joint_stiffness, model.rest_rotation, model.joint_damping, res, x_end, R_end, w_new)
    force = -P[:, :3].copy()
    force[:-1] += P[1:, :3]
    z = np.concatenate([state.velocity + force / model.mass[:, None], w_new, P], axis=1)
    scale = np.abs(P[:, :3]).max()  # N s
    for levers in ("start", "mean"):
        r = B.JointStage(model, state, levers).residual(z, dt).reshape(n, 4, 3)
        body = np.abs(r[:, :2]).max() / scale
        if levers == "mean":
            assert body > 1e-3
            continue
        assert body < 1e-12
        np.testing.assert_allclose(r[:, 2], res[:, :3] * (model.mass / dt)[:, None], rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(r[:, 3], res[:, 3:] / model.half_length[:, None], rtol=0, atol=1e-12 * scale)
        assert np.abs(r[:, 2:]).max() > 1e-3 * scale  # not trivially zero


def test_mean_lever_kernel_has_the_diagnostics_equations():
    """The solver's joint stage with ``joint_levers`` = "mean" (``_kernels.chains_mean.mean_lever_residual``) and the
    diagnostic's ``JointStage(levers="mean")`` (NumPy, Rotation) are the same equations, rows scaled alike: at
    random twists and impulses of the moving 5 mm coil (turning up to ≈ 0.5 rad in the step) the residuals agree to
    round-off, for the anchored chain and with the first body's joint dropped (a free root: there the kernel pins
    the missing joint's impulse to 0, rows 6:12 = P)."""
    from headsim.solvers._kernels import chains_mean as KM

    B = _joint_stage_module()
    model, state, rng = _moving_coil(B, 11)
    n, dt = model.n_segments, 1e-3
    m, inertia = model.mass[0], model.inertia[0, 0]
    z = np.concatenate([state.velocity + rng.normal(0, 0.01, (n, 3)), state.angular_velocity
                        + rng.normal(0, 100.0, (n, 3)), rng.normal(0, 0.05 * m, (n, 3)),
                        rng.normal(0, 100.0 * inertia, (n, 3))], axis=1)
    zero = np.zeros((n, 3))
    out = np.zeros((n, 12))
    for anchored in (True, False):
        j0 = 0 if anchored else 1
        KM.mean_lever_residual(0, n, j0, z, state.position, state.rotation, state.velocity, state.angular_velocity,
                               model.mass, model.inertia, model.half_length, model.root_point, model.root_frame, 0,
                               dt, np.zeros(3), zero, zero, model.joint_stiffness, model.rest_rotation,
                               model.joint_damping, np.zeros((n, 3)), np.zeros((n, 3, 3)), out)
        ref = B.JointStage(model, state, "mean").residual(z, dt).reshape(n, 12)
        scale = np.abs(ref).max()
        if anchored:
            np.testing.assert_allclose(out, ref, rtol=0, atol=1e-10 * scale)
        else:  # body 0 without its root joint: its impulse rows are P, and no impulse of joint 0 acts on it
            zf = z.copy()
            zf[0, 6:] = 0.0
            ref = B.JointStage(model, state, "mean").residual(zf, dt).reshape(n, 12)
            np.testing.assert_allclose(out[1:], ref[1:], rtol=0, atol=1e-10 * scale)
            np.testing.assert_allclose(out[0, :6], ref[0, :6], rtol=0, atol=1e-10 * scale)
            np.testing.assert_array_equal(out[0, 6:], z[0, 6:])


def test_mean_lever_newton_from_kept_factors_reaches_the_fresh_root():
    """``solve_mean_levers_serial`` keeps each fibre's Jacobian factors for its next call (the solver's next
    harmonisation pass and step) and starts there with chord steps. On the moving 5 mm coil: a first solve from a
    fresh Jacobian, then the problem changed as a later pass changes it (an extra rotation Δθ_extra of ≈ 0.05 rad
    per body, and 1 mm/s more on every velocity) solved from the kept factors, from a fresh Jacobian, and from
    useless factors (the identity): all three converge to the same root (twists within the joint tolerance's
    scale: 1e-9 m of gap per Δt = 1 ms is 1e-6 m/s), and the kept factors were used (their iterates differ
    bitwise from the fresh Jacobian's)."""
    from headsim.solvers._kernels import chains_mean as KM

    B = _joint_stage_module()
    model, state, rng = _moving_coil(B, 13)
    n, dt = model.n_segments, 1e-3
    fibres = np.zeros(1, np.int64)
    zero = np.zeros((n, 3))

    def solve(v, dth, factors, kept):
        v_out, w_out = v.copy(), state.angular_velocity.copy()
        its, ok = np.zeros(1, np.int64), np.zeros(1, np.bool_)
        KM.solve_mean_levers_serial(fibres, model.segment_offsets, model.anchored, state.position, state.rotation, v,
                                    state.angular_velocity, model.mass, model.inertia, model.half_length,
                                    model.root_point, model.root_frame, dt, np.zeros(3), zero, dth,
                                    model.joint_stiffness, model.rest_rotation, model.joint_damping, 1e-9, 40, v_out,
                                    w_out, its, ok, *factors, kept)
        assert ok[0] and kept[0]
        return v_out, w_out, int(its[0])

    def fresh_factors():
        return tuple(np.zeros((n, KM.BLOCK, KM.BLOCK)) for _ in range(3))

    kept_factors = fresh_factors()
    solve(state.velocity, zero, kept_factors, np.zeros(1, np.bool_))
    v2 = state.velocity + 1e-3
    dth = rng.normal(0.0, 0.05, (n, 3))
    v_kept, w_kept, _ = solve(v2, dth, kept_factors, np.ones(1, np.bool_))
    v_new, w_new, _ = solve(v2, dth, fresh_factors(), np.zeros(1, np.bool_))
    identity = (np.broadcast_to(np.eye(KM.BLOCK), (n, KM.BLOCK, KM.BLOCK)).copy(),
                np.zeros((n, KM.BLOCK, KM.BLOCK)), np.zeros((n, KM.BLOCK, KM.BLOCK)))
    v_bad, w_bad, _ = solve(v2, dth, identity, np.ones(1, np.bool_))
    for v, w in ((v_kept, w_kept), (v_bad, w_bad)):
        np.testing.assert_allclose(v, v_new, rtol=0, atol=1e-5)
        np.testing.assert_allclose(w, w_new, rtol=0, atol=1e-5 / model.half_length.min())
    assert not np.array_equal(v_kept, v_new)


def test_joint_stage_root_diagnostic_runs_and_its_roots_converge():
    """``benchmarks/bench_joint_stage_root.py`` (issue 10: the released coil with the solver's plain step and with
    Method I's joint stage solved to its root, with the start and with the mean levers) runs 3 steps of 1 ms: every
    run prints finite energies at each millisecond, starting from 1, and every root solve of those steps converges
    (the script's comparisons rest on exact roots); bad arguments exit with 2."""
    script = str(ROOT / "benchmarks" / "bench_joint_stage_root.py")
    out = subprocess.run([sys.executable, script, "--dt-ms", "1", "--duration-ms", "3"], capture_output=True,
                         text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("released coil: 30 × 3 mm, radius 5 mm, 3 ms"), out.stdout
    runs = dict(re.findall(r"^Δt 1 ms, (linear|root, start levers|root, mean levers): energy/start per ms ([^;]+);",
                           out.stdout, re.M))
    assert set(runs) == {"linear", "root, start levers", "root, mean levers"}, out.stdout
    for energies in runs.values():
        e = [float(v) for v in energies.split()]
        assert len(e) == 4 and e[0] == 1.0 and np.isfinite(e).all()
    assert len(re.findall(r"root solves not converged 0 of 3;", out.stdout)) == 2, out.stdout
    bad = subprocess.run([sys.executable, script, "--dt-ms", "0"], capture_output=True, text=True, timeout=600,
                         cwd=ROOT)
    assert bad.returncode == 2 and "must be positive" in bad.stderr, bad.stderr[-2000:]
