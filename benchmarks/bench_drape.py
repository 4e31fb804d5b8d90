"""Benchmark: time per step of the drape reference scene (Sobottka 2008 §8.6.2: 355 helical fibres ×
100 segments on a sphere, Δt = 1 ms) — batched Numba kernels vs a one-fibre-at-a-time loop of the same
algorithm in the same run. Goal ≤ 0.2 s per step on 2 cores (seed: 30–180 s per step, serial).

Usage: python benchmarks/bench_drape.py [--fibres 355] [--segments 100] [--settle 30] [--steps 5]
       [--loop-steps 1] [--friction aniso] [--coupled-only] [--geometry derived|former]
       [--set OPTION=VALUE ...] [--state FILE.npz] [--save-state FILE.npz]

``--geometry former`` is the ringlet start (:meth:`HelicalSphereGeometry.former`) all the timings below
were measured on: the strand is in contact with itself from the first steps. The default derived
geometry hangs 2.8 cm above the sphere: at t = 5 ms it has no active contacts (168 k rows, 868 k
candidates; 0.94 s per step, load 1.0, branch ``gs``), so short runs of it do not exercise the contact
stage. ``--set`` overrides ChainOptions (e.g. ``--set joint_gap_fraction=1.0 --set contact_tolerance=1e-9``:
the former joint-gap targets and fixed 60 sweeps, which reproduce the former states exactly).

The scene is first advanced ``--settle`` steps (so the strand is in contact with itself and the
sphere), then ``--steps`` steps are timed with the batched solver; the loop baseline (``fibre_loop=True``:
Python calls the joint kernel per fibre and the contact kernel per body) is timed on ``--loop-steps``
steps from the same state (same algorithm, per-body contact mode, since the coupled mode is one
Gauss–Seidel over all contacts and has no per-fibre form). Both CPU (process_time) and wall times are
printed, with the load average.

Measured (issue 10, branch ``speed``, 2 cores shared with other jobs; before = commit e77196d, after =
the commits up to the one that added this paragraph; same process command, alternating runs):

* Reference scene, coupled only: ``--fibres 355 --segments 100 --settle 3 --steps 3 --coupled-only``
  (ringlet start, t = 5 ms, 199 k rows + 2.1 M candidates, 6,946 active contacts; the states, energies and
  contact counts are bitwise the same before and after): before 7.01 / 5.97 s per step wall (load 0.8 /
  1.7), after 5.37 / 5.57 s (load 1.3 / 2.0). Phases after: contacts 3.6 s (of which the Gauss–Seidel
  sweeps ≈ 2.4 s: 3 solves × 60 sweeps × ≈ 13 ms, of which ≈ 4 ms the chains' block-Thomas solves),
  detection 1.4–1.5 s, joints 0.18 s. Goal 0.2 s: still ≈ 27× off.
* Reduced: ``--fibres 120 --segments 50 --settle 5 --steps 2 --loop-steps 1`` (load 0.8–1.3): coupled
  0.84 → 0.80 s per step (within the noise; the changes act on the ≈ 2 M pairs of the full scene),
  per-body 6.2 / 6.5 s, one fibre at a time 9.9 / 9.5 s.

Branch ``energy10`` (issue 10, ``ChainOptions.end_velocity_positions`` with ``end_velocity_predictor`` =
"previous", ``sweep_budget``, ``exact_final_solve``; before = commit 6ce31d0's source tree, same script and
venv, alternating runs, ``--fibres 120 --segments 50 --settle 5 --steps 2 --coupled-only --geometry former``;
2 cores shared with other jobs, so the wall times follow the load): before 0.44 / 0.49 / 0.47 s per step wall,
0.85 / 0.94 / 0.90 s CPU (load 0.9–2.0; two busy threads), 6.8 / 1.64 s wall (load 3.2–3.8); after 0.78 / 0.76 /
0.78 / 0.78 s wall, 0.76–0.82 s CPU (load 1.7–4.1; one busy thread in every run, also with
``end_velocity_positions=False``, whose states are bitwise the former ones: 0.71 s wall, 0.71 s CPU at
load 2.0, against 0.47 s wall, 0.90 s CPU for the former tree 6 s later; a serial Numba kernel timed in both
trees at load 3.6 ran at the same speed, so the thread count is the machine's, not the code's). Per step, after:
contacts 0.39–0.47 s, integration 0.05–0.06 s (the projection QP is skipped; before 0.05–0.24 s), detection
0.20 s. The small-system paths (sweep budget, exact solve) do not act on this scene (31 k rows, 6,000
segments). State at t = 7 ms: max joint gap 23 µm (before 4.5 µm), max penetration 23.5 µm (before 18.5 µm).
The "after" numbers above were measured with ``sweep_budget`` = 1,000,000 (its default then). Re-measured at
the current default 100,000 (same command, later session, warm Numba cache): the same state (max joint gap
2.337e-05 m, max penetration 2.346e-05 m, kinetic energy 2.5827e-05 J, also with ``--set sweep_budget=1000000``
in the same session); 0.48 / 0.43 s per step wall, 0.91 / 0.81 s CPU (load 2.3, another job on one core; two
busy threads this time), 0.48 s wall, 0.91 s CPU with ``--set sweep_budget=1000000``. The first run after the
venv was built spent 4.7 s per step in the timed steps: Numba compiling (108 s warm-up), not the solver.

Branch ``gs`` (issue 10: joint rows J u = 0 in the contact solve, ``joint_gap_fraction`` = 0; stopping rule
``contact_tolerance`` = 1e-5 m/s with the 60-sweep cap; the rows' gather in one Numba pass). Same session,
alternating runs, before = commit dbd7b37 (its source tree, same benchmark script), ``--geometry former``:

* Reference ``--fibres 355 --segments 100 --settle 3 --steps 3 --coupled-only`` (load 1.05–1.40): before
  5.00 / 4.74 s per step wall (contacts 3.31 / 3.14 s, detection 1.47 / 1.39 s), after 4.70 / 4.63 s
  (contacts 2.95 / 2.96 s, detection 1.55 / 1.41 s, joints 0.09–0.11 s). All three contact solves of every
  step still end at the 60-sweep cap (``qp_capped`` = 3): the stopping rule does not shorten them on this
  scene. The states differ (joint targets): 6,946 → 6,608 active contacts, max joint gap 19.5 → 14.7 µm,
  max penetration 68.9 → 67.5 µm, kinetic energy 5.734e-5 → 5.709e-5 J; the ≈ 0.3 s less in the contact
  phase is the gather (0.42 s per step in the former NumPy gathers, cProfile).
* Reduced ``--fibres 120 --segments 50 --settle 5 --steps 2 --coupled-only`` (load 1.6): before 0.59 / 0.45,
  after 0.44 / 0.50 s per step (noise); max joint gap 18.8 → 4.6 µm, penetration 48.6 → 45.1 µm.
* Settled strand ``--fibres 40 --segments 30 --settle 1500 --steps 20 --coupled-only`` (t = 1.5 s, load 1.4–1.6,
  each on its own trajectory; before = the ``--set`` options above): 0.049 → 0.055 s per step, every
  solve at the cap in both; max penetration 126 / 140 µm (3.6–4 fibre radii), joint gap 13.7 / 11.6 µm.
* Goal 0.2 s: still ≈ 23× off. A process-time CPU profile of one reference step (t = 6 ms): Gauss–Seidel
  iterations 2.04 s (3 × 0.68 s, 11 ms per sweep), pair rows 0.28 s, joint-duplicate filter 0.18 s, pair
  sort 0.16 s, BVH query threads ≈ 0.23 s, set-ups 0.12 s. Detection was not changed here.

Branch ``det`` (issue 10, detection only): the BVH pairs come unsorted and one fused Numba pass
(``chains_pairs.detect_rows``) orders them by (a, b), drops the joint copies and writes the rows and keys,
instead of the radix sort → joint-duplicate filter → ``pairs[keep]`` → row kernel chain. The rows are the
same in the same order: states, energies, contact counts and every row of the last step bitwise identical
(reference scene, 8 steps from the former start). Before = commit dd7805a, after = branch ``det``:

* ``_detect`` alone, same process, same mid-step state (t = 6 ms, 4.32 M BVH pairs → 2.20 M rows; the
  commit dd7805a ``_detect`` loaded from its source next to the new one), 3 alternating repeats, load
  1.7: before 1.30 / 1.30 / 1.30 s, after 0.77 / 0.87 / 0.75 s (0.69–1.02 s with the serial kernel).
  Kernels alone on that input (load 2.0–2.4): sort + filter + rows 0.93–1.43 s → 0.45–0.71 s.
* Reference ``--fibres 355 --segments 100 --settle 3 --steps 3 --coupled-only --geometry former``,
  alternating runs while a second job kept the 2 cores busy (load 3.6–4.0): before 7.28 / 4.26 s per step
  (detection 1.64 / 1.33 s), after 7.28 / 3.77 s (detection 1.95 / 1.11 s): at that load the phase times
  are noise; same stats (6,608 contacts, max penetration 6.754e-05 m, KE 5.7093e-05 J).
* Left in detection (cProfile, t = 6 ms): fused pass ≈ 0.6 s (the gather of the 4.3 M pairs into
  (a, b) order and the per-segment sorts ≈ 0.2 s, the duplicate and gap tests ≈ 0.2 s, writing 2.2 M
  rows ≈ 0.2 s), BVH query threads ≈ 0.25–0.35 s, tree build 0.03–0.06 s. Half of the 4.3 M pairs are
  dropped after the query (≈ 1.1 M joint copies, ≈ 1 M separating pairs of the persistence filter).

After the merges of the branches ``gs``, ``pen`` and ``det`` (commit c85af25 + README), unloaded (load 0.9–1.2,
nothing else running), ``--fibres 355 --segments 100 --settle 3 --steps 3 --coupled-only --geometry
former``: **3.55 s per step wall** (6.14 s CPU): detection 1.03 s, contacts 2.34 s, joints 0.08 s,
integration 0.05 s; 6,604 active contacts, 60 sweeps in every solve (3 per step at the cap), max
penetration 6.70e-05 m. Goal 0.2 s: ≈ 18× off.

What limits the speed (``bench_contact_convergence.py``): the 60 sweeps are far from converged (velocity
correction 31 % off its converged value), so fewer sweeps would change the physics, and the shipped
iteration needs ≈ 2,000 sweeps for 1e-5 m/s; the rest is proportional to the ≈ 3 M detected pairs that
the absolute speed margin gives a falling strand (BVH query and sort, rows, gathers; 0–7 candidates
become rows per solve).

With ``half_step_projection`` and ``separating_candidates`` (the defaults since the merge of branch
``pen2``), same command, same session, load 0.4–0.7: before (commit 91a027b) 5.06 s per step wall
(detection 1.62 s, contacts 3.22 s, integration 0.06 s), after 5.91 s (detection 1.60 s, contacts 3.45 s,
integration 0.72 s: the projection's Gauss–Seidel over the previous pass's contacts, solved to
``qp_tolerance``); 6,440 active contacts, max penetration 5.69e-05 m (6.70e-05 before), 78 sweeps in the
largest solve (candidate rows added during the solve extend it). This machine ran the same command at
3.55 s per step in an earlier session: the absolute numbers move with the machine's state, the ratio
was measured in one session.

Issue 10, twelfth session (one process per line, machine otherwise idle, same command
``--fibres 355 --segments 100 --settle 3 --steps 3 --coupled-only --geometry former``):

* former defaults (``--set "contact_acceleration='none'" --set qp_iterations=60``, bitwise the former
  states): 4.94 s per step wall (contacts 2.97 s, detection 1.66 s), 191.8 k rows, 2.14 M candidates, 7,831
  active contacts, max penetration 55.1 µm; 5.25 s in a first run;
* Nesterov-accelerated contact solve (``contact_acceleration``) at 60 sweeps: 4.91 s (contacts 3.17 s), max
  penetration 23.3 µm; at 30 sweeps (the new default cap): 4.26 s (contacts 2.30 s, detection 1.67 s),
  43.7 µm, 7,806 contacts;
* and the fibre pairs that only the speculative margin reaches as candidates instead of rows from the
  start (the defaults now): **3.50 s** (contacts 2.09 s, detection 1.05 s), 19.7 k rows, 2.32 M candidates of
  which 1,266 per step became rows in the solves, 7,423 contacts, max penetration 42.0 µm (the same row
  change with the former plain 60-sweep solve: 4.07 s, 46.3 µm). A profiled pair of later steps (t = 6–7 ms):
  2.4 / 2.9 s per step, of which the three Gauss–Seidel solves 1.04 s, the fused detection pass 0.64 s
  (4.3 M BVH pairs → 2.2 M candidates), the BVH query 0.25 s. Goal 0.2 s: still ≈ 17 × off; what is left
  scales with the 2.2 M candidates of the absolute-speed band and the 35.5 k joints swept 30 times per solve.
* and the first candidate test of each solve screened against the candidates' normal velocities at the
  detection's u⁻ (``ref_vn`` of the kernel; the same promotions, bitwise the same states): 3.40 s (contacts
  1.80 s). On the captured solves of one step (t = 6 ms) the kernel took 0.25–0.32 s per solve with it,
  0.34–0.40 s without; with the candidates removed 0.14–0.16 s (their O(candidates) set-up and copies,
  the screened tests and the sweeps the promotions add are the rest).
* and the per-row passes over rows and candidates in parallel (``prange``: the rows' normal velocities, the
  kernel inputs, the impulse scatter, the warm start), the touched fibres in one Numba pass, the coupled
  kernel iterating its impulses in place and setting up only the rows' entries of its per-row work arrays
  (the candidates' when they become rows): **2.68 s** per step (contacts 1.42 s, detection 1.02 s), bitwise
  the same states.

Later in the reference sequence the candidates grow with the fall speed: the derived default geometry
(``build_drape_scene("sphere-helical")``, 355 × 100) run from t = 0 takes 1.0 s per step at t = 10 ms, 2.6 s at
30 ms, 6–7 s at 60 ms (0.6 m/s free fall: 7.4 M candidates, 35 k rows, 4.9–5.7 k contacts); reproducible as
``--settle 58 --steps 3 --coupled-only`` (derived geometry): 5.97 s per step (detection 2.84 s, contacts 2.84 s),
7.5 M candidates, 5,291 contacts. From one saved state at t = 60 ms, 3 steps each in one session: the source
tree before this session (commit d28e51d) 9.28 s per step (175 k rows), Nesterov + candidate rows 8.30 s,
+ the per-row passes 6.51 s, + the kernel's in-place impulses 5.99 s (same contacts and penetrations in the
last three). There the candidates of the
absolute-speed band cost more than the solves: the fused detection pass 1.3 s, the gather of 7.6 M rows
0.58 s, the kernel's O(candidates) work in each of the 3 solves. The candidate band is the lever left: it
grows with |u|Δt of each segment although a falling strand's neighbours move together.

``ChainOptions.candidate_band = "relative"`` (opt-in in the twelfth session, the default since the thirteenth): the candidate band from each segment's speed relative to a
smooth reference field (velocities gathered on a grid) plus an allowance for its velocity change in the solves,
checked after them (a step whose change exceeds it is redone with the absolute band). ``--settle 58 --steps 3
--coupled-only --set "candidate_band='relative'"`` (derived geometry, t = 60 ms, the whole 60 steps run in the
mode): 1.47 s per step (detection 0.36 s, contacts 0.87 s), 1.26 M candidates, against 5.97 s and 7.5 M with the
default absolute band; the same 5,291 contacts, max penetration 7.739e-07 m, kinetic energy 1.0273e-04 J and joint
gap 4.941e-07 m. On the ringlet start every step keeps the absolute band (2.74 s per step, bitwise the same
states). Through the landing (from a saved t = 60 ms state, 30 steps per mode, 2 shared cores; the same trajectory
to the printed digits) the relative mode redid 13 of the 15 steps from 80 to 90 ms and took 393 s against 262 s:
it stays opt-in until its allowance foresees segments stopped by other fibres.

Issue 10, thirteenth session (machine otherwise idle; "old" = commit db3666c's source tree run from a git worktree
with the same venv, alternating with the new tree in one session):

* Reference ringlet start (``--fibres 355 --segments 100 --settle 3 --steps 3 --coupled-only --geometry former``):
  old 3.07 / 3.07 s per step (detection 1.25 s, contacts 1.50 s), new **1.95 / 1.91 s** (detection 1.00 s,
  contacts 0.68 s); 7,626 active contacts (old 7,423), max penetration 44.2 µm (42.0), kinetic energy
  5.7314e-05 J (5.7300e-05), max joint gap 22.4 µm (22.5). What changed, in the order it was measured:
  the candidate reserve (``ChainOptions.candidate_reserve``: 2.3 M → 0.22 M candidates in the solves, 2.1 M
  kept in reserve and checked after every solve; contacts 1.25 → 0.80 s per step; 2.69 / 2.63 → 2.27 / 2.31 s
  per step with the einsum change below in both), the four-operand ``einsum`` calls of the integration and the
  energies replaced by batched products (0.12 s per step), the detected pairs ordered by a parallel two-pass
  radix sort with work buffers kept across steps (the fused pass 0.68 → 0.49 s), the solver stepping with
  writable copies of the model's arrays (``ChainModel.kernel``: Numba's read-only specialisation of the fused
  detection pass took 1.0–1.2 s against 0.36 s on the same inputs), and 2 contact domains
  (``contact_domains`` = 2: contacts 0.82 → 0.65 s). The relative band does not act here (every step keeps the
  absolute band). Goal 0.2 s: still ≈ 10× off.
* The fall and the landing (derived geometry, from a saved t = 60 ms state, 30 steps to 90 ms, candidate reserve
  and 2 domains in both): relative band (the default now) 156 s, absolute 177 s (the twelfth session's code:
  262 s absolute, 393 s relative). Per step: 61–82 ms 1.3–2.5 s against 2.8–4.6 s; 83 ms 8.6 s against
  11.5 s; 84 ms (the strand lands: 300–500 k reserve pairs closed by the solves, 5 re-solves of the last pass)
  30 s against 31 s; 85–90 ms 12–16 s against 9–14 s (50–57 k active contacts, 190–330 k rows, 1.7–2.1 M
  candidates against 1.4–1.8 M, of which ≈ 170 k are promoted in each solve; the solves run 60 sweeps; the
  relative band is the wider one there: its radii carry the allowance 2 δ̂, the absolute band none). The
  allowance of a segment with an obstacle row is at least its speed at the end of the step (at its start
  before: 163 s for the relative band, 10–15 % more candidates at 85–90 ms). One
  captured landing solve (t = 86 ms) took 2.24–2.72 s with 1 contact domain, 1.59–1.65 s with 2, 1.78 s with 4.

Issue 10, fourteenth session ("old" = commit 60ed2ca's source tree from a git worktree, same venv, alternating
runs in one session, machine otherwise idle; the machine ran ≈ 10 % faster than in the thirteenth session: the
old tree's ringlet start took 1.69–1.80 s against 1.91–1.95 s then):

* The relative band's bound is now local (:class:`headsim.solvers.chain_band.LocalMotionBound`: each
  segment's deviation from a trilinear reference field of the point velocities on a 1 mm grid (coarser for a
  spread strand: at most 200 k nodes), plus the field's change within the segment's reach), a band widened
  for a few segments is detected around those only
  (:func:`headsim.collide.fibre_bvh.subset_contact_pairs`: 5–80 ms against 0.3–0.5 s for a whole query), the
  half step has no temporaries (integration 0.11 → 0.03 s per step), and a reserve chunk with one pair a solve
  closes hands all its suspects back (one re-solve instead of up to five).
* Ringlet start (command above): old 1.69 / 1.80 / 1.77 / 1.68 s per step, final **1.37–1.39 s** (detection
  0.83–0.96 → 0.66–0.67 s, integration 0.11 → 0.03 s; 4.3 M → 1.8 M detected pairs at t = 6 ms, of which ≈ 1 M
  belong to the ≈ 2,000 segments near the tips moving at ≈ 2 m/s; the same contacts, rows, penetration, energy
  and joint gap to the printed digits).
* Fall and landing (derived geometry, 30 steps from a saved t = 60 ms state; ``--settle 58 --steps 30
  --coupled-only`` runs the same steps after settling): old 146.5 / 146.6 / 149.8 s, final **92.7 s**. Per
  step (old → final): 61–76 ms 1.10–1.23 → 0.81–0.95 s (1.2–1.3 M → 0.35–0.48 M reserve pairs, the same
  states), 77–82 ms 1.6–2.4 → 1.0–1.2 s, 83 ms 8.5 → 4.2 s, 84 ms 29.8 → 10.7 s (300 k reserve pairs closed:
  1 re-solve instead of 5), 85–90 ms 11–15 → 7.4–13.4 s (contacts 6–11 s: 190–330 k rows and 1.7–2.1 M
  candidates, whose allowances δ̂ of 0.7–0.9 m/s belong to the 10 % of the segments sliding off the sphere;
  1.0× instead of 1.5× the last change as the allowance changed the candidates by < 10 % and the time not at
  all; each solve runs 60 sweeps and promotes 25–160 k candidates).
* Then the joint stage without temporaries per segment (the SO(3) log as scalars): joints 0.086 → 0.062 s per
  step, ringlet start 1.34 s per step (the same states).
* Tried and left out: the candidates one solve promoted starting the next solve of the same rows as rows
  (the landing sequence 7 % faster, but on the ringlet start the capped iterates came out worse: max
  penetration 44.2 → 50.3 µm, largest solve 49 → 60 sweeps).
* Goal 0.2 s: still ≈ 4–5× off for the falling strand (0.8–0.95 s per step: 3 solves of 30 sweeps ≈ 0.36 s
  and ≈ 0.14 s of their set-ups and reserve checks, detection 0.28 s, joints 0.07 s, integration 0.03 s) and
  ≈ 7× for the ringlet start.

Issue 10, fifteenth session (one process per line, machine otherwise idle; this session's machine ran the
unchanged ringlet start at 1.31–1.41 s per step):

* **Numba cache (numba issue #6845).** The serial and ``parallel=True`` builds of one kernel source shared one
  cache index, so the build compiled first was loaded by both. After a small scene (the tests, the README
  demo) had compiled first, the ringlet start ran its "parallel" kernels as serial builds: 2.43 s per step
  (contacts 1.22 s, detection 1.10 s) against 1.51 s with the fix (contacts 0.69 s, detection 0.70 s), same
  states. Every serial/parallel pair now has its own cache files (``headsim.solvers._kernels.twins``); a test
  checks that the parallel builds reproduce the serial ones bitwise.
* **Coupled iteration.** Three changes:
  - the candidate test runs in parallel, then the promotions in order;
  - the screen rebases after every full sweep that tested candidates exactly;
  - the partial sweeps' slack band is set per row from its bodies' velocity changes
    (``chains_coupled.BAND_FACTOR``).

  Captured solves, timed alone (before → after):

  | solve | before | after | iterates |
  |---|---|---|---|
  | landing, t = 86 ms, first solve (144 k rows, 1.85 M candidates) | 1.78–1.94 s | 1.30–1.32 s | differ in the last change: 0.10363 vs 0.10361 m/s, same promotions |
  | falling, t = 61 ms | 0.10–0.12 s | 0.088–0.10 s | bitwise the same |
  | ringlet, t = 6 ms | 0.12–0.24 s | 0.083–0.20 s (repeat runs later in the session) | last changes equal to 5 digits |

  Exact tests in the landing solve: 5.7 M → 2.2 M.

  In the steps themselves the gain is smaller and mostly within the noise:
  - landing steps 85–86 ms (commit a422972 against the final tree, alternating runs): 12.3–13.2 / 8.8–9.1 s against 11.9–12.1 / 8.5–8.8 s;
  - the 30-step fall and landing from t = 60 ms: 95.6 s against 94.4 s;
  - falling steps 62–66 ms: 0.85–1.02 s against 0.91–1.05 s;
  - ringlet start: 1.41 / 1.48 s against 1.62 / 1.48 s.

  With the per-row band, the ringlet start's state changed: 7,645 contacts, max penetration 41.8 µm (44.2 µm before), kinetic energy
  5.7312e-05 J, largest solve 60 sweeps (49).
* Goal 0.2 s: still ≈ 4–5× off on the falling strand and ≈ 7× on the ringlet start.

Issue 10, sixteenth session (session start = commit 099a0b0's tree against the final one, same venv and script,
alternating runs, machine otherwise idle):

* **Detection.** The widened band's subset query bins the query segments in a uniform grid (the same pairs,
  1.5–3× faster than the former slab sweep: 0.12 → 0.06 s for 1,960 query segments); the fused detection pass
  builds its radix histogram per chunk row and with fewer chunks for small calls; the packed fibre tree is
  refitted across steps (``PackedFibreBVH.refit_fibres``; rebuilt after 10 steps or 30 % box growth) instead of
  built every step (24 ms); the pairs without rows (separating, outside the band) are dropped in the query's
  worker threads (``chunk_filter``), so they are neither joined nor sorted (ringlet start 2.0–2.5 M → 1.4–1.7 M
  pairs). Since then a joint copy of a contact is dropped only where the copy it defers to is a row.
* **NumPy glue.** The per-segment frame products, the joint rows and the end-velocity gaps in Numba passes
  (``headsim.solvers._kernels.chains_frames``, ``KP.end_velocity_gaps``).
* Tried and left out: the earlier harmonisation pass's velocity solve capped at 10 sweeps (contacts 0.65–0.74 →
  0.57 s per step at the ringlet start, but max penetration 38 → 42 µm); one harmonisation pass (1.52 → 1.07 s
  per step, but max penetration 38 → 64 µm); the Lipschitz bound's block maxima from SciPy's maximum filter (the
  kernel 12 → 3 ms per call, the filters cost as much).

  | scene (command or state) | start of session | final |
  |---|---|---|
  | ringlet start, ``--settle 3 --steps 3 --coupled-only --geometry former`` | 1.48 / 1.56 s (detection 0.70 / 0.78, contacts 0.64 / 0.66) | **1.17 / 1.17 s** (detection 0.49, contacts 0.57 / 0.58) |
  | derived geometry t = 5 ms (no contact yet), ``--settle 3 --steps 3 --coupled-only`` | 0.47 / 0.51 s | **0.36 / 0.38 s** |
  | falling, t = 62–66 ms (5 steps from a saved t = 60 ms state) | 0.78–0.85 s | 0.66–0.84 s |
  | landing, t = 86–88 ms (from a saved t = 85 ms state) | 12.0 / 8.1 / 7.7 s (detection 1.35–1.52 s at 87–88 ms) | 11.4 / 8.0 / 7.1 s (detection 1.00–1.04 s) |
  | reduced, ``--fibres 120 --segments 50 --settle 5 --steps 2 --loop-steps 1`` | coupled 0.086 s, loop 1.58 s | coupled 0.071 s, loop 1.80 s (ratio 0.04) |

  States: the ringlet start's steps are the former ones to rounding until the joint-copy change (7,644 active
  contacts, max penetration 41.9 µm, kinetic energy 5.7312e-05 J, against 7,645, 41.8 µm, 5.7312e-05 J); the
  landing's contacts 56,299 / 55,709 / 53,154 against 56,297 / 55,749 / 53,122.
* Goal 0.2 s: ≈ 1.8× off with no contact yet, ≈ 3.5–4× on the falling strand, ≈ 6× at the ringlet start and
  35–57× while the strand lands (there the contact solves' 3 × 60 Gauss–Seidel sweeps over 200–300 k rows and
  1.7–2.4 M candidates take 5–6 s of the 7–11 s).

Issue 10, seventeenth session (session start = commit 730dd0e's tree against the final one, same venv and script,
alternating runs):

* **Contact solve.** The Nesterov extrapolation of the coupled solve restarted on every full sweep that promoted
  candidates. On the landing strand nearly every full sweep promotes some (25–111 k promotions per solve, most of
  them ending without impulse), so the solves ran almost without extrapolation. Now only the gradient test
  restarts. On the captured t = 87 ms solves the summed bound violation Σ max(0, target − n·Δu) after their 60
  sweeps fell from 247–272 to 60–83 m/s (plain Gauss–Seidel: 340–359 m/s). Behaviour change: the states differ.
* **Iteration kernel, bitwise the same iterates.** The friction polygon's boundary case walks along the boundary
  to the KKT point and compares only that edge and its neighbours, instead of all 16 edges; promoted candidates'
  Jacobian rows go to consecutive slots instead of scattered ones (each scattered first write was a page fault:
  0.085 s of a 2.2 s serial solve); the restart test's terms are written by the sweep that visits the row. The
  captured t = 87 ms landing solve: 1.29–1.41 → 1.09–1.14 s (alternating runs), the same impulses and twists to
  the last bit.
* Tried and left out: promoting the previous solve's candidates with impulse at the start of the next one (only
  781 / 5,650 of the 111 k promotions still carried impulse, 1.73 → 1.52 s for the push-out solve; not kept once
  the restart fix made promotions cheap); building the promoted rows in parallel (no measurable gain); a momentum
  factor 1.3 (no better than 1.0); the dot products of the row update as pairwise sums (≤ 4 %, not bitwise).

  | scene (command or state) | start of session | final |
  |---|---|---|
  | ringlet start, ``--settle 3 --steps 3 --coupled-only --geometry former`` | 1.23 / 1.31 s (contacts 0.62 / 0.70) | **1.10 / 1.14 s** (contacts 0.48 / 0.53) |
  | derived geometry t = 5 ms (no contact yet), ``--settle 3 --steps 3 --coupled-only`` | 0.38 s | 0.38 s |
  | falling, t = 62–65 ms (steps from a saved t = 60 ms state) | 0.73–0.80 s | 0.70–0.71 s |
  | landing, t = 86 / 87 / 88 ms (from a saved t = 85 ms state) | 12.0–12.8 / 8.6 / 7.7 s | **9.9 / 5.4 / 4.9 s** |
  | reduced, ``--fibres 120 --segments 50 --settle 5 --steps 2 --loop-steps 1`` | coupled 0.071 s | coupled 0.079 s, loop 1.75 s (ratio 0.05) |

  States: ringlet start 6,634 active contacts (before 7,644), max penetration 18.5 µm (before 41.9 µm), kinetic
  energy 5.7336e-05 J (5.7312e-05 J), largest solve 46 sweeps (60); landing t = 86 / 87 / 88 ms 39,715 / 32,379 /
  29,909 active contacts (before 56,299 / 55,709 / 53,154; better-converged impulses sit on fewer contacts), max
  penetration 70 / 72 / 61 µm (70 / 67 / 69 µm). The falling strand's states are the former ones to the printed
  digits.
* Goal 0.2 s: ≈ 1.9× off with no contact yet, ≈ 3.5× on the falling strand, ≈ 5.5× at the ringlet start and
  25–50× while the strand lands. The landing solves still end at their sweep cap, now with a 3–4× smaller
  residual: a smaller cap would trade that accuracy for time (``--set qp_iterations=20`` at the ringlet start:
  0.47 s contacts, 20.3 µm penetration; not made the default).

Issue 10, eighteenth session (session start = commit b8dc73e's tree in a worktree against the final one, same
venv and scripts, alternating runs, four rounds). Every change keeps the states: the ringlet start's 4-step state
hash, the falling and landing strands' printed stats.

* Contact domains: the breadth-first orders of the bisection (``_fibre_domains``) come from one Numba kernel
  (``breadth_first_cover``) instead of one SciPy ``breadth_first_order`` call per connected component; before the
  first contact every fibre is a component of its own: 21.5 → 1.6 ms per step.
* Joint stage: the block-Thomas factors of every chain's Newton matrix depend on the rotations of t_i only, so
  they are factorised once per step and shared by both harmonisation passes: joints 0.057–0.066 → 0.042–0.052 s.
* Fused detection pass: its rows go to arrays kept across steps (as its work arrays already did), not to 1.4–4 M
  fresh rows per step: its main call at the ringlet start 0.143–0.165 → 0.113–0.143 s.
* Candidate screen: the rebase swaps the two slack arrays instead of copying one into the other (≈ 1 %).
* Per-step statistics: kinetic energy, joint spring energy and joint gaps in one Numba pass (``chain_energies``)
  instead of NumPy's batched products: 12–15 → 0.9 ms per step (same values on the reference scene); before
  contact 0.340–0.343 s per step afterwards (not in the table below, which was measured before this change).

  | scene (command or state) | start of session | final |
  |---|---|---|
  | ringlet start, ``--settle 3 --steps 3 --coupled-only --geometry former`` | 1.08–1.11 s | **1.05–1.12 s** (1.05 in the last two rounds) |
  | derived geometry t = 5 ms (no contact yet), ``--settle 3 --steps 3 --coupled-only`` | 0.36–0.39 s | 0.34–0.38 s |
  | falling, t = 62–64 ms (steps from a saved t = 60 ms state) | 0.70–0.76 s | 0.67–0.70 s |
  | landing, t = 86 / 87 / 88 ms (from a saved t = 85 ms state) | 10.3–10.8 / 5.2–5.7 / 4.5–4.8 s | 10.2–10.7 / 5.2–5.4 / 4.3–4.8 s |

  The machine ran slower than in the seventeenth session (its final tree: landing 9.9 / 5.4 / 4.9 s then,
  10.3–10.8 / 5.2–5.7 / 4.5–4.8 s now). The t = 86 ms figure includes the cold start of a solver that loaded a
  saved state (first touches of every work array: the fused pass 0.45 s per call against 0.11 s a step later).
* Tried and left out (all measured): a cursor into the warm-start keys instead of a binary search per reserve pair
  in the fused pass (0.094 against 0.096 s on the captured ringlet call); separating-axis rejects along both segment
  axes before the packed tree's exact capsule test (no gain: 0.197 against 0.199 s single-threaded; the query's
  time is in the traversal and the lane tests, not in its 4.6 M capsule tests); reusing the tree's pairs over
  several steps with a skin (the helical strand's tips move up to 0.7 mm per step relative to its mean motion
  from the first step on, 10 radii); a sweep cap of 8 for the first pass's velocity solve (landing ≈ 7 % faster);
  a cap of 15 for the push-out solve (landing ≈ 5 % faster, ringlet max penetration 24.8 → 34.2 µm after 4 steps);
  one harmonisation pass (landing ≈ 40 % faster, but 95 against 61 µm max penetration at t = 88 ms, and the
  second pass's half-step projection and end-velocity positions off); ``qp_iterations`` = 20 (fails
  ``test_former_half_step_never_gains_energy_on_the_fibre_held_bent[0.2]``: an energy gain of 1.9e-15 J against
  its 1.1e-19 J round-off bound); the next full sweep sooner after promotions (6 × 10 log pile, rows starting as
  candidates: 2,191 → 2,104 sweeps without friction, 12,096 → 14,544 with); a screen of the partial sweeps' inactive
  listed rows by their bodies' velocity drift since the row's last visit (counted on the captured landing solve:
  at best 45 % of its 4.4 M inactive visits skipped, ≈ 5 % of its time, against bookkeeping on every twist
  update; not built).
* Convergence on the reference ringlet (``bench_contact_convergence.py --fibres 355 --segments 100 --settle 3``,
  t = 3 ms, 6,533 rows, 263 k candidates), distance to a 3,000-sweep answer in the kinetic metric: Nesterov 60
  sweeps 0.091, 30 sweeps 0.180, cap 20 (run to 40 by its promotions) 0.130; plain Gauss–Seidel 60 sweeps 0.279.
* Settled strand (``--fibres 40 --segments 30 --settle 1500 --steps 20 --coupled-only``, t = 1.5 s): 0.050 s per
  step, 595 active contacts, max penetration 51 µm, every solve at its cap (as in the ninth session's 0.049–0.055 s).
* Goal 0.2 s: ≈ 1.8× off with no contact yet, ≈ 3.4× on the falling strand, ≈ 5.3× at the ringlet start,
  ≈ 22–53× while the strand lands. Per step before contact (cProfile): tree query 0.10 s, fused pass 0.03 s,
  contact set-ups 2 × 15 ms and iterations 2 × 11 ms (chain factors and sweeps of every fibre with candidates),
  joints 0.045 s, relative band 0.03 s, per-step statistics 0.02 s (then 1 ms). Landing, t = 87 ms: the three contact
  iterations 3.3 s, detection 0.9 s (tree query 0.45 s, fused passes 0.34 s, gather 0.16 s).

Issue 10, nineteenth session (the first full-size run past the landing; captured solves timed with a serial copy of
the coupled kernel that adds cycle counters per section, ``llvm.readcyclecounter``):

* The reference sequence at full size, aniso, from the t = 85 ms state saved in the thirteenth session (the current
  solver from there on; the first full-size run past t ≈ 0.1 s): 1,434 steps to t = 1.52 s in 2,954 s wall. Per
  step: t = 0.5–1.0 s 1.37 s and **1.0–1.5 s 1.05 s** (detection 0.10 s, contacts 0.87 s; 13.4 k active contacts,
  66 k rows, 57 k candidates; the absolute band, which is then the smaller one), both windows with no other work on
  the machine; the earlier part shared it with this session's experiments (as run: 11.5 s per step at t = 86–130 ms,
  4.8 s at 131–250 ms, 2.5 s at 251–500 ms). Timed alone from the t = 1.5 s state: 1.0–1.3 s per step. The goal of
  0.2 s is ≈ 5× off at rest.
* Where a solve's time goes (serial kernel, share of its cycles): landing t = 86 ms — chain sweeps 13–15 %, contact
  visits of the partial sweeps 45–47 % and of the full sweeps 8–9 %, candidate tests and promotions 15 %, Nesterov
  extrapolation 16 %, friction block solves 23–25 % (part of the visits); 8.48 M row visits (6.99 M in 51 partial
  sweeps, 5.46 M of all to rows without impulse), 3.02 M friction solves, 2.56 M exact candidate tests. At rest
  (t = 1.5 s) the chain sweeps are 38–40 %, partial visits 39–43 %, friction 26–30 %, candidates 3 %.
* Why every solve runs to its cap at rest: the stopping quantity, the largest joint gap-rate residual before a
  chain solve, stays at 70–200 mm/s from sweep 10 on, and its joint is always joint 1–6 of its chain, next to the
  root. There the strand hangs from roots anchored 105 µm apart (1.5 diameters) and, from t ≈ 0.47 s (when it has
  slid over the sphere's rim), neighbouring fibres' first 8 segments overlap by up to 70 µm (one diameter; 124–155
  pairs deeper than a radius at t = 0.5, 1.0, 1.5 s; the run's reported largest penetration rises from 20–70 µm
  to 90–230 µm then). Before, the deepest overlaps are 28–62 µm where the strand lands (segments 44–86). A contact
  whose centre lines nearly cross has no consistent normal, so these rows and the root joints keep undoing each
  other. Not fixed; this is where the settled regime's sweeps go, and a cap that stops it is a result change.
  The crossings come from the capped solves, not from a geometry that cannot be resolved: from the t = 0.45 s state
  (9 pairs deeper than a radius), 25 steps with ``qp_iterations`` = 30 (the default) / 60 / 120 leave 37 / 26 / 6
  such pairs at t = 0.475 s (largest overlap 69.9 / 69.1 / 57.1 µm), in 40 / 49 / 75 s. More sweeps where these rows
  and the root joints fight, rather than everywhere, is the lead. A small case that shows the same: the settled
  40 × 30 strand (``--fibres 40 --segments 30``, 1,500 steps, 86 s): its 51 µm resting overlap (see above) is between
  root segments (segment 0 of both fibres; 4 pairs deeper than a radius); with ``qp_iterations`` = 120 (154 s) the
  largest overlap is 23 µm, mid-fibre, and none is deeper than a radius.
  (The run's reported penetration of up to 230 µm exceeds the 70 µm two capsules can overlap, and the sphere's
  penetration at the nodes stays below 13 µm: most likely it is the rows' first-order gaps at t_i (mid-step gap
  less the first half step's approach), which a pair whose centre lines cross can take beyond −2r. Not checked.)
* At t = 200 ms the solves end at 48–57 sweeps instead of their 30 because 1–6 candidates become rows in each
  full sweep after sweep 28 (each extends the cap by 9; 75–418 in the first full sweep).
* Tried and left out (captured landing solve t = 86 ms unless said; iterates bitwise the same where said):
  one record of 88 doubles per contact slot (J, M⁻¹Jᵀ and W together) instead of five arrays: bitwise the same,
  slower (1.20–1.25 against 0.99–1.10 s with 2 threads, 2.44–2.59 against 2.07–2.16 s serial); a compact array of
  the normal rows (W₀₀, both J rows) beside the five for the visits of rows without impulse: bitwise the same,
  slower (1.14–1.17 against 1.06–1.11 s); skipping the chain sweep of fibres whose bodies no contact visit changed
  since their last one: nothing to skip (every chain changed in every sweep at t = 200 ms); the push-out solve
  warm-started from the velocity solve's impulses: landing 8–12 % faster (t = 86–89 ms: 8.8 / 4.6 / 4.1 / 3.8 against
  10.3 / 5.2 / 4.3 / 4.1 s), penetration and kinetic energy the same to 2–3 digits, not kept (in-step warm starts raised
  the energy of the stack tests before, see ChainOptions.warm_start_fraction, and this was not validated again).
* The joint stage's Newton factors now go to arrays kept across steps (30 MB of fresh pages per step before): joints
  phase 0.0435 → 0.041–0.0425 s per step; ringlet 4-step hash unchanged (a2aae719…).

Issue 10, twentieth session (the three captured solves of one resting step, t = 1.5 s, 65.8 k rows, 57 k candidates,
35.5 k joints, replayed with copies of the coupled kernel; residuals measured at the solve's final twists):

* The resting solves cannot reach the stopping rule at any affordable cap: the velocity solve's last change is
  0.143 / 0.070 / 0.039 / 0.020 / 0.0073 m/s after 20 / 60 / 127 / 300 / 1,000 sweeps (1e-5 asked). The change is an
  impulse change times the free segment's W₀₀; the true residuals are smaller: after its 60 sweeps the largest bound
  violation is 3.8 mm/s (99th percentile 55 µm/s, 53 rows above 1 mm/s) and the largest joint gap rate 4.3 mm/s;
  after 300 sweeps 0.66 and 2.6 mm/s.
* Why so slow: with the chains solved, a contact impulse moves its bodies by 6–20 % of what it moves free segments
  (W₀₀ with the chains' response / without, 400 sampled rows: 0.058 / 0.063 / 0.20 at the 10th / 50th / 90th
  percentile; 0.015–0.057 on segments 0–4), and every row's Gauss–Seidel step is sized by the free W₀₀. The
  largest impulse changes between sweeps 100 and 200 are all on segments 0–4, between neighbouring roots.
* Tried and left out: that chain-aware W₀₀ (computed exactly per row) as the rows' step size diverges (NaN), also
  at 2× and 4× it: the rows of one fibre then act together on a chain that only the next sweep solves. Ending the
  solve at ``qp_iterations`` and settling the late promotions by local sweeps over their fibres instead of 9 more
  global sweeps each: the three solves 1.10 → 0.61 s, but their residuals are those of 30 sweeps (rows above
  1 mm/s: 269 / 976 / 1,151 against 53 / 297 / 512): the late promotions are what runs the resting solves to 60
  sweeps, and those sweeps are accuracy, not waste. Not kept.
* Kept: root sweeps (``ChainOptions.root_sweeps``, default 8, first 8 segments): block Gauss–Seidel over the root
  region after every unconverged full sweep; the same fixed point. On the captured solves (experimental copy, 16
  sweeps) 1.27 s (0) against 1.29 s for the three, fewer rows above 1 mm/s in the push-out solves (136 / 371 against 297 / 512), and no
  extra cost at the landing (t = 86 ms, 1.09–1.14 against 1.13–1.17 s; the same sweeps, promotions and residuals:
  no root row carries an impulse then).
  Full size, aniso, from the saved states (pairs overlapping by more than a radius, all but a few on segments 0–7):
  t = 0.4 → 0.5 s 132 → 62 pairs (1.77 → 1.82 s per step); 0.45 → 0.475 s 37 → 7; at rest 1.475 → 1.5 s 155 → 117
  (1.43 → 1.56 s per step); the settled 40 × 30 strand 51 µm / 4 pairs → 39 µm / 1 pair (``--fibres 40 --segments 30
  --settle 1500 --steps 20 --coupled-only``: 0.062 → 0.068 s per step, reported max penetration 50.9 → 36.6 µm,
  against ``--set root_sweeps=0`` in the same session). See the option's notes
  (16 sweeps: more cost, not consistently fewer crossings). The crossings are fewer, not gone.
* The reported penetration beyond 2r (nineteenth session, "not checked") is checked now: it is the rows' gaps at
  t_i, first order, not an overlap. One step from the saved t = 1.5 s state reports 96 µm; that is the t_i gap of a
  row (segment 9 of fibres 118 and 312) whose mid-step gap is −19 µm, and the deepest mid-step gap of the step is
  −66.6 µm (no row beyond −2r at mid-step). StepStats.max_penetration therefore overstates the overlap where the
  first half step moves a pair fast relative to itself (first order over ½Δt); left as it is (documented here).
* Goal 0.2 s per step: not met; ≈ 7× off at rest in these 25-step runs (1.4–1.6 s per step; 1.0–1.3 s in the
  nineteenth session's).

Issue 10, twenty-second session: nothing changed on this scene's path (the exact final solve, now able to take
redundant rows, acts on models of at most 100 bodies: ``bench_exact_solve.py``). The lever named above, the
anchored root region, was measured on captured solves (``bench_root_solve.py``): on the pinched former ringlet
(30 × 30) one solve of the root region on its exact Delassus matrix takes the Gauss–Seidel from 0.92 to 0.04–0.3
of its error (90 more sweeps: 0.90); on the derived geometry's 120 × 100 proxy at t = 0.5 s the iteration has no
such stuck mode and the safe form of that solve gains 7–10 %. The full-size resting strand was not measured.

Issue 10, twenty-third session: a resting state of the reference scene is in the repository,
``benchmarks/data/drape_355x100_aniso_t1.0.npz`` (derived geometry, aniso, t = 1.0 s, made by this session's
solver from t = 0 in 1,000 steps, 36 min wall on the 2 idle cores: 2.2 s per step on average, landing steps
t = 90–100 ms 5.3–9.5 s, t = 0.13–0.5 s 1.6–2.5 s, t = 0.5–1.0 s 2.0–2.5 s). Time the resting strand from it with
``--state benchmarks/data/drape_355x100_aniso_t1.0.npz --settle 3 --steps 5 --coupled-only`` (the first steps from a
loaded state start cold: no warm-start impulses). Measured, machine idle: **2.10 / 2.25 s per step** (contacts
1.88 / 2.01 s, detection 0.12–0.13 s, joints 0.05 s; 14.9 k active contacts, 75 k rows, 113 k candidates; every
solve at its cap, the largest 60 sweeps); with ``--set root_sweeps=0`` 1.79 s (contacts 1.56 s): the root sweeps
cost 17–25 % of a resting step here (the twentieth session measured +9 % at t = 1.5 s). Goal 0.2 s: ≈ 10× off
at rest. The Numba compile-time change of this session (``chains_coupled``'s chain helpers called, not inlined)
leaves the iterates bitwise and the ringlet start's time per step within the noise (1.02–1.10 against
1.05–1.06 s).

Issue 10, twenty-fourth session: the coupled solve now starts from the previous step's whole answer
(``ChainOptions.warm_start_fraction`` = 1; the former constant was 0.5). Why: replaying the resting step's first
solve (t = 1.003 s) against a 2,000-sweep reference, the half warm start starts 65 % off in Σ|λ − λ_ref|/Σλ_ref and
ends its 60 sweeps at Σλ = 2.24e-5 against 2.41e-5 N s: every step throws half of the load path away and rebuilds
it within the cap. With the full one the same replay ends at Σλ = 2.5388e-5 against 2.5383e-5 N s, and fewer solves
are extended past their 30 sweeps by late candidate promotions. Whole steps with ``wsf_run``-style runs (machine
idle but its speed drifting by up to 50 % within the hour, so only interleaved pairs count; each mode on its own
trajectory): at rest (from the saved state, 20 steps, two rounds) 2.33 / 2.07 against 3.38 / 3.07 s per step
(−32 %); after the landing (t = 0.12 s, 30 steps) 2.33 against 2.89 s (−19 %); the landing (t = 0.08 s, 25 steps)
7.16 against 6.93 s (+3 %, within the drift; a first, non-interleaved pair had shown +24 %). Energy change over
those runs the same to two digits, no step raising the total energy, no positive energy bound. This script's
command above: 2.40 / 2.14 against 2.63 s per step (5 steps after 3: the warm start needs steps to pay).
Tried and not kept: in-step warm starts (the second pass's velocity solve from the first pass's impulses, the
push-out from the velocity solve's): 2.17 against 2.08 s at rest, 7.92 against 7.83 s through the landing; the
root sweeps' rows visited by domain in parallel (27 % of the 8 k root rows cross the two domains): root-sweep
cost 1.03 against 1.19 s over 9 replayed solves, within the noise of the solves' total.
Then at rest about half of the solves still ran to 48–60 sweeps instead of 30: 400–980 candidates became rows during
each solve (most next to the anchored roots, where the capped iterates swing by mm/s) and every promotion in a full
sweep at the cap extended it. ``ChainOptions.late_promotion_overlap`` (default 0.1) extends it only for a promoted
pair that would overlap by more than 0.1 r by the step's end (first order) if the solve stopped: at rest every solve
then ends at 30 sweeps, 2.10 / 1.64 against 2.50 / 2.06 s per step (−16 / −20 %, 20 steps, interleaved); after the
landing −6 %; through the landing (deficits of m/s) 7.27 against 7.43 s.
Both changes against the session's start (commit c12c9e3 in a worktree, same venv and script, alternated, 20 steps
from the same state): at rest (t = 1.0 s) **1.42 / 1.46 against 2.39 / 2.61 s per step (−41 to −44 %)**; after the
landing (t = 0.12 s) 1.93 against 2.59 s (−26 %); through the landing (t = 0.08 s, 15 steps) 6.85 against 5.95 s
(+15 %: the full warm start costs there, +3 % and +24 % in the two pairs above; 40 landing steps against ≈ 900
resting ones in the first second). Energy change over each run the same to two digits, no step raising it. The
goal stays ≈ 7× off at rest: every resting solve still ends at its 30-sweep cap (the stall measured in the
twenty-third session).

Twenty-fifth session (issue 10). Where a resting step goes (t = 1.005 s, wrappers around the calls, 6 steps): 1.46 s
per step = three coupled solves of 30 sweeps (the first pass's velocity solve, the last pass's velocity and push-out
solves) 1.05 s (≈ 0.35 s each: ≈ 10 ms per sweep and ≈ 45 ms of first full sweep and set-up inside the kernel), two
kernel set-ups 0.12 s, detection 0.11 s, joints 0.05 s. Replayed (the last pass's velocity solve against a 1,000-sweep
answer): max |Δv| 13 mm/s after 30 sweeps, 18 mm/s after 10 (extended to 19 by late promotions), 72 mm/s after 2. The
first pass's solve only predicts the last pass's mid-step state: ``ChainOptions.predictor_sweeps`` (default 10,
extended to ≤ 20 by late promotions) caps it. Against the former 30, alternated, 20 steps from the same states: at
rest 1.30 / 1.29 against 1.38 / 1.39 s per step (−6.5 %), after the landing 1.74 / 1.68 against 1.86 / 1.92 s (−8 %),
through it 6.75 against 7.10 s (−5 %); a cap of 2 gained −15 % at rest and −10 % through the landing but opened the
landing strand's joints to 49.6 µm (6.6 µm with 30, 8.0 µm with 10). Capping the push-out solve (``push_out_sweeps``,
default None) at 5 gave 0.95 s per step at rest but doubled the landing's penetrations: not the default. The push-out
now starts from its own previous solution (``push_out_warm_start``, default) instead of the velocity solve's: the same
time per step, mean max penetration 114 against 119 µm at rest, 34.5 against 41.0 µm after the landing, 59.9 against
62.0 µm through it; with it, 10 push-out sweeps ran 1.24 against 1.36 s at rest and 4.79 against 6.75 s through the
landing (penetrations 116 / 46 / 67 µm), left as an option. This benchmark's command (``--state
benchmarks/data/drape_355x100_aniso_t1.0.npz --settle 3 --steps 5 --coupled-only``) on the session's last tree: 1.37 /
1.35 s per step (1.34 / 1.30 s with ``--set push_out_warm_start=False``; 1.41 / 1.40 s at the session's start). Goal:
≈ 6.5–7× off.

Twenty-sixth session (issue 10). The kernel's row order is not the stall: the last pass's velocity solve at t = 1.003 s,
captured and replayed with its 75 k rows ordered by their contact-graph distance from the sphere (either way), root
rows first or last, or at random, ends 0.129–0.130 off a 1,000-sweep answer (kinetic metric) after 30 sweeps, as in
the kernel's order (0.130); 69 % of that error lies on segments 1–5, next to the roots: the 355 roots sit 105 µm apart
and at rest the nodes 1–3 of neighbouring fibres come within 15–25 µm of each other, and the rows of segments 0–5
carry 70 % of the normal impulse (2.7 of 3.9e-5 N s after 3,000 sweeps). The predictor solve, capped at 10, runs 20
sweeps at rest (late promotions extend it; 290 ms replayed, like the 30-sweep velocity solve's 327 ms); without the
extension (``ChainOptions.predictor_extension=False``, an option) −10 % at rest but +11 % mean penetration after the
landing. ``ChainOptions.kernel_precision`` (default "auto": float32 for the kernel's stored row and chain arrays on
this scene, the arithmetic float64): at rest 1.17 against 1.29 s per step, after the landing 1.64 against 1.79 s,
through it 4.66 against 5.21 s, with the same penetrations and energy to the printed digits at rest and after the
landing. The coupled set-up no longer allocates small arrays per row and per joint block (bitwise the same arrays):
≈ −10 % of the set-up. This benchmark's command on the session's last tree: 1.05 / 1.03 s per step (1.16 / 1.31 s
with ``--set kernel_precision='"float64"'``; 1.26 s at the session's start). Tried and not kept: a larger predictor-only
promotion threshold (r: −8 % at rest, after the landing as False), capping the push-out at 15 / 10 sweeps (−4 / −8 %
at rest, −16 / −22 % through the landing, but mean penetration +12 % at rest and +40–50 % after the landing),
``qp_iterations`` 20 / 15 (−8 / −15 % at rest, +1 / +11 % mean penetration), Numba ``fastmath`` on the iteration (no
gain), an inner-disc shortcut of the friction polygon test (no gain), the root sweeps' row visits run by domain in
parallel as the main sweep's (they are serial, 20–30 % of a replayed solve's time: −4 to −6 % per step at rest, but
mean / largest penetration 120 / 168 against 112 / 137 µm: the root rows' visiting order matters at the cap). Goal:
≈ 5× off.

Twenty-seventh session (issue 10). **The floor of this step's design** (``--floor``, printed after the timed run):
the same resting start with every contact solve capped at one sweep and no root sweeps (``FLOOR_OPTIONS``; two
sweeps per solve ran: a promotion at the cap extends it by one) takes
0.53 s per step (min 0.47; detection 0.15, joints 0.05, contacts 0.28 s per step), against 1.26 s (min 1.18) with
the shipped caps in the same run (8 steps each, alternated): the fixed parts alone (detection, the two set-ups, the
joint stage, the first full sweeps with their candidate tests) are 2.6 × the goal, so no convergence gain of the
contact iteration can meet 0.2 s per step on 2 cores. The floor's ``StepStats`` penetrations at rest are those of the
shipped caps (100 steps each, alternated, from the saved state: mean / largest 111.4 / 157.8 against 110.9 / 159.0 µm;
the total energy falls in every step of both), but that largest overlap is the pinched root bundle's: the end state
of the floor run has 9,929 fibre overlaps above 10 µm away from the roots (segments ≥ 5) against 192 (99th
percentile 57.7 against 15.1 µm, largest 69.8 against 34.7 µm). So the sweeps are not wasted at rest; the benchmark
now prints these counts for the end state of each run (``overlap_summary``). The twenty-sixth session's float32 kernel
storage passes this finer check: after this command with ``--steps 20``, 293 overlaps above 10 µm away from the roots
(99th percentile 18.4 µm, largest 60.3 µm) against 277 (17.6, 60.1 µm) with ``--set kernel_precision='"float64"'``,
1,145 against 1,125 next to them; 1.10 against 1.31 s per step. The same check at rest (``--steps 20``) for two
trade-offs that earlier sessions judged on ``max_penetration``: ``--set predictor_extension=False`` 1.00 against 1.19
s per step, 259 against 293 overlaps above 10 µm away from the roots (99th percentile 18.9 against 18.4 µm), 1,129
against 1,145 next to them; ``--set push_out_sweeps=15`` 1.09 s, 258 above 10 µm but 3,307 against 2,523 above 1 µm
(99th percentile 16.3 µm), 1,194 next to the roots. At rest neither costs accuracy by this measure; through the landing
(re-checked in the twenty-eighth session, see ``ChainOptions.predictor_extension``) predictor_extension=False keeps
the overlaps but opens the joints to 43.8 against 7.6 µm, so the default stays. A profile of 5 resting steps (cProfile): the iteration 0.83 s, the set-ups 0.095 s, the
joint stage 0.052 s, the pair detection kernel 0.024 s per step; the Python between the kernels is a few per cent.
**The root packing is not the stall's cause**: the strand built on a 210 µm lattice (3 diameters instead of 1.5,
``--fibre-spacing 210e-6``; the seed gives no packing), run from its start to t = 1.0 s (29 min), still has its
deepest overlaps and widest joint gaps next to the roots (the bundle now pinches at segments 3–4 instead of 1–3:
max joint gap 15.5 µm at fibre 276's joint 3; penetrations 86–190 µm from t = 0.47 s on), every solve still ends at
its cap, and a resting step takes 0.94 s against 1.26 s (alternated, 8 steps; 57 k rows against 76 k: fewer fibres
touch near the roots) with penetrations mean / largest 116 / 145 against 110 / 129 µm. The coupled kernel no longer
collects the restitution's normal-impulse twists when ε = 0 (bitwise the same iterates; the replayed solves of one
resting step −5 to −11 % on one thread, within the noise on two). This benchmark's command with ``--floor`` on the
session's last tree: 1.23 s per step, the floor 0.53 s (0.43 of it); without it, alternated with the session's start
tree (4923f66, a worktree): 1.27 / 1.27 against 1.29 / 1.46 s per step. The machine ran ≈ 20 % slower than in the
previous session, where the start tree gave 1.03–1.05 s per step.

Thirty-first session, measured and not kept: the last pass's velocity solve and its split push-out do not depend on
each other (the push-out's gaps, warm start and joint targets are known before the velocity solve), so the two could
run side by side, each on one core, with the serial kernel (whose iterates are bitwise the parallel one's). On the
captured resting solve (t = 1.003 s, 191 k rows and candidates, 30 sweeps) replayed with a ``nogil`` build of the
serial kernel: one solve 0.174–0.242 s with the parallel kernel, 0.381–0.440 s serial (the two-domain kernel scales
by 2.2 on the 2 cores), and two serial solves in two threads 0.456–0.465 s against 0.35–0.48 s for two parallel solves
one after the other: nothing to gain, the sweeps are bound by memory traffic, not by idle cores.

Thirty-second session (``ChainOptions.post_stabilisation`` and ``step_halvings``, both on by default): this
command at rest, alternated on a quiet machine: 0.95 s per step with the post-stabilisation against 0.76 s with
``--set post_stabilisation=False`` (its correction solve runs every step on the pinched root bundle, whose overlaps
it lowers: > 10 µm next to the roots 244 against 420, largest 44 against 67 µm; elsewhere 1 against 4); capped at
10 sweeps it cost 0.82 s but let the plane 20 × 50 strand's overlaps and obstacle penetrations grow back (2,528
pair-steps > 10 µm against 478, 152 µm into the plane against 62), so it runs to ``qp_iterations`` like the other
solves. No step of this state is halved (the energy falls in every one). The full comparison (``--steps 3
--loop-steps 1`` from the saved state, machine shared with other runs): coupled 1.85 s per step, per-body batched
4.13 s, one fibre at a time 6.04 s (batched per-body 1.5 × the loop; coupled 0.31 of the loop).

Thirty-fourth session (``restore_crossings`` also checks the rows' joint neighbours, 2–3 evaluations of 15 ms per
step here; position corrections bounded by ``CORRECTION_TRUST``, which does not act on this state: its push-outs
move no point by more than 2.2 × the correction asked for). The full comparison (``--settle 2 --steps 4
--loop-steps 1`` from the saved state, quiet machine): coupled 1.84 s per step wall (2.71 s CPU), per-body batched
12.1 s (4 solver steps per step: its energy rose), one fibre at a time 25.6 s; coupled 0.07 of the loop (wall).
Coupled only, alternated with the session's start tree (6035b9d, a worktree; ``--settle 3 --steps 6``): 1.34 /
1.22 s per step before, 1.31 / 1.44 s after (within the noise; the same machine measured 0.87–1.12 s in the
previous session). Goal 0.2 s: not met.

Thirty-eighth session: ``ChainOptions.joint_levers`` = "mean" is the default (the joint impulses at the levers averaged
over each body's rotation, solved to the root per fibre: no energy gain of the plain step). Its Newton now uses
forward differences, keeps each fibre's Jacobian factors across calls and steps, and runs the start levers' kernel
only for fibres where it fails. This command, alternated: 1.91 / 1.72 s per step against 1.85 / 1.74 s with ``--set
joint_levers='"start"'`` (joint stage 0.15–0.16 against 0.06–0.07 s; 17.2 k against 17.3 k active contacts, max
joint gap 0.160 against 0.162 µm, max penetration 115 against 117 µm). Goal 0.2 s: not met.

Thirty-ninth session. Where a resting step goes now (t = 1.005 s, wrappers around the calls): the three contact solves
≈ 0.8–0.9 s (20 + 30 + 30 sweeps of ≈ 9.5 ms over ≈ 207 k rows and candidates and the chains of 355 fibres), the
post-stabilisation 0.37–0.38 s (its projection 0.20 s: 30 sweeps over ≈ 43 k rows of 352 fibres, > 90 % of its
≈ 1,000 deep rows on segments 0–3, the pinched root bundle; two evaluations of the end rows 0.17 s), detection 0.13 s,
joints 0.11 s. Changed: the post-stabilisation's projection stores its arrays in float32 like the contact solves
(``kernel_precision``) and the joint-neighbour crossing check skips ``np.isin`` where no pair flipped (it hashed all
row keys, 20 ms per call): post-stabilisation 0.29 s. This command alternated with the session's start tree (b13ad32,
a worktree): 1.63 / 1.38 against 1.82 / 1.79 s per step, the same overlaps. Measured, not kept: the last pass's
velocity solve captured at t = 1.003 s and replayed with other caps, against 400 sweeps (whose last full sweep still
changes an impulse by 0.012 m/s): the point-speed error away from segments 0–4 is p99 1.22e-2 / 1.03e-2 / 6.8e-3 /
4.1e-3 m/s after 10 / 30 / 60 / 100 sweeps (median 9.9e-4 / 6.4e-4 / 4.0e-4 / 2.5e-4; median point speed 5.3e-2 m/s,
the anisotropic strand still slides at t = 1 s); the Gauss–Seidel stagnates, so fewer sweeps lose little per step,
but ``--set qp_iterations=10`` ran 1.40 s per step (extensions to 20 sweeps) with 642 overlaps > 10 µm next to the
roots against 295. Goal 0.2 s: not met.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np


# ChainOptions of --floor: every contact solve capped at one sweep (a promotion at the cap may add one), no root sweeps
FLOOR_OPTIONS = {"qp_iterations": 1, "predictor_sweeps": 1, "push_out_sweeps": 1, "root_sweeps": 0}


def overlap_summary(scene, state, root_segments: int = 5) -> str:
    """The fibre–fibre overlaps (r_a + r_b − centre-line distance) of ``state``, next to the roots (either segment
    within ``root_segments`` of its root) and elsewhere: how many exceed 1 and 10 µm, their 99th percentile and
    largest. ``StepStats.max_penetration`` is the largest overlap alone, which the pinched root bundle sets at
    rest; these counts show the rest of the strand (with the contact solves cut to one sweep it hides 50 × more
    overlaps above 10 µm away from the roots behind the same largest one, twenty-seventh session). An overlap here
    is at most r_a + r_b (a pair that passed through reads as its distance on the far side); ``max_penetration``
    also counts the depth of a row whose normal the solver holds (``ChainOptions.persistent_normals``)."""
    from headsim.collide.fibre_bvh import fibre_self_contacts
    from headsim.collide.fibres import FibreSet
    from headsim.solvers.chains import polylines_from_state

    P = polylines_from_state(scene.model, state)
    F, n1 = P.shape[0], P.shape[1]
    fc = fibre_self_contacts(FibreSet(P.reshape(-1, 3), np.arange(F + 1) * n1, scene.model.radius))
    fibre = ~fc.obstacle
    depth = fc.depth[fibre]
    root = np.minimum(fc.segment_a[fibre] % (n1 - 1), fc.segment_b[fibre] % (n1 - 1)) < root_segments

    def summary(d):
        if not len(d):
            return "none"
        return (f"{int((d > 1e-6).sum())} > 1 µm, {int((d > 1e-5).sum())} > 10 µm, 99 % {np.quantile(d, 0.99) * 1e6:.1f} "
                f"µm, largest {d.max() * 1e6:.1f} µm")

    return (f"fibre overlaps at the end: next to the roots (segments < {root_segments}) {summary(depth[root])}; "
            f"elsewhere {summary(depth[~root])}")


def _per_step(phases, steps) -> str:
    """The phase times summed over ``steps`` steps (``_time``) as "name seconds-per-step, …"."""
    return ", ".join(f"{k} {v / steps:.4f}" for k, v in phases.items())


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
        counts.setdefault("qp_sweeps", []).append(st.qp_sweeps)
        counts.setdefault("qp_capped", []).append(st.qp_capped)
        counts.setdefault("max_joint_gap", []).append(st.max_joint_gap)
        counts.setdefault("kinetic_energy", []).append(st.kinetic_energy)
        counts.setdefault("substeps", []).append(st.substeps)
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
    ap.add_argument("--coupled-only", action="store_true",
                    help="time the coupled solver only (the per-body stages take minutes per step at full size)")
    ap.add_argument("--geometry", choices=("derived", "former"), default="derived",
                    help="sphere-helical geometry: the default derived from Table 8.1, or the former ringlet start "
                         "(HelicalSphereGeometry.former(), in contact with itself from the first steps)")
    ap.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                    help="ChainOptions override (Python literal), e.g. --set joint_gap_fraction=1.0")
    ap.add_argument("--fibre-spacing", type=float, default=None, metavar="M",
                    help="lattice spacing of the strand's fibres, m (build_drape_scene's fibre_spacing; default "
                         "1.5 diameters); a --state must come from a scene of the same spacing (its roots)")
    ap.add_argument("--floor", action="store_true",
                    help="also time the coupled step from the same state with every contact solve capped at one "
                         "sweep and no root sweeps (FLOOR_OPTIONS): what the step costs without its iteration (a system "
                         "small enough for ChainOptions.sweep_budget still runs its budget in the last pass)")
    ap.add_argument("--state", metavar="FILE.npz",
                    help="start from a saved state (drape_states.py) instead of the scene's start")
    ap.add_argument("--save-state", metavar="FILE.npz",
                    help="write the state reached after the warm-up and --settle steps (drape_states.py)")
    args = ap.parse_args()
    if args.save_state and not os.path.isdir(os.path.dirname(os.path.abspath(args.save_state))):
        ap.error(f"--save-state: no directory for {args.save_state}")  # before the settle steps, not after them
    import ast

    import numba

    from drape_states import load_state, save_state

    from headsim.errors import ParameterError
    from headsim.hair.drape import HelicalSphereGeometry, build_drape_scene
    from headsim.solvers.chains import ChainSolver

    overrides = {}
    for kv in args.set:
        k, v = kv.split("=", 1)
        overrides[k] = ast.literal_eval(v)
    geometry = HelicalSphereGeometry.former() if args.geometry == "former" else None
    print(f"geometry {args.geometry}, option overrides {overrides}")

    print(f"load average {os.getloadavg()}, numba threads {numba.get_num_threads()}")
    timed = {}
    for coupling in ("coupled",) if args.coupled_only else ("coupled", "per-body"):
        try:  # impossible --fibre-spacing or --set values: a usage error (exit 2), not a traceback
            scene = build_drape_scene("sphere-helical", args.friction, n_fibres=args.fibres, segments=args.segments,
                                      geometry=geometry, contact_coupling=coupling, fibre_spacing=args.fibre_spacing,
                                      **overrides)
        except ParameterError as e:
            ap.error(str(e))
        solver = ChainSolver(scene.options)
        state = load_state(args.state, scene.model) if args.state else scene.state
        t0 = time.perf_counter()
        state, _, _, _, _ = _time(solver, scene, state, 2)  # compile / warm up
        print(f"[{coupling}] warm-up (incl. compile) {time.perf_counter() - t0:.1f} s")
        state, _, _, _, _ = _time(solver, scene, state, args.settle)
        if args.save_state and coupling == "coupled":
            print(f"[{coupling}] state at t = {state.time:.3f} s saved to {save_state(args.save_state, state)}")
        state_b, wall, cpu, phases, nc = _time(solver, scene, state, args.steps)
        timed[coupling] = (wall, cpu)
        # the row counters are kept by the coupled stage only (the per-body mode has no candidate rows)
        rows = (f", rows {nc['contact_rows']:.0f} (candidates {nc['candidate_rows']:.0f}, added in the solves "
                f"{nc['promoted_rows']:.0f})") if coupling == "coupled" else ""
        print(f"[{coupling}] {scene.model.n_segments} segments, t = {state.time:.3f} s, mean active contacts "
              f"{nc['contacts']:.0f}{rows}, max penetration {nc['max_penetration']:.3e} m, "
              f"kinetic energy {nc['kinetic_energy']:.4e} J, max joint gap {nc['max_joint_gap']:.3e} m, "
              f"Gauss–Seidel sweeps (largest solve) {nc['qp_sweeps']:.0f}, solves per step ending at the sweep "
              f"cap {nc['qp_capped']:.1f}, solver steps per step {nc['substeps']:.2f} (ChainOptions.step_halvings)")
        print(f"[{coupling}] batched: {wall:.4f} s/step wall, {cpu:.4f} s/step CPU; phases (s/step): "
              + _per_step(phases, args.steps))
        if coupling == "coupled":
            print(f"[{coupling}] {overlap_summary(scene, state_b)}")
            if args.floor:
                floor = ChainSolver(replace(scene.options, **FLOOR_OPTIONS))
                fstate, _, _, _, _ = _time(floor, scene, state, 2)  # its own warm-up from the timed run's start
                fend, fw, fc, fph, fnc = _time(floor, scene, fstate, args.steps)
                print(f"[floor] one sweep per contact solve "
                      f"({', '.join(f'{k}={v}' for k, v in FLOOR_OPTIONS.items())}): {fw:.4f} s/step wall, "
                      f"{fc:.4f} s/step CPU = {fw / wall:.2f} of the step above; phases (s/step): "
                      + _per_step(fph, args.steps) + f"; max penetration {fnc['max_penetration']:.3e} m")
                print(f"[floor] {overlap_summary(scene, fend)}")
        if coupling == "per-body":
            loop = ChainSolver(scene.options, fibre_loop=True)
            loop._bvh = None
            _, lw, lc, lph, _ = _time(loop, scene, state, args.loop_steps)
            print(f"[{coupling}] one fibre at a time: {lw:.4f} s/step wall, {lc:.4f} s/step CPU; phases (s/step): "
                  + _per_step(lph, args.loop_steps))
            print(f"[{coupling}] speed-up batched vs loop: {lw / wall:.1f}x wall, {lc / cpu:.1f}x CPU")
            cw, cc = timed["coupled"]
            print(f"[coupled] time per step / per-body loop's: {cw / lw:.2f} wall, {cc / lc:.2f} CPU "
                  "(coupled timed on its own trajectory)")
        print(f"[{coupling}] goal <= 0.2 s/step: {'met' if wall <= 0.2 else 'NOT met'} (wall)")


if __name__ == "__main__":
    main()
