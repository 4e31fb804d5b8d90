"""Experiment (issue 10): does an exact solve of the anchored root region, between Gauss–Seidel sweeps, remove the
coupled contact solve's slow mode?

The drape scene (``sphere-helical``, Sobottka 2008 §8.6.2) is advanced ``--settle`` steps and the next step's
first coupled contact solve is captured (as in ``bench_contact_convergence.py``). Its iteration
(:func:`headsim.solvers._kernels.chains_coupled.coupled_iterate`) is then replayed:

* ``GS n``: n Gauss–Seidel sweeps (the shipped Nesterov iteration) from the captured start;
* ``GS k + <local>(depth d) + m``: k sweeps, then the root region solved on its own with everything else held
  at its velocities after the k sweeps, then m sweeps warm-started from the resulting impulses. The root region:
  the first d segments of every fibre that has a fibre–fibre row between two such segments carrying an
  impulse after the k sweeps; its problem holds every row (from the start, not the candidates) and every joint
  that touches it; the other bodies of those rows and joints are held (their mass and inertia × 1e9, their
  velocity the iterate's). Local solvers (``--local``): ``exact``, :func:`headsim.solvers.chains_exact._exact_final_solve`
  (active set from the k sweeps' impulses, least-norm Schur complement, up to ``--rounds`` rounds); ``pgs``,
  :func:`local_delassus_pgs`, ``--local-sweeps`` sweeps of projected block Gauss–Seidel on the region's exact
  Delassus matrix (its chains, clamped at the roots and held at their far ends, eliminated exactly); ``dual``,
  :func:`block_dual_pgs`, the same sweeps as block coordinate descent of the whole problem over the region's
  rows: the other rows' impulses frozen, no body held, the Delassus matrix over the whole chains of the fibres
  the rows touch, started from the iterate's velocities;
* ``GS k + warm m``: the same continuation without the local solve.

Printed: CPU time, the relative error of the velocity correction in the kinetic metric against a
``--reference``-sweep answer, the largest bound violation and joint gap-rate residual (m/s) and the summed
normal impulse (N s).

Usage: python benchmarks/bench_root_solve.py [--fibres 30] [--segments 30] [--settle 20] [--geometry former]
       [--friction none] [--sweeps 30] [--more 10 30 90] [--depth 3 8] [--reference 20000] [--rounds 60]
       [--local exact pgs dual] [--local-sweeps 200]

Measured (twenty-second session, serial kernel; Python prototypes of the local solvers):

* former ringlet 30 × 30, t = 20 ms, frictionless (``--friction none``; 900 segments, 2,871 rows, 900
  joints): the 20,000-sweep answer's normal impulses sum to 3.0e-5 N s, 30 sweeps reach 3.1e-7 (the root
  segments pinched between their neighbours, see ``bench_contact_convergence.py``); relative error 0.920
  after 30 sweeps, 0.918 / 0.905 after 30 + 30 / 30 + 90, 0.895 after 120. Root region of depth 8 (240
  bodies, 273 rows, 270 joints): ``exact`` (1.4–1.6 s) gives the converged impulse sum at once and an error of
  0.080 after 30 / 90 more sweeps (largest violation 3.7e-5 m/s after 90; plain: 2.0e-3); ``pgs`` (200 local
  sweeps, 0.6 s) 0.062. Depth 3 (90 bodies, 66 rows): ``exact`` fails ('inconsistent'), ``pgs`` 0.235 / 0.233.
* the same with the anisotropic friction (``--friction aniso``): ``exact`` fails at depth 3 and 8
  ('inconsistent' within 60 rounds, 'active set' within the shipped 8: from 30 sweeps' impulses the sticking /
  sliding guess is too far off); ``pgs`` at depth 3 (90 rows, 0.3 s): 0.227 / 0.220 after 30 / 90 more sweeps
  (plain 0.921 / 0.903); at depth 8 (344 rows, 1.1 s): 3.8 after 30 more sweeps (a transient) and 0.041
  after 90; ``dual`` at depth 3 (0.5 s) and 8 (1.3–1.5 s): 0.295 / 0.293, without a transient (the regions' impulse
  sums 2.972e-5 / 2.973e-5 N s from 1.8e-7 / 2.0e-7).
* derived geometry, the 120 × 100 proxy of the reference scene at t = 0.5 s (aniso; 12,000 segments, 27,745
  rows, 32,228 candidates; the strand over the sphere's rim, a 4,000-sweep reference): here the iteration is
  not stuck (30 sweeps 0.041, 30 + 30 / 30 + 90 0.032 / 0.018, 60 / 120 sweeps 0.028 / 0.012), and ``pgs``
  wrecks it: depth 3 (282 bodies, 1,017 rows, 4.9 s) 3.9e3 / 3.1e2 after 30 / 90 more sweeps, the normal
  impulses summing to 2.4e-2 N s against 4.3e-6 (a held region is not a sub-problem of the whole: a body
  pressed between held ones can take unbounded impulses); depth 8 (952 bodies, 2,704 rows, 34 s) 225 / 0.87.
  ``dual`` is safe but hardly helps: depth 3 (28 s) 0.0302 / 0.0182, depth 8 (84 s) 0.0302 / 0.0165 after 30 /
  90 more sweeps, against 0.0324 / 0.0184 without it.

So the slow mode of the pinched ringlet is its root region: one solve of it on its exact Delassus matrix takes the
iteration from 0.92 to 0.04–0.3 of its error, where 90 more plain sweeps take it to 0.90. On the derived
geometry's proxy at t = 0.5 s the iteration has no such mode (the errors fall with the sweeps), and the safe form
(``dual``) gains 7–10 %; the held form (``pgs``) must not be used there. Whether the full-size resting strand
(whose root segments overlap from t ≈ 0.47 s on, ``bench_drape.py``, nineteenth and twentieth sessions) has the
ringlet's mode was not measured (no saved state). Not a solver yet: the prototypes cost 0.3–84 s.

Twenty-third session, the full-size resting strand (``--fibres 355 --segments 100 --settle 2 --geometry derived
--friction aniso --state benchmarks/data/drape_355x100_aniso_t1.0.npz --local dual --depth 3 --reference 4000
--more 30 90``; t = 1.002 s, 75,068 rows, 114,329 candidates, 35,500 joints): the iteration **stalls** here — 30 /
60 / 120 sweeps 0.0547 / 0.0354 / 0.0341 (30 + 30 / 30 + 90: 0.0543 / 0.0357), its normal impulses summing to
2.24e-5 N s after 60 and 120 sweeps against the reference's 2.45e-5 (largest bound violation 2.6 / 1.6 mm/s,
joint gap-rate residual 5.8 / 4.4 mm/s). The depth-3 root region (873 bodies, 4,428 rows, 1,164 joints) carries
half of all the normal impulse (1.07e-5 → 1.23e-5 N s after ``dual``), and ``dual`` there (288 s CPU) gives 0.0437 /
0.0308 after 30 / 90 more sweeps against 0.0543 / 0.0357 without it: 13–20 % less error, so the root region is part
of the stalled mode but not all of it. Depth 8 and ``exact`` / ``pgs`` were not run (time).
"""

