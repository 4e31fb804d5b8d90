"""Benchmark: the coupled contact solve with its contact rows swept in parallel body domains
(``ChainOptions.contact_domains``) against the former single sequence (``contact_domains=1``), on the same
captured solves of the drape reference scene, in one process (Sobottka 2008 §8.6.2; issue 10).

The scene is advanced ``--settle`` steps; the coupled solves of the next step (velocity solve of each
harmonisation pass and the split push-out solve: 3 per step) are captured with their set-up and rerun
here, alternating baseline and domains ``--repeats`` times, with the parallel (``prange``) kernel the solver
uses on this scene and, with ``--serial``, the serial one. Printed per solve and variant: wall and CPU time,
the sweeps, the last sweep's change (m/s), the largest violation of a contact row's bound and joint gap-rate
residual (m/s), and the ratio of the wall time to the baseline's; with ``--ref-sweeps N`` also the distance
of each result to an N-sweep single-sequence answer (relative kinetic-metric error ‖u − u_ref‖_M /
‖u_ref − u⁻‖_M), to show that the domain order is not a worse iterate.

Usage: python benchmarks/bench_contact_domains.py [--fibres 355] [--segments 100] [--settle 3]
       [--domains 2] [--repeats 3] [--serial] [--ref-sweeps 0] [--geometry former|derived]

The machine has 2 cores; a second job on it leaves one core to the two threads and hides the gain (the
load average is printed: compare only runs at load ≤ ≈ 1 besides this one).

Measured (issue 10, branch ``gsfast``; the same captured solves of the reference scene, 355 × 100, ringlet
start, t = 4 ms: 197 k rows from the start, 1.6 M candidates, 35.5 k joints; the 2-domain split puts 93.9 k /
94.4 k rows in the domains and 4.5 % across; parallel kernel, 3 alternating repeats, load 1.3 with this job
alone): velocity solve 1 domain 0.485–0.528 s, 2 domains 0.415–0.435 s (× 0.85); push-out solve 0.561–0.579
s against 0.465–0.519 s (× 0.86). Same distance to a 6,000-sweep single-sequence answer (relative M-error
0.4412 → 0.4417 and 0.5066 → 0.5087), largest bound violation 1.67e-2 → 2.25e-2 m/s and 2.59e-2 → 2.71e-2
m/s (the iterate at the 60-sweep cap is ≈ 45 % off the converged answer either way). With a second job on
the machine (load 2–3.5) the ratio was 0.98 (no gain; all timings 5–10 × the unloaded ones because the
threads' barriers wait for a descheduled thread). The serial kernel with 2 domains is ≈ 10 % slower than
with one (the domain rows are gathered through an order array). Why the gain is small: per sweep the
contact rows are ≈ 55 % of the serial time (≈ 3 ms of inactive-row checks over 197 k rows, memory bound, and
≈ 3 ms for the ≈ 10 k active rows), the chains' block-Thomas solves ≈ 40 % (already parallel); two threads
on a memory-bound loop share the memory bandwidth.

Whole steps (``bench_drape.py --fibres 355 --segments 100 --settle 3 --steps 3 --coupled-only --geometry
former``, alternating runs, machine otherwise idle, load 0.8–1.5 from these runs): default (1 domain)
4.14 / 3.95 s per step, contacts 2.80 / 2.74 s; ``--set contact_domains=2`` 3.73 / 3.78 s, contacts 2.34 /
2.48 s (× 0.86 on the contact phase). Stats 1 → 2 domains: 6,604 → 6,587 active contacts, max penetration
6.703e-05 → 6.711e-05 m, kinetic energy 5.7091e-05 → 5.7092e-05 J, max joint gap 5.11 → 4.77 µm.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _convergence_helpers():
    """(``_residuals``, ``iterate_args``) of ``bench_contact_convergence.py``: the same measure of a captured
    solve, and its arguments read by name, so that the two benchmarks report one metric."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_contact_convergence import _residuals, iterate_args

    return _residuals, iterate_args


