"""Benchmark: Coulomb forces for the seed's test 1 (Sobottka §4.5: 300 fibres x 30 cm at 330 charges/cm,
~3 M charges): the treecode against fmm3dpy at the same requested accuracy and the exact direct sum
on a subsample of targets (its full cost is extrapolated). Prints wall and CPU time (the machine may
be shared), errors against the exact sum at the subsample, and the ratios. Then an accuracy table
(fmm3dpy eps, treecode theta/order against the direct sum) on a smaller bundle.

    python benchmarks/bench_electrostatics.py            # full size (~3 M charges; fmm3dpy takes minutes)
    python benchmarks/bench_electrostatics.py --quick    # 30 fibres (~0.3 M charges)
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


class Clock:
    def __enter__(self):
        self.w, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *a):
        self.wall = time.perf_counter() - self.w
        self.cpu = time.process_time() - self.c


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="30 fibres instead of 300")
    ap.add_argument("--theta", type=float, default=0.5)
    ap.add_argument("--order", type=int, default=2)
    ap.add_argument("--leaf", type=int, default=32)
    ap.add_argument("--eps", type=float, default=1e-3)
    ap.add_argument("--targets", type=int, default=400, help="subsample size for the exact direct sum")
    ap.add_argument("--no-local", action="store_true", help="treecode without cell-to-leaf local expansions")
    ap.add_argument("--no-fmm", action="store_true", help="skip fmm3dpy at full size")
    ap.add_argument("--no-table", action="store_true")
    args = ap.parse_args()

    import numba

    from headsim.hair.electrostatics import (
        Treecode,
        TreecodeOptions,
        accuracy_table,
        bundle_scene,
        direct_field,
        fmm_field,
        force_errors,
        format_table,
        sample_charges,
    )
    from headsim.hair.electrostatics.charging import equilibrate
    from headsim.hair.electrostatics.units import SEED_LINE_CHARGE_STATC_PER_CM, statc_per_cm_to_c_per_m

    print(f"numba threads: {numba.get_num_threads()}, cores: {os.cpu_count()}, load: {os.getloadavg()}")
    n_fibres = 30 if args.quick else 300
    sc = bundle_scene(n_fibres=n_fibres)
    _, pos, _ = equilibrate(sc.model, (0.0, -9.81, 0.0))
    smp = sample_charges(sc.model.length, sc.model.n_segments, 33000.0)
    x = smp.positions(pos)
    q = smp.charges(statc_per_cm_to_c_per_m(SEED_LINE_CHARGE_STATC_PER_CM))
    n = len(q)
    print(f"test 1 bundle: {n_fibres} fibres x 30 cm x 100 segments, {n:,} charges (330 /cm)")

    # warm up the JIT on a small problem (compile time is not part of one evaluation)
    Treecode(x[:5000], q[:5000]).field()
    direct_field(x[:100], q[:100])

    rng = np.random.default_rng(0)
    sub = np.sort(rng.choice(n, size=min(args.targets, n), replace=False))
    with Clock() as c_dir:
        E_ref = direct_field(x, q, targets=x[sub])
    # remove the self term: the target is one of the sources (direct_field skips r = 0 already)
    t_direct_full = c_dir.wall * n / len(sub)
    cpu_direct_full = c_dir.cpu * n / len(sub)
    print(f"direct sum on {len(sub)} targets: {c_dir.wall:.2f} s wall, {c_dir.cpu:.2f} s CPU "
          f"-> full direct sum extrapolated {t_direct_full:.0f} s wall, {cpu_direct_full:.0f} s CPU")

    opts = TreecodeOptions(args.theta, args.order, args.leaf, not args.no_local)
    with Clock() as c_build:
        tree = Treecode(x, q, opts)
    with Clock() as c_eval:
        E_tree, counts = tree.field(return_counts=True)
    moved = x + 1e-4 * np.sin(50 * x[:, [1, 2, 0]])
    with Clock() as c_refit:
        tree.refit(moved, q)
    with Clock() as c_eval2:
        tree.field()
    err_tree = force_errors(E_tree[sub], E_ref)
    t_tree = c_build.wall + c_eval.wall
    cpu_tree = c_build.cpu + c_eval.cpu
    print(f"treecode theta={args.theta} order={args.order} leaf={args.leaf} local={not args.no_local}: "
          f"build {c_build.wall:.2f} s "
          f"(CPU {c_build.cpu:.2f}), evaluation {c_eval.wall:.2f} s (CPU {c_eval.cpu:.2f}); "
          f"refit {c_refit.wall:.2f} s + evaluation {c_eval2.wall:.2f} s (CPU {c_refit.cpu + c_eval2.cpu:.2f})")
    n_leaves = len(tree.leaves)
    print(f"  cell-to-leaf expansions {counts['cell_to_leaf']:,} ({counts['cell_to_leaf'] / n_leaves:.0f}/leaf), "
          f"far-cell evaluations {counts['far_evaluations']:,} ({counts['far_evaluations'] / n:.0f}/charge), "
          f"near pairs {counts['near_pairs']:,} ({counts['near_pairs'] / n:.0f}/charge)")
    print(f"  errors at the subsample: mean angle {err_tree['mean_angle_rad']:.2e} rad, "
          f"max rel {err_tree['max_relative']:.2e}, rms rel {err_tree['rms_relative']:.2e}")
    print(f"  speed-up vs the direct sum: {t_direct_full / t_tree:.0f}x wall, {cpu_direct_full / cpu_tree:.0f}x CPU")

    if not args.no_fmm:
        with Clock() as c_fmm:
            E_fmm = fmm_field(x, q, args.eps)
        err_fmm = force_errors(E_fmm[sub], E_ref)
        print(f"fmm3dpy eps={args.eps:g}: {c_fmm.wall:.2f} s wall, {c_fmm.cpu:.2f} s CPU; errors: mean angle "
              f"{err_fmm['mean_angle_rad']:.2e} rad, max rel {err_fmm['max_relative']:.2e}, "
              f"rms rel {err_fmm['rms_relative']:.2e}")
        print(f"  treecode vs fmm3dpy: {c_fmm.wall / t_tree:.1f}x wall, {c_fmm.cpu / cpu_tree:.1f}x CPU "
              f"(build + evaluation); refit + evaluation {c_fmm.wall / (c_refit.wall + c_eval2.wall):.1f}x wall")

    if not args.no_table:
        k = 3 if args.quick else 10
        xs, qs = x[: smp.offsets[k]], q[: smp.offsets[k]]
        print(f"\naccuracy table on {k} fibres of the bundle ({len(qs):,} charges) against the direct sum:")
        rows = accuracy_table(xs, qs, fmm_eps=(1e-2, 1e-3, 1e-6, 1e-9), thetas=(0.8, 0.5, 0.3, 0.2), orders=(0, 2),
                              leaf_size=args.leaf)
        print(format_table(rows))


if __name__ == "__main__":
    main()
