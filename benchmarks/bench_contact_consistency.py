"""Geometric consistency of the nonlinear mask fit's contact (issue 6 follow-up, the leak question).

Run:  python benchmarks/bench_contact_consistency.py [--forces 15,30] [--no-rotate]
      [--tissue-thickness 0.01] [--tissue-modulus 30e3]

Demo configuration (nasal-M at the CLI's 4 mm, bundled neutral face), fits in ascending force, each
warm-started from the previous. For each fit: the strict seal answer and leak estimate, and
:func:`headsim.mask.contact_check.contact_consistency` -- skin vertices inside the cushion (and the
penalty force on their true depths, as a ratio to the strap force: 1 for a consistent penalty
contact), skin vertices with contact pressure outside the cushion ("phantom" contact, and the
fraction of the strap force they carry: 0 for a consistent contact), cushion vertices inside the
skin. The options let the tissue / pitch hypotheses of the issue be checked with the same numbers.
"""

from __future__ import annotations

import argparse
import os
import time


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--forces", default="15,30")
    ap.add_argument("--no-rotate", action="store_true", help="FitOptions(rotate=False)")
    ap.add_argument("--tissue-thickness", type=float, default=0.01, help="m")
    ap.add_argument("--tissue-modulus", type=float, default=30e3, help="Pa")
    args = ap.parse_args(argv)

    from headsim.data import face_path
    from headsim.errors import HeadsimError
    from headsim.mask import find_landmarks, make_mask
    from headsim.mask.contact_check import contact_consistency
    from headsim.mask.fit import FitOptions, prepare_fit, problem_fit
    from headsim.mesh.io import load_surface

    print(f"bench_contact_consistency: {os.cpu_count()} CPUs visible; load average {os.getloadavg()[0]:.1f}")
    face = load_surface(face_path("neutral"))
    opts = FitOptions(rotate=not args.no_rotate, tissue_thickness=args.tissue_thickness,
                      tissue_modulus=args.tissue_modulus)
    problem = prepare_fit(face, make_mask("nasal-M", edge_length=4e-3), opts, landmarks=find_landmarks(face))
    print("force N | strict | leak L/min | inside: n, max depth mm, true-depth force / F | "
          "phantom: n, max gap mm, force / F | cushion in skin: n, max mm | fit s wall (CPU)")
    prev = None
    for f in (float(v) for v in args.forces.split(",")):
        t, c = time.perf_counter(), time.process_time()
        try:
            r = problem_fit(problem, f, warm_start=prev)
        except HeadsimError as e:
            print(f"{f:7.3f} | failed: {str(e)[:100]}")
            continue
        wall, cpu = time.perf_counter() - t, time.process_time() - c
        prev = r.state
        k = contact_consistency(problem, r)
        print(f"{f:7.3f} | {'sealed' if r.sealed else 'leaks':6s} | {r.leak.flow_lpm:6.2f} | "
              f"{k.n_inside:4d}, {k.max_inside_depth * 1e3:5.2f}, {k.true_depth_force / f:6.2f} | "
              f"{k.n_phantom:4d}, {k.max_phantom_gap * 1e3:5.2f}, {k.phantom_force / f:5.2f} | "
              f"{k.n_cushion_in_skin:4d}, {k.max_cushion_in_skin_depth * 1e3:5.2f} | {wall:5.2f} ({cpu:.2f})", flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