def _kinetic_metric(mass, R, inertia):
    """Squared kinetic-metric norm ‖du‖²_M of twist differences (S, 6), M at the rotations R."""
    Iw = np.einsum("sac,sc,sbc->sab", R, inertia, R)

    def m2(du):
        return float((mass * (du[:, :3] ** 2).sum(1)).sum() + np.einsum("sa,sab,sb->", du[:, 3:], Iw, du[:, 3:]))

    return m2


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fibres", type=int, default=355)
    ap.add_argument("--segments", type=int, default=100)
    ap.add_argument("--settle", type=int, default=3)
    ap.add_argument("--friction", default="aniso")
    ap.add_argument("--domains", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--serial", action="store_true", help="also time the serial kernel")
    ap.add_argument("--ref-sweeps", type=int, default=0, help="reference answer with this many sweeps (0: none)")
    ap.add_argument("--geometry", choices=("derived", "former"), default="former")
    args = ap.parse_args()

    import numba

    from headsim.hair.drape import HelicalSphereGeometry, build_drape_scene
    from headsim.solvers import chains as C
    from headsim.solvers._kernels import chains_coupled as KC

    print(f"load average {os.getloadavg()}, numba threads {numba.get_num_threads()}")
    geometry = HelicalSphereGeometry.former() if args.geometry == "former" else None
    scene = build_drape_scene("sphere-helical", args.friction, n_fibres=args.fibres, segments=args.segments,
                              geometry=geometry, contact_domains=args.domains)
    solver = C.ChainSolver(scene.options)
    state = scene.state
    for _ in range(args.settle):
        state = solver.step(scene.model, state, scene.dt, scene.obstacles)
    captured = []  # (setup outputs, iterate arguments without the set-up)
    originals = (KC.coupled_iterate, KC.coupled_iterate_parallel)

    def capture(orig):
        def wrapped(*a):
            captured.append([x.copy() if isinstance(x, np.ndarray) else x for x in a])
            return orig(*a)
        return wrapped

    KC.coupled_iterate, KC.coupled_iterate_parallel = (capture(f) for f in originals)
    try:
        state = solver.step(scene.model, state, scene.dt, scene.obstacles)
    finally:
        KC.coupled_iterate, KC.coupled_iterate_parallel = originals
    st = solver.last_stats
    print(f"t = {state.time:.3f} s, {scene.model.n_segments} segments, {len(captured)} solves captured; step "
          f"phases (s): " + ", ".join(f"{k} {v:.3f}" for k, v in st.seconds.items()))
    kernels = [("parallel", KC.coupled_iterate_parallel)]
    if args.serial:
        kernels.append(("serial", KC.coupled_iterate))
    totals = {}
    residuals, iterate_args = _convergence_helpers()
    ix = iterate_args()
    U = ix["u"]
    for i, a0 in enumerate(captured):
        body_part = a0[ix["body_part"]]
        n_rows = a0[ix["n_listed_rows"]]
        body, partner = a0[ix["body"]][:n_rows], a0[ix["partner"]][:n_rows]
        pa = body_part[body]
        pb = np.where(partner >= 0, body_part[np.maximum(partner, 0)], pa)
        print(f"solve {i}: {n_rows} rows from the start, {len(a0[ix['body']]) - n_rows} candidates, "
              f"{len(a0[ix['joint_k']])} joints, push-out {a0[ix['joints_last']]}; domains "
              f"{np.bincount(pa[pa == pb])} rows, cross {np.mean(pa != pb):.3f}")

        def run(kern, part, **changes):
            """The captured call with these arguments replaced (and the body domains ``part``): (arguments after
            the call, wall s, CPU s, kernel result)."""
            a = [x.copy() if isinstance(x, np.ndarray) else x for x in a0]
            a[ix["body_part"]] = part
            for k, v in changes.items():
                a[ix[k]] = v
            w0, c0 = time.perf_counter(), time.process_time()
            out = kern(*a)
            return a, time.perf_counter() - w0, time.process_time() - c0, out

        ref = m2 = None
        if args.ref_sweeps > 0:
            ref = run(KC.coupled_iterate_parallel, np.zeros(0, np.int64), max_iter=args.ref_sweeps, tol=0.0)[0][U]
            m2 = _kinetic_metric(*(a0[ix[k]] for k in ("mass", "R", "inertia")))
        for kname, kern in kernels:
            variants = (("1 domain (former)", np.zeros(0, np.int64)), (f"{int(body_part.max()) + 1} domains", body_part))
            for rep in range(args.repeats):
                base = None
                for vname, part in variants:
                    a, w, c, (sw, change, prom) = run(kern, part)
                    base = w if base is None else base
                    key = (kname, vname)
                    totals.setdefault(key, []).append(w)
                    viol, jr = residuals(a, a[U])
                    err = ""
                    if ref is not None:
                        err = f", rel. M-error vs {args.ref_sweeps} sweeps {np.sqrt(m2(a[U] - ref) / m2(ref - a0[U])):.4f}"
                    print(f"  {kname:8s} {vname:18s} rep {rep}: wall {w:.3f} s (× {w / base:.2f}), CPU {c:.3f} s, "
                          f"{sw} sweeps, change {change:.2e} m/s, violation {viol:.2e}, joint residual {jr:.2e}"
                          f"{err}", flush=True)
    print(f"load average {os.getloadavg()}")
    for (kname, vname), ws in totals.items():
        print(f"total {kname:8s} {vname:18s}: median wall per step {np.median(ws) * len(captured):.3f} s")
    keys = list(totals)
    for kname, _ in kernels:
        b, d = (np.median(totals[k]) for k in keys if k[0] == kname)
        print(f"ratio {kname}: domains / former = {d / b:.2f}")


if __name__ == "__main__":
    main()
