"""Benchmark / slow check: the reference scene's bounding-box volume (Sobottka 2008 §8.6.2, §8.6.5.2).

Two statements of the seed, checked as assertions on ``sphere-helical`` (355 × 100 at full size;
reduce with ``--fibres`` / ``--segments``; Δt = 1 ms and the 30 cm fibres are kept). The scene's
geometry (coil radius, root height, sphere radius) is derived from the seed's own Table 8.1 box, see
``headsim.hair.drape.HelicalSphereGeometry``. The exit status is 1 when an assertion fails.

* **Table 8.1** (friction models at t ≈ 0.7 s, axis-aligned bounding box of all fibre nodes, roots
  included): volumes relative to the anisotropic run 0.99 (isotropic μ = 0.47), 1.00 (anisotropic),
  0.906 (none). Asserted: none/aniso < 0.95, none/iso < 0.95 and |iso/aniso − 1| < 0.05. 0.95 is
  half-way between the seed's 0.91 and 0.99–1.00, i.e. the threshold that tells its two groups apart,
  and 0.05 is half the gap between them; both come from the seed's figures, not from our runs.
* **"stable volume"** (§8.6.2: the strand stays stacked, "volume constancy shows that tunnelling is
  largely eliminated", at rest "after a few seconds"), asserted for the runs with friction (the seed's
  reference scene has friction on; without it §8.6.1 shows fibres sliding off): over the last
  ``--window`` seconds of a run of ``--settle`` seconds, the bounding-box volume varies by less than 5 %
  of its mean (half the seed's 9 % friction / no-friction difference: a change Table 8.1 could not
  resolve) and the kinetic energy of the last step is below 1/100 of its peak. (The frictionless run
  stops at ``--duration``; its stability is printed, not asserted.)

``--no-fibre-contacts`` runs the broken variant (fibre–fibre contacts off) to show what a failing
volume looks like; ``--rest-shape initial`` makes the initial coil the springs' rest shape.

Measured (``--fibres F --segments n``, derived geometry; extents x × y (vertical) × z in cm; volumes at
t = 0.7 s; seed: iso 8.69 × 14.09 × 8.35 = 1,022 cm³, aniso 1,032, none 935):

* rest shape straight (the default): the straightening strand slides over the rim of the sphere and
  hangs down its side; the boxes are 2–5 times the seed's and the frictionless one is the narrowest.

  ========  ======================  ======================  ======================  =====================
  F × n     aniso V / cm³           iso V / cm³             none V / cm³            none/a, none/i, i/a
  ========  ======================  ======================  ======================  =====================
  7 × 30    4,442 (19.5×19.8×11.5)  3,897 (12.2×19.9×16.1)  2,193 (12.3×24.0×7.5)   0.49, 0.56, 0.88
  19 × 30   4,852 (20.2×20.0×12.0)  4,143 (12.9×20.0×16.1)  2,830 (12.4×25.0×9.1)   0.58, 0.68, 0.85
  61 × 50   5,378 (20.1×20.6×13.0)  3,966 (12.5×19.5×16.3)  2,864 (12.5×22.8×10.0)  0.53, 0.72, 0.74
  ========  ======================  ======================  ======================  =====================

  none < aniso and none < iso hold at every size; iso ≈ aniso (within 5 %) fails at every size.
  Stable volume at 1.5 s (range over the last 0.2 s, kinetic energy / peak): iso 0.2 %, 3.9e-4 (7 × 30),
  0.2 %, 2.8e-4 (19 × 30) and 0.2 %, 3.2e-5 (61 × 50): PASS, at rest with the strand 20 cm tall (partly
  over the rim, held by friction); aniso 29 %, 4.0e-2 (7 × 30), 16 %, 1.0e-2 (19 × 30) and 15 %, 1.3e-2
  (61 × 50): FAIL (loops whose root → tip direction points uphill slide down with the scales, μ = 0.13,
  and the strand keeps swinging). Later (issue 10, thirty-first session): run longer, the anisotropic strand
  comes to rest as the seed says ("after a few seconds"): 7 × 30 by 2.5–3.5 s depending on the trajectory (0.5 %,
  7.3e-5 at 2.5 s; with the band grid capped per segment 3.2 %, 1.3e-4 at 3.5 s; asserted at 4 s in
  ``tests/hair/test_drape.py``), 19 × 30 from 3.75 s on (1.6–4.3 % to 7 s, creeping ≈ 1 % per second).
  Why none < friction holds for a different reason than in the seed: on a sphere on which a μ = 0.47
  pile can rest out to the seed's 7 cm rim (slope 25°), a frictionless fibre there accelerates at
  g sin 25° ≈ 4 m/s² and in the ≈ 0.6 s after landing slides until the anchored strand is taut; the
  seed's frictionless box (8.24 cm tall at 0.7 s) means its strand had not slid off, which Moreau
  dynamics on such a sphere does not give.
* rest shape initial (the coil is the springs' rest shape), 19 × 30: aniso 1,849 cm³
  (8.8 × 13.1 × 16.0), iso 475 (7.8 × 7.5 × 8.1, the size of the seed's short sides), none 2,502
  (slides off) → none/aniso 1.35, none/iso 5.3, iso/aniso 0.26: all three FAIL. Stable volume at 1.5 s:
  aniso 0.6 %, 2.9e-5; iso 3.4 %, 2.2e-3: PASS.

Load on the shared 2-core machine 0.4–3.1 during these runs; 19 × 30 takes 17–70 s per mode, 61 × 50
114–293 s per 0.7 s and 425 s per 1.5 s (one thread). Full size (355 × 100, aniso, load 1.0): the start
box is 8.69 × 4.27 × 8.70 cm (the coil's diameter is the seed's short side, as derived); the first 10
steps (free fall) take 1.4 s each (detection 0.46 s, contacts 0.75 s); a 120-step run (through the
landing at ≈ 0.08 s) did not finish within 1,200 s (> 10 s per step, load 1.2–2.0) in the sessions that wrote
the table above. Since then (issue 10, nineteenth session, the solver of that session):

* ``--modes iso`` at full size (``--settle 1.5 --duration 0.7``): 1,500 steps in 2,209 s wall (1.47 s per step on
  average, 4,277 s CPU, load ≈ 2). V = 318 cm³ at t = 0, 783 at 0.1 s, 2,389 at 0.3 s, 4,767 at 0.7 s
  (14.55 × 19.62 × 16.70 cm; seed 1,022), then 4,811–4,849 cm³ from 0.8 s on (14.7 × 20.0 × 16.4 cm at 1.5 s).
  Stable volume: 0.3 % over the last 0.2 s, kinetic energy at 2.8e-5 of its peak: PASS, as at the reduced sizes.
* aniso at full size, stepped by hand from a t = 85 ms state saved in the thirteenth session (the current solver
  from there on; not this script): V = 716 cm³ at 0.085 s, 1,791 at 0.2 s, 5,667 at 0.5 s (19.2 × 19.1 × 15.4 cm),
  6,192 at 0.7 s, 7,041 at 1.0 s, 12,855 at 1.5 s (30.7 × 26.0 × 16.1 cm), still growing: 18 % over 1.3–1.5 s,
  kinetic energy at 2.8e-3 of its peak (the one at landing): stable volume FAIL, as at the reduced sizes. Per step
  1.37 s at t = 0.5–1.0 s and 1.05 s at 1.0–1.5 s; see ``bench_drape.py`` (nineteenth session) for the deep
  overlaps next to the roots that this run shows from t ≈ 0.47 s.
* aniso at full size again, with the solver of the twenty-seventh session, stepped by hand from
  ``benchmarks/data/drape_355x100_aniso_t1.0.npz`` (1,580 steps, ≈ 1.1 s each): V = 5,947 cm³ at 1.01 s, 10,912 at
  1.5 s (21.8 × 24.8 × 20.2 cm), 14,938 at 2.0 s (34.8 × 26.1 × 16.4 cm), 16,680 at 2.5 s and 14,117 at 2.58 s
  (34.1 × 26.5 × 15.6 cm): the strand slides over the sphere's rim (x extent 21 → 34 cm) and its loops keep moving.
  The volume's range over 0.2 s windows is 7.7–51 % from 1.2 s on (28 % over 2.38–2.58 s) while the kinetic energy
  falls to 1.3e-7 J (≈ 6e-4 of the landing peak, estimated from the nineteenth session's ratio at 1.5 s): stable
  volume FAIL by 2.6 s; the creeping loops move with the scales (μ = 0.13) and across them (0.21) on a sphere sized
  for μ = 0.47 (rim slope 25°). The largest joint gap grows with the load the hanging strand puts on the roots: 7.7
  µm at 1.0 s, 28.7 at 1.5 s, 34.9 at 2.0 s, 52.7 at 2.58 s, always at joints 1–3 of the same few fibres (238, 260,
  233, 321, 112) pinched in the root bundle (mean gap there 2–3 µm, elsewhere 0.5–1.5 µm); penetrations 75–125 µm.
* **Table 8.1 at full size** (twenty-eighth session, the solver of that session; the three modes run at once, one
  process each, ``--modes M --duration 0.7 --settle 0.7`` with NUMBA_NUM_THREADS=1 on the 2 cores: 2,429–2,603 s
  wall each, not a timing). Volumes at t = 0.7 s (extents x × y × z):

  ========  ======================  ======================  ======================  ======================
  F × n     aniso V / cm³           iso V / cm³             none V / cm³            none/a, none/i, i/a
  ========  ======================  ======================  ======================  ======================
  355 × 100 6,209 (20.4×20.2×15.0)  5,369 (16.0×20.1×16.7)  5,142 (13.8×24.7×15.1)  0.83, **0.96**, **0.86**
  ========  ======================  ======================  ======================  ======================

  none/aniso < 0.95 holds; none/iso < 0.95 fails (by 0.01) and iso ≈ aniso fails, as at the reduced sizes. No
  mode is at rest at 0.7 s (range over the last 0.2 s: aniso 18.7 %, iso 22.2 %, none 24.6 %; kinetic energy at
  5.2e-2, 2.4e-2, 0.57 of its peak). The frictionless box peaked at 8,129 cm³ (t = 0.40 s, 19.9 × 21.7 × 18.8 cm)
  and then narrowed as the strand slid over the rim (24.7 cm tall at 0.7 s); the frictional ones were still
  growing or swinging. Largest penetration per window of ≈ 47 steps after the landing (t > 0.14 s): iso 29–53 µm,
  aniso 37–228 µm, none 50–466 µm. The earlier iso run (older solver) had 4,767 cm³ at 0.7 s.

Usage: python benchmarks/bench_drape_volume.py [--fibres 355] [--segments 100] [--duration 0.7]
       [--settle 1.5] [--modes aniso,iso,none] [--window 0.2] [--rest-shape straight|initial]
       [--no-fibre-contacts]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

GROUP_THRESHOLD = 0.95  # half-way between the seed's 0.91 (none) and 0.99-1.00 (iso, aniso)
SAME_BAND = 0.05  # |iso/aniso - 1|: half the gap between the seed's two groups
STABLE_FRACTION = 0.05  # half the seed's 9 % friction / no-friction difference
KE_FRACTION = 1e-2


def table_8_1_checks(vol_aniso: float, vol_iso: float, vol_none: float) -> dict[str, tuple[float, bool]]:
    """The seed's ordering none < iso ≈ aniso (Table 8.1) as (ratio, holds) per assertion."""
    a, i, n = vol_aniso, vol_iso, vol_none
    return {"none/aniso < 0.95": (n / a, n / a < GROUP_THRESHOLD),
            "none/iso < 0.95": (n / i, n / i < GROUP_THRESHOLD),
            "|iso/aniso - 1| < 0.05": (i / a, abs(i / a - 1) < SAME_BAND)}


