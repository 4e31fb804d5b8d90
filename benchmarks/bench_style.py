"""Benchmark: hairstyle reconstruction (Sobottka 2008 ch. 5) on the bundled head.

Goal (issue 12): 90 k fibres / 3 k guides in <= 30 s on 2 cores (seed: ~150 s on a 2.2 GHz P4). Prints the
wall and CPU time (time.process_time) of every stage, the machine load, and a baseline ratio: the same main-guide
optimisation written straightforwardly (NumPy objective through ``solvers.rods_statics.pai_static``, scipy
L-BFGS-B with scipy's own finite-difference gradient, one guide after another in Python) run in the same process
on a sample of guides and EXTRAPOLATED to all guides. Numba compilation is excluded by a warm-up run.

    python benchmarks/bench_style.py [--style short|long] [--fibres 90000] [--guides 3000] [--baseline-guides 30]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _timed(fn, *a, **kw):
    w, c = time.perf_counter(), time.process_time()
    out = fn(*a, **kw)
    return out, time.perf_counter() - w, time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--style", default="short", choices=["short", "long"])
    ap.add_argument("--fibres", type=int, default=90_000)
    ap.add_argument("--guides", type=int, default=3000)
    ap.add_argument("--density-model", default="continuous", choices=["none", "binary", "continuous"])
    ap.add_argument("--baseline-guides", type=int, default=10)
    args = ap.parse_args()

    from headsim.hair.reconstruct import StyleOptions, boundary_fields, bundled_inputs, reconstruct
    from headsim.hair.reconstruct._reference import reference_optimise_guide
    from headsim.hair.reconstruct.density import DensityGrid
    from headsim.hair.reconstruct.growth import (GuideOptions, grow_preguides, optimise_guide, rod_stiffness,
                                                 root_frames)
    from headsim.hair.reconstruct.maps import ScalpMap, default_maps, farthest_point_order

    print(f"load average at start: {os.getloadavg()}")
    inputs, w_in, c_in = _timed(bundled_inputs, args.style)
    print(f"input preparation (scalp cut + generated {args.style} hair volume): {w_in:.2f} s wall, {c_in:.2f} s CPU")
    fields, w_f, c_f = _timed(boundary_fields, inputs)
    print(f"distance fields (head 3 mm, hair volume 4 mm narrow bands): {w_f:.2f} s wall, {c_f:.2f} s CPU")
    opts = StyleOptions(n_fibres=args.fibres, n_guides=args.guides, style=args.style, density_model=args.density_model)
    _timed(reconstruct, inputs, StyleOptions(n_fibres=2000, n_guides=40, style=args.style,
                                             density_model=args.density_model), fields=fields)  # Numba warm-up

    hs, wall, cpu = _timed(reconstruct, inputs, opts, fields=fields)
    print(f"\nreconstruction, {args.fibres} fibres / {args.guides} guides / {opts.n_segments} segments, "
          f"density model {args.density_model}:")
    for stage, t in hs.timings.items():
        if stage not in ("total", "distance fields"):
            print(f"  {stage:16s} {t:7.2f} s wall {hs.timings_cpu[stage]:7.2f} s CPU")
    print(f"  {'all stages':16s} {wall:7.2f} s wall, {cpu:.2f} s CPU")
    total_w = wall + w_f
    total_c = cpu + c_f
    print(f"  with the distance fields: {total_w:.2f} s wall, {total_c:.2f} s CPU  (goal <= 30 s; seed ~150 s)")
    print(f"  with input preparation too: {total_w + w_in:.2f} s wall, {total_c + c_in:.2f} s CPU")
    st = hs.stats
    print(f"  fibres kept {st['fibres_kept']} (dropped {st['fibres_dropped']}), pre-guides {st['preguides']} "
          f"({100 * st['preguides_fitted']:.0f} % met the depth), guides cut {100 * st['guides_cut']:.0f} %, "
          f"objective evaluations {st['objective_evaluations']}, occupancy CV {st['occupancy_cv']:.3f}")

    # the seed's Fig. 5.6 as a number: the same run without a density model and with the binary one
    for model in [m for m in ("none", "binary", "continuous") if m != args.density_model]:
        other, w_o, c_o = _timed(reconstruct, inputs, StyleOptions(n_fibres=args.fibres, n_guides=args.guides,
                                                                   style=args.style, density_model=model), fields=fields)
        print(f"  density model {model:10s}: occupancy CV {other.stats['occupancy_cv']:.3f} "
              f"(guides {other.timings['guides']:.1f} s wall, {other.timings_cpu['guides']:.1f} s CPU)")
    print(f"  density model {args.density_model:10s}: occupancy CV {hs.stats['occupancy_cv']:.3f}  "
          f"(coefficient of variation of segments per 5 mm cell; lower = more homogeneous)")

    # baseline: the same optimisation per guide, straightforward, on a sample of guides (same inputs, same start)
    go = GuideOptions()
    head_f, hair_f = fields
    smap = ScalpMap(inputs.scalp)
    roots = smap.sample_roots(*default_maps(hs.stats.get("length", None) or (0.07 if args.style == "short" else 0.26)),
                              n=args.fibres, seed=0)
    K = rod_stiffness()
    pre_ids = farthest_point_order(roots.positions, max(3, int(round(smap.area * 1e4))), seed=1)
    pre = grow_preguides(roots.subset(pre_ids), hair_f, K, opts.n_segments, go)
    ids = farthest_point_order(roots.positions, args.baseline_guides, seed=2)
    g = roots.subset(ids)
    R0 = root_frames(g)
    lo, hi = inputs.volume.bounds
    dens = DensityGrid(args.density_model, lo, hi, 0.0025)
    dens.calibrate(head_f, hair_f, float(g.lengths.mean()) * args.guides)
    from scipy.spatial import cKDTree

    dist, near = cKDTree(pre.roots.positions).query(g.positions, k=3)
    w = 1.0 / (dist + 1e-3)
    w /= w.sum(1, keepdims=True)
    pre_d3 = np.ascontiguousarray(pre.frames[:, :, :, 2])
    pre_kl = np.ascontiguousarray(pre.kappa * pre.roots.lengths[:, None, None])
    fast_f, base_f = [], []
    t_fast = c_fast = t_base = c_base = 0.0
    from threadpoolctl import threadpool_limits

    blas = threadpool_limits(limits=1, user_api="blas")  # as in the pipeline, for both
    np.seterr(over="ignore", invalid="ignore")  # the plain objective overflows harmlessly at extreme probes
    for k in range(len(ids)):
        eta0 = (w[k, :, None] * pre.eta[near[k]]).sum(0)
        a = (R0[k], g.positions[k], K, float(g.lengths[k]), opts.n_segments, np.ascontiguousarray(pre_d3[near[k]]),
             np.ascontiguousarray(pre_kl[near[k]]), np.ascontiguousarray(w[k]), head_f, hair_f, dens, go, eta0)
        res, tw, tc = _timed(optimise_guide, *a)
        fast_f.append(res[1])
        t_fast += tw
        c_fast += tc
        res, tw, tc = _timed(reference_optimise_guide, *a)
        base_f.append(res[1])
        t_base += tw
        c_base += tc
    blas.restore_original_limits()
    n = len(ids)
    print(f"\nbaseline (per-guide Python loop, NumPy objective, scipy finite differences), {n} guides:")
    print(f"  fast   {1e3 * t_fast / n:8.2f} ms/guide wall, {1e3 * c_fast / n:8.2f} ms CPU; mean f {np.mean(fast_f):.5f}")
    print(f"  plain  {1e3 * t_base / n:8.2f} ms/guide wall, {1e3 * c_base / n:8.2f} ms CPU; mean f {np.mean(base_f):.5f}")
    print(f"  ratio  {t_base / t_fast:.1f}x wall, {c_base / c_fast:.1f}x CPU")
    print(f"  EXTRAPOLATED to {args.guides} guides: baseline guide stage {c_base / n * args.guides:.0f} s CPU "
          f"(fast, same sample: {c_fast / n * args.guides:.1f} s CPU; measured in the pipeline: "
          f"{hs.timings_cpu['guides']:.1f} s CPU, {hs.timings['guides']:.1f} s wall)")
    print(f"load average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
