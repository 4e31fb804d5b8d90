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
       [--sweeps 60 120 300 1000 10000] [--geometry former|derived] [--set OPTION=VALUE ...]

Besides the fixed counts, the stopping rule (``ChainOptions.contact_tolerance``) is run with the shipped cap
(``qp_iterations``) and without one. ``--geometry`` defaults to ``former`` (the ringlet start all numbers
below were measured on); ``--set`` overrides ChainOptions (e.g. ``--set joint_gap_fraction=1.0``, the
former joint-gap targets).

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

Branch ``gs`` (issue 10; joint-gap targets now ``joint_gap_fraction`` γ, default 0: the contact solve keeps
every joint's anchors moving together, J u⁺ = 0, and leaves the position drift to the next step's joint
stage; the solve stops on ``contact_tolerance`` = 1e-5 m/s, cap 60 sweeps). Same session, 2 shared cores,
load 3–4 (CPU times unreliable, not quoted):

* Settling strand (``--fibres 40 --segments 30 --settle 1500 --sweeps 60 300 3000 10000 40000``, each run on
  its own trajectory, t = 1.5 s): γ = 1 (``--set joint_gap_fraction=1.0``) reproduces the growth (largest
  normal impulse 1.6e-8 / 3.3e-8 / 1.5e-7 / 3.9e-7 / 6.6e-7 N s, 60 sweeps 0.75 off its 40,000-sweep
  answer); γ = 0: bounded (largest 6.9e-9 … 1.6e-8 N s, sum 3.2e-7 … 3.6e-7 N s ≈ the strand's weight
  impulse per step) and convergent (last change 1.8e-9 m/s at 40,000 sweeps, violation 3e-10 m/s);
  60 / 300 / 3,000 / 10,000 sweeps are 0.073 / 0.055 / 0.022 / 0.0021 off. (With the stopping rule on
  the trajectory: 60 sweeps 0.12 off; the rule at 1e-4 m/s needs 7,219 sweeps there and is then still
  1.6e-2 off with a largest velocity error of 1.45e-3 m/s = 14 × the residual: slow convergence.)
* Ringlet start (defaults, t = 5 ms, 32.8 k rows), γ = 1 → γ = 0 at the shipped 60 sweeps: rel. M-error
  0.310 → 0.466, but the error itself is smaller: ½‖u − u_ref‖²_M 2.30e-9 → 1.94e-9 J, max |Δv| 2.48e-2 →
  2.45e-2 m/s, max violation 1.37e-2 → 1.36e-2 m/s, max joint residual 7.9e-3 → 6.9e-3 m/s (the relative
  error is larger because the correction it is divided by is smaller: γ = 0 demands no gap-closing
  velocities). 100 sweeps: 2.39e-1 → 3.55e-1 rel., 1.37e-9 → 1.12e-9 J. The stopping rule without a cap
  stops after 2,892 (γ = 1) / 3,249 (γ = 0) sweeps at a residual of 1e-5 m/s, 2.3e-4 / 1.2e-4 off (max
  |Δv| 3.8e-5 / 1.7e-5 m/s); with the cap of 60 both runs end at the cap (counted in
  ``StepStats.qp_capped``), i.e. on this scene the answer is the 60-sweep one, at least as accurate as
  before in absolute terms, not faster.

The joint-eliminated (Schur-complement) Gauss–Seidel of the prototype above was not landed: at the
shipped accuracy it was not faster (≈ 0.15 s CPU for the 0.31 error either way), only at tighter ones.

Nesterov extrapolation of the contact impulses (``ChainOptions.contact_acceleration = "nesterov"``, the
default since; every count is now run both ways, the reference is the largest count of the accelerated
iteration). Issue 10, serial kernel, machine otherwise idle:

* Reference scene ``--fibres 355 --segments 100 --settle 3 --sweeps 20 30 60 120 3000`` (first solve of the
  fourth step, 189 k rows from the start, 1.64 M candidates, 35.5 k joints), relative M-error against 3,000
  accelerated sweeps / CPU s: plain 20 / 30 / 60 / 120 / 3,000 sweeps 0.471 / 0.427 / 0.344 / 0.255 / 0.016
  (0.51 / 0.64 / 0.98 / 1.65 / 33.7 s); accelerated 0.320 (28 sweeps: candidates became rows) / 0.308 /
  0.138 / 0.036 (0.74 / 0.79 / 1.81 / 3.38 s). Largest bound violation at 30 sweeps 2.4e-2 → 1.9e-2 m/s, at
  60 2.0e-2 → 8.2e-3 m/s. So 30 accelerated sweeps are nearer the answer than the former default of 60
  plain ones (0.308 against 0.344) in 0.79 against 0.98 s: the new default cap is 30. An accelerated
  sweep costs more than a plain one (more rows stay listed for the partial sweeps, the extrapolation
  pass): 26 ms against 21 ms at 30 sweeps, 30 against 16 ms at 60.
