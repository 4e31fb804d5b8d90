"""Benchmark: how far the coupled contact solve (``ChainOptions.qp_iterations`` Gauss–Seidel sweeps, default
60) is from its own converged answer, on the drape reference scene's ringlet start (Sobottka 2008 §8.6.2;
issue 10: the contact kernel's convergence is the speed lever).

The scene is advanced ``--settle`` steps, the first coupled contact solve of the next step (the velocity
solve of the first harmonisation pass) is captured, and its iteration
(:func:`headsim.solvers._kernels.chains_coupled.coupled_iterate`) is rerun from the same set-up with a fixed
number of sweeps (tolerance 0) for every count in ``--sweeps``; the largest count is the reference.
Printed per count: CPU time, the relative error of the velocity correction in the kinetic metric
‖u − u_ref‖_M / ‖u_ref − u⁻‖_M, the largest velocity difference to the reference (m/s), the largest
violation of a contact row's bound max(target − J u, 0) (m/s; × Δt = the penetration it leaves, m),
the largest joint gap-rate residual (m/s; × ½Δt = the joint gap it leaves, m) and the largest and summed
normal impulses (N s; growing without bound would mean an infeasible row set).

Usage: python benchmarks/bench_contact_convergence.py [--fibres 120] [--segments 50] [--settle 5]
       [--sweeps 60 120 300 1000 10000]

Measured (branch ``speed``, 2 shared cores, load 1.5–2.5; 120 × 50 ringlet, 6,000 segments, solve at
t = 5 ms with 32.9 k rows and ≈ 1,000 contacts carrying impulse; the reference is 10,000 sweeps, where the
change per sweep is 2e-6 m/s):

======  =====================  ===============  ==================  =====================
sweeps  rel. M-error vs 10 k   max |Δv| (m/s)   max violation m/s   max joint residual m/s
======  =====================  ===============  ==================  =====================
60      0.31                   2.5e-2           1.4e-2              7.9e-3
300     0.081                  1.0e-2           2.9e-3              3.4e-3
2,000   5.6e-4                 1.0e-4           1.1e-5              2.6e-5
======  =====================  ===============  ==================  =====================

So the default 60 sweeps leave the velocity correction 31 % off the converged one (kinetic energy of the
result 3e-4 relative off), up to 14 µm of penetration per step and a 4 µm joint gap that the next step
corrects. The convergence is linear and slow (≈ 2 ms per sweep here, ≈ 11 ms on the 355 × 100 scene).
A prototype (not committed) that eliminates the joints exactly (Gauss–Seidel on the Schur complement
W = J Y Jᵀ, Y the joint-constrained mobility of each fibre applied through per-contact columns computed
by one block-Thomas solve each) reached 0.14 / 0.048 / 0.018 / 0.0055 at 20 / 40 / 60 / 100 sweeps: at equal
CPU time (≈ 0.7 s, unoptimised) 4–5 × smaller error than the shipped kernel, but not faster at the shipped
accuracy (both need ≈ 0.15 s CPU for the 0.31 error). Over-relaxation (ω = 1.3–1.9) gave 0.27–0.23 at 60
sweeps of the shipped kernel (no gain worth its risk). The remaining slow mode is the contact network
of the stacked bundle, not the joints.

Settling strand (``--fibres 40 --segments 30 --settle 1500 --sweeps 60 3000 10000 40000``, t = 1.5 s, 1,219
rows, load 1.3–1.7): no convergence at all. Against 40,000 sweeps: 60 / 3,000 / 10,000 sweeps are 0.62 /
0.33 / 0.21 off; the largest violation is still 6.3e-3 / 1.7e-3 / 1.3e-3 / 5.4e-4 m/s and the joint
residual 9.9e-3 … 7.7e-4 m/s, while the normal impulses keep growing with the sweeps (largest 8.5e-9 /
1.5e-7 / 2.2e-7 / 6.1e-7 N s, sum 3.3e-7 … 2.0e-6 N s; the whole strand's weight impulse per step is
≈ 6e-7 N s). Growing impulses point to a row set that is (nearly) infeasible together with the joint
rows (e.g. a joint-gap target that pulls a segment into a contact); then no tolerance is ever met and
the result is set by the sweep cap. Check (same captured solve, 3,000 / 20,000 sweeps): with the joint
rows' targets −d_mid/(½Δt) set to 0 the impulses stay bounded (largest 1.5e-8 / 2.5e-8 N s, sum 3.6e-7 /
4.0e-7 N s ≈ the strand's weight impulse) and the violation falls to 3.0e-4 / 1.3e-5 m/s; without friction
but with the targets it still grows (1.3e-7 / 3.3e-7 N s). So the joint-gap closure demanded within one
step conflicts with the contacts once the strand rests; on the ringlet start (120 × 50, t = 5 ms) the
targets are not the problem (zeroing them leaves the convergence as slow: 0.40 / 0.10 / 2.3e-4 off its
own 10,000-sweep answer at 60 / 300 / 2,000 sweeps). A softer joint-gap target (a fraction of the gap per
step, or a compliant joint row) would make the resting problem feasible; not tried here.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _residuals(a, u):
    """(max bound violation m/s, max joint gap-rate residual m/s) of twists u for the captured arguments."""
    (body, partner, normal, lever, plever, target) = a[10:16]
    jk, jl, jrk, jrl, jt = a[27:32]
    n_rows = a[-1]

    def vel(b, r):
        return u[b, :3] + np.cross(u[b, 3:], r)

    rows = np.arange(n_rows)  # the rows from the start (promoted candidates are few)
    ju = (normal[rows] * vel(body[rows], lever[rows])).sum(1)
    pb = partner[rows] >= 0
    ju[pb] -= (normal[rows][pb] * vel(partner[rows][pb], plever[rows][pb])).sum(1)
    viol = float(np.maximum(target[rows] - ju, 0.0).max(initial=0.0))
    vk = np.where((jk >= 0)[:, None], vel(np.maximum(jk, 0), jrk), 0.0)
    jr = float(np.linalg.norm(jt + vel(jl, jrl) - vk, axis=1).max(initial=0.0))
    return viol, jr


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fibres", type=int, default=120)
    ap.add_argument("--segments", type=int, default=50)
    ap.add_argument("--settle", type=int, default=5)
    ap.add_argument("--friction", default="aniso")
    ap.add_argument("--sweeps", type=int, nargs="+", default=[60, 120, 300, 1000, 10000])
    args = ap.parse_args()
    from headsim.hair.drape import build_drape_scene
    from headsim.solvers import chains as C
    from headsim.solvers._kernels import chains_coupled as KC

    print(f"load average {os.getloadavg()}")
    scene = build_drape_scene("sphere-helical", args.friction, n_fibres=args.fibres, segments=args.segments)
    solver = C.ChainSolver(scene.options)
    state = scene.state
    for _ in range(args.settle):
        state = solver.step(scene.model, state, scene.dt, scene.obstacles)
    captured = []
    originals = (KC.coupled_iterate, KC.coupled_iterate_parallel)

    def capture(orig):
        def wrapped(*a):
            if not captured:
                captured.append([x.copy() if isinstance(x, np.ndarray) else x for x in a])
            return orig(*a)
        return wrapped

    KC.coupled_iterate, KC.coupled_iterate_parallel = (capture(f) for f in originals)
    try:
        solver.step(scene.model, state, scene.dt, scene.obstacles)
    finally:
        KC.coupled_iterate, KC.coupled_iterate_parallel = originals
    a0 = captured[0]
    u_minus, mass, R, inertia = a0[16], a0[17], a0[18], a0[19]
    Iw = np.einsum("sac,sc,sbc->sab", R, inertia, R)

    def m2(du):
        return float((mass * (du[:, :3] ** 2).sum(1)).sum() + np.einsum("sa,sab,sb->", du[:, 3:], Iw, du[:, 3:]))

    print(f"t = {state.time:.3f} s, {scene.model.n_segments} segments, {a0[-1]} rows from the start, "
          f"{len(a0[10]) - a0[-1]} candidates, {len(a0[27])} joints")
    results = {}
    for n in sorted(args.sweeps):
        a = [x.copy() if isinstance(x, np.ndarray) else x for x in a0]
        a[23], a[24] = int(n), 0.0  # max_iter, tol
        c = time.process_time()
        sw, change, _ = KC.coupled_iterate(*a)
        results[n] = (time.process_time() - c, a[16], sw, change, _residuals(a, a[16]), a[25].max(initial=0.0),
                      a[25].sum())
    ref = results[max(results)][1]
    for n, (cpu, u, sw, change, (viol, jr), lmax, lsum) in results.items():
        err = np.sqrt(m2(u - ref) / m2(ref - u_minus))
        print(f"{n:6d} sweeps ({sw}): CPU {cpu:.3f} s, last change {change:.2e} m/s, rel. M-error {err:.3e}, "
              f"max |dv| {np.abs(u - ref)[:, :3].max():.2e} m/s, max violation {viol:.2e} m/s, "
              f"max joint residual {jr:.2e} m/s, normal impulses max {lmax:.3e} / sum {lsum:.4e} N s")


if __name__ == "__main__":
    main()
