"""Diagnostic (issue 10): is the plain chain step's energy gain on a strongly bent, stiff fibre a fault of the joint
stage's linearisation, or of its time discretisation? Runs the released coil of
``tests/solvers/test_chains_stabilisation.py`` (30 segments of 3 mm, 70 µm, straight rest shape, wound into a helix
and released at rest; no gravity, no contacts; the plain step, ``step_halvings`` = 0) twice per time step:

* ``linear``: the solver as it is. Method I's spring rows are linearly implicit
  (``_kernels.chains.correct_fibre_joints``: one solve of the gaps and springs with the start frames' small-angle
  stiffness, then Newton passes on the gaps);
* ``root``: every fibre's joint stage solved to the root of the same trial residual (joint gaps, eq. 8.76, and
  implicit spring rows, §8.5.3, of ``_kernels.chains._fibre_trial``), all rows at once: Newton on a central-difference
  Jacobian (block-tridiagonal, 3 colours × 6 columns) with a backtracking line search on the residual (gap rows
  weighted by m/Δt), converged when the gaps are ≤ ``ChainOptions.joint_tolerance`` and the spring rows ≤ 1e-9 of
  the largest angular impulse. Python per fibre: for small chains only.

Prints, per run, the total energy (kinetic + springs) relative to the start at every millisecond, the steps whose
energy rose, the root solves that did not converge in 60 iterations, and the run time relative to ``linear``.

Usage: python benchmarks/bench_joint_stage_root.py [--radius-mm 5] [--dt-ms 1 0.5 0.25] [--duration-ms 20]

Measured (issue 10, thirty-seventh session; 5 mm coil, 0.6 rad of bending per joint, 20 ms; energy relative to the
start after 5 / 10 / 20 ms, the steps whose energy rose, the root solves not converged):

=======  ===============================  ===========================================================
Δt       linear                           root
=======  ===============================  ===========================================================
1 ms     0.847 / 1.11 / 8.67; 13 of 20    3.41 / 1.8e3 / 7.5e6; 19 of 20; 34 of 40 solves not converged
0.5 ms   0.849 / 0.789 / 0.574; 1 of 40   0.965 / 0.895 / 0.815; 14 of 40; all 80 converged
0.25 ms  0.877 / 0.827 / 0.669; 0 of 80   0.919 / 0.868 / 0.675; 11 of 80; all 160 converged
=======  ===============================  ===========================================================

(With 2 harmonisation passes a step makes 2 joint solves.) At 1 ms the root solves converge in the first 3 steps
(7–10 iterations) and the energy rises already in the second and third (0.910 → 0.922 → 1.010); then no root is
found, and the figures after that depend on where the failed solves stop. At 0.5 and 0.25 ms every root solve
converges and the energy still rises in 14 and 11 steps, where the linearly implicit step's falls in all steps but
one. On 15 and 50 mm coils (``--radius-mm 15``, ``50``: 0.2 and 0.06 rad per joint) the two agree to 3 digits at
1 ms and fall in every step (0.780 and 0.789 after 20 ms), the root solves converging. The root solves cost 20–30
times the linear step's run time (124 times where they fail).

So the gain is not the linearisation's: the joint stage's trial integration itself (impulses at the start-of-step
levers, the exp-map rotation with the start inertia, springs evaluated at the end frames) is not energy-stable at
≈ 1 rad per step, and solved exactly it is less dissipative than the linearly implicit step. A remedy needs a
different discretisation of that stage (e.g. a discrete-gradient or variational Lie-group step), not a better
Newton; until then the step control (``max_rotation_per_step``, ``step_halvings``) resolves such motion.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from headsim.solvers._kernels import chains as K
from headsim.solvers.chains import ChainOptions, ChainSolver, chain_model_from_polylines
from headsim.solvers.chains_model import kinetic_energy, spring_energy

ROOT_ITERATIONS = 60
SPRING_TOLERANCE = 1e-9  # spring rows: fraction of the largest angular impulse (plus 1e-3 s⁻¹ of I)


def released_coil(radius, segments=30, segment_length=3e-3, pitch=5e-3):
    """The root-anchored helix of the released-coil tests (radius m): (model, state) at rest."""
    c = np.hypot(radius, pitch / (2 * np.pi))
    t = np.arange(segments + 1) * segment_length / c
    nodes = np.stack([radius * np.cos(t), radius * np.sin(t), pitch / (2 * np.pi) * t], 1)
    return chain_model_from_polylines(nodes, [0, segments + 1], radius=35e-6, rest_shape="straight")


def _fibre_root(model, f, x, R, v, w, dt, gravity, dx_extra, dth_extra, tol, v_out, w_out):
    """Fibre f's joint stage solved to the root of ``_kernels.chains._fibre_trial``'s residual; writes the corrected
    twists into v_out, w_out. Returns (Newton iterations, converged, largest gap m)."""
    s0, s1 = model.segment_offsets[f], model.segment_offsets[f + 1]
    n = s1 - s0
    j0 = 0 if model.anchored[f] else 1
    nj = n - j0
    if nj <= 0:
        v_out[s0:s1], w_out[s0:s1] = v[s0:s1], w[s0:s1]
        return 0, True, 0.0
    x_end, R_end, w_new, res = np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((nj, 6))

    def residual(P):
        g = K._fibre_trial(s0, n, j0, P.reshape(nj, 6), x, R, v, w, model.mass, model.inertia, model.half_length,
                           model.root_point, model.root_frame, f, dt, gravity, dx_extra, dth_extra,
                           model.joint_stiffness, model.rest_rotation, model.joint_damping, res, x_end, R_end, w_new)
        return res.ravel().copy(), g

    m, inertia = model.mass[s0], model.inertia[s0].max()
    weight = np.tile(np.r_[np.full(3, m / dt), np.ones(3)], nj)  # gap rows as impulses
    h = np.tile(np.r_[np.full(3, 1e-5 * m), np.full(3, 1e-3 * inertia)], nj)  # 10 µm/s, 1 mrad/s
    P = np.zeros(6 * nj)
    r, g = residual(P)
    merit = np.linalg.norm(weight * r)
    it, converged = 0, False
    while True:
        spring = np.abs(r.reshape(nj, 6)[:, 3:]).max()
        if g <= tol and spring <= SPRING_TOLERANCE * (np.abs(P.reshape(nj, 6)[:, 3:]).max() + 1e-3 * inertia):
            converged = True
            break
        if it == ROOT_ITERATIONS:
            break
        J = np.zeros((6 * nj, 6 * nj))
        for colour in range(3):  # joint j's impulse reaches the residuals of joints j − 1 … j + 1
            for a in range(6):
                cols = np.arange(colour, nj, 3) * 6 + a
                dP = np.zeros(6 * nj)
                dP[cols] = h[cols]
                d = residual(P + dP)[0] - residual(P - dP)[0]
                for j in range(colour, nj, 3):
                    lo, hi = max(0, j - 1) * 6, min(nj, j + 2) * 6
                    J[lo:hi, 6 * j + a] = d[lo:hi] / (2 * h[6 * j + a])
        step = np.linalg.solve(J, -r)
        t = 1.0
        for _ in range(30):
            r_new, g_new = residual(P + t * step)
            merit_new = np.linalg.norm(weight * r_new)
            if merit_new < (1 - 1e-4 * t) * merit:
                break
            t *= 0.5
        P, r, g, merit = P + t * step, r_new, g_new, merit_new
        it += 1
    P = P.reshape(nj, 6)
    fl, tq = np.empty(3), np.empty(3)
    for b in range(n):
        s = s0 + b
        K._joint_impulses_into(b, s, n, j0, P, R, model.half_length, fl, tq)
        v_out[s] = v[s] + fl / model.mass[s]
        w_out[s] = w[s] + R[s] @ ((R[s].T @ tq) / model.inertia[s])
    return it, converged, g


class RootJointSolver(ChainSolver):
    """:class:`ChainSolver` whose joint stage (Method I) is solved to its nonlinear root (see the module notes)."""

    def __init__(self, options):
        super().__init__(options)
        self.root_solves = self.root_failures = 0

    def _joints(self, model, x, R, v, w, dt, dx_extra, dth_extra, factor=None, store=None):
        v_out, w_out = np.empty_like(v), np.empty_like(w)
        g = np.asarray(self.options.gravity, float)
        its, gaps = [0], [0.0]
        for f in range(model.n_fibres):
            it, ok, gap = _fibre_root(model, f, x, R, v, w, float(dt), g, dx_extra, dth_extra,
                                      float(self.options.joint_tolerance), v_out, w_out)
            self.root_solves += 1
            self.root_failures += not ok
            its.append(it)
            gaps.append(gap)
        return v_out, w_out, max(its), max(gaps)


def run(solver_class, radius, dt, duration):
    """(energies relative to the start at every step, seconds, solver) of the released coil."""
    model, state = released_coil(radius)
    solver = solver_class(ChainOptions(gravity=(0.0, 0.0, 0.0), fibre_contacts=False, step_halvings=0))
    energies = [kinetic_energy(model, state) + spring_energy(model, state)]
    t0 = time.perf_counter()
    for _ in range(int(round(duration / dt))):
        state = solver.step(model, state, dt)
        energies.append(solver.last_stats.total_energy)
    return np.array(energies) / energies[0], time.perf_counter() - t0, solver


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--radius-mm", type=float, default=5.0)
    ap.add_argument("--dt-ms", type=float, nargs="+", default=[1.0, 0.5, 0.25])
    ap.add_argument("--duration-ms", type=float, default=20.0)
    args = ap.parse_args()
    if args.radius_mm <= 0 or args.duration_ms <= 0 or min(args.dt_ms) <= 0:
        ap.error("--radius-mm, --dt-ms and --duration-ms must be positive")
    radius, duration = 1e-3 * args.radius_mm, 1e-3 * args.duration_ms
    run(ChainSolver, radius, 1e-3 * args.dt_ms[0], 1e-3 * args.dt_ms[0])  # compile
    print(f"released coil: 30 × 3 mm, radius {args.radius_mm:g} mm, {args.duration_ms:g} ms, plain step")
    for dt_ms in args.dt_ms:
        dt = 1e-3 * dt_ms
        every = max(1, int(round(1e-3 / dt)))
        base = None
        for label, cls in (("linear", ChainSolver), ("root", RootJointSolver)):
            e, secs, solver = run(cls, radius, dt, duration)
            base = secs if base is None else base
            rises = int((np.diff(e) > 0).sum())
            extra = (f"; root solves {solver.root_solves}, not converged {solver.root_failures}"
                     if label == "root" else "")
            print(f"Δt {dt_ms:g} ms {label:6s}: energy/start per ms " + " ".join(f"{v:.3g}" for v in e[::every])
                  + f"; rising steps {rises} of {len(e) - 1}{extra}; time × {secs / base:.1f}", flush=True)


if __name__ == "__main__":
    main()