* 120 × 50 ringlet, the defaults (``--sweeps 20 40 60 120 300 1000 5000``, first solve at t = 5 ms; the
  reference is 5,000 accelerated sweeps, whose last sweep changed 6.5e-14 m/s; 5,000 plain sweeps are
  6.9e-5 off it with a last change of 1.7e-5 m/s): plain 20 / 40 / 60 / 120 / 300 / 1,000 sweeps 0.614 /
  0.523 / 0.452 / 0.305 / 0.116 / 6.6e-3; accelerated 0.447 / 0.138 / 0.052 / 9.7e-3 / 8.6e-4 / 1.9e-5
  (CPU within 20 % of the plain sweeps at equal counts); largest violation at 60 sweeps 1.3e-2 → 3.1e-4 m/s.
  The stopping rule without a cap now stops after 656 sweeps (1e-5 m/s, 8.6e-5 off; the plain iteration
  needed 2,892–3,249 on this scene before, see above); at the default cap of 30 the answer is 0.267 off.

Issue 10, twenty-first session. The captured calls are read by argument name (``iterate_args``): the root sweeps'
two arguments, appended in the twentieth session, had shifted the tail this script addressed by position
(``a[-4]`` was the momentum), so it had stopped running. A small ringlet (``--fibres 30 --segments 30 --settle
20``, t = 20 ms, 1,091 rows, 1,718 candidates) shows what "growing impulses" look like there: the normal
impulses sum to 2.8e-7 N s after 30 accelerated sweeps, 6.4e-6 after 300, 2.3e-5 after 3,000 and 2.5e-5 after
20,000 (largest violation 2.1e-3 → 1.9e-5 m/s), and every one of the largest impulses sits on a root segment
(segment 0) pressed between two neighbouring root segments from opposite sides (normals at cos −1.00): the
anchored roots give way so little that holding them apart takes impulses ≈ 100 × those of the capped solve,
and the 30-sweep answer is 0.92 off the 20,000-sweep one (20,000 plain sweeps: 0.56). On the derived geometry
(120 × 100, t ≈ 0.25 s, the step's second solve: 24 k rows, 116 k candidates) the impulse sum is 3.07e-6 N s
after 30 sweeps and 3.12e-6 after 300 and 3,000, the largest impulses mid-fibre: no such pinch there.
Two accelerations of the Gauss–Seidel were measured on captured solves of that step (scripts not kept). Anderson
acceleration (type II, memory 5–10, every 1–3 plain sweeps) of the impulses, on the step's second solve against
a 4,000-sweep answer: after 60 sweeps a largest bound violation of 5.5–7.0 mm/s (plain 13.3, the shipped
Nesterov 1.1), after 120 sweeps 3.2–3.5 (plain 6.9, Nesterov 0.52). MPRGP (Dostál's proportioning / CG for the
dual QP on the joint-eliminated Delassus operator, every product one exact chain solve, rows scaled by their free
W₀₀), on the step's first solve made frictionless: the largest violation went from 40.6 mm/s (the warm start) to
33–38 mm/s in 180 products, then a zero division (a degenerate proportioning step). Neither is kept: the Nesterov-accelerated Gauss–Seidel stays the best measured.

Issue 10, twenty-ninth session: the same questions on the full-size reference scene at rest (``--state
benchmarks/data/drape_355x100_aniso_t1.0.npz``, the velocity solve of the fourth step's last pass, 75.6 k rows,
35.5 k joints; made frictionless and without its candidates; scripts not kept). Reference: MPRGP run to 9,704
products of the joint-eliminated operator A = J P₀ M⁻¹ Jᵀ (P₀ the exact chain solve; 12.6 k rows active, smallest
w = A λ + q −3.7e-4 m/s, largest |λ w| 6.8e-11). Error of the twists against it, largest / median point-velocity
difference |Δv| + |Δω| ρ (m/s), all warm-started from the step's impulses:

* the shipped kernel (Nesterov, root sweeps): 10 / 30 / 60 / 100 sweeps 0.109 / 0.056 / 0.037 / 0.023 and
  2.0e-3 / 1.0e-3 / 5.1e-4 / 2.7e-4 (≈ 1/k); 1,000 sweeps 4.5e-3 / 1.7e-5;
* MPRGP with the rows scaled by their free W₀₀ (scaled ‖A‖ ≈ 2.5): 30 / 100 / 300 iterations (60 / 200 / 600
  products) 0.093 / 0.069 / 0.053 and 2.0e-3 / 1.4e-3 / 9.5e-4, i.e. 300 iterations match 30 sweeps;
* the same with the exact joint-eliminated diagonal D = diag A (by probing: 533 colourings of the rows so that
  no two rows of a probe share a fibre; D / W₀₀ is 0.052 in the median, 4e-4 at least): scaled ‖A‖ ≈ 32, and
  30 / 100 / 300 iterations 0.074 / 0.061 / 0.046 and 1.9e-3 / 1.3e-3 / 8.8e-4: no better. A diagonal cannot fix
  the conditioning: the slow modes are collective (a fibre's rows coupled through its chain, the bundle's rows
  through each other). Nor is the error a bundle-wide mode that a coarse space of few aggregates could take
  out: of the translational kinetic energy of the 30-sweep error (M-weighted), per-fibre blocks of 100 / 25 /
  10 / 5 segments hold 15 / 31 / 53 / 78 % (their mean velocities), cubic cells across fibres of 20 / 10 / 5 /
  2.5 mm only 5 / 8 / 13 / 20 % (the same after 100 sweeps): it varies from fibre to fibre along 1.5–3 mm of
  each, so a coarse correction would need thousands of per-fibre aggregates (not tried);
* the rows' order: the kernel's rows visited bottom-up (by the contact point's height above the sphere),
  top-down or at random instead of in index order give the same errors to within 8 % at 10 / 30 / 60 sweeps
  (the sweeps alternate their direction, and the error is not a stack's one-layer-per-sweep propagation).

Thirtieth session, the same captured solve and reference: over-relaxation of the contact rows' normal update
(projected SOR, λ ← max(0, λ + ω (target − J u)/W₀₀) in the full and the root sweeps; the chains solved exactly as
before), largest / median error after 10 / 30 / 60 sweeps:

* with the Nesterov extrapolation: ω = 1 0.109 / 0.056 / 0.037 and 2.0e-3 / 1.0e-3 / 5.2e-4; ω = 1.4 0.111 / 0.057 /
  0.038 and 1.9e-3 / 8.9e-4 / 4.4e-4; ω = 1.7 0.114 / 0.057 / 0.055 and 1.9e-3 / 1.2e-3 / 8.7e-4; ω = 1.9 worse;
* plain Gauss–Seidel: ω = 1 0.130 / 0.086 / 0.070 and 2.4e-3 / 1.8e-3 / 1.4e-3; ω = 1.4 0.130 / 0.084 / 0.066 and
  2.3e-3 / 1.6e-3 / 1.3e-3; ω = 1.7 and 1.9 the same to ±5 %.

At most 15 % on the median error and nothing on the largest: a contact visit under-corrects by W₀₀ / D (≈ 20 in
the median) because the chain solve after it takes most of its push away, and scaling the push does not change
that split. Not kept (scripts not kept).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def iterate_args():
    """Position of every argument of ``coupled_iterate`` by name: the captured calls are positional lists, and
    reading them by name keeps this benchmark right when the kernel gains arguments (the twentieth session's
    ``root_sweeps``, ``root_segments`` shifted the tail that ``a[-4]`` used to address)."""
    import inspect

    from headsim.solvers._kernels import chains_coupled as KC

    return {name: i for i, name in enumerate(inspect.signature(KC.coupled_iterate.py_func).parameters)}


def capture_first_solve(fibres, segments, settle, friction, geometry, overrides=None, start=None):
    """The ``sphere-helical`` drape (``geometry`` 'former' or 'derived') advanced ``settle`` steps from its start or
    from the state saved in ``start`` (a path, see ``drape_states.py``), and the argument list of the next step's
    first ``coupled_iterate`` call (copies). Returns (scene, state before that step, args)."""
    from headsim.hair.drape import HelicalSphereGeometry, build_drape_scene
    from headsim.solvers import chains as C
    from headsim.solvers._kernels import chains_coupled as KC

    scene = build_drape_scene("sphere-helical", friction, n_fibres=fibres, segments=segments,
                              geometry=HelicalSphereGeometry.former() if geometry == "former" else None,
                              **(overrides or {}))
    solver = C.ChainSolver(scene.options)
    if start:
        from drape_states import load_state

        state = load_state(start, scene.model)
    else:
        state = scene.state
    for _ in range(settle):
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
    return scene, state, captured[0]


def _residuals(a, u):
    """(max bound violation m/s, max joint gap-rate residual m/s) of twists u for the captured arguments."""
    ix = iterate_args()
    body, partner, normal, lever, plever, target = (a[ix[k]] for k in ("body", "partner", "normal", "lever",
                                                                         "partner_lever", "target"))
    jk, jl, jrk, jrl, jt = (a[ix[k]] for k in ("joint_k", "joint_l", "joint_rk", "joint_rl", "joint_target"))
    n_rows = a[ix["n_listed_rows"]]

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
    ap.add_argument("--geometry", choices=("derived", "former"), default="former",
                    help="sphere-helical geometry (default: the former ringlet start the table below was measured on)")
    ap.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                    help="ChainOptions override (Python literal), e.g. --set joint_gap_fraction=1.0")
    ap.add_argument("--state", metavar="FILE.npz",
                    help="start from a saved state (drape_states.py, e.g. the one bench_drape.py --save-state "
                         "writes); --geometry then only sets up the scene")
    args = ap.parse_args()
    import ast

    from headsim.solvers._kernels import chains_coupled as KC

    print(f"load average {os.getloadavg()}")
    overrides = {k: ast.literal_eval(v) for k, v in (kv.split("=", 1) for kv in args.set)}
    print(f"geometry {args.geometry}, option overrides {overrides}")
    scene, state, a0 = capture_first_solve(args.fibres, args.segments, args.settle, args.friction, args.geometry,
                                           overrides, start=args.state)
    ix = iterate_args()
    U, LAM = ix["u"], ix["lam_out"]
    u_minus, mass, R, inertia = (a0[ix[k]] for k in ("u", "mass", "R", "inertia"))
    Iw = np.einsum("sac,sc,sbc->sab", R, inertia, R)

    def m2(du):
        return float((mass * (du[:, :3] ** 2).sum(1)).sum() + np.einsum("sa,sab,sb->", du[:, 3:], Iw, du[:, 3:]))

    print(f"t = {state.time:.3f} s, {scene.model.n_segments} segments, {a0[ix['n_listed_rows']]} rows from the start, "
          f"{len(a0[ix['body']]) - a0[ix['n_listed_rows']]} candidates, {len(a0[ix['joint_k']])} joints")
    results = {}
    # every count with the plain Gauss–Seidel (momentum 0) and the Nesterov extrapolation (momentum 1,
    # ChainOptions.contact_acceleration); the reference is the largest count of the accelerated iteration
    for mom in (1.0, 0.0):
        for n in sorted(args.sweeps, reverse=True):
            a = [x.copy() if isinstance(x, np.ndarray) else x for x in a0]
            a[ix["max_iter"]], a[ix["tol"]], a[ix["momentum"]] = int(n), 0.0, mom
            c = time.process_time()
            sw, change, _ = KC.coupled_iterate(*a)
            results[f"{n} {'nesterov' if mom else 'plain'}"] = (
                time.process_time() - c, a[U], sw, change, _residuals(a, a[U]), a[LAM].max(initial=0.0), a[LAM].sum())
    ref = results[f"{max(args.sweeps)} nesterov"][1]
    # the stopping rule (ChainOptions.contact_tolerance) with the cap of the shipped options and without a cap
    tol = float(scene.options.contact_tolerance)
    for label, cap in ((f"tol {tol:g}, cap {scene.options.qp_iterations}", scene.options.qp_iterations),
                       (f"tol {tol:g}, no cap", max(args.sweeps))):
        a = [x.copy() if isinstance(x, np.ndarray) else x for x in a0]
        a[ix["max_iter"]], a[ix["tol"]] = int(cap), tol
        c = time.process_time()
        sw, change, _ = KC.coupled_iterate(*a)
        results[label] = (time.process_time() - c, a[U], sw, change, _residuals(a, a[U]), a[LAM].max(initial=0.0),
                          a[LAM].sum())
    for n, (cpu, u, sw, change, (viol, jr), lmax, lsum) in results.items():
        err = np.sqrt(m2(u - ref) / m2(ref - u_minus))
        eabs = 0.5 * m2(u - ref)
        print(f"{n:>16} ({sw} sweeps): CPU {cpu:.3f} s, last change {change:.2e} m/s, rel. M-error {err:.3e} "
              f"(½‖u − u_ref‖²_M {eabs:.2e} J), "
              f"max |dv| {np.abs(u - ref)[:, :3].max():.2e} m/s, max violation {viol:.2e} m/s, "
              f"max joint residual {jr:.2e} m/s, normal impulses max {lmax:.3e} / sum {lsum:.4e} N s")


if __name__ == "__main__":
    main()
