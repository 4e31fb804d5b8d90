"""Benchmark: the exact final solve of small chain systems (``ChainOptions.exact_final_solve``, issue 10) against
the Gauss–Seidel answer alone, in the same process.

Usage: python benchmarks/bench_exact_solve.py [--steps 300] [--stack-sweeps 30 150]

Scenes (those of ``tests/solvers/test_chains.py``):

* the resting 4-layer stack (:func:`headsim.solvers.chain_scenes.crossed_layer_stack`): four crossed layers of
  three 70 µm × 3 mm fibres, chains of 5 segments (60 bodies), on the plane y = 0, Δt = 1 ms, ε = 0; every
  crossing sticks, so a crossing's rows next to a joint are redundant with the joint rows. A fibre's elastic sag
  between supports 1 mm apart is 5qL⁴/(384 EI) = 1.4e-10 m: a layer sinking further is numerical creep;
* the clamped bent fibre (``bench_energy_ledger.py``'s scene: 20 × 1 mm, held bent onto a plane by its own
  rest curvature).

Printed per scene and mode: time per step, the exact solves used and the reasons of the failures, the layers'
largest sink (stack) or the resting depth and the energy rises (clamped fibre), and the time ratio.

Measured (twenty-second session, machine otherwise idle, 300 steps, two runs; "GS only" =
``exact_final_solve=False``, i.e. the Gauss–Seidel under the sweep budget):

* stack, defaults: GS only 14.2–14.3 ms per step, largest layer sink 2.1e-9 m (15 × the elastic sag); exact
  23.0–23.6 ms per step (× 1.6), 300 exact solves, no failure, sink 2.8e-11 m;
* stack, ``qp_iterations`` = 150: GS only 13.7–14.1 ms, sink 2.1e-9 m; exact 25.1–25.8 ms (× 1.8), 300 / 0,
  sink 2.5e-11 m;
* clamped fibre, defaults: GS only 2.5–3.3 ms per step, the energy rises in 285 of the 300 steps (largest
  6.4e-16 J, 5.6e-7 of the start energy); exact 7.0–7.8 ms
  (× 2.4–2.8), 1 failed first try ('active set', recovered by the budgeted retry), resting depth 1.5 nm,
  rises in 43 steps, largest 3.4e-23 J (round-off).

Before the least-norm Schur solve (commit 4d0bc6a's tree, the same scenes) the exact solve failed in every
step of the stack (defaults: 297 × 'inconsistent', 3 × 'active set') and cost 33–34 ms per step there, the
layers sinking as with the Gauss–Seidel alone.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

R_FIBRE = 35e-6
DT = 1e-3


def run_stack(steps, **options):
    from headsim.collide import PlaneField
    from headsim.solvers import chains_exact
    from headsim.solvers.chains import ChainOptions, ChainSolver, Obstacle

    from headsim.solvers.chain_scenes import crossed_layer_stack

    model, state = crossed_layer_stack(segments=5, radius=R_FIBRE)
    solver = ChainSolver(ChainOptions(**options))
    plane = [Obstacle(PlaneField((0.0, 0.0, 0.0), (0.0, 1.0, 0.0)))]
    y0 = state.position[:, 1].copy()
    chains_exact.EXACT_FAILURES.clear()
    used = 0
    t0 = time.perf_counter()
    for _ in range(steps):
        state = solver.step(model, state, DT, plane)
        used += solver.last_stats.exact_solves
    wall = (time.perf_counter() - t0) / steps
    sink = (y0 - state.position[:, 1]).reshape(4, -1).mean(1).max()
    return wall, used, dict(chains_exact.EXACT_FAILURES), f"largest layer sink {sink:.2e} m"


def run_clamped(steps, **options):
    from bench_energy_ledger import run

    from headsim.solvers import chains_exact

    chains_exact.EXACT_FAILURES.clear()
    t0 = time.perf_counter()
    e, pen = run(steps, **options)
    wall = (time.perf_counter() - t0) / steps
    d = np.diff(e)
    return (wall, None, dict(chains_exact.EXACT_FAILURES),
            f"resting depth {pen[-1]:.2e} m, energy rises in {int((d > 0).sum())} steps (largest {d.max():.2e} J)")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--stack-sweeps", type=int, nargs="+", default=[30, 150])
    a = ap.parse_args()
    if a.steps < 1:
        ap.error(f"--steps must be positive, got {a.steps}")
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    run_stack(2)  # compile / warm up
    scenes = [(f"stack, qp_iterations {n}", run_stack, dict(qp_iterations=n)) for n in a.stack_sweeps]
    scenes.append(("clamped fibre, defaults", run_clamped, {}))
    print(f"load average {os.getloadavg()}")
    for name, fn, opt in scenes:
        times = {}
        for mode, exact in (("GS only", False), ("exact", True)):
            wall, used, failures, summary = fn(a.steps, exact_final_solve=exact, **opt)
            times[mode] = wall
            solves = "" if used is None else f", exact solves used {used}"
            print(f"{name:30s} {mode:8s} {1e3 * wall:7.2f} ms/step{solves}, failures {failures or 'none'}; "
                  f"{summary}")
        print(f"{name:30s} time exact / GS only: {times['exact'] / times['GS only']:.2f}")


if __name__ == "__main__":
    main()