from __future__ import annotations

import argparse
import time
import types

import numpy as np


def local_delassus(model, rows, joints, R, used, u_minus=None, chunk=256):
    """The exact Delassus matrix W = J_c K⁻¹ J_cᵀ (3 rows per contact: normal, t₁, t₂) of the contact rows over the
    bodies ``used`` (K: their M̃ with the joints as equality rows, :func:`headsim.solvers.chains_exact._exact_system`),
    with J_c; K⁻¹ applied in chunks of columns. Returns (W, J_c, u_free): u_free = K⁻¹ of the momentum at
    ``u_minus`` and the joint targets (velocities of ``used``), None without ``u_minus``."""
    import scipy.sparse
    import scipy.sparse.linalg

    from headsim.solvers import chains_exact as C

    Mt, momentum, G, J = C._exact_system(model, rows, np.zeros((model.n_segments, 6)) if u_minus is None else u_minus,
                                         R, joints, used)
    N, m = Mt.shape[0], len(rows.body)
    lu = scipy.sparse.linalg.splu(scipy.sparse.bmat([[Mt, -G.T], [G, None]]).tocsc())
    Jc = scipy.sparse.vstack(J).tocsr()[np.arange(3 * m).reshape(3, m).T.reshape(-1)]  # rows n, t₁, t₂ per contact
    JcT = Jc.T.tocsc()
    W = np.empty((3 * m, 3 * m))
    for c0 in range(0, 3 * m, chunk):
        rhs = np.zeros((N + G.shape[0], min(chunk, 3 * m - c0)))
        rhs[:N] = JcT[:, c0:c0 + chunk].toarray()
        W[:, c0:c0 + chunk] = Jc @ lu.solve(rhs)[:N]
    u_free = None if u_minus is None else lu.solve(np.concatenate([momentum, joints[4].reshape(-1)]))[:N]
    return W, Jc, u_free


