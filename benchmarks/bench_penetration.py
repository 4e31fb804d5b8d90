"""Diagnosis: where and why a settled drape strand interpenetrates (issue 10).

Usage: python benchmarks/bench_penetration.py [--fibres 40] [--segments 30] [--settle 1500] [--steps 3]
       [--set OPTION=VALUE ...]

Settles the sphere-helical drape scene (derived geometry, anisotropic friction, coupled contacts) for
``--settle`` steps of 1 ms, then, for ``--steps`` more steps, reports

1. the deepest rows of the step's contact set (``StepStats.max_penetration`` is −min of their mid-step
   gaps): fibre–fibre or fibre–sphere, fibre and segment index (k0 = root segment), and the same
   overlaps recomputed from the end-of-step state with exact capsule distances (no band, radius r per
   fibre; the BVH leaves out the segment itself and its chain neighbours only);
2. per step, the mean gap change of the pairs deeper than one radius over the first half step (the
   unconstrained move q^{i+½} = q^i + ½Δt u_J with the joint stage's twists u_J) and over the second half
   step (contact solve and split push-out);
3. the normal relative velocity of the deep rows at t_i (the previous contact solution) and after the
   joint stage, with the model's joint springs and with them set to zero (the drift's source);
4. the joint-rate residual of the velocity and push-out solutions (m/s) and the largest joint gap.

Measured (2 shared cores; HEAD of main dd7805a, branch ``pen``), ``--fibres 40 --segments 30 --settle 1500``:
the penetration is physical, not a metric artefact — the capsules overlap in the end-of-step state too
(60 µm deepest, 25 overlaps deeper than r) and ``max_penetration`` uses r_a + r_b, the BVH's adjacency
exclusion and the joint-duplicate filter, so it counts no excluded pair. Deepest: root segments (k0) of
fibres anchored 105 µm or more apart that converge below the anchors (axes parallel to cos 0.997–0.9999,
overlap 2–8 mm below the roots), mid-strand segments (k14–k18) of neighbouring fibres, and the sphere
(k15, 50–60 µm). All deep rows are rows of the solve with an impulse; nothing is missed by detection.
Steady state: each step the first half step closes the deep pairs by ≈ 4.4 µm and the push-out reopens
them by the same ≈ 4.4 µm (0.2 × 45 µm would be 9 µm: the 60-sweep push-out solve reaches about half of
its target). The closing comes from the joint stage: the deep rows' normal velocity is −0.1 mm/s at t_i
and −10 to −17 mm/s after the joint stage (−0.3 mm/s with the joint springs set to zero): the bending /
torsion spring impulses of the joint stage move the segments into the contacts that hold the bent
strand in the unconstrained first half step, which only the split push-out corrects. With
``qp_iterations`` 1,000 or 10,000 the penetration stays (60–69 µm over 40 / 15 steps). At t = 0.2 s
(``--settle 200``) the strand is 130 µm (3.7 r) into the sphere (segments k14), the closing speed after
the joint stage −38.5 mm/s at those rows (+0.2 mm/s without the springs): the colleague's 126–140 µm.

A second mechanism (fixed, ``ChainOptions.recovery_keeps_joints``): the push-out solve, stopped at its
60-sweep cap, left a 27.6 mm/s joint-rate residual (the sweeps end with the contacts), which opened
17 µm joint gaps that the next joint stage closed by moving the segments back (bench_drape.py's settled
strand: max joint gap 17.4 → 1.9 µm; max penetration 60.7 / 69.2 µm, unchanged within its trajectory
noise). With ``--set springs_in_first_half_step=False`` (opt-in) the sphere penetration falls from 55.7
to 1.3 µm within 100 steps of the settled state and the rows deeper than r from 79 to 9; what remains
(≈ 60 µm) are root segments of converging fibres, probably crossed during the fall (their axes are
parallel and ≈ 10 µm apart 2 mm below the anchors; not analysed further).

Since ``ChainOptions.half_step_projection`` and ``separating_candidates`` (both default; the numbers above
are from before them): the last harmonisation pass's first half step no longer moves into the contacts
of the previous pass, and penetrating pairs that separate at u⁻ stay candidate rows. Measured
(``--fibres 40 --segments 30 --settle 300 --steps 3``, 2 shared cores, 31 s each): at the defaults
StepStats.max_penetration 48 / 39 / 31 µm over the 3 steps (sphere rows deeper than r: 0), end-of-step
capsule overlaps deepest 38.6 / 31.5 / 25.3 µm, deeper than r 3 / 0 / 0; with
``--set half_step_projection=False separating_candidates=False`` (the former scheme) 166 / 165 / 163 µm
(160 sphere rows deeper than r), end-of-step overlaps 53 / 49 / 50 µm, 32 / 30 / 30 deeper than r; the
projection alone (``--set separating_candidates=False``) 58 / 48 / 49 µm, end-of-step overlaps 70 / 69 /
68 µm, 48 / 45 / 43 deeper than r. StepStats.max_penetration is now taken from the last pass's mid-step
gaps (first order from the detection state); the "first half step" gap change printed below is measured
at the detection state, i.e. the first pass's predictor, not the projected half step that is integrated.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses

import numpy as np


def _pair_gaps(model, x, R, pad=1.5):
    from headsim.collide import FibreBVH, FibreSet

    so, h, r, F, fib = model.segment_offsets, model.half_length, model.radius, model.n_fibres, model.segment_fibre
    d3 = R[:, :, 2]
    nodes = np.empty((model.n_segments + F, 3))
    nodes[np.arange(model.n_segments) + fib + 1] = x + h[:, None] * d3
    nodes[so[:-1] + np.arange(F)] = x[so[:-1]] - h[so[:-1], None] * d3[so[:-1]]
    bvh = FibreBVH(FibreSet(nodes, so + np.arange(F + 1), r * pad), "aabb", "spatial", threads=1)
    p, q = bvh.self_contact_pairs()
    a, b = p[:, 0], p[:, 1]
    ta, tb = (2 * q[:, 0] - 1) * h[a], (2 * q[:, 1] - 1) * h[b]
    g = np.linalg.norm(x[a] + ta[:, None] * d3[a] - x[b] - tb[:, None] * d3[b], axis=1) - r[a] - r[b]
    return {(i, j): gg for i, j, gg in zip(a, b, g)}


def _normal_velocity(rows, u):
    from headsim.solvers._kernels import chains_pairs as KP

    out = np.empty(len(rows.body))
    KP.row_normal_velocity(rows.body, rows.partner, rows.normal, rows.lever, rows.partner_lever,
                           np.ascontiguousarray(u), out)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fibres", type=int, default=40)
    ap.add_argument("--segments", type=int, default=30)
    ap.add_argument("--settle", type=int, default=1500)
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE")
    args = ap.parse_args()
    from headsim.hair.drape import build_drape_scene
    from headsim.solvers.chains import ChainSolver

    over = {k: ast.literal_eval(v) for k, v in (kv.split("=", 1) for kv in args.set)}
    sc = build_drape_scene("sphere-helical", "aniso", n_fibres=args.fibres, segments=args.segments, **over)
    m = sc.model
    fib, so, r = m.segment_fibre, m.segment_offsets, float(m.radius[0])
    name = lambda s: f"f{fib[s]}k{s - so[fib[s]]}"  # noqa: E731
    solver = ChainSolver(sc.options)
    state = sc.state
    for _ in range(args.settle):
        state = solver.step(m, state, sc.dt, sc.obstacles)
    print(f"t = {state.time:.3f} s, max penetration {solver.last_stats.max_penetration * 1e6:.1f} µm "
          f"(r = {r * 1e6:.0f} µm), max joint gap {solver.last_stats.max_joint_gap * 1e6:.1f} µm")

    cap = {}
    det, joints, contacts = solver._detect, solver._joints, solver._contacts

    def _det(*a, **k):
        rows = det(*a, **k)
        cap["rows"], cap["mid"] = rows, (a[1].copy(), a[2].copy())
        return rows

    def _joints(model, x, R, v, w, *a):
        out = joints(model, x, R, v, w, *a)
        cap.setdefault("u", (np.concatenate([v, w], 1), np.concatenate([out[0], out[1]], 1)))
        return out

    def _contacts(rows, gaps, beta, *a, **k):
        u = contacts(rows, gaps, beta, *a, **k)
        jk, jl, jrk, jrl = solver._pass_setup[2][:4]
        k0 = np.maximum(jk, 0)
        vk = np.where((jk >= 0)[:, None], u[k0, :3] + np.cross(u[k0, 3:], jrk), 0.0)
        res = np.linalg.norm(vk - (u[jl, :3] + np.cross(u[jl, 3:], jrl)), axis=1).max(initial=0.0)
        cap.setdefault("jres", []).append((beta, res))
        return u

    solver._detect, solver._joints, solver._contacts = _det, _joints, _contacts
    for i in range(args.steps):
        cap.clear()
        g0 = _pair_gaps(m, state.position, state.rotation)
        new = solver.step(m, state, sc.dt, sc.obstacles)
        rows = cap["rows"]
        gm = _pair_gaps(m, *cap["mid"])
        g1 = _pair_gaps(m, new.position, new.rotation)
        print(f"step {i}: max penetration {solver.last_stats.max_penetration * 1e6:.1f} µm, rows {len(rows.gap)}, "
              f"with gap < 0: {(rows.gap < 0).sum()}, < −r: {(rows.gap < -r).sum()}")
        for j in np.argsort(rows.gap)[:6]:
            a, b = rows.body[j], rows.partner[j]
            print(f"   row gap {rows.gap[j] * 1e6:7.1f} µm  {name(a)} – {name(b) if b >= 0 else 'sphere'}  "
                  f"{'row' if rows.tight[j] else 'candidate'}")
        end = np.array(list(g1.values()))
        deep_end = [(k, g) for k, g in g1.items() if g < -r]
        roots = sum(1 for (a, b), _ in deep_end if a == so[fib[a]] and b == so[fib[b]])
        print(f"   end-of-step capsule overlaps: deepest {-end.min(initial=0) * 1e6:.1f} µm, deeper than r: "
              f"{len(deep_end)} (both root segments: {roots})")
        keys = [k for k in g0 if k in gm and k in g1 and g0[k] < -r]
        if keys:
            A = np.array([[g0[k], gm[k], g1[k]] for k in keys])
            print(f"   pairs deeper than r at t_i: {len(keys)}, mean gap change first half step "
                  f"{np.mean(A[:, 1] - A[:, 0]) * 1e6:+.2f} µm, second half step "
                  f"{np.mean(A[:, 2] - A[:, 1]) * 1e6:+.2f} µm")
        u0, uJ = cap["u"]
        a0, aJ = _normal_velocity(rows, u0), _normal_velocity(rows, uJ)
        for label, sel in (("fibre", (rows.gap < -r) & ~rows.obstacle), ("sphere", (rows.gap < -r) & rows.obstacle)):
            if sel.any():
                print(f"   {label} rows deeper than r: {sel.sum()}, normal velocity (+ separating) at t_i "
                      f"{a0[sel].mean() * 1e3:+.2f} mm/s, after the joint stage {aJ[sel].mean() * 1e3:+.2f} mm/s "
                      f"(min {aJ[sel].min() * 1e3:+.2f})")
        print("   joint-rate residual of the solutions: "
              + ", ".join(f"β = {b:g}: {res * 1e3:.2f} mm/s" for b, res in cap["jres"])
              + f"; max joint gap after the step {solver.last_stats.max_joint_gap * 1e6:.1f} µm")
        if i == 0:  # the same joint stage without the springs
            m0 = dataclasses.replace(m, joint_stiffness=0.0 * m.joint_stiffness)
            vJ0, wJ0, _, _ = joints(m0, state.position, state.rotation, state.velocity, state.angular_velocity, sc.dt,
                                    np.zeros((m.n_segments, 3)), np.zeros((m.n_segments, 3)))
            aJ0 = _normal_velocity(rows, np.concatenate([vJ0, wJ0], 1))
            sel = rows.gap < -r
            print(f"   joint stage with the joint springs set to zero: deep rows' normal velocity "
                  f"{aJ0[sel].mean() * 1e3:+.2f} mm/s (min {aJ0[sel].min() * 1e3:+.2f})")
        state = new


if __name__ == "__main__":
    main()
