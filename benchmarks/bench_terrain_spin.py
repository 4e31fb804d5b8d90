"""Diagnostic: the local spin-up of the terrain drape (Sobottka 2008 §8.6.3, 355 fibres × 100 segments, Δt = 1 ms), an
open problem of issue 10. Steps the scene from a saved state and prints, per step, the fastest-spinning segment, the
largest joint gap, the total energy and the solver steps taken (``ChainOptions.step_halvings``).

Usage: python benchmarks/bench_terrain_spin.py [--state FILE.npz] [--steps 30] [--friction aniso]
       [--fibres FIRST:STOP] [--set OPTION=VALUE ...]

``--fibres 300:330`` steps those fibres of the state alone (``headsim.solvers.chains.select_fibres``: the others
and their contacts are dropped), a quick look at the neighbourhood of fibre 316; fibre numbers in the output are
the full scene's.

Measured (issue 10, thirty-second session, from the scene's start with the session's defaults, ≈ 6 s per step on a
loaded machine): no step's total energy rose (the landing dissipates far more than the spin gains), yet the segments
spun up locally, ω 443 → 596 → 765 → 929 → 1,162 → 1,533 rad/s over t = 0.070–0.075 s and 3,515 rad/s at 0.076 s
(the first halved step), 2,950 rad/s at 0.098 s, with joint gaps up to 0.40 mm. The 7 × 100 strand of the same scene
ran away with rising energy (``tests/solvers/test_chains_stabilisation.py``), which the step halving stops; this one
is not caught by a global energy check. The default state, ``data/drape_terrain_355x100_aniso_t0.069.npz`` (t = 69
ms, written with ``drape_states.save_state`` after 69 steps from the start, 6.2 min), is the state just before that
spin-up. A run from a saved state starts without the continuous run's warm starts and allowances, yet this script's
first 12 steps from it (the defaults, same session) repeat it: ω 443, 596, 767, 933, 1,158, 1,536 and 3,375 rad/s at
t = 0.070–0.076 s, all on fibre 316's segments 52–55 (mid-fibre), joint gaps 11.6 → 148.8 µm, the total energy
falling in every step; the step at 0.076 s took 3 solver steps, the next 5; then ω 700–1,200 rad/s to 0.081 s; 6–23
s per step (the landing).

With ``ChainOptions.max_rotation_per_step`` (0.5 rad, the default since the thirty-third session: a step after which
a segment turns more than 0.5 rad per step is halved) the same 14 steps from the state: ω 443, 465, 410, 578, 536,
494, 436, 467, 495, 465, 491, 519, 578, 621 rad/s (t = 0.070–0.083 s), joint gaps ≤ 23.9 µm, 1–2 solver steps per
step, 5–22 s per step (machine shared with another run). ``--set max_rotation_per_step=None`` gives the spin-up
above.

Where it comes from (thirty-fifth session, ``--set max_rotation_per_step=None``, ω at t = 0.070–0.074 s): the same
spin-up, 440 → 596 → ≈ 750 → ≈ 950 → ≈ 1,170 rad/s, with ``--friction none`` and ``--friction iso``, and with
``warm_start=False``, ``split_recovery=False``, ``harmonisation_iterations=1``, ``end_velocity_positions=False`` or
``post_stabilisation=False`` (each alone). With
``springs_in_first_half_step=False`` it does not start: 453, 198, 194, 185, 206 rad/s (joint gaps 55–87 µm, 6–8 s per
step against 16–20 s). So it lives in the first half step's motion with the joint springs' impulses (the default,
see that option's notes), not in the contacts' friction or the stabilisations. Traced with the defaults: fibre 316's
segments 48–57 swing with the sign of their axial and transverse spin alternating every step (period-2 ringing), the
kinetic energy of segments 46–59 rising 5–18 % per step (t = 0.070–0.073 s), by 10–16 % in each step's joint stage
(Method I: from the start state's twists to the joint-corrected ones), the contact solves then adding or removing up
to 10 %; their contact rows come and go (124–331 rows on segments 50–53 at t = 0.070 s, none on 53–57 at 0.073 s).

Thirty-sixth session: the 30 fibres ``--fibres 300:330`` spin up the same way without the limit, in 0.2 s per step
(fibre 328's segments 48–52: ω 464 → 4,070 rad/s in 12 steps, joint gaps 590 µm); the 10 fibres 320:330 up to 1,070
rad/s. Fibre 328 alone, without obstacles, shows the joint stage's twist flipping sign and growing every step
(−0.17, +0.32, −0.33, +0.57, −0.65 rad) and gains energy even from rest: the plain step's energy gain on a strongly
bent, stiff chain (see ``tests/solvers/test_chains_stabilisation.py::test_the_plain_step_dissipates_a_released_coil``
and ``ChainOptions.max_rotation_per_step`` for the refinement study).
"""

from __future__ import annotations

import argparse
import ast
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_STATE = os.path.join(HERE, "data", "drape_terrain_355x100_aniso_t0.069.npz")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--state", default=DEFAULT_STATE, metavar="FILE.npz")
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--friction", default="aniso")
    ap.add_argument("--fibres", default=None, metavar="FIRST:STOP",
                    help="step only the fibres FIRST … STOP − 1 of the state (default: all)")
    ap.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                    help="ChainOptions override, e.g. --set step_halvings=0")
    args = ap.parse_args()
    from drape_states import load_state

    from headsim.errors import ParameterError
    from headsim.hair.drape import build_drape_scene
    from headsim.solvers.chains import ChainSolver, select_fibres

    overrides = {}
    for kv in args.set:
        k, v = kv.split("=", 1)
        overrides[k] = ast.literal_eval(v)
    try:
        scene = build_drape_scene("terrain", args.friction, **overrides)
    except ParameterError as e:
        ap.error(str(e))
    solver = ChainSolver(scene.options)
    model = scene.model
    state = load_state(args.state, model)
    n = model.n_segments // model.n_fibres
    first = 0
    if args.fibres is not None:
        try:
            first, stop = (int(v) for v in args.fibres.split(":"))
            model, state = select_fibres(model, state, np.arange(first, stop))
        except (ValueError, ParameterError) as e:
            ap.error(f"--fibres {args.fibres}: {e}")
    print(f"terrain {model.n_fibres} × {n}, from t = {state.time:.3f} s, overrides {overrides}")
    for _ in range(args.steps):
        t0 = time.perf_counter()
        state = solver.step(model, state, scene.dt, scene.obstacles)
        st = solver.last_stats
        w = np.linalg.norm(state.angular_velocity, axis=1)
        k = int(np.argmax(w))
        print(f"t {state.time:.3f} s: max ω {w[k]:7.0f} rad/s (fibre {first + k // n}, segment {k % n}), max joint gap "
              f"{st.max_joint_gap * 1e6:7.1f} µm, total energy {st.total_energy:.6e} J, solver steps {st.substeps}, "
              f"{time.perf_counter() - t0:.2f} s", flush=True)


if __name__ == "__main__":
    main()