def run(mode, args):
    from headsim.hair.drape import bounding_box, build_drape_scene, run_drape

    kw = dict(fibre_contacts=False) if args.no_fibre_contacts else {}
    sc = build_drape_scene("sphere-helical", mode, n_fibres=args.fibres, segments=args.segments,
                           duration=args.duration if mode == "none" else max(args.duration, args.settle),
                           rest_shape=args.rest_shape, **kw)
    every = max(1, int(round(args.record / sc.dt)))
    w, c = time.perf_counter(), time.process_time()
    report_every = max(1, sc.n_steps // 30)
    stamps = [w]

    def progress(i, n):  # a full-size run takes most of an hour: report every thirtieth of it
        stamps.append(time.perf_counter())
        if i % report_every == 0 or i == n:
            print(f"[{mode}] step {i}/{n} (t = {i * sc.dt:.3f} s), {stamps[-1] - w:.0f} s wall", flush=True)

    res = run_drape(sc, record_every=every, progress=progress)
    w, c = time.perf_counter() - w, time.process_time() - c
    step_wall = np.diff(stamps)
    edges = np.unique(np.linspace(0, len(step_wall), 16).astype(int))
    print(f"[{mode}] per window of steps: simulated time, wall s per step (mean), largest penetration µm, solves "
          "ending at the sweep cap per step")
    for a, b in zip(edges[:-1], edges[1:]):
        print(f"   t = {a * sc.dt:.3f}–{b * sc.dt:.3f} s  {step_wall[a:b].mean():7.3f} s  "
              f"{1e6 * res.max_penetration[a:b].max():7.1f} µm  {res.qp_capped[a:b].mean():.1f}")
    boxes = [bounding_box(p) for p in res.polylines]
    ext = np.array([b[0] for b in boxes])
    vol = np.array([b[1] for b in boxes])
    print(f"[{mode}] {sc.description}")
    print(f"[{mode}] {sc.n_steps} steps: {w:.1f} s wall, {c:.1f} s CPU, load {os.getloadavg()[0]:.2f}")
    stride = max(1, len(vol) // 15)
    for t, v, e in zip(res.times[::stride], vol[::stride], ext[::stride]):
        print(f"   t = {t:.2f} s  V = {v * 1e6:9.2f} cm³  extent (x, y vertical, z) {np.round(e * 100, 2)} cm")
    return res, vol, ext


def main(argv=None) -> int:
    from headsim.hair.drape import SEED_TABLE_8_1, SEED_TABLE_8_1_RATIO, volume_stability

    ap = argparse.ArgumentParser()
    ap.add_argument("--fibres", type=int, default=355)
    ap.add_argument("--segments", type=int, default=100)
    ap.add_argument("--duration", type=float, default=0.7, help="time of the Table 8.1 box, s")
    ap.add_argument("--settle", type=float, default=1.5, help="run length for the stable-volume check, s")
    ap.add_argument("--modes", default="aniso,iso,none")
    ap.add_argument("--window", type=float, default=0.2)
    ap.add_argument("--record", type=float, default=0.01, help="recording interval, s")
    ap.add_argument("--rest-shape", default="straight", choices=("straight", "initial"))
    ap.add_argument("--no-fibre-contacts", action="store_true")
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()}")
    at_table, ok_all = {}, True
    for mode in args.modes.split(","):
        res, vol, ext = run(mode, args)
        k = int(np.argmin(np.abs(res.times - args.duration)))
        at_table[mode] = vol[k]
        seed = SEED_TABLE_8_1[mode]
        print(f"[{mode}] t = {res.times[k]:.2f} s: extent {np.round(ext[k] * 100, 2)} cm, V = {vol[k] * 1e6:.2f} cm³ "
              f"(seed: {seed[0]} × {seed[1]} × {seed[2]} cm, {np.prod(seed):.2f} cm³)")
        spread, ke = volume_stability(res, args.window)
        ok = spread < STABLE_FRACTION and ke < KE_FRACTION
        asserted = mode != "none"
        ok_all &= ok or not asserted
        print(f"[{mode}] over the last {args.window:g} s of {res.times[-1]:.2f} s the volume varies by {100 * spread:.1f} % "
              f"(< {100 * STABLE_FRACTION:g} %), kinetic energy at {ke:.2e} of its peak (< {KE_FRACTION:g}): "
              f"stable volume {'PASS' if ok else 'FAIL'}{'' if asserted else ' (not asserted without friction)'}")
    if {"aniso", "iso", "none"} <= at_table.keys():
        a, i, n = at_table["aniso"], at_table["iso"], at_table["none"]
        print(f"Table 8.1 at t = {args.duration:g} s: iso/aniso {i / a:.3f} (seed {SEED_TABLE_8_1_RATIO['iso']:.2f}), "
              f"none/aniso {n / a:.3f} (seed {SEED_TABLE_8_1_RATIO['none']:.3f}), none/iso {n / i:.3f} (seed "
              f"{SEED_TABLE_8_1_RATIO['none'] / SEED_TABLE_8_1_RATIO['iso']:.3f})")
        for name, (ratio, ok) in table_8_1_checks(a, i, n).items():
            ok_all &= ok
            print(f"   {name}: {ratio:.3f} {'PASS' if ok else 'FAIL'}")
    print("ALL PASS" if ok_all else "FAILED")
    return 0 if ok_all else 1


if __name__ == "__main__":
    sys.exit(main())
