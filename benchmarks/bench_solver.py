"""Benchmark of the deformable-body solver (issue 5): seed-faithful explicit loop vs quasi-static Newton.

Run:  python benchmarks/bench_solver.py [--quick]

Problems
--------
1. sphere-on-block: rigid sphere pressed onto a soft block (the Hertz problem of
   ``headsim.solvers.hertz``, quarter model).
2. two bodies: a soft ball (about 20k tets, FEM / mass-spring) pressed onto a soft block (about 20k tets).

For each problem, in one process:
- seed-faithful explicit loop: mass-spring bodies, Heinze eqs. 3.1-3.2 (explicit Euler, forces from the
  old state) with the seed's consistent collision force (eqs. 3.7-3.13, BVH + Möller-Trumbore + BFS)
  every step. It runs a fixed number of steps; the time to equilibrium is EXTRAPOLATED as
  (steps needed) x (measured time per step), with steps needed = settling time / dt, dt = 0.9 x the
  explicit stability limit, settling time = ln(1/tol) / lowest_angular_frequency (ω_min) of the supported body, tol = 1e-6 (the decay
  of a critically damped slowest mode to the Newton tolerance; optimistic for the explicit loop,
  which the seed ran undamped and whose damping would lower the stable dt).
- quasi-static Newton (``solve_quasi_static``, FEM, penalty contact): measured wall time to equilibrium.
- implicit Euler (FEM): measured time per step at dt = 0.2 s (the seed's step).
- linear solvers: sparse direct (SuperLU) vs pyamg smoothed aggregation + CG on the FEM Hessian.
Ratios are printed against the seed-faithful loop measured in the same run.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np

from headsim.mesh.tet import TetMesh
from headsim.solvers.contact import PlaneContact, solve_quasi_static, surface_vertex_areas
from headsim.solvers.contact_consistent import SeedCollisionForce
from headsim.solvers.fem import fem_from_tetmesh
from headsim.solvers.grids import ball_tetmesh, block_tetmesh
from headsim.solvers.integrators import ExplicitEuler, ImplicitEuler, critical_time_step, lowest_angular_frequency
from headsim.solvers.massspring import combine_mass_spring, mass_spring_from_tetmesh
from headsim.solvers.materials import Material
from headsim.solvers.newton import NewtonOptions, blas_threads, rigid_body_modes, solve_spd
from headsim.solvers.contact import QuasiStaticOptions
from headsim.solvers.state import BodyState

MAT = Material.from_kpa(10.0, 0.3, 1000.0)
#: relative force residual both solvers are taken to equilibrium to (Newton's force tolerance; the
#: explicit loop's settling time ln(1/tol) / ω_min of a critically damped slowest mode)
SETTLE_TOLERANCE = 1e-6
#: largest linear system the table solves with SuperLU (its fill grows ~ N^(4/3) on 3-D meshes)
DIRECT_LIMIT = 60_000


class Clock:
    """Wall (perf_counter) and CPU (process_time) seconds of a block."""

    def __enter__(self):
        self.w0, self.c0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall, self.cpu = time.perf_counter() - self.w0, time.process_time() - self.c0


def _timed(fn, *a, **k):
    with Clock() as c:
        out = fn(*a, **k)
    return out, c


def _load() -> str:
    return "load %.1f %.1f %.1f" % os.getloadavg()


def _phases(timings: dict) -> str:
    keys = ("hessian", "free_block", "linear_solve", "amg_setup", "cg", "line_search", "gradient", "contact_update")
    return ", ".join(f"{k} {timings[k]:.2f}" for k in keys if k in timings)


def explicit_seed_loop(ms_model, surfaces, n_steps, k_coll, supported):
    """Time per step (s, wall) of the seed-faithful loop, dt, steps needed, and the extrapolated time
    to equilibrium (wall s, CPU s).

    ``supported`` is the body held by fixed vertices (its slowest mode sets the settling time; a
    free body's rigid modes have zero frequency).
    """
    force = SeedCollisionForce(ms_model.body, surfaces, ms_model.edges, k_coll, 0.0, "consistent")
    dt_crit = critical_time_step(ms_model)
    # the collision spring k_coll on a point mass must be stable too: dt < 2 sqrt(m / k_coll)
    dt_contact = 2.0 * np.sqrt(float(ms_model.mass.min()) / k_coll) if k_coll > 0 else np.inf
    dt = 0.9 * min(dt_crit, dt_contact)
    state = BodyState.at_rest(ms_model.rest_positions)
    solver = ExplicitEuler(max_jump=1e9)
    state = solver.step(ms_model, state, dt, extra_forces=force)  # warm-up (JIT, BVH build)
    with Clock() as c:
        for _ in range(n_steps):
            state = solver.step(ms_model, state, dt, extra_forces=force)
    per_step = c.wall / n_steps
    per_step_cpu = c.cpu / n_steps
    w = lowest_angular_frequency(supported)
    steps_needed = (np.log(1.0 / SETTLE_TOLERANCE) / w) / dt
    return per_step, dt, steps_needed, steps_needed * per_step, steps_needed * per_step_cpu


def bench_sphere_on_block(quick: bool, solvers=("direct", "amg-cg")):
    from headsim.solvers.hertz import hertz_indentation

    print("\n== sphere-on-block (rigid sphere on soft block, quarter model) ==")
    kw = dict(first_cell=1e-3 / (4 if quick else 6), growth=1.25 if quick else 1.2)
    rows = {}
    hertz_indentation(MAT, 0.01, 0.001, first_cell=1e-3 / 2, growth=1.5)  # warm-up (Numba cache, pyamg)
    for solver in solvers:
        res, c = _timed(hertz_indentation, MAT, 0.01, 0.001, linear_solver=solver, **kw)
        rows[solver] = c
        print(f"quasi-static Newton [{solver:6s}]: {c.wall:7.2f} s wall / {c.cpu:6.2f} s CPU to equilibrium "
              f"(incl. model set-up), {res.newton_iterations} Newton its, {res.n_vertices} vertices / {res.n_tets} "
              f"tets; Hertz errors a {100 * res.contact_radius_error:+.1f} %, delta {100 * res.indentation_error:+.1f} %"
              f" [{_load()}]")
        print(f"    CPU s per phase: {_phases(res.timings)}")
    # seed-faithful: the same block as a mass-spring body (k from E), the sphere as a second body
    mesh = TetMesh(res.model.rest_positions, res.model.tets)
    mesh = replace(mesh, fixed=res.model.fixed)
    block = mass_spring_from_tetmesh(mesh, material=Material.from_kpa(10.0, 0.25, 1000.0))
    ball = ball_tetmesh(0.01, 3 if quick else 4, center=(0, 0, 0.01 + 1e-4))
    # the sphere is 10x stiffer than the block (a rigid sphere would force a much smaller explicit dt;
    # this keeps the block's own stability limit in charge, in favour of the explicit loop)
    sph = mass_spring_from_tetmesh(ball, material=Material.from_kpa(100.0, 0.25, 1000.0))
    model, off = combine_mass_spring([block, sph])
    surfaces = [mesh.boundary_triangles, ball.boundary_triangles + off[1]]
    # collision constant per point = the quasi-static penalty on a vertex of the finest surface cell
    h0 = kw["first_cell"]
    k_coll = 300.0 * MAT.plane_strain_modulus / 1e-3 * h0 * h0
    per_step, dt, steps, t_eq, t_eq_cpu = explicit_seed_loop(model, surfaces, 5 if quick else 20, k_coll=k_coll,
                                                             supported=block)
    print(f"seed-faithful explicit loop: {1 / per_step:8.1f} steps/s, dt = {dt:.3g} s (stability limit), "
          f"{steps:.3g} steps to equilibrium -> {t_eq:.4g} s wall / {t_eq_cpu:.4g} s CPU (extrapolated) [{_load()}]")
    best = min(rows.values(), key=lambda c: c.cpu)
    print(f"ratio seed-faithful / quasi-static: {t_eq / best.wall:.3g} x wall, {t_eq_cpu / best.cpu:.3g} x CPU")
    return t_eq / best.wall, t_eq_cpu / best.cpu


def two_body_meshes(quick: bool):
    d = 5 if quick else 7  # ball: 6 (2d)^3 tets -> 6000 / 16464
    n = (12, 12, 5) if quick else (20, 20, 8)  # block: 6 nx ny nz tets -> 4320 / 19200
    r = 0.01
    ball = ball_tetmesh(r, d, center=(0, 0, r * 1.001))
    block = block_tetmesh((4 * r, 4 * r, 2 * r), n, origin=(-2 * r, -2 * r, -2 * r))
    block = replace(block, fixed=np.isclose(block.vertices[:, 2], -2 * r))
    return ball, block


def bench_two_bodies(quick: bool, solvers=("direct", "amg-cg")):
    print("\n== two deformable bodies (ball on block) ==")
    ball, block = two_body_meshes(quick)
    n0 = block.n_vertices
    both = TetMesh(np.vstack([block.vertices, ball.vertices]), np.vstack([block.tets, ball.tets + n0]),
                   fixed=np.r_[block.fixed, np.zeros(ball.n_vertices, bool)])
    print(f"block {block.n_tets} tets, ball {ball.n_tets} tets, {both.n_vertices} vertices")
    fem = fem_from_tetmesh(both, MAT)
    x = both.vertices
    load = 0.01  # N, body force on the ball
    ext = np.zeros_like(x)
    ball_v = np.arange(n0, len(x))
    ext[ball_v, 2] = -load * fem.mass[ball_v] / fem.mass[ball_v].sum()
    fem = replace(fem, external_force=ext)
    sym = np.column_stack([np.isclose(x[:, 0], 0.0), np.isclose(x[:, 1], 0.0), np.zeros(len(x), bool)])
    kappa = 300 * MAT.young_modulus / 0.002
    a_block = surface_vertex_areas(len(x), block.boundary_triangles, x)
    a_ball = surface_vertex_areas(len(x), ball.boundary_triangles + n0, x)
    blk_s = np.flatnonzero(a_block > 0)
    ball_s = np.flatnonzero(a_ball > 0)
    rows = {}
    for solver in solvers:
        contacts = [
            PlaneContact(ball_s, a_ball[ball_s], block.boundary_triangles, kappa, slave_edges=both.edges, margin=1e-4),
            PlaneContact(blk_s, a_block[blk_s], ball.boundary_triangles + n0, kappa, slave_edges=both.edges, margin=1e-4),
        ]
        opts = QuasiStaticOptions(newton=NewtonOptions(relative_tolerance=1e-8, linear_solver=solver),
                                  force_tolerance=SETTLE_TOLERANCE * load)
        try:
            res, c = _timed(solve_quasi_static, fem, contacts, fixed_dofs=sym, options=opts)
        except Exception as e:  # noqa: BLE001 - report and go on
            print(f"quasi-static Newton [{solver}]: FAILED ({e})")
            continue
        rows[solver] = c
        print(f"quasi-static Newton [{solver:6s}]: {c.wall:7.2f} s wall / {c.cpu:6.2f} s CPU to equilibrium, "
              f"{res.newton_iterations} Newton its, {res.contact_updates} contact updates; support reaction "
              f"{res.reaction_forces[:, 2].sum():.4g} N (load {load} N) [{_load()}]")
        print(f"    CPU s per phase: {_phases(res.timings)}")
    # implicit Euler steps at the seed's dt
    contacts = [
        PlaneContact(ball_s, a_ball[ball_s], block.boundary_triangles, kappa, slave_edges=both.edges, margin=1e-4),
        PlaneContact(blk_s, a_block[blk_s], ball.boundary_triangles + n0, kappa, slave_edges=both.edges, margin=1e-4),
    ]
    fem_d = replace(fem, rayleigh_stiffness=0.01, fixed=fem.fixed | sym.any(axis=1))
    state = BodyState.at_rest(x)
    n_imp = 2 if quick else 3
    cache: dict = {}
    try:
        with Clock() as c:
            for _ in range(n_imp):
                state = ImplicitEuler().step(fem_d, state, 0.2, terms=contacts, amg_cache=cache)
        print(f"implicit Euler (FEM, dt = 0.2 s): {n_imp / c.wall:8.3f} steps/s wall, {n_imp / c.cpu:8.3f} steps/s CPU")
    except Exception as e:  # noqa: BLE001
        print(f"implicit Euler: FAILED ({e})")
    # seed-faithful explicit loop on mass-spring versions of both bodies
    mb = mass_spring_from_tetmesh(block, material=Material.from_kpa(10.0, 0.25, 1000.0))
    mball = mass_spring_from_tetmesh(ball, material=Material.from_kpa(10.0, 0.25, 1000.0))
    ms, off = combine_mass_spring([mb, mball])
    per_step, dt, steps, t_eq, t_eq_cpu = explicit_seed_loop(
        ms, [block.boundary_triangles, ball.boundary_triangles + off[1]], 3 if quick else 10,
        k_coll=kappa * float(np.median(a_ball[ball_s])), supported=mb)
    print(f"seed-faithful explicit loop: {1 / per_step:8.2f} steps/s, dt = {dt:.3g} s (stability limit), "
          f"{steps:.3g} steps to equilibrium -> {t_eq:.4g} s wall / {t_eq_cpu:.4g} s CPU (extrapolated) [{_load()}]")
    if rows:
        best = min(rows.values(), key=lambda c: c.cpu)
        print(f"ratio seed-faithful / quasi-static: {t_eq / best.wall:.3g} x wall, {t_eq_cpu / best.cpu:.3g} x CPU")
        return t_eq / best.wall, t_eq_cpu / best.cpu
    return float("nan"), float("nan")


def bench_linear_solvers(quick: bool):
    print("\n== linear solve of the FEM Hessian (block, bottom fixed) ==")
    sizes = [(16, 16, 8)] if quick else [(16, 16, 8), (30, 30, 15), (36, 36, 36)]
    for n in sizes:
        mesh = block_tetmesh((0.04, 0.04, 0.04 * n[2] / n[0]), n)
        mesh = replace(mesh, fixed=np.isclose(mesh.vertices[:, 2], 0.0))
        m = fem_from_tetmesh(mesh, MAT)
        free = np.flatnonzero(np.repeat(~m.fixed, 3))
        a = m.hessian(m.rest_positions).tocsr()[free][:, free]
        b = np.random.default_rng(0).standard_normal(len(free))
        out = []
        for method in ("direct", "amg-cg"):
            nn = rigid_body_modes(m.rest_positions)[free]
            if method == "direct" and len(free) > DIRECT_LIMIT:
                out.append(f"direct skipped (> {DIRECT_LIMIT} unknowns: SuperLU's fill on a 3-D mesh passes "
                           "the 4 GiB memory budget of a shared machine)")
                continue
            try:
                with blas_threads(1):
                    xs, c = _timed(solve_spd, a, b, method, nn, 1e-8)
                out.append(f"{method} {c.wall:7.3f} s wall / {c.cpu:7.3f} s CPU "
                           f"(residual {np.linalg.norm(a @ xs - b) / np.linalg.norm(b):.1e})")
            except MemoryError:
                out.append(f"{method} out of memory")
        print(f"{len(free):7d} unknowns: " + ", ".join(out))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (a minute)")
    ap.add_argument("--skip-linear", action="store_true", help="skip the direct vs AMG linear-solver table")
    ap.add_argument("--skip-direct", action="store_true",
                    help="quasi-static solves with AMG-CG only (SuperLU takes minutes at full size)")
    args = ap.parse_args()
    print(f"{os.cpu_count()} CPUs, {_load()} at start")
    solvers = ("amg-cg",) if args.skip_direct else ("direct", "amg-cg")
    r1 = bench_sphere_on_block(args.quick, solvers)
    r2 = bench_two_bodies(args.quick, solvers)
    if not args.skip_linear:
        bench_linear_solvers(args.quick)
    print(f"\nsummary: quasi-static is {r1[0]:.3g} x wall / {r1[1]:.3g} x CPU (sphere-on-block) and {r2[0]:.3g} x wall / "
          f"{r2[1]:.3g} x CPU (two bodies) faster to equilibrium than the seed-faithful explicit loop "
          f"(extrapolated from measured steps) [{_load()} at end]")


if __name__ == "__main__":
    main()
