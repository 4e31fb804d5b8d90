"""Benchmark: convergence of the barrier contact's friction loop on the mask fit (issue 6).

Cold fits of nasal-M on the bundled neutral face with the IPC barrier contact and skin-silicone
friction (``FitOptions(contact="barrier", friction=MU)``) at a list of strap forces. Prints, per
force, the outer friction updates, Newton iterations, wall time, leak, pitch, contact area and peak
pressure -- or the ConvergenceError -- for the chosen tangent planes (``--normals``, BarrierContact
``friction_normals``) and outer iteration (``--lag``, ``friction_lag``). With ``--compare`` the
plain lagged iteration and ipctk's planes are run too, in the same process, and the counts of
converged fits are printed side by side.

Usage: python benchmarks/bench_mask_friction.py [--problem demo|coarse] [--mu 0.5]
       [--forces 2.5,8,15,30] [--normals smooth|pair] [--lag adaptive|plain] [--compare]

``--problem demo`` is the demo configuration (4 mm cushion mesh, 1 tissue layer, 8 mm crop;
``bench_mask.py``), ``coarse`` the tests' coarse problem (tests/mask/_fit_case.py: 5 mm analytic
saddle cushion, 6 mm crop). Numbers measured with it are in the docs of
:mod:`headsim.solvers.barrier_friction` and :mod:`headsim.mask.fit` ("Barrier contact").
"""

from __future__ import annotations

import argparse
import os
import time


def _problem(kind: str, mu: float):
    from headsim.data import face_path
    from headsim.mask import find_landmarks, make_mask
    from headsim.mask.fit import FitOptions, prepare_fit
    from headsim.mesh.io import load_surface

    face = load_surface(face_path("neutral"))
    lm = find_landmarks(face)
    if kind == "demo":
        return prepare_fit(face, make_mask("nasal-M", edge_length=4e-3), FitOptions(contact="barrier", friction=mu),
                           landmarks=lm)
    coarse = FitOptions(tissue_layers=1, crop_margin=0.006, contact="barrier", friction=mu)
    return prepare_fit(face, make_mask("nasal-M", edge_length=5e-3, contour=False), coarse, landmarks=lm)


def _fits(problem, forces, normals: str, lag: str) -> int:
    """Cold fits with the given BarrierContact friction settings; returns how many converged."""
    from headsim.errors import ConvergenceError
    from headsim.mask.fit import problem_fit
    from headsim.solvers import barrier

    init = barrier.BarrierContact.__init__

    def configured(self, *args, **kwargs):
        kwargs.update(friction_normals=normals, friction_lag=lag)
        init(self, *args, **kwargs)

    barrier.BarrierContact.__init__ = configured
    ok = 0
    try:
        for f in forces:
            t = time.perf_counter()
            try:
                r = problem_fit(problem, f)
            except ConvergenceError as e:
                print(f"  {normals:6s} {lag:8s} {f:6.2f} N: FAILED after {time.perf_counter() - t:6.1f} s ({str(e)[-60:]})",
                      flush=True)
                continue
            ok += 1
            s = r.summary
            print(f"  {normals:6s} {lag:8s} {f:6.2f} N: {r.contact_updates:3d} updates, {r.newton_iterations:4d} Newton its, "
                  f"{time.perf_counter() - t:6.1f} s; leak {r.leak.flow_lpm:6.2f} L/min, pitch {r.mask_rotation_deg[0]:6.2f} deg, "
                  f"area {s.contact_area_cm2:5.2f} cm2, peak {s.peak_pressure / 1e3:6.1f} kPa", flush=True)
    finally:
        barrier.BarrierContact.__init__ = init
    return ok


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problem", default="demo", choices=("demo", "coarse"))
    ap.add_argument("--mu", type=float, default=0.5, help="skin-cushion Coulomb coefficient")
    ap.add_argument("--forces", default="2.5,8,15,30", help="strap forces, N, comma-separated")
    ap.add_argument("--normals", default="smooth", choices=("smooth", "pair"))
    ap.add_argument("--lag", default="adaptive", choices=("adaptive", "plain"))
    ap.add_argument("--compare", action="store_true", help="also the plain lagged loop and ipctk's planes")
    args = ap.parse_args(argv)
    forces = [float(f) for f in args.forces.split(",")]
    print(f"bench_mask_friction: {os.cpu_count()} CPUs visible; load average {os.getloadavg()[0]:.1f}; "
          f"problem {args.problem}, mu {args.mu:g}, forces {forces}")
    problem = _problem(args.problem, args.mu)
    runs = [(args.normals, args.lag)]
    if args.compare:
        runs += [r for r in (("smooth", "plain"), ("pair", "adaptive")) if r not in runs]
    converged = {run: _fits(problem, forces, *run) for run in runs}
    for (normals, lag), ok in converged.items():
        print(f"normals {normals}, lag {lag}: {ok} of {len(forces)} fits converged")


if __name__ == "__main__":
    main()
