"""Benchmark / slow check: the seed's horizontal ribbon at full size (Sobottka 2008 §8.6.1, Fig. 8.8).

500 fibres × 40 segments × 30 cm (70 µm, 2.2 r apart: a 3.84 cm wide ribbon), fixed at one end, 2 mm above
a sphere centred under the ribbon's midline, Δt = 1 ms, for ``--duration`` s (default 0.6 s, the scene's).
The seed: "Die Berechnung der Reibung verhindert ein Abrutschen der Fasern von der Kugeloberfläche" (with
friction the fibres stay on the sphere); without friction the arrangement splits into two portions of
different size that fall down to the right and the left of the sphere. It does not state the sphere, the
drop or the ribbon's width. Checked as assertions with :mod:`headsim.hair.drape_checks` at each fibre's middle
node (the exit status is 1 when one fails; thresholds are the fibre's own size and the ribbon's, not fitted):

* **none** (frictionless): every middle node stays on its start side of the midline in every frame while it is on
  the sphere's upper half, no farther from it than the ribbon started (two portions, left and right; a fibre that
  slid off swings in the air and under the sphere), and every one gets farther from the midline on that side than
  it started by more than half the ribbon's width (the portions end farther apart than the ribbon was wide).
  Printed: how many middle nodes went below the sphere's equator.
* **with friction** (``--friction``, default iso, μ = 0.47, the seed's only value): at the end every fibre's
  middle segments touch the sphere (within 2 r of its surface) and no middle node moved sideways by more than a
  fibre diameter (2 r) over the last 0.08 s.

``--sphere-radius`` (default the scene's :data:`~headsim.hair.drape.RIBBON_SPHERE_RADIUS`, 6 cm) shows how the
outcome with friction depends on that unstated sphere; ``--fibres`` / ``--segments`` reduce the scene.

Usage: python benchmarks/bench_drape_ribbon.py [--fibres 500] [--segments 40] [--duration 0.6]
       [--friction iso [aniso ...]] [--sphere-radius 0.06] [--no-frictionless]

Measured (issue 10, thirty-ninth session, 2 cores, 0.38–0.53 s per step, ≈ 4–5 min per mode at 0.6 s):

* R = 6 cm (the scene's default), iso: FAIL. 382 of 500 middle sections touch the sphere at the end; 140 middle
  nodes still move sideways (up to 34 mm in 0.08 s), all of fibres that start 13.9–19.2 mm from the midline, and
  112 went below the equator. Why: on landing each fibre slides along its own axis over the sphere (the tip side
  falls, the anchored root side pulls taut); Coulomb friction opposes the sliding velocity, so while a fibre
  slides lengthwise it hardly resists the sideways pull z/R of the slope, and the ribbon drifts outward (the
  edge fibre 19.2 → 22 mm by 0.04 s). Beyond z = R sin(arctan 0.47) = 25.5 mm the slope is steeper than the
  friction angle and the edge fibres slide off. The same run (to 0.32 s) with fibre contacts off gives the
  sampled fibres' middle-node tracks to 0.5 mm (each fibre does it alone).
* R = 8 cm, iso: PASS (all 500 touch the sphere, the largest sideways motion over the last 0.08 s 0.01 mm; the
  edge fibres drift 19.2 → 24.2 mm, z/R = 0.30 < 0.43, and stop); aniso: FAIL (across the fibre axis μ = 0.21,
  friction angle 11.9°: 366 still moving, those starting 5.0–19.2 mm out, 310 below the equator).
* none at R = 6 and 8 cm: every middle node moves outward on its side by 47 (R = 6) / 24 (R = 8) mm at least,
  against the half width 19.2 mm (PASS; 500 / 494 below the equator). The side check of these runs was the
  former, stricter one (every frame above the sphere's centre, in the air too) and failed: fibres that slid off
  lengthwise swing in the air over the sphere's far side and cross the midline there. With the check as stated
  above (on the sphere's upper half within the start's distance of its surface) the full-size frictionless runs
  were not repeated; the 0.32 s recordings of both radii keep their sides. Largest penetrations of the
  frictionless runs 434 / 484 µm (aniso R = 8: 494 µm; iso 199 / 29 µm): not examined.

So the seed's "with friction the fibres stay" holds at full size only on a sphere large enough for the landing
drift, which the seed does not state; the scene keeps 6 cm (the reduced ribbon of the tests is unchanged).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

SIDEWAYS_WINDOW = 0.08  # s, the rest test's window (the reduced ribbon of the tests uses the same)


def run(mode, args):
    """Run the ribbon with friction ``mode`` (its time per step and largest penetration printed); returns (scene,
    result)."""
    from headsim.hair.drape import build_drape_scene, run_drape

    sc = build_drape_scene("sphere-horizontal", mode, n_fibres=args.fibres, segments=args.segments,
                           duration=args.duration, sphere_radius=args.sphere_radius)
    every = max(1, int(round(0.02 / sc.dt)))
    report = max(1, sc.n_steps // 10)
    w = time.perf_counter()

    def progress(i, n):  # minutes per mode at full size
        if i % report == 0 or i == n:
            print(f"[{mode}] step {i}/{n} (t = {i * sc.dt:.3f} s), {time.perf_counter() - w:.0f} s wall", flush=True)

    res = run_drape(sc, record_every=every, progress=progress)
    per_step = (time.perf_counter() - w) / sc.n_steps
    print(f"[{mode}] {sc.description}")
    print(f"[{mode}] {sc.n_steps} steps, {per_step:.3f} s per step wall, load {os.getloadavg()[0]:.2f}; largest "
          f"penetration {1e6 * res.max_penetration.max():.1f} µm, "
          f"max joint gap {1e6 * res.max_joint_gap.max():.2f} µm")
    return sc, res


def frictionless_checks(m) -> dict[str, tuple[str, bool]]:
    """The seed's split, measured (:class:`~headsim.hair.drape_checks.RibbonMeasures` ``m``)."""
    width, last = m.spread()
    exc = m.excursion()
    return {
        "every middle node stays on its start side of the midline on the sphere's upper half":
            (f"{m.sides_kept()}", m.sides_kept()),
        "every one moves outward on its side by more than half the ribbon's width":
            (f"least {exc.min() * 1e3:.2f} mm against {0.5 * width * 1e3:.2f} mm "
             f"(median {np.median(exc) * 1e3:.1f} mm, "
             f"spread {width * 1e3:.1f} → {last * 1e3:.1f} mm; {int(m.slid_off().sum())} of {len(exc)} below the "
             "sphere's equator)", bool(exc.min() > 0.5 * width)),
    }