def delassus_pgs(W, v, x, targets, polygon, sweeps):
    """Projected block Gauss–Seidel on W: per contact the normal impulse max(0, λ + (target − v_n)/W_nn), then the
    friction impulse by the kernel's exact polygon QP (λ·conv{μ_β d_β}); every update applied to all contact
    velocities v (3 per contact, consistent with the impulses x) at once. Returns x (m, 3) after ``sweeps``."""
    from headsim.solvers._kernels import chains as K

    x, v = x.reshape(-1).copy(), v.copy()
    m = len(x) // 3
    px, py = (np.ascontiguousarray(p) for p in polygon)
    for _ in range(sweeps):
        for i in range(m):
            a = 3 * i
            dn = max(0.0, x[a] + (targets[i] - v[a]) / W[a, a]) - x[a]
            if dn != 0.0:
                x[a] += dn
                v += W[:, a] * dn
            f_old = x[a + 1:a + 3].copy()
            if x[a] > 0.0 and len(px):
                B = np.ascontiguousarray(W[a + 1:a + 3, a + 1:a + 3])
                fx, fy = K._polygon_qp(B, v[a + 1:a + 3] - B @ f_old, px * x[a], py * x[a], len(px))
                f = np.array([fx, fy])
            else:
                f = np.zeros(2)
            df = f - f_old
            if df.any():
                x[a + 1:a + 3] = f
                v += W[:, a + 1:a + 3] @ df
    return x.reshape(m, 3)


def local_delassus_pgs(model, rows, joints, u_minus, R, targets, lam, fr, polygon, sweeps):
    """``--local pgs``: the root region (its other bodies held) solved by :func:`delassus_pgs` from its free
    velocities J_c u_free (u_free: K⁻¹ of the momentum and the joint targets). Returns (λ, friction)."""
    from headsim.solvers import chains_exact as C

    W, Jc, u_free = local_delassus(model, rows, joints, R, C._exact_bodies(rows, joints), u_minus)
    x = np.column_stack([lam, fr])
    x = delassus_pgs(W, Jc @ u_free + W @ x.reshape(-1), x, targets, polygon, sweeps)
    return x[:, 0].copy(), x[:, 1:].copy()


