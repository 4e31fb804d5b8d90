"""Benchmark: headsim.collide.TriangleBVH against brute force, trimesh and libigl on the bundled face.

    python benchmarks/bench_collide.py            # 100k queries
    python benchmarks/bench_collide.py --quick    # 10k queries

Every library is warmed up on a few queries first, so Numba compilation (and cache loading) is
excluded from the timings. Each fast timing is the best of ``--repeat`` runs; slow baselines
(brute force, trimesh's pure-Python paths) run on a subsample and are extrapolated linearly to the
full query count, which the output says. Ratios are "baseline time / headsim time" (> 1: headsim
is faster).
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np


def _load_face():
    from headsim.data import face_path

    try:
        from headsim.mesh.io import load_surface

        mesh = load_surface(face_path())
        return np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    except ImportError:
        import trimesh

        m = trimesh.load(face_path(), process=False)
        return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


class Timing:
    """Best wall-clock and process CPU time (all threads) of a call, s."""

    def __init__(self, wall: float, cpu: float):
        self.wall = wall
        self.cpu = cpu

    def __sub__(self, other: "Timing") -> "Timing":
        return Timing(self.wall - other.wall, self.cpu - other.cpu)


def best_time(fn, repeat: int) -> Timing:
    wall = cpu = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return Timing(wall, cpu)


def extrapolated(fn, n_sub: int, n_full: int) -> Timing:
    t = best_time(fn, 1)
    return Timing(t.wall * n_full / n_sub, t.cpu * n_full / n_sub)


class Table:
    def add(self, query, method, t: Timing, ours: Timing | None = None, note=""):
        ratio = f"{t.wall / ours.wall:8.1f}x {t.cpu / ours.cpu:8.1f}x" if ours else f"{'-':>9} {'-':>9}"
        print(f"  {query:<22} {method:<46} {t.wall:10.4f} s {t.cpu:10.4f} s {ratio}  {note}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="10k queries instead of 100k")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs for fast timings")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    n = 10_000 if args.quick else 100_000
    n_brute = 200 if args.quick else 500
    n_trimesh_closest = 200 if args.quick else 1000
    rng = np.random.default_rng(args.seed)

    from headsim.collide import TriangleBVH
    from headsim.collide import _reference as ref

    V, F = _load_face()
    lo, hi = V.min(axis=0), V.max(axis=0)
    print(f"face: {len(V)} vertices, {len(F)} triangles, extent {np.round((hi - lo) * 1000, 1)} mm")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"queries: {n}; numba threads: {numba.get_num_threads()}; CPU cores: {os.cpu_count()}; "
          f"load average at start: {load:.1f}")
    print("times: best of --repeat runs; 'CPU' is process CPU time summed over threads (a fairer\n"
          "comparison when the machine is shared); ratios are baseline / headsim (> 1: headsim faster)")

    # query sets ---------------------------------------------------------------------------------
    box_points = rng.uniform(lo - 0.02, hi + 0.02, (n, 3))  # bounding box + 2 cm
    tri = rng.integers(0, len(F), n)
    w = rng.dirichlet([1, 1, 1], n)
    near_points = np.einsum("qi,qik->qk", w, V[F[tri]]) + rng.normal(scale=2e-3, size=(n, 3))  # ~2 mm
    ray_o = rng.uniform(lo - 0.02, hi + 0.02, (n, 3))
    ray_d = rng.normal(size=(n, 3))
    ray_d /= np.linalg.norm(ray_d, axis=1, keepdims=True)
    # rays cast at the face from the front (+z), like the heightmap or a mask approaching
    front_o = np.column_stack([rng.uniform(lo[0], hi[0], n), rng.uniform(lo[1], hi[1], n), np.full(n, hi[2] + 0.05)])
    front_d = np.tile([0.0, 0.0, -1.0], (n, 1)) + rng.normal(scale=0.1, size=(n, 3))
    front_d /= np.linalg.norm(front_d, axis=1, keepdims=True)

    # warm-up (Numba compile / cache load) ---------------------------------------------------------
    t0 = time.perf_counter()
    bvh = TriangleBVH(V, F)
    bvh.closest_points(box_points[:3000])
    bvh.intersect_rays(ray_o[:3000], ray_d[:3000])
    bvh.intersect_rays_all(ray_o[:3000], ray_d[:3000])
    bvh.contains(box_points[:3000])
    bvh.refit(V)
    print(f"warm-up (Numba compile or cache load, excluded below): {time.perf_counter() - t0:.1f} s\n")

    table = Table()
    print(f"  {'query':<22} {'method':<46} {'wall':>12} {'CPU':>12} {'ratio wall':>10} {'CPU':>8}")

    # build and refit ------------------------------------------------------------------------------
    t_build = best_time(lambda: TriangleBVH(V, F), args.repeat)
    table.add("BVH build", f"headsim binned SAH ({bvh.n_nodes} nodes, depth {bvh.depth})", t_build)
    Vd = V + rng.normal(scale=1e-3, size=V.shape)  # random 1 mm deformation
    t_refit = best_time(lambda: bvh.refit(Vd), 10 * args.repeat)
    table.add("BVH refit", "headsim bottom-up refit after 1 mm noise", t_refit, note="(per solver step)")
    bvh.refit(V)
    import igl

    t_igl_tree = best_time(lambda: igl.AABB().init(V, F), args.repeat)
    table.add("BVH build", "libigl AABB.init (closest point / ray tree)", t_igl_tree, t_build)
    import trimesh

    mesh = trimesh.Trimesh(V, F, process=False)
    try:
        import trimesh.ray.ray_pyembree as ray_pyembree

        t_embree_build = best_time(lambda: ray_pyembree.RayMeshIntersector(trimesh.Trimesh(V, F, process=False))
                                   .intersects_first(ray_o[:1], ray_d[:1]), args.repeat)
        table.add("BVH build", "embree scene via trimesh (+1 ray)", t_embree_build, t_build)
    except ImportError:
        ray_pyembree = None
        print("  (embreex not installed: embree rows skipped)")

    # closest point ----------------------------------------------------------------------------------
    for label, pts in (("closest (box)", box_points), ("closest (near 2 mm)", near_points)):
        numba.set_num_threads(1)
        t_serial = best_time(lambda: bvh.closest_points(pts), args.repeat)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        t_ours = best_time(lambda: bvh.closest_points(pts), args.repeat)
        table.add(label, f"headsim BVH, {numba.get_num_threads()} threads", t_ours)
        table.add(label, "headsim BVH, 1 thread", t_serial, t_ours)
        tree = igl.AABB()
        tree.init(V, F)
        t_igl = best_time(lambda: tree.squared_distance(V, F, pts), args.repeat)
        table.add(label, "libigl AABB.squared_distance (prebuilt tree)", t_igl, t_ours)
        t_igl2 = best_time(lambda: igl.point_mesh_squared_distance(pts, V, F), 1)
        table.add(label, "libigl point_mesh_squared_distance (+build)", t_igl2, t_ours)
        sub = pts[:n_trimesh_closest]
        t_tm = extrapolated(lambda: trimesh.proximity.closest_point(mesh, sub), len(sub), n)
        table.add(label, "trimesh.proximity.closest_point", t_tm, t_ours, f"(extrapolated from {len(sub)})")
        sub = pts[:n_brute]
        t_bf = extrapolated(lambda: ref.closest_points_bruteforce(sub, V, F), len(sub), n)
        table.add(label, "brute force O(q·m) NumPy", t_bf, t_ours, f"(extrapolated from {len(sub)})")
        got = bvh.closest_points(pts)
        d2, _, _ = tree.squared_distance(V, F, pts)
        print(f"    check: max |distance - libigl| = {np.abs(got.distance - np.sqrt(d2)).max():.2e} m")

    # inside / signed distance -----------------------------------------------------------------------
    t_wn = best_time(lambda: bvh.winding_number(box_points), args.repeat)
    table.add("winding number", "headsim BVH, 3rd-order far field, beta=2", t_wn)
    t_moments = best_time(lambda: (bvh.refit(V), bvh._winding_data()), args.repeat) - t_refit
    table.add("winding number", "headsim far-field moments after a refit", t_moments, note="(once per refit)")
    t_wn3 = best_time(lambda: bvh.winding_number(box_points, beta=3.0), args.repeat)
    table.add("winding number", "headsim BVH, 3rd-order far field, beta=3", t_wn3, t_wn)
    t_fwn = best_time(lambda: igl.fast_winding_number(V, F, box_points), args.repeat)
    table.add("winding number", "libigl fast_winding_number (+precompute)", t_fwn, t_wn)
    sub = box_points[:n_brute]
    t_wex = extrapolated(lambda: ref.winding_number_exact(sub, V, F), len(sub), n)
    table.add("winding number", "exact sum O(q·m) NumPy", t_wex, t_wn, f"(extrapolated from {len(sub)})")
    exact = igl.winding_number(V, F, box_points[:5000])
    print(f"    check: max |w - exact| on 5000 points: headsim beta=2 "
          f"{np.abs(bvh.winding_number(box_points[:5000]) - exact).max():.1e}, beta=3 "
          f"{np.abs(bvh.winding_number(box_points[:5000], beta=3.0) - exact).max():.1e}, libigl fast "
          f"{np.abs(igl.fast_winding_number(V, F, box_points[:5000]) - exact).max():.1e}")
    t_sd = best_time(lambda: bvh.signed_distance(near_points), args.repeat)
    table.add("signed distance", "headsim BVH (closest + winding)", t_sd)
    t_igl_sd = best_time(lambda: igl.signed_distance(near_points, V, F), 1)
    table.add("signed distance", "libigl signed_distance (winding sign)", t_igl_sd, t_sd)
    ours_sd = bvh.signed_distance(near_points)
    igl_sign = np.sign(igl.signed_distance(near_points, V, F)[0])  # its value is (1 - 2w) d: not a distance
    igl_abs = np.abs(igl.signed_distance(near_points, V, F,
                                         sign_type=igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)[0])
    print(f"    check: |signed distance| vs libigl max diff {np.abs(np.abs(ours_sd) - igl_abs).max():.1e} m, "
          f"same sign as libigl's winding sign on {np.mean(np.sign(ours_sd) == igl_sign):.4%} of points")

    # rays ----------------------------------------------------------------------------------------------
    for label, o, d in (("ray first hit (random)", ray_o, ray_d), ("ray first hit (front)", front_o, front_d)):
        numba.set_num_threads(1)
        t_serial = best_time(lambda: bvh.intersect_rays(o, d), args.repeat)
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        t_ours = best_time(lambda: bvh.intersect_rays(o, d), args.repeat)
        hits = bvh.intersect_rays(o, d)
        table.add(label, f"headsim BVH, {numba.get_num_threads()} threads", t_ours, note=f"({hits.hit.mean():.0%} hit)")
        table.add(label, "headsim BVH, 1 thread", t_serial, t_ours)
        if ray_pyembree is not None:
            emb = ray_pyembree.RayMeshIntersector(mesh)
            emb.intersects_first(o[:10], d[:10])
            t_emb = best_time(lambda: emb.intersects_location(o, d, multiple_hits=False), args.repeat)
            table.add(label, "trimesh + embree (float32) intersects_location", t_emb, t_ours)
            loc, ir, _ = emb.intersects_location(o, d, multiple_hits=False)
            agree = np.zeros(len(o), bool)
            agree[ir] = True
            dist = np.linalg.norm(loc - o[ir], axis=1)
            both = hits.hit[ir]
            print(f"    check: hit flags agree with embree on {np.mean(agree == hits.hit):.4%} of rays, "
                  f"max |distance difference| {np.abs(dist[both] - hits.distance[ir][both]).max():.1e} m")
        tree = igl.AABB()
        tree.init(V, F)
        t_igl = best_time(lambda: tree.intersect_ray_first(V, F, o, d), 1)
        table.add(label, "libigl AABB.intersect_ray_first (prebuilt)", t_igl, t_ours)
        sub = slice(0, 2000)
        t_tri = extrapolated(lambda: trimesh.ray.ray_triangle.RayMeshIntersector(mesh).intersects_first(o[sub], d[sub]),
                             2000, n)
        table.add(label, "trimesh ray_triangle (no embree, rtree)", t_tri, t_ours, "(extrapolated from 2000)")
        sub = slice(0, n_brute)
        t_bf = extrapolated(lambda: ref.intersect_rays_bruteforce(o[sub], d[sub], V, F), n_brute, n)
        table.add(label, "brute force O(q·m) NumPy", t_bf, t_ours, f"(extrapolated from {n_brute})")
    t_all = best_time(lambda: bvh.intersect_rays_all(ray_o, ray_d), args.repeat)
    table.add("ray all hits (random)", "headsim BVH (two passes, sorted)", t_all)
    if ray_pyembree is not None:
        t_emb_all = best_time(lambda: emb.intersects_id(ray_o, ray_d, multiple_hits=True), 1)
        table.add("ray all hits (random)", "trimesh + embree multiple_hits", t_emb_all, t_all)

    # segments after refit, the solver's use -----------------------------------------------------------
    a = V[F[tri, 0]] + 0.004 * rng.normal(size=(n, 3))
    b = a + 0.005 * rng.normal(size=(n, 3))
    t_seg = best_time(lambda: (bvh.refit(Vd), bvh.intersect_segments(a, b)), args.repeat)
    table.add("refit + segments", "headsim: refit, then 5 mm segments", t_seg)
    print(f"\nload average at end: {os.getloadavg()[0] if hasattr(os, 'getloadavg') else float('nan'):.1f}")


if __name__ == "__main__":
    main()