def friction_checks(m, r: float) -> dict[str, tuple[str, bool]]:
    """The seed's "fibres stay on the sphere", measured (``m`` as above; r the fibre radius, m)."""
    gap = np.abs(m.contact_gap)
    side = m.sideways(SIDEWAYS_WINDOW)
    z0 = np.abs(m.middle[0, :, 2])
    moving = side > 2 * r
    where = (f"; those start {z0[moving].min() * 1e3:.1f}–{z0[moving].max() * 1e3:.1f} mm from the midline (the "
             f"ribbon's half width {z0.max() * 1e3:.1f} mm)") if moving.any() else ""
    return {
        "every fibre's middle segments touch the sphere at the end (within 2 r)":
            (f"{int((gap < 2 * r).sum())} of {len(gap)} (largest {gap.max() * 1e3:.2f} mm)", bool((gap < 2 * r).all())),
        f"no middle node moves sideways by more than 2 r over the last {SIDEWAYS_WINDOW:g} s":
            (f"{int(moving.sum())} do (largest {side.max() * 1e3:.2f} mm){where}; "
             f"{int(m.slid_off().sum())} below the sphere's equator", bool(not moving.any())),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fibres", type=int, default=500)
    ap.add_argument("--segments", type=int, default=40)
    ap.add_argument("--duration", type=float, default=0.6)
    ap.add_argument("--friction", nargs="+", default=["iso"], choices=("iso", "aniso"))
    ap.add_argument("--sphere-radius", type=float, default=None, metavar="M")
    ap.add_argument("--no-frictionless", action="store_true", help="skip the frictionless run")
    args = ap.parse_args(argv)
    if not args.duration > 2 * SIDEWAYS_WINDOW:
        ap.error(f"--duration must exceed {2 * SIDEWAYS_WINDOW:g} s (landing, then the rest test's window)")
    from headsim.errors import ParameterError
    from headsim.hair.drape_checks import ribbon_measures

    failed = []
    for mode in ([] if args.no_frictionless else ["none"]) + list(args.friction):
        try:
            sc, res = run(mode, args)
        except ParameterError as e:
            ap.error(str(e))
        m = ribbon_measures(sc, res)
        checks = frictionless_checks(m) if mode == "none" else friction_checks(m, float(sc.model.radius[0]))
        for name, (value, ok) in checks.items():
            print(f"[{mode}] {'PASS' if ok else 'FAIL'}  {name}: {value}")
            if not ok:
                failed.append(f"{mode}: {name}")
    print("all checks pass" if not failed else f"{len(failed)} check(s) failed: " + "; ".join(failed))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
