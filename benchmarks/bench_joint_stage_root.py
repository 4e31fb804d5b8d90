"""Diagnostic (issue 10): where does the plain chain step's energy gain on a strongly bent, stiff fibre come from?
Runs the released coil of ``tests/solvers/test_chains_stabilisation.py`` (30 segments of 3 mm, 70 µm, straight rest
shape, wound into a helix and released at rest; no gravity, no contacts) three ways per time step:

* ``linear``: the solver's plain step (``ChainSolver``, ``step_halvings`` = 0). Method I's spring rows are linearly
  implicit (``_kernels.chains.correct_fibre_joints``: one solve of the gaps and springs with the start frames'
  small-angle stiffness, then Newton passes on the gaps);
* ``root, start levers``: the joint stage's own equations (:class:`JointStage`, the same as
  ``_kernels.chains._fibre_trial``'s: impulses at the start-of-step levers ±h R e₃, eq. 8.72; x' = x + Δt v',
  R' = exp(Δt ω̃') R; joint gaps at the end, eq. 8.76; implicit springs at the end frames, §8.5.3) solved to their
  root, every step;
* ``root, mean levers``: the same with the impulses at each body's levers averaged over its rotation φ = Δt ω' of
  the step, J_l(φ) (±h R e₃) (J_l the left Jacobian of SO(3)). Because (exp(φ̃) − E) r = φ × J_l(φ) r, the
  end-of-step gap is then exactly Δt times the joint's relative velocity at those levers, so joint impulses that
  close it do no work on the end velocities (at the start levers they do).

The root solves are Newton iterations on all of a step's unknowns at once (twists u' and joint impulses P of every
body and joint) with a coloured central-difference Jacobian and a backtracking line search; converged when every
scaled residual is below 1e-10 of m × 1 mm/s. NumPy, one fibre: for small chains only.

Prints, per run, the total energy (kinetic + springs, :func:`headsim.solvers.chains_model.kinetic_energy` and
``spring_energy``) relative to the start at every millisecond, the steps whose energy rose, the root solves that did
not converge (``ROOT_ITERATIONS``), and the run time relative to ``linear``.

Usage: python benchmarks/bench_joint_stage_root.py [--radius-mm 5] [--dt-ms 1 0.5] [--duration-ms 20]

Measured (issue 10, thirty-seventh session; energy relative to the start after 5 / 10 / 20 ms; steps whose energy
rose; root solves not converged):

=========================  ============================  ==============================  =============================
coil, Δt                   linear                        root, start levers              root, mean levers
=========================  ============================  ==============================  =============================
5 mm (0.6 rad/joint), 1    0.847 / 1.11 / 8.67; 13/20    2.12 / 70.1 / 1.3e3; 19/20;     0.799 / 0.641 / 0.344; 0/20;
ms                                                       17 of 20 not converged          all converged
5 mm, 0.5 ms               0.849 / 0.789 / 0.574; 1/40   0.965 / 0.895 / 0.815; 14/40;   0.836 / 0.692 / 0.419; 0/40;
                                                         all converged                   all converged
5 mm, 0.25 ms              0.877 / 0.827 / 0.669; 0/80   0.919 / 0.868 / 0.675; 11/80;   0.867 / 0.756 / 0.516; 0/80;
                                                         all converged                   all converged
3 mm (1 rad/joint), 1 ms   2.51 / 3.00 / 4.76; 14/20     none converged                  none converged
3 mm, 0.5 ms               2.34 / 4.29 / 3.77; 24/40     39 of 40 not converged          0.417 / 0.195 / 0.107; 0/40;
                                                                                         all converged
=========================  ============================  ==============================  =============================

The start levers' root reproduces the kernel's trial: 0.910 → 0.922 → 1.010 in the first three steps at 1 ms with
every root found, the energy rising from the second step (``tests/solvers/test_contact_benchmarks.py`` checks that
:class:`JointStage` with the start levers has ``_fibre_trial``'s residual). So the energy gain is not the linearly
implicit springs' (an exact solve gains more, and more often): it is the work of the joint impulses applied at the
start-of-step levers while the gap they close moves with the rotated ones. With the mean levers every step whose root
was found lost energy, at every step size measured. Where no root is found (3 mm at 1 ms: 1 rad of bending per
joint turning by ≈ 1 rad per step) neither lever choice helps; the step control does (halving).

In the solver since the same session, and its default since the thirty-eighth: ``ChainOptions.joint_levers = "mean"``
(:mod:`headsim.solvers._kernels.chains_mean`, the same equations as :class:`JointStage` with the mean levers, checked
by a test, solved the same way in Numba); its plain steps on the 5 mm coil at 1 ms give this table's mean-lever
column (0.344 × after 20 ms). Two ways into the existing ``correct_fibre_joints`` failed first (5 mm coil at 1 ms):
(1) each body's twist solved for its mean levers inside the trial integration (the kernel eliminates the twists
per body): that equation has spurious branches at ≈ 1 rad per step (a per-body Newton found twists of 7 rad per
step) and the impulse Newton stalled; (2) the levers lagged one iteration behind the twists, with the start levers'
chord matrix and the springs' single linear solve: 41 × the energy after the first step (8 iterations), 400 × with
40. The twists had to be Newton unknowns with the impulses, and the springs solved to the root.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial.transform import Rotation

from headsim.solvers.chains import ChainOptions, ChainSolver, chain_model_from_polylines
from headsim.solvers.chains_model import ChainState, kinetic_energy, spring_energy

ROOT_ITERATIONS = 60
ROOT_TOLERANCE = 1e-10  # of m × 1 mm/s, on every scaled residual row (impulse units, N s)


def released_coil(radius, segments=30, segment_length=3e-3, pitch=5e-3):
    """The root-anchored helix of the released-coil tests (radius m): (model, state) at rest."""
    c = np.hypot(radius, pitch / (2 * np.pi))
    t = np.arange(segments + 1) * segment_length / c
    nodes = np.stack([radius * np.cos(t), radius * np.sin(t), pitch / (2 * np.pi) * t], 1)
    return chain_model_from_polylines(nodes, [0, segments + 1], radius=35e-6, rest_shape="straight")


def _skew(a):
    z = np.zeros(a.shape[:-1] + (3, 3))
    z[..., 0, 1], z[..., 0, 2], z[..., 1, 2] = -a[..., 2], a[..., 1], -a[..., 0]
    z[..., 1, 0], z[..., 2, 0], z[..., 2, 1] = a[..., 2], -a[..., 1], a[..., 0]
    return z


def left_jacobian(phi):
    """J_l(φ) = ∫₀¹ exp(s φ̃) ds = E + (1 − cos θ)/θ² φ̃ + (θ − sin θ)/θ³ φ̃², (..., 3, 3)."""
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    small = th < 1e-4
    t = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th**2 / 24, (1 - np.cos(t)) / t**2)
    b = np.where(small, 1 / 6 - th**2 / 120, (t - np.sin(t)) / t**3)
    S = _skew(phi)
    return np.eye(3) + a * S + b * (S @ S)


def _inverse_left_jacobian_transposed(theta):
    """J_l⁻ᵀ(θ) = E + ½ θ̃ + c θ̃², c = 1/θ² − (1 + cos θ)/(2 θ sin θ), as ``_kernels.chains._spring_moment``."""
    th = np.linalg.norm(theta, axis=-1)[..., None, None]
    small = th < 1e-4
    t = np.where(small, 1.0, th)
    c = np.where(small, 1 / 12, 1 / t**2 - (1 + np.cos(t)) / (2 * t * np.sin(t)))
    S = _skew(theta)
    return np.eye(3) + 0.5 * S + c * (S @ S)


class JointStage:
    """Method I's joint stage of one root-anchored chain (no gravity, no contacts) as a NumPy system in the step's
    twists u' = (v', ω') (n, 6) and joint impulses P (n, 6) (joint j between body j − 1, or the root, and body
    j): body rows M (u' − u) = the impulses' wrench; gap rows d(x', R') = 0; spring rows P_ang = Δt (R'_k
    J_l⁻ᵀ(θ) K (θ − θ°) + c (ω'_l − ω'_k)), θ = log(R'_kᵀ R'_l). Rows are scaled to impulses (N s): angular rows
    by 1/h, gap rows by m/Δt. ``levers``: "start" (eq. 8.72, the kernel's) or "mean" (J_l(Δt ω') times them)."""

    def __init__(self, model, state, levers):
        if model.n_fibres != 1 or not model.anchored[0]:
            raise ValueError("JointStage takes one root-anchored fibre")
        if not np.allclose(model.inertia, model.inertia[:, :1]):
            raise ValueError("JointStage needs the spherical inertia (I₁ = I₂ = I₃)")
        if levers not in ("start", "mean"):
            raise ValueError(f"levers must be 'start' or 'mean', got {levers!r}")
        self.model, self.levers = model, levers
        self.m, self.I, self.h = model.mass, model.inertia[:, 0], model.half_length
        self.n = model.n_segments
        self.state = state

    def _frames_k(self, R):
        return np.concatenate([self.model.root_frame[:1], R[:-1]])

    def residual(self, z, dt):
        """Scaled residual (n · 12,) of the unknowns z (n, 12) = (v', ω', P) per body / joint."""
        st, mo, n = self.state, self.model, self.n
        z = z.reshape(n, 12)
        v1, w1, Pl, Pa = z[:, 0:3], z[:, 3:6], z[:, 6:9], z[:, 9:12]
        R1 = Rotation.from_rotvec(dt * w1).as_matrix() @ st.rotation
        x1 = st.position + dt * v1
        e3 = st.rotation[:, :, 2]
        r_inner, r_outer = -self.h[:, None] * e3, self.h[:, None] * e3  # joint b (body is l), joint b + 1 (k)
        if self.levers == "mean":
            J = left_jacobian(dt * w1)
            r_inner, r_outer = np.einsum("bij,bj->bi", J, r_inner), np.einsum("bij,bj->bi", J, r_outer)
        force = -Pl.copy()
        force[:-1] += Pl[1:]
        torque = -(Pa + np.cross(r_inner, Pl))
        torque[:-1] += Pa[1:] + np.cross(r_outer[:-1], Pl[1:])
        body_lin = self.m[:, None] * (v1 - st.velocity) - force
        body_ang = (self.I[:, None] * (w1 - st.angular_velocity) - torque) / self.h[:, None]
        e3_1 = R1[:, :, 2]
        outer_point = np.concatenate([mo.root_point[:1], (x1 + self.h[:, None] * e3_1)[:-1]])
        gap = (outer_point - (x1 - self.h[:, None] * e3_1)) * (self.m / dt)[:, None]
        Rk = self._frames_k(R1)
        theta = Rotation.from_matrix(np.einsum("jba,jbc->jac", Rk, R1)).as_rotvec()
        e = mo.joint_stiffness * (theta - mo.rest_rotation)
        moment = np.einsum("jab,jb->ja", Rk, np.einsum("jab,jb->ja", _inverse_left_jacobian_transposed(theta), e))
        wk = np.concatenate([np.zeros((1, 3)), w1[:-1]])
        moment += mo.joint_damping[:, None] * (w1 - wk)
        spring = (Pa - dt * moment) / self.h[:, None]
        return np.concatenate([body_lin, body_ang, gap, spring], axis=1).ravel()

    def step(self, dt):
        """One step to the root: (converged, Newton iterations); self.state becomes the end of the step."""
        st, n = self.state, self.n
        z = np.zeros((n, 12))
        z[:, 0:3], z[:, 3:6] = st.velocity, st.angular_velocity
        z = z.ravel()
        hz = np.tile(np.r_[np.full(3, 1e-6), np.full(3, 1e-4), np.full(3, 1e-6 * self.m[0]),
                           np.full(3, 1e-4 * self.I[0])], n)  # 1 µm/s, 0.1 mrad/s and their impulses
        r = self.residual(z, dt)
        merit = np.linalg.norm(r)
        tol = ROOT_TOLERANCE * self.m[0] * 1e-3
        converged, it = False, 0
        while True:
            if np.abs(r).max() <= tol:
                converged = True
                break
            if it == ROOT_ITERATIONS:
                break
            jac = np.zeros((12 * n, 12 * n))
            for colour in range(3):  # block b reaches the rows of blocks b − 1 … b + 1
                blocks = np.arange(colour, n, 3)
                for a in range(12):
                    cols = 12 * blocks + a
                    dz = np.zeros(12 * n)
                    dz[cols] = hz[cols]
                    d = self.residual(z + dz, dt) - self.residual(z - dz, dt)
                    for b in blocks:
                        lo, hi = 12 * max(0, b - 1), 12 * min(n, b + 2)
                        jac[lo:hi, 12 * b + a] = d[lo:hi] / (2 * hz[12 * b + a])
            step = np.linalg.solve(jac, -r)
            t = 1.0
            for _ in range(40):
                r_new = self.residual(z + t * step, dt)
                merit_new = np.linalg.norm(r_new)
                if merit_new < (1 - 1e-4 * t) * merit:
                    break
                t *= 0.5
            z, r, merit = z + t * step, r_new, merit_new
            it += 1
        z = z.reshape(n, 12)
        v1, w1 = z[:, 0:3].copy(), z[:, 3:6].copy()
        R1 = Rotation.from_rotvec(dt * w1).as_matrix() @ st.rotation
        self.state = ChainState(st.position + dt * v1, R1, v1, w1, st.time + dt)
        return converged, it


def run(kind, radius, dt, duration):
    """(energies relative to the start at every step, seconds, root solves not converged) of the released coil."""
    model, state = released_coil(radius)
    energies = [kinetic_energy(model, state) + spring_energy(model, state)]
    failed = 0
    t0 = time.perf_counter()
    if kind == "linear":
        solver = ChainSolver(ChainOptions(gravity=(0.0, 0.0, 0.0), fibre_contacts=False, step_halvings=0))
    else:
        stage = JointStage(model, state, kind)
    for _ in range(int(round(duration / dt))):
        if kind == "linear":
            state = solver.step(model, state, dt)
        else:
            ok, _ = stage.step(dt)
            failed += not ok
            state = stage.state
        energies.append(kinetic_energy(model, state) + spring_energy(model, state))
    return np.array(energies) / energies[0], time.perf_counter() - t0, failed


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--radius-mm", type=float, default=5.0)
    ap.add_argument("--dt-ms", type=float, nargs="+", default=[1.0, 0.5])
    ap.add_argument("--duration-ms", type=float, default=20.0)
    args = ap.parse_args()
    if args.radius_mm <= 0 or args.duration_ms <= 0 or min(args.dt_ms) <= 0:
        ap.error("--radius-mm, --dt-ms and --duration-ms must be positive")
    radius, duration = 1e-3 * args.radius_mm, 1e-3 * args.duration_ms
    run("linear", radius, 1e-3 * args.dt_ms[0], 1e-3 * args.dt_ms[0])  # compile
    print(f"released coil: 30 × 3 mm, radius {args.radius_mm:g} mm, {args.duration_ms:g} ms")
    for dt_ms in args.dt_ms:
        dt = 1e-3 * dt_ms
        every = max(1, int(round(1e-3 / dt)))
        base = None
        for kind, label in (("linear", "linear"), ("start", "root, start levers"), ("mean", "root, mean levers")):
            e, secs, failed = run(kind, radius, dt, duration)
            base = secs if base is None else base
            roots = "" if kind == "linear" else f"; root solves not converged {failed} of {len(e) - 1}"
            print(f"Δt {dt_ms:g} ms, {label}: energy/start per ms " + " ".join(f"{v:.3g}" for v in e[::every])
                  + f"; rising steps {int((np.diff(e) > 0).sum())} of {len(e) - 1}{roots}; time × {secs / base:.1f}",
                  flush=True)


if __name__ == "__main__":
    main()
