"""Benchmark of the mask fit (issue 6): one fit and the least-seal-force search on the bundled face,
against the seed-faithful explicit mass-spring loop on the same meshes.

Run:  python benchmarks/bench_mask.py [--quick]

Measured in one process:

- set-up: landmarks, placement, cropped tissue layer, FEM model (``prepare_fit``);
- one fit (quasi-static FEM contact, force control) at 15 N from first contact (cold), and one
  warm-started at 14 N;
- the least-seal-force search (bracketing + bisection, warm-started; ``least_seal_force``);
- the sparse direct solve inside Newton: the symmetric-mode SuperLU factorisation
  (:func:`headsim.solvers.newton.factorize_spd`) against SuperLU's default partial pivoting (the
  solver before) on the Hessians of one fit, recorded as they are solved;
- the condensed re-fit mode (:mod:`headsim.mask.condensed`): the one-off condensation, one fit at
  15 N (and the LCP alone), its search, and its numbers next to the nonlinear fit's;
- the seed-faithful loop (Heinze ch. 3, 5): the same tissue + mask tet meshes as mass-spring bodies
  (springs from the same moduli), explicit Euler (eqs. 3.1-3.2) with the seed's consistent
  collision force (eqs. 3.7-3.13, BVH + Moeller-Trumbore + BFS) every step, the strap force spread
  over the shell vertices. It runs a FIXED number of steps; its time to equilibrium is EXTRAPOLATED
  as (steps needed) x (time per step), steps needed = settling time / dt, dt = 0.9 x the explicit
  stability limit (springs and collision springs), settling time = ln(1e6) / ω_min (lowest_angular_frequency) of the
  tissue (decay of a critically damped slowest mode to 1e-6; optimistic for the explicit loop).
  A search needs one such equilibrium per force tried; the seed's search would need at least as
  many equilibria as ours (stated as such).

Goals (issue 6): one fit <= 10 s, the search <= 60 s on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from headsim.solvers.integrators import lowest_angular_frequency


_CPU = {}


def _timed(fn, *a, **k):
    """(result, wall s); the CPU time of the same call is kept in _CPU[fn.__name__] (s)."""
    t, c = time.perf_counter(), time.process_time()
    out = fn(*a, **k)
    _CPU[fn.__name__] = time.process_time() - c
    return out, time.perf_counter() - t


def seed_loop(problem, force: float, n_steps: int):
    """Per-step time of the seed-faithful explicit loop on the fit's meshes, and its extrapolation."""
    from dataclasses import replace

    from headsim.mesh.tet import REGION_CUSHION, REGION_TISSUE, TetMesh
    from headsim.solvers.contact_consistent import SeedCollisionForce
    from headsim.solvers.integrators import ExplicitEuler, critical_time_step
    from headsim.solvers.massspring import mass_spring_from_tetmesh
    from headsim.solvers.materials import Material
    from headsim.solvers.state import BodyState

    p = problem
    m = p.model
    nt = p.n_tissue
    region = np.where(m.tets.max(axis=1) < nt, REGION_TISSUE, REGION_CUSHION).astype(np.int32)
    mesh = TetMesh(m.rest_positions, m.tets, tet_region=region, fixed=m.fixed)
    o = p.options
    cm = p.mask.material
    mats = {REGION_TISSUE: Material(o.tissue_modulus, 0.25, o.tissue_density),
            REGION_CUSHION: Material(cm.youngs_modulus, 0.25, cm.density)}
    ms = mass_spring_from_tetmesh(mesh, material=mats)
    ext = np.zeros_like(ms.external_force)
    ext[p.shell_vertices] = force * p.approach / len(p.shell_vertices)  # the strap pulls the shell
    body = np.where(np.arange(mesh.n_vertices) < nt, 0, 1).astype(np.int32)
    ms = replace(ms, external_force=ext, body=body)
    tissue_tris = TetMesh(m.rest_positions[:nt], m.tets[region == REGION_TISSUE], fixed=m.fixed[:nt]).boundary_triangles
    surfaces = [tissue_tris, p.mask_surface]
    a_min = float(np.median(p.skin_areas))
    k_coll = p.penalty * a_min  # the quasi-static penalty on one skin vertex, N/m
    collide = SeedCollisionForce(body, surfaces, ms.edges, k_coll, 0.0, "consistent")
    dt_crit = critical_time_step(ms)
    dt_contact = 2.0 * np.sqrt(float(ms.mass.min()) / k_coll)
    dt = 0.9 * min(dt_crit, dt_contact)
    # start with the mask just touching (the fit's start), at rest
    state = BodyState.at_rest(ms.rest_positions)
    solver = ExplicitEuler(max_jump=1e9)
    state = solver.step(ms, state, dt, extra_forces=collide)  # warm-up (JIT, BVH build)
    t = time.perf_counter()
    for _ in range(n_steps):
        state = solver.step(ms, state, dt, extra_forces=collide)
    per_step = (time.perf_counter() - t) / n_steps
    tissue = mass_spring_from_tetmesh(TetMesh(m.rest_positions[:nt], m.tets[region == REGION_TISSUE],
                                              fixed=m.fixed[:nt]), material=mats[REGION_TISSUE])
    w = lowest_angular_frequency(tissue)
    steps = (np.log(1e6) / w) / dt
    return per_step, dt, steps, steps * per_step