def block_dual_pgs(model, rows, joints, u, R, targets, lam, fr, polygon, sweeps):
    """``--local dual``: block coordinate descent of the whole problem over the root region's rows, the other rows'
    impulses frozen: W over every segment of the fibres those rows touch (whole chains, roots anchored, no body
    held), started from the current velocities J_c u (which already hold every impulse). Returns (λ, friction)."""
    fibres = np.unique(model.segment_fibre[np.concatenate([rows.body, rows.partner[rows.partner >= 0]])])
    used = np.flatnonzero(np.isin(model.segment_fibre, fibres))
    jsel = np.flatnonzero(np.isin(joints[1], used))
    chain_joints = tuple(j[jsel] for j in joints[:7]) + (None,)
    W, Jc, _ = local_delassus(model, rows, chain_joints, R, used)
    x = delassus_pgs(W, Jc @ u[used].reshape(-1), np.column_stack([lam, fr]), targets, polygon, sweeps)
    return x[:, 0].copy(), x[:, 1:].copy()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fibres", type=int, default=30)
    ap.add_argument("--segments", type=int, default=30)
    ap.add_argument("--settle", type=int, default=20)
    ap.add_argument("--geometry", choices=("derived", "former"), default="former")
    ap.add_argument("--friction", default="none")
    ap.add_argument("--sweeps", type=int, default=30)
    ap.add_argument("--more", type=int, nargs="+", default=[10, 30, 90])
    ap.add_argument("--depth", type=int, nargs="+", default=[3, 8])
    ap.add_argument("--reference", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=60)
    ap.add_argument("--local", nargs="+", choices=("exact", "pgs", "dual"), default=["exact", "pgs", "dual"],
                    help="local solvers: the active-set exact solve, projected Gauss-Seidel on the held region's "
                         "exact Delassus matrix, block descent over the region's rows with whole chains")
    ap.add_argument("--local-sweeps", type=int, default=200)
    ap.add_argument("--state", metavar="FILE.npz",
                    help="start from a saved state (drape_states.py, e.g. the one bench_drape.py --save-state "
                         "writes); --geometry then only sets up the scene")
    args = ap.parse_args()
    from bench_contact_convergence import _residuals, capture_first_solve, iterate_args

    from headsim.solvers import chains_exact as C
    from headsim.solvers._kernels import chains_coupled as KC

    scene, state, a0 = capture_first_solve(args.fibres, args.segments, args.settle, args.friction, args.geometry,
                                           start=args.state)
    ix = iterate_args()
    n_listed = a0[ix["n_listed_rows"]]
    u_minus, mass, R = a0[ix["u"]].copy(), a0[ix["mass"]], a0[ix["R"]]
    model = scene.model
    S = model.n_segments
    Iw = np.einsum("sac,sc,sbc->sab", R, a0[ix["inertia"]], R)

    def m2(du):
        return float((mass * (du[:, :3] ** 2).sum(1)).sum() + np.einsum("sa,sab,sb->", du[:, 3:], Iw, du[:, 3:]))

    def run(n, lam=None, fr=None):
        a = [x.copy() if isinstance(x, np.ndarray) else x for x in a0]
        a[ix["max_iter"]], a[ix["tol"]] = int(n), 0.0
        if lam is not None:
            a[ix["lam_out"]][:], a[ix["fr_out"]][:] = lam, fr
        c = time.process_time()
        KC.coupled_iterate(*a)
        return a, time.process_time() - c

    ref, _ = run(args.reference)
    u_ref = ref[ix["u"]]

    def report(name, a, cpu):
        u = a[ix["u"]]
        viol, jr = _residuals(a, u)
        print(f"{name:34s} CPU {cpu:6.3f} s, rel. M-error {np.sqrt(m2(u - u_ref) / m2(u_ref - u_minus)):.3e}, "
              f"max violation {viol:.2e} m/s, max joint residual {jr:.2e} m/s, "
              f"normal impulses sum {a[ix['lam_out']].sum():.3e} N s", flush=True)

    body, partner = a0[ix["body"]], a0[ix["partner"]]
    n_rows = len(body)
    first = np.searchsorted(model.segment_fibre, model.segment_fibre, side="left")
    segment_index = np.arange(S) - first
    print(f"t = {state.time:.3f} s, {S} segments, {n_listed} rows from the start, {n_rows - n_listed} candidates, "
          f"{len(a0[ix['joint_k']])} joints, friction {args.friction}")
    report(f"reference {args.reference}", ref, 0.0)
    k = args.sweeps
    for m in args.more:
        report(f"GS {k + m}", *run(k + m))
    a_k, cpu_k = run(k)
    report(f"GS {k}", a_k, cpu_k)
    lam_k, fr_k, u_k = a_k[ix["lam_out"]].copy(), a_k[ix["fr_out"]].copy(), a_k[ix["u"]].copy()
    for m in args.more:
        a, c = run(m, lam_k, fr_k)
        report(f"GS {k} + warm {m}", a, cpu_k + c)

    fibre_rows = partner >= 0
    pb = np.maximum(partner, 0)
    for depth in args.depth:
        pinch = fibre_rows & (segment_index[body] < depth) & (segment_index[pb] < depth) & (lam_k > 0)
        fibres = np.unique(np.concatenate([model.segment_fibre[body[pinch]], model.segment_fibre[pb[pinch]]]))
        inside = np.isin(model.segment_fibre, fibres) & (segment_index < depth)
        rsel = np.flatnonzero((inside[body] | (fibre_rows & inside[pb])) & (np.arange(n_rows) < n_listed))
        jk, jl = a0[ix["joint_k"]], a0[ix["joint_l"]]
        jsel = np.flatnonzero(inside[jl] | ((jk >= 0) & inside[np.maximum(jk, 0)]))
        held = ~inside
        held_mass, held_inertia = mass.copy(), a0[ix["inertia"]].copy()
        held_mass[held] *= 1e9
        held_inertia[held] *= 1e9
        um = u_minus.copy()
        um[held] = u_k[held]
        local_model = types.SimpleNamespace(mass=held_mass, inertia=held_inertia, n_segments=S)
        rows = types.SimpleNamespace(body=body[rsel], partner=partner[rsel], normal=a0[ix["normal"]][rsel],
                                     lever=a0[ix["lever"]][rsel], partner_lever=a0[ix["partner_lever"]][rsel])
        joints = tuple(a0[ix[name]][jsel] for name in ("joint_k", "joint_l", "joint_rk", "joint_rl", "joint_target",
                                                       "joint_compliance_inv", "joint_w0")) + (None,)
        for local in args.local:
            c = time.process_time()
            if local == "exact":
                C.EXACT_FAILURES.clear()
                out = C._exact_final_solve(local_model, rows, lam_k[rsel], fr_k[rsel], a0[ix["target"]][rsel], um, R,
                                           joints, (a0[ix["mu_cos"]], a0[ix["mu_sin"]]), max_dof=10**9,
                                           rounds=args.rounds)
                out = None if out is None else out[1:]
                outcome = "ok" if out is not None else dict(C.EXACT_FAILURES)
            elif local == "pgs":
                out = local_delassus_pgs(local_model, rows, joints, um, R, a0[ix["target"]][rsel], lam_k[rsel],
                                         fr_k[rsel], (a0[ix["mu_cos"]], a0[ix["mu_sin"]]), args.local_sweeps)
                outcome = f"{args.local_sweeps} sweeps"
            else:
                all_joints = tuple(a0[ix[name]] for name in ("joint_k", "joint_l", "joint_rk", "joint_rl",
                                                             "joint_target", "joint_compliance_inv", "joint_w0"))
                out = block_dual_pgs(model, rows, all_joints, u_k, R, a0[ix["target"]][rsel], lam_k[rsel],
                                     fr_k[rsel], (a0[ix["mu_cos"]], a0[ix["mu_sin"]]), args.local_sweeps)
                outcome = f"{args.local_sweeps} sweeps"
            c_local = time.process_time() - c
            print(f"   root region of depth {depth}: {int(inside.sum())} bodies, {len(rsel)} rows, {len(jsel)} "
                  f"joints; {local} {outcome} in {c_local:.3f} s CPU")
            if out is None:
                continue
            lam, fr = lam_k.copy(), fr_k.copy()
            lam[rsel], fr[rsel] = out[0], out[1]
            print(f"   local impulses: {len(rsel)} rows, sum {out[0].sum():.4e} N s (before {lam_k[rsel].sum():.4e})")
            for m in args.more:
                a, c = run(m, lam, fr)
                report(f"GS {k} + {local}(depth {depth}) + {m}", a, cpu_k + c_local + c)


if __name__ == "__main__":
    main()
