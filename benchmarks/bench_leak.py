"""Leak flow vs strap force on the demo configuration (nasal-M, bundled neutral face, CLI defaults).

Run:  python benchmarks/bench_leak.py [--forces 2.5,5,10,...] [--condensed]

For each force (ascending, each fit warm-started from the previous one, as the seal-force search
does): the strict seal answer, the leak-flow estimate of :mod:`headsim.mask.leak` (L/min; its
viscous film flow and the orifice bound), the number of leak channels, the largest aperture at
the narrowest cross-section, and the same estimate with the axial skin->cushion gap
(``FitResult.gap``) in place of the closest-point distance -- the check of the aperture choice on
steep skin. Prints the time of the leak estimate against the fit's own solve time, measured in
this process. The table is recorded in :mod:`headsim.mask.fit` ("Leak flow").
"""

from __future__ import annotations

import argparse
import os
import time


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--forces", default="2.5,3.125,5,7.5,10,12.5,15,17.5,20,25,30")
    ap.add_argument("--condensed", action="store_true", help="the condensed linear mode instead of the nonlinear fit")
    args = ap.parse_args(argv)

    from headsim.data import face_path
    from headsim.errors import HeadsimError
    from headsim.mask import find_landmarks, make_mask
    from headsim.mask.fit import FitOptions, prepare_fit, problem_fit
    from headsim.mask.leak import estimate_leak
    from headsim.mesh.io import load_surface

    print(f"bench_leak: {os.cpu_count()} CPUs visible; load average {os.getloadavg()[0]:.1f}")
    face = load_surface(face_path("neutral"))
    # the CLI's mask (headsim demo: --mask-edge 4 mm)
    problem = prepare_fit(face, make_mask("nasal-M", edge_length=4e-3), FitOptions(), landmarks=find_landmarks(face))
    if args.condensed:
        from headsim.mask.condensed import condense_fit, condensed_fit

        cf = condense_fit(problem)

        def fitter(_p, f, warm_start=None):
            return condensed_fit(cf, f)
    else:
        fitter = problem_fit
    o = problem.options
    prev = None
    print("force N | strict  | leak L/min (viscous / orifice) | channels | widest gap at cut um | "
          "leak with axial gap | fit s | leak s (CPU)")
    for f in (float(x) for x in args.forces.split(",")):
        t = time.perf_counter()
        try:
            r = fitter(problem, f, warm_start=prev)
        except HeadsimError as e:
            print(f"{f:7.3f} | failed: {str(e)[:100]}")
            continue
        fit_s = time.perf_counter() - t
        prev = r.state
        c = time.process_time()
        leak = r.leak
        axial = estimate_leak(r.deformed_face, r.deformed_mask, r.pressure, problem.airway, o.therapy_pressure,
                              skin_roughness=o.skin_roughness, gap_cap=o.leak_gap_cap, distance=r.gap)
        leak_cpu = (time.process_time() - c)
        widest = max((ch.max_aperture for ch in leak.channels), default=0.0) * 1e6
        print(f"{f:7.3f} | {'sealed' if r.sealed else 'leaks':7s} | {leak.flow_lpm:8.3f} ({leak.viscous_lpm:9.3g} / "
              f"{leak.orifice_lpm:7.3g}) | {len(leak.channels):3d} | {widest:6.0f} | {axial.flow_lpm:8.3f} | "
              f"{fit_s:5.2f} | {leak.seconds:.2f} ({leak_cpu:.2f} for the axial variant)", flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