def factorisation_section(problem, warm_start) -> None:
    """Symmetric-mode vs partial-pivoting SuperLU on the Newton Hessians of one (warm) 15 N fit."""
    import scipy.sparse.linalg as spla

    from headsim.mask.fit import problem_fit
    from headsim.solvers import newton

    systems = []
    # every factorisation of the Newton solve (solve_direct and the lagged factorisation) goes through it
    solve = newton._solve_direct_factor

    def recording(a, b, *args, **kw):
        systems.append((a, b))
        return solve(a, b, *args, **kw)

    newton._solve_direct_factor = recording
    try:
        problem_fit(problem, 15.0, warm_start=warm_start)
    finally:
        newton._solve_direct_factor = solve
    cpu = {"symmetric": 0.0, "pivoting": 0.0}
    fill = {"symmetric": 0, "pivoting": 0}
    res = {"symmetric": 0.0, "pivoting": 0.0}
    for a, b in systems:
        a = a.tocsc()
        for name, factor in (("symmetric", newton.factorize_spd),
                             ("pivoting", lambda m: spla.splu(m, permc_spec="MMD_AT_PLUS_A"))):
            c = time.process_time()
            lu = factor(a)
            x = lu.solve(b)
            cpu[name] += time.process_time() - c
            fill[name] = max(fill[name], lu.L.nnz + lu.U.nnz)
            res[name] = max(res[name], float(np.linalg.norm(a @ x - b) / np.linalg.norm(b)))
    n = systems[0][0].shape[0] if systems else 0
    print(f"direct solve, {len(systems)} Newton Hessians of a 15 N fit ({n} unknowns): symmetric-mode SuperLU "
          f"{cpu['symmetric']:.2f} s CPU (fill <= {fill['symmetric'] / 1e6:.2f} M, residual <= {res['symmetric']:.1e}), "
          f"partial pivoting {cpu['pivoting']:.2f} s CPU (fill <= {fill['pivoting'] / 1e6:.2f} M, residual <= "
          f"{res['pivoting']:.1e}): ratio {cpu['pivoting'] / max(cpu['symmetric'], 1e-12):.2f} x")


