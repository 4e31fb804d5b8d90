"""Benchmark: time per step of the drape reference scene (Sobottka 2008 §8.6.2: 355 helical fibres ×
100 segments on a sphere, Δt = 1 ms) — batched Numba kernels vs a one-fibre-at-a-time loop of the same
algorithm in the same run. Goal ≤ 0.2 s per step on 2 cores (seed: 30–180 s per step, serial).

Usage: python benchmarks/bench_drape.py [--fibres 355] [--segments 100] [--steps 60] [--loop-steps 3]
       [--friction aniso]

The scene is first advanced ``--settle`` steps (so the strand is in contact with itself and the
sphere), then ``--steps`` steps are timed with the batched solver; the loop baseline (``fibre_loop=True``:
Python calls the joint kernel per fibre and the contact kernel per body) is timed on ``--loop-steps``
steps from the same state (same algorithm, per-body contact mode, since the coupled mode is one
Gauss–Seidel over all contacts and has no per-fibre form). Both CPU (process_time) and wall times are
printed, with the load average.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _time(solver, scene, state, steps):
    if steps <= 0:
        return state, 0.0, 0.0, {}, {}
    w0, c0 = time.perf_counter(), time.process_time()
    phases = {}
    counts = {}
    for _ in range(steps):
        state = solver.step(scene.model, state, scene.dt, scene.obstacles)
        st = solver.last_stats
        for k, v in st.seconds.items():
            phases[k] = phases.get(k, 0.0) + v
        for k in ("contacts", "contact_rows", "candidate_rows", "promoted_rows"):
            counts.setdefault(k, []).append(getattr(st, k))
        counts.setdefault("max_penetration", []).append(st.max_penetration)
        counts.setdefault("kinetic_energy", []).append(st.kinetic_energy)
    counts = {k: float(np.mean(v)) for k, v in counts.items()}
    return state, (time.perf_counter() - w0) / steps, (time.process_time() - c0) / steps, phases, counts


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fibres", type=int, default=355)
    ap.add_argument("--segments", type=int, default=100)
    ap.add_argument("--settle", type=int, default=30)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--loop-steps", type=int, default=1)
    ap.add_argument("--friction", default="aniso")
    args = ap.parse_args()
    import numba

    from headsim.hair.drape import build_drape_scene
    from headsim.solvers.chains import ChainSolver

    print(f"load average {os.getloadavg()}, numba threads {numba.get_num_threads()}")
    timed = {}
    for coupling in ("coupled", "per-body"):
        scene = build_drape_scene("sphere-helical", args.friction, n_fibres=args.fibres, segments=args.segments,
                                  contact_coupling=coupling)
        solver = ChainSolver(scene.options)
        state = scene.state
        t0 = time.perf_counter()
        state, _, _, _, _ = _time(solver, scene, state, 2)  # compile / warm up
        print(f"[{coupling}] warm-up (incl. compile) {time.perf_counter() - t0:.1f} s")
        state, _, _, _, _ = _time(solver, scene, state, args.settle)
        state_b, wall, cpu, phases, nc = _time(solver, scene, state, args.steps)
        timed[coupling] = (wall, cpu)
        # the row counters are kept by the coupled stage only (the per-body mode has no candidate rows)
        rows = (f", rows {nc['contact_rows']:.0f} (candidates {nc['candidate_rows']:.0f}, added in the solves "
                f"{nc['promoted_rows']:.0f})") if coupling == "coupled" else ""
        print(f"[{coupling}] {scene.model.n_segments} segments, t = {state.time:.3f} s, mean active contacts "
              f"{nc['contacts']:.0f}{rows}, max penetration {nc['max_penetration']:.3e} m, "
              f"kinetic energy {nc['kinetic_energy']:.4e} J")
        print(f"[{coupling}] batched: {wall:.4f} s/step wall, {cpu:.4f} s/step CPU; phases (s/step): "
              + ", ".join(f"{k} {v / args.steps:.4f}" for k, v in phases.items()))
        if coupling == "per-body":
            loop = ChainSolver(scene.options, fibre_loop=True)
            loop._bvh = None
            _, lw, lc, lph, _ = _time(loop, scene, state, args.loop_steps)
            print(f"[{coupling}] one fibre at a time: {lw:.4f} s/step wall, {lc:.4f} s/step CPU; phases (s/step): "
                  + ", ".join(f"{k} {v / args.loop_steps:.4f}" for k, v in lph.items()))
            print(f"[{coupling}] speed-up batched vs loop: {lw / wall:.1f}x wall, {lc / cpu:.1f}x CPU")
            cw, cc = timed["coupled"]
            print(f"[coupled] time per step / per-body loop's: {cw / lw:.2f} wall, {cc / lc:.2f} CPU "
                  "(coupled timed on its own trajectory)")
        print(f"[{coupling}] goal <= 0.2 s/step: {'met' if wall <= 0.2 else 'NOT met'} (wall)")


if __name__ == "__main__":
    main()
