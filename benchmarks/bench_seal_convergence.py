"""Mesh convergence of the least sealing strap force (issue 6): nasal-M on the bundled neutral face.

Run:  python benchmarks/bench_seal_convergence.py [--quick] [--nonlinear] [--leak-threshold L/min]

For each resolution -- the cushion's spacing along the outline (``edge_length``), across its
cross-section (``section_edge``), the rows of its rounded r = 3 mm corner (``corner_segments``; "old"
= the original rows 0, r/2, r) and the skin (the bundled face as it is, 2.8 mm median edge, or
midpoint-subdivided once, 1.4 mm: the same polyhedral surface, finer) -- it runs the least-seal-force
search (``headsim.mask.least_seal_force``, default SearchOptions: 10 N start, 1-60 N, tolerance
max(0.5 N, 5 %)) in the condensed linear mode, and with ``--nonlinear`` also the nonlinear search
(10-30 N, as benchmarks/bench_mask.py) for the outline/section/corner rows on the unrefined skin.
Prints the seal force (or the largest leaking force when the search stops without a seal), the
least force whose leak-flow estimate is acceptable (<= ``--leak-threshold``, default the clinical
24 L/min, :mod:`headsim.mask.leak`; a smaller one, e.g. 1 L/min, makes it discriminate) with the
leak at the forces the search solved at 10 and 20 N, fits, wall and CPU time, and the time of each row against the first (the default mesh), measured in this
process. The table it printed is recorded in :mod:`headsim.mask.fit` ("Mesh convergence").
"""

from __future__ import annotations

import argparse
import os
import time

FULL = [  # (outline mm, section mm, corner segments or None, skin subdivisions)
    (4.0, 4.0, None, 0), (4.0, 4.0, 4, 0), (3.0, 3.0, None, 0), (3.0, 3.0, 4, 0), (2.0, 4.0, 4, 0),
    (2.0, 2.0, None, 0), (2.0, 2.0, 4, 0), (1.5, 1.5, 4, 0),
    (4.0, 4.0, None, 1), (4.0, 4.0, 4, 1), (2.0, 4.0, 4, 1), (2.0, 2.0, None, 1), (2.0, 2.0, 4, 1),
]
QUICK = [(4.0, 4.0, None, 0), (4.0, 4.0, 4, 0), (2.0, 4.0, 4, 0), (4.0, 4.0, 4, 1)]


def _answer(res) -> str:
    strict = (f"seals at {res.seal_force:6.2f} N" if res.seal_force is not None
              else f"no seal, leaks at {res.lower_bound} N ({res.status})")
    leak = {c.force: c.leak_flow_lpm for c in res.curve}
    at = ", ".join(f"{leak[f]:.2f} L/min at {f:g} N" for f in (10.0, 20.0) if f in leak)
    acc = (f"leak acceptable from {res.leak_force:.2f} N ({res.leak_status})" if res.leak_force is not None
           else f"leak not acceptable up to {res.leak_lower_bound} N")
    return f"{strict}; {acc}; {at}"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="4 resolutions instead of 13")
    ap.add_argument("--nonlinear", action="store_true", help="also the nonlinear search on the unrefined skin")
    ap.add_argument("--leak-threshold", type=float, default=24.0, help="acceptable leak, L/min (default 24)")
    args = ap.parse_args(argv)

    from headsim.data import face_path
    from headsim.errors import HeadsimError
    from headsim.mask import find_landmarks, make_mask
    from headsim.mask.fit import FitOptions, prepare_fit
    from headsim.mask.search import SearchOptions, least_seal_force
    from headsim.mesh.io import load_surface
    from headsim.mesh.subdivide import subdivide_midpoint

    print(f"bench_seal_convergence: {os.cpu_count()} CPUs visible; load average {os.getloadavg()[0]:.1f}")
    face = load_surface(face_path("neutral"))
    landmarks = find_landmarks(face)
    faces = {0: face, 1: subdivide_midpoint(face)}
    base = None
    for outline, section, corner, sub in (QUICK if args.quick else FULL):
        mask = make_mask("nasal-M", edge_length=outline * 1e-3, section_edge=section * 1e-3, corner_segments=corner)
        t, c = time.perf_counter(), time.process_time()
        problem = prepare_fit(faces[sub], mask, FitOptions(leak_threshold_lpm=args.leak_threshold), landmarks=landmarks)
        label = (f"outline {outline:3.1f} mm, section {section:3.1f} mm, corner {corner or 'old':>3}, skin "
                 f"{'1.4' if sub else '2.8'} mm ({len(problem.crop_face_ids)} skin / {mask.tetmesh.n_vertices} "
                 f"cushion vertices)")
        try:
            res = least_seal_force(problem, SearchOptions(), mode="condensed")
            answer = f"{_answer(res)}, {res.n_solves} fits"
        except HeadsimError as e:
            answer = f"failed: {str(e)[:120]}"
        wall, cpu = time.perf_counter() - t, time.process_time() - c
        base = base or wall
        print(f"condensed  {label}: {answer}; {wall:.1f} s wall ({cpu:.1f} s CPU, {wall / base:.2f} x the first row, "
              f"load {os.getloadavg()[0]:.1f})", flush=True)
        if args.nonlinear and sub == 0:
            t, c = time.perf_counter(), time.process_time()
            try:
                res = least_seal_force(problem, SearchOptions(start=10.0, maximum=30.0, abs_tol=0.5))
                answer = f"{_answer(res)}, {res.n_solves} fits" + (f", failed: {res.failures[0][:120]}"
                                                                   if res.failures else "")
            except HeadsimError as e:
                answer = f"failed: {str(e)[:120]}"
            print(f"nonlinear  {label}: {answer}; {time.perf_counter() - t:.1f} s wall "
                  f"({time.process_time() - c:.1f} s CPU)", flush=True)


if __name__ == "__main__":
    main()