def condensed_section(problem, nonlinear_15, search_options) -> None:
    """The condensed mode: condensation, one fit, the LCP alone, its search; vs the nonlinear fit."""
    from headsim.mask.condensed import condense_fit, condensed_fit
    from headsim.mask.search import least_seal_force
    from headsim.solvers.contact_qp import solve_contact_lcp

    cf, t_c = _timed(condense_fit, problem)
    print(f"condensed: condensation {t_c:.2f} s wall ({_CPU['condense_fit']:.2f} s CPU), {cf.n_pairs} contact pairs")
    lin, t_fit = _timed(condensed_fit, cf, 15.0)
    cpu_fit = _CPU["condensed_fit"]
    load = np.zeros(cf.jacobian.shape[1])
    load[0] = 15.0
    lcp, t_lcp = _timed(solve_contact_lcp, cf.compliance, cf.gaps0, cf.jacobian, load)
    print(f"condensed fit at 15 N: {t_fit:.3f} s wall ({cpu_fit:.3f} s CPU) incl. seal analysis; LCP alone "
          f"{t_lcp:.4f} s wall ({_CPU['solve_contact_lcp']:.4f} s CPU), {lcp.iterations} active-set iterations")
    for name, r in (("condensed", lin), ("nonlinear", nonlinear_15)):
        s = r.summary
        print(f"   {name:9s} 15 N: area {s.contact_area_cm2:6.2f} cm², peak {s.peak_pressure / 1e3:6.1f} kPa, mean "
              f"{s.mean_pressure / 1e3:5.1f} kPa, rotation {np.round(r.mask_rotation_deg, 2)} deg, "
              f"{'sealed' if r.sealed else 'leaks'}")
    res, t_s = _timed(least_seal_force, problem, search_options, mode="condensed")
    print(f"condensed least-seal-force search: {t_s:.2f} s wall ({_CPU['least_seal_force']:.2f} s CPU, condensation "
          f"included), {res.n_solves} fits, status {res.status}, seal force {res.seal_force} N "
          f"(largest leaking {res.lower_bound} N)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer explicit steps, looser search tolerance")
    ap.add_argument("--contact", default="barrier", choices=("planes", "barrier"),
                    help="the nonlinear fit's contact model (FitOptions.contact)")
    ap.add_argument("--workers", type=int, default=None,
                    help="fits of the search solved at once (default: 2 with the barrier, 1 with the planes; "
                         "the CLI's --workers auto)")
    ap.add_argument("--friction", type=float, default=0.0, help="skin-cushion Coulomb coefficient (FitOptions.friction)")
    ap.add_argument("--rotation", default="free", choices=("free", "held"),
                    help="the mask's orientation: turns on its strap (free) or held by the headgear")
    ap.add_argument("--fits-only", action="store_true",
                    help="only the set-up, the two fits and the search (no factorisation, condensed or seed sections)")
    args = ap.parse_args(argv)

    from headsim.data import face_path
    from headsim.mask import find_landmarks, make_mask
    from headsim.mask.fit import FitOptions, prepare_fit, problem_fit
    from headsim.mask.search import SearchOptions, least_seal_force
    from headsim.mesh.io import load_surface

    print(f"bench_mask: {os.cpu_count()} CPUs visible; load average {os.getloadavg()[0]:.1f}")
    face = load_surface(face_path("neutral"))
    lm, t_lm = _timed(find_landmarks, face)
    problem, t_prep = _timed(prepare_fit, face, make_mask("nasal-M", edge_length=4e-3),
                               FitOptions(contact=args.contact, friction=args.friction,
                                          rotate=args.rotation == "free"), landmarks=lm)
    d = problem.describe()
    print(f"contact model: {args.contact}, friction {args.friction:g}, rotation {args.rotation}")
    print(f"set-up: landmarks {t_lm:.2f} s, placement + tissue + model {t_prep:.2f} s; model {d['model_vertices']} "
          f"vertices / {d['model_tets']} tets ({d['cropped_skin_vertices']} skin vertices)")
    cold, t_cold = _timed(problem_fit, problem, 15.0)
    cpu_cold = _CPU["problem_fit"]
    warm, t_warm = _timed(problem_fit, problem, 14.0, warm_start=cold.state)
    print(f"CPU time: cold fit {cpu_cold:.2f} s, warm fit {_CPU['problem_fit']:.2f} s")
    for name, r, t in (("cold, 15 N", cold, t_cold), ("warm, 14 N", warm, t_warm)):
        s = r.summary
        print(f"one fit ({name}): {t:6.2f} s, {r.newton_iterations} Newton its, {r.contact_updates} contact updates; "
              f"contact force {r.contact_force:.4f} N (error {100 * r.balance_error:.2g} %), area "
              f"{s.contact_area_cm2:.2f} cm², peak {s.peak_pressure / 1e3:.1f} kPa, mean {s.mean_pressure / 1e3:.1f} kPa, "
              f"{'sealed' if r.sealed else 'leaks'}")
    opts = SearchOptions(start=10.0, maximum=30.0, abs_tol=1.0 if args.quick else 0.5)
    from headsim.cli.mask_cmd import search_workers

    workers = args.workers or search_workers("auto", args.contact, "nonlinear")
    res, t_search = _timed(least_seal_force, problem, opts, workers=workers)
    cpu_search = _CPU["least_seal_force"]
    print(f"least-seal-force search ({workers} worker{'s' if workers > 1 else ''}; CPU of this process only): "
          f"{t_search:6.2f} s wall ({cpu_search:.2f} s CPU), {res.n_solves} fits, "
          f"status {res.status}, seal force {res.seal_force} N (largest leaking {res.lower_bound} N)")
    for c in res.curve:
        print(f"   F = {c.force:6.2f} N: area {c.contact_area_cm2:6.2f} cm², peak {c.peak_pressure_kpa:7.1f} kPa, "
              f"mean {c.mean_pressure_kpa:6.1f} kPa, {'sealed' if c.sealed else 'leaks'}")
    if args.fits_only:
        print(f"goals: one fit <= 10 s: {'met' if t_cold <= 10 else 'NOT met'} ({t_cold:.1f} s); "
              f"search <= 60 s: {'met' if t_search <= 60 else 'NOT met'} ({t_search:.1f} s)")
        return
    factorisation_section(problem, cold.state)
    condensed_section(problem, cold, opts)
    n_steps = 3 if args.quick else 10
    per_step, dt, steps, t_eq = seed_loop(problem, 15.0, n_steps)
    print(f"seed-faithful explicit loop: {per_step:.3f} s/step measured over {n_steps} steps, dt = {dt:.3g} s "
          f"(stability limit), {steps:.3g} steps to equilibrium -> {t_eq:.4g} s per fit (EXTRAPOLATED)")
    print(f"ratio seed-faithful / quasi-static, one fit: {t_eq / t_cold:.3g} x (cold), {t_eq / t_warm:.3g} x (warm)")
    print(f"ratio for the search ({res.n_solves} equilibria): {res.n_solves * t_eq / t_search:.3g} x")
    print(f"goals: one fit <= 10 s: {'met' if t_cold <= 10 else 'NOT met'} ({t_cold:.1f} s); "
          f"search <= 60 s: {'met' if t_search <= 60 else 'NOT met'} ({t_search:.1f} s)")


if __name__ == "__main__":
    main()
