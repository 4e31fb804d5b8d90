"""Benchmark / slow check: the reference scene's bounding-box volume (Sobottka 2008 §8.6.2, §8.6.5.2).

Two statements of the seed, checked on ``sphere-helical`` (355 × 100 at full size; reduce with
``--fibres`` / ``--segments``, Δt = 1 ms and the 30 cm fibres are kept):

* **Table 8.1** (friction models at t ≈ 0.7 s, axis-aligned bounding box): volumes relative to the
  anisotropic run 0.99 (isotropic μ = 0.47), 1.00 (anisotropic), 0.91 (none). Checked as
  none/aniso < 0.95, none/iso < 0.95 and |iso/aniso − 1| < 0.05: 0.95 is half-way between the seed's
  0.91 and 0.99–1.00, i.e. the threshold that tells its two groups apart, not a fit to our numbers.
* **"stable volume"** (the arrangement stays stacked, "volume constancy shows that tunnelling is
  largely eliminated", at rest "after a few seconds"): over the last ``--window`` seconds the
  bounding-box volume varies by less than 5 % of its mean (again half the seed's friction/no-friction
  difference: a change the table could not resolve) while the kinetic energy has fallen below 1/100 of
  its peak.

``--no-fibre-contacts`` runs the broken variant (fibre–fibre contacts off) to show what a failing
volume looks like. Prints the volume trace, the ratios and PASS / FAIL per statement, with CPU and
wall time and the load average.

Measured (19 × 30 reduced scene, load 4–6): neither statement holds for the scene as built. The strand
hangs from roots 12 cm above the sphere, its free 18 cm swing as a pendulum damped only by contact
friction, and the box swings with it: 2,000–10,000 cm³ within 0.2 s, still 69–128 % over the last
0.2 s of 1.2 s with the kinetic energy at ≈ 1 % of its peak; at 0.7 s iso/aniso 1.33, none/aniso 0.88.
With ``--rest-shape initial`` the strand bounces as a spring (46–136 %). The seed's box (8.7 × 14.1 ×
8.4 cm for 30 cm fibres, diagonal 18.5 cm) means its fibres lay folded on the sphere with the roots
within ≈ 8 cm of the lowest point; ours is 28 cm tall. The scene geometry (not stated by the seed) is
the open question, not the thresholds.

Usage: python benchmarks/bench_drape_volume.py [--fibres 355] [--segments 100] [--duration 0.7]
       [--modes aniso,iso,none] [--window 0.2] [--rest-shape straight|initial] [--no-fibre-contacts]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

# the seed's Table 8.1, relative to the anisotropic volume (the header's "%" is a fraction)
SEED_RATIO = {"iso": 0.990, "aniso": 1.000, "none": 0.906}
GROUP_THRESHOLD = 0.95  # half-way between 0.91 and 0.99
STABLE_FRACTION = 0.05  # half the seed's 9 % friction / no-friction difference


def run(mode, args):
    from headsim.hair.drape import bounding_box, build_drape_scene, run_drape

    kw = dict(fibre_contacts=False) if args.no_fibre_contacts else {}
    sc = build_drape_scene("sphere-helical", mode, n_fibres=args.fibres, segments=args.segments,
                           duration=args.duration, rest_shape=args.rest_shape, **kw)
    every = max(1, int(round(args.record / sc.dt)))
    w, c = time.perf_counter(), time.process_time()
    res = run_drape(sc, record_every=every)
    w, c = time.perf_counter() - w, time.process_time() - c
    boxes = [bounding_box(p) for p in res.polylines]
    ext = np.array([b[0] for b in boxes])
    vol = np.array([b[1] for b in boxes])
    print(f"[{mode}] {sc.model.n_fibres} x {sc.model.n_segments // sc.model.n_fibres}, {sc.n_steps} steps: "
          f"{w:.1f} s wall, {c:.1f} s CPU, load {os.getloadavg()[0]:.2f}")
    for t, v, e in zip(res.times[::max(1, len(vol) // 15)], vol[::max(1, len(vol) // 15)],
                       ext[::max(1, len(vol) // 15)]):
        print(f"   t = {t:.2f} s  V = {v * 1e6:9.2f} cm³  extent {np.round(e * 100, 2)} cm")
    return res, vol, ext


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fibres", type=int, default=355)
    ap.add_argument("--segments", type=int, default=100)
    ap.add_argument("--duration", type=float, default=0.7)
    ap.add_argument("--modes", default="aniso,iso,none")
    ap.add_argument("--window", type=float, default=0.2)
    ap.add_argument("--record", type=float, default=0.01, help="recording interval, s")
    ap.add_argument("--rest-shape", default="straight", choices=("straight", "initial"))
    ap.add_argument("--no-fibre-contacts", action="store_true")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()}")
    final = {}
    for mode in args.modes.split(","):
        res, vol, ext = run(mode, args)
        final[mode] = vol[-1]
        win = res.times >= res.times[-1] - args.window - 1e-12
        spread = (vol[win].max() - vol[win].min()) / vol[win].mean()
        ke_ratio = res.kinetic[-1] / max(res.kinetic.max(), 1e-300)
        ok = spread < STABLE_FRACTION and ke_ratio < 1e-2
        print(f"[{mode}] final extent {np.round(ext[-1] * 100, 2)} cm, V = {vol[-1] * 1e6:.2f} cm³; over the last "
              f"{args.window:g} s the volume varies by {100 * spread:.1f} % (< {100 * STABLE_FRACTION:g} %), kinetic "
              f"energy at {ke_ratio:.2e} of its peak (< 1e-2): stable volume {'PASS' if ok else 'FAIL'}")
    if {"aniso", "iso", "none"} <= final.keys():
        a, i, n = final["aniso"], final["iso"], final["none"]
        print(f"Table 8.1 at t = {args.duration:g} s: iso/aniso {i / a:.3f} (seed {SEED_RATIO['iso']:.2f}), "
              f"none/aniso {n / a:.3f} (seed {SEED_RATIO['none']:.2f}), none/iso {n / i:.3f}")
        checks = {"none/aniso < 0.95": n / a < GROUP_THRESHOLD, "none/iso < 0.95": n / i < GROUP_THRESHOLD,
                  "|iso/aniso - 1| < 0.05": abs(i / a - 1) < 1 - GROUP_THRESHOLD}
        for k, v in checks.items():
            print(f"   {k}: {'PASS' if v else 'FAIL'}")


if __name__ == "__main__":
    main()
