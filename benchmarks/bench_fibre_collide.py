"""Benchmarks of fibre collision detection: Sobottka 2008 Ch. 7 §7.4 (digest §11, B1–B7).

Synthetic stand-ins with the thesis' fibre and segment counts (``headsim.collide.fibre_scenes``).
Every section prints wall-clock and CPU seconds (CPU = all threads of this process; on a shared,
loaded machine wall-clock times are inflated, CPU times are not) and ratios against baselines run in
the same process: brute force (on a subsample), the SciPy cKDTree + NumPy peer, python-fcl capsules
(if installed), and the thesis' own comparisons (AS vs AL, refit vs rebuild, k sweep).

    python benchmarks/bench_fibre_collide.py --quick      # small sizes, ~2 min
    python benchmarks/bench_fibre_collide.py              # thesis sizes (2.4 M-segment head: ~3 GB, minutes)
    python benchmarks/bench_fibre_collide.py --only B3    # one section

Thesis reference numbers (Pentium IV 2.4 GHz): 2 M-segment AL update 300 ms; full head (549 k
contacts) AL 100 s, spheres > 30 min; refit ≈ 1/12 of rebuild; AS:AL detection 1:43 (soup),
≈ 1:10 (heads), 1:1.7 (Tress I); k-DOP optimum k = 20 on Locke.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from headsim.collide._reference_fibres import capsule_contacts_bruteforce, capsule_contacts_kdtree
from headsim.collide.bounding_volumes import AABB, KDOP, kdop_directions, min_chordal_angle
from headsim.collide.fibre_bvh import VARIANTS, FibreBVH, PackedFibreBVH, RebuildPolicy
from headsim.collide.fibre_scenes import head_scene, loop_frames, soup_scene, strand_scene
from headsim.collide.fibres import FibreSet

RESULTS: dict = {}


class Timer:
    def __enter__(self):
        self.w, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *a):
        self.wall = time.perf_counter() - self.w
        self.cpu = time.process_time() - self.c


def timed(fn, *args, **kw):
    with Timer() as t:
        out = fn(*args, **kw)
    return out, t


def fmt(t):
    return f"{t.wall:8.3f} s wall {t.cpu:8.3f} s cpu"


def say(*a):
    print(*a, flush=True)


def subset(f: FibreSet, fibre_ids) -> FibreSet:
    ids = np.asarray(fibre_ids)
    parts = [f.nodes[f.fibre_offsets[i]:f.fibre_offsets[i + 1]] for i in ids]
    segs = [f.radius[f.segment_offsets[i]:f.segment_offsets[i + 1]] for i in ids]
    off = np.concatenate([[0], np.cumsum([len(p) for p in parts])])
    return FibreSet(np.vstack(parts), off, np.concatenate(segs))


def fcl_available():
    try:
        import fcl  # noqa: F401

        return True
    except ImportError:
        return False


def fcl_capsule_contacts(f: FibreSet):
    """python-fcl peer: one capsule per segment in a DynamicAABBTree manager, self-collide.

    Returns the colliding segment pairs (a < b, sorted, same-fibre neighbours removed as in Alg. 3) and
    the cpu seconds of FCL's own work (manager setup + self-collide, without building the Python objects).
    Capsules that touch only at a point (FCL's test is ≤, ours is <) would differ; none occur in
    random scenes.
    """
    import fcl

    p, q = f.segment_endpoints()
    geoms, objs = [], []
    z = np.array([0, 0, 1.0])
    for i in range(f.n_segments):
        d = q[i] - p[i]
        length = np.linalg.norm(d)
        axis = np.cross(z, d / length)
        s = np.linalg.norm(axis)
        if s < 1e-12:
            rot = np.eye(3) if d[2] > 0 else np.diag([1.0, -1.0, -1.0])
        else:
            axis /= s
            ang = np.arctan2(s, z @ (d / length))
            kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
            rot = np.eye(3) + np.sin(ang) * kx + (1 - np.cos(ang)) * kx @ kx
        g = fcl.Capsule(f.radius[i], length)
        geoms.append(g)
        objs.append(fcl.CollisionObject(g, fcl.Transform(rot, 0.5 * (p[i] + q[i]))))
    index = {id(g): i for i, g in enumerate(geoms)}
    c0 = time.process_time()
    mgr = fcl.DynamicAABBTreeCollisionManager()
    mgr.registerObjects(objs)
    mgr.setup()
    data = fcl.CollisionData(request=fcl.CollisionRequest(num_max_contacts=10**8, enable_contact=True))
    mgr.collide(data, fcl.defaultCollisionCallback)
    cpu = time.process_time() - c0
    pairs = np.array([(index[id(c.o1)], index[id(c.o2)]) for c in data.result.contacts], np.int64).reshape(-1, 2)
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    return pairs[~f.adjacent(pairs[:, 0], pairs[:, 1])], cpu


# -----------------------------------------------------------------------------------------------
def b1(quick):
    say("\n== B1 strand scaling, 100 segments/fibre, AL vs SW (§7.4.1, Fig. 7.9) ==")
    sizes = [50, 100, 200] if quick else [50, 100, 200, 400, 600, 800, 1000]
    say(f"{'fibres':>7} {'segments':>9} {'contacts':>9} | {'AL build':>9} {'AL upd':>8} {'AL det':>8} |"
        f" {'SW build':>9} {'SW upd':>8} {'SW det':>8} | SW/AL det (cpu)")
    rows = []
    for n in sizes:
        f = strand_scene(n, 100, length=0.1, seed=n)
        row = {"fibres": n, "segments": f.n_segments}
        for v in ("AL", "SW"):
            bvh, tb = timed(FibreBVH.from_variant, f, v)
            bvh.update()
            _, tu = timed(bvh.update)
            (pairs, _), td = timed(bvh.self_contact_pairs)
            row[v] = (tb.cpu, tu.cpu, td.cpu, len(pairs))
        rows.append(row)
        a, s = row["AL"], row["SW"]
        say(f"{n:7d} {f.n_segments:9d} {a[3]:9d} | {a[0]:9.4f} {a[1]:8.4f} {a[2]:8.4f} | {s[0]:9.4f} {s[1]:8.4f}"
            f" {s[2]:8.4f} | {s[2] / max(a[2], 1e-9):6.1f}")
    RESULTS["B1"] = rows


def b2(quick):
    nf, ns = (100, 2000) if quick else (1000, 2000)
    say(f"\n== B2 large strand {nf} fibres x {ns} segments (§7.4.1; thesis AL update 300 ms at 2 M) ==")
    f = strand_scene(nf, ns, length=0.4, seed=2)
    bvh, tb = timed(FibreBVH.from_variant, f, "AL")
    say(f"segments {f.n_segments:,}; AL build {fmt(tb)}")
    moved = f.nodes + np.random.default_rng(0).normal(scale=1e-5, size=f.nodes.shape)
    ups = []
    for i in range(5):
        _, t = timed(bvh.update, moved if i % 2 else f.nodes)
        ups.append(t)
    wall = np.median([t.wall for t in ups])
    cpu = np.median([t.cpu for t in ups])
    say(f"AL update median of 5: {wall * 1e3:.1f} ms wall, {cpu * 1e3:.1f} ms cpu (goal ≤ 50 ms; thesis 300 ms)")
    (pairs, _), td = timed(bvh.self_contact_pairs)
    say(f"AL detection: {len(pairs):,} contacts, {fmt(td)}  {bvh.stats}")
    bs, tbs = timed(FibreBVH.from_variant, f, "AS")
    (pairs2, _), tds = timed(bs.self_contact_pairs)
    assert np.array_equal(pairs, pairs2)
    say(f"AS build {fmt(tbs)}; detection {fmt(tds)}; AS:AL detection (cpu) 1:{td.cpu / max(tds.cpu, 1e-9):.2f}")
    del bs
    ap, tba = timed(PackedFibreBVH, f)
    aups = []
    for i in range(5):
        _, t = timed(ap.update, moved if i % 2 else f.nodes)
        aups.append(t)
    (pairs3, _), tda = timed(ap.self_contact_pairs)
    assert np.array_equal(pairs, pairs3)
    say(f"AP build {fmt(tba)}; update median {np.median([t.wall for t in aups]) * 1e3:.1f} ms wall, "
        f"{np.median([t.cpu for t in aups]) * 1e3:.1f} ms cpu; detection {fmt(tda)}")
    RESULTS["B2"] = dict(segments=f.n_segments, update_ms_wall=wall * 1e3, update_ms_cpu=cpu * 1e3,
                         contacts=len(pairs), AL_detect=(td.wall, td.cpu), AS_detect=(tds.wall, tds.cpu),
                         AS_build=(tbs.wall, tbs.cpu), AP_build=(tba.wall, tba.cpu), AP_detect=(tda.wall, tda.cpu),
                         AP_update_ms_cpu=float(np.median([t.cpu for t in aups]) * 1e3))


def peer_and_brute(f, pairs, label, brute_segments=3000):
    """Run the cKDTree peer (chunked, memory-bounded) on the whole scene and brute force on a fibre subsample."""
    brute_fibres = max(2, int(brute_segments * f.n_fibres / f.n_segments))
    (kp, _), tk = timed(capsule_contacts_kdtree, f)
    same = np.array_equal(kp, pairs)
    say(f"[{label}] cKDTree+NumPy peer: {len(kp):,} contacts, {fmt(tk)}; same set as BVH: {same}")
    rng = np.random.default_rng(0)
    ids = np.sort(rng.choice(f.n_fibres, min(brute_fibres, f.n_fibres), replace=False))
    sub = subset(f, ids)
    (bp, _), tbf = timed(capsule_contacts_bruteforce, sub)
    bvh = PackedFibreBVH(sub)
    (sp, _), tsub = timed(bvh.self_contact_pairs)
    scale = (f.n_segments / sub.n_segments) ** 2
    say(f"[{label}] brute force on {sub.n_segments:,}-segment subsample: {fmt(tbf)} "
        f"(same set as BVH: {np.array_equal(bp, sp)}); extrapolated O(S²) to full: {tbf.cpu * scale:,.0f} s cpu")
    if fcl_available():
        n_fcl = max(5, int(30_000 * f.n_fibres / f.n_segments))  # ≈ 30 k segments (FCL calls Python per pair)
        small = subset(f, np.sort(rng.choice(f.n_fibres, min(n_fcl, f.n_fibres), replace=False)))
        fp, fcl_cpu = fcl_capsule_contacts(small)
        bs, tb2 = timed(PackedFibreBVH, small)
        (sp2, _), ts2 = timed(bs.self_contact_pairs)
        say(f"[{label}] python-fcl capsules on {small.n_segments:,} segments: {len(fp)} pairs, manager setup + "
            f"self-collide {fcl_cpu:.4f} s cpu; same set as AP: {np.array_equal(fp, sp2)}; AP build + query "
            f"{tb2.cpu + ts2.cpu:.4f} s cpu ({fcl_cpu / max(tb2.cpu + ts2.cpu, 1e-9):.1f}x)")
    else:
        say(f"[{label}] python-fcl not installed (pip install python-fcl): skipped")
    return tk, same


def scene_facts(f, label):
    """Segment lengths, root spacing and contact density: is the stand-in comparable to the thesis' model?"""
    from scipy.spatial import cKDTree

    p, q = f.segment_endpoints()
    length = np.linalg.norm(q - p, axis=1)
    roots = f.nodes[f.fibre_offsets[:-1]]
    d_nn = cKDTree(roots).query(roots, k=2)[0][:, 1]
    say(f"[{label}] segment length min / median / max {length.min() * 1e3:.3f} / {np.median(length) * 1e3:.3f} / "
        f"{length.max() * 1e3:.3f} mm; root nearest-neighbour distance median {np.median(d_nn) * 1e3:.3f} mm "
        f"(325 /cm² on a square grid: {1e3 / np.sqrt(325e4):.3f} mm); radius {f.radius.mean() * 1e6:.0f} µm")
    return dict(length=(length.min(), float(np.median(length)), length.max()), root_nn=float(np.median(d_nn)))


def b3(quick, spheres, head_al, head_fibres=0):
    nf = head_fibres or (4_900 if quick else 49_000)
    say(f"\n== B3 full head: {nf:,} fibres x 49 segments at 325 roots/cm² on the bundled head (§7.4.1) ==")
    f, tg = timed(head_scene, nf, 49)
    say(f"scene: {f.n_fibres:,} fibres, {f.n_segments:,} segments (generated in {tg.wall:.1f} s)")
    out = {"segments": f.n_segments, "scene": scene_facts(f, "head")}
    res = {}
    for v in ("AP", "AS", "AL"):
        bvh, tb = timed(FibreBVH.from_variant, f, v)
        _, tu = timed(bvh.update)
        if v == "AL" and not (quick or head_al):
            say(f"AL: build {fmt(tb)} | update {fmt(tu)} | detection skipped (≈ 10x AS; use --head-al)")
            out[v] = dict(build=(tb.wall, tb.cpu), update=(tu.wall, tu.cpu))
            continue
        (pairs, _), td = timed(bvh.self_contact_pairs)
        _, tr = timed(bvh.self_contacts)  # query again + the FibreContacts records
        res[v] = (pairs, td)
        say(f"{v}: build {fmt(tb)} | update {fmt(tu)} | detection {len(pairs):,} contacts {fmt(td)} | "
            f"with records {fmt(tr)}")
        say(f"    {bvh.stats}")
        out[v] = dict(build=(tb.wall, tb.cpu), update=(tu.wall, tu.cpu), detect=(td.wall, td.cpu),
                      records=(tr.wall, tr.cpu), contacts=len(pairs), bv_tests=bvh.stats.bv_tests,
                      primitive_tests=bvh.stats.primitive_tests)
        del bvh
    for v in res:
        assert np.array_equal(res["AP"][0], res[v][0]), v
    n_c = len(res["AP"][0])
    say(f"contacts {n_c:,} = {n_c / 550e3:.2f} x the thesis' ≈ 550 k on 'Charming' "
        f"({n_c / f.n_segments:.3f} per segment)")
    tk, same = peer_and_brute(f, res["AP"][0], "head")
    ap = res["AP"][1]
    say("(cpu = summed over both threads; on an idle 2-core machine wall ≈ cpu / 2 for the parallel query)")
    say(f"head all-contacts: AP {ap.wall:.2f} s wall / {ap.cpu:.2f} s cpu; AS {res['AS'][1].wall:.2f} s wall / "
        f"{res['AS'][1].cpu:.2f} s cpu; peer {tk.wall:.2f} s wall / {tk.cpu:.2f} s cpu; AP speed-up vs peer: "
        f"{tk.wall / ap.wall:.1f}x wall, {tk.cpu / ap.cpu:.1f}x cpu; vs AS {res['AS'][1].cpu / ap.cpu:.1f}x cpu "
        f"(goal ≤ 1 s and ≥ 5x; thesis AL 100 s)")
    if "AL" in res:
        say(f"AS:AL detection (cpu) = 1:{res['AL'][1].cpu / max(res['AS'][1].cpu, 1e-9):.2f} (thesis ≈ 1:10 on heads)")
    if spheres:
        bvh, tb = timed(FibreBVH.from_variant, f, "SL")
        (pairs, _), td = timed(bvh.self_contact_pairs)
        say(f"SL: build {fmt(tb)} detection {fmt(td)}; SL/AS = {td.cpu / res['AS'][1].cpu:.1f} (thesis SL/AL > 18)")
        out["SL_detect"] = (td.wall, td.cpu)
    out.update(peer=(tk.wall, tk.cpu), peer_same=same)
    RESULTS["B3"] = out


def soup(quick):
    nf = 1_000 if quick else 10_000
    say(f"\n== Filament Soup: {nf:,} random fibres x 100 segments in the unit cube (Fig. 7.7; ≈ 70 k contacts at 1 M) ==")
    target = 70_000 * (nf / 10_000) ** 2  # contacts scale with density²·volume
    f = soup_scene(nf, 100, radius=4.5e-4)
    bvh = FibreBVH(f)
    n0 = len(bvh.self_contact_pairs()[0])
    r = 4.5e-4 * target / max(n0, 1)
    f = soup_scene(nf, 100, radius=r)
    say(f"radius calibrated to {r * 1e6:.0f} µm for ≈ {target:,.0f} contacts")
    res = {}
    ref = None
    for v in ("AP", "AS", "AL", "DS", "DL"):
        bvh, tb = timed(FibreBVH.from_variant, f, v, k=18)
        (pairs, _), td = timed(bvh.self_contact_pairs)
        ref = pairs if ref is None else ref
        assert np.array_equal(pairs, ref), v
        res[v] = td
        say(f"{v}: build {fmt(tb)} detection {len(pairs):,} contacts {fmt(td)}")
    tk, same = peer_and_brute(f, pairs, "soup")
    say(f"AS:AL detection (cpu) = 1:{res['AL'].cpu / res['AS'].cpu:.1f} (thesis 1:43); "
        f"peer / AS = {tk.wall / res['AS'].wall:.1f}x wall, {tk.cpu / res['AS'].cpu:.1f}x cpu; "
        f"peer / AP = {tk.wall / res['AP'].wall:.1f}x wall, {tk.cpu / res['AP'].cpu:.1f}x cpu (goal ≥ 5x)")
    RESULTS["soup"] = dict(radius=r, contacts=len(pairs), AP=(res["AP"].wall, res["AP"].cpu),
                           AS=(res["AS"].wall, res["AS"].cpu), AL=(res["AL"].wall, res["AL"].cpu),
                           peer=(tk.wall, tk.cpu))


def b4_b5(quick):
    steps = 20 if quick else 100
    say(f"\n== B4 loop deformation, 150 fibres x 100 segments, {steps} steps, AL (§7.4.2a, Fig. 7.11) ==")
    frames = loop_frames(150, 100, steps, length=0.2, radius=35e-6)
    _, f0 = next(frames)
    al = FibreBVH.from_variant(f0, "AL")
    ups, dets, counts = [], [], []
    for _, f in frames:
        _, tu = timed(al.update, f.nodes)
        (p, _), td = timed(al.self_contact_pairs)
        ups.append(tu.cpu)
        dets.append(td.cpu)
        counts.append(len(p))
    ups, dets, counts = map(np.array, (ups, dets, counts))
    corr = np.corrcoef(dets, counts)[0, 1] if counts.std() > 0 else float("nan")
    say(f"contacts per step {counts.min()}…{counts.max()}; update {ups.mean() * 1e3:.2f} ± {ups.std() * 1e3:.2f} ms cpu; "
        f"detection {dets.min() * 1e3:.1f}…{dets.max() * 1e3:.1f} ms cpu; corr(detection, contacts) = {corr:.2f} "
        "(thesis: strongly correlated; update flat)")
    RESULTS["B4"] = dict(update_ms=ups.tolist(), detect_ms=dets.tolist(), contacts=counts.tolist(), corr=corr)

    say("\n== B5 update strategies on the same deformation (§7.4.2b, Fig. 7.12) ==")
    strategies = {"AS refit only": ("AS", RebuildPolicy("refit")),
                  "AS rebuild every step": ("AS", RebuildPolicy("rebuild")),
                  "AS refit + rebuild every 10": ("AS", RebuildPolicy("every", every=10)),
                  "AL bottom-up update": ("AL", RebuildPolicy("refit"))}
    tot = {}
    for name, (v, pol) in strategies.items():
        frames = loop_frames(150, 100, steps, length=0.2, radius=35e-6)
        _, f0 = next(frames)
        bvh = FibreBVH.from_variant(f0, v)
        m_t, d_t, d_first, d_last = 0.0, 0.0, None, None
        for _, f in frames:
            _, tm = timed(bvh.maintain, f.nodes, pol)
            _, td = timed(bvh.self_contact_pairs)
            m_t += tm.cpu
            d_t += td.cpu
            d_first = td.cpu if d_first is None else d_first
            d_last = td.cpu
        tot[name] = (m_t, d_t)
        say(f"{name:30s}: maintenance {m_t / steps * 1e3:7.2f} ms/step, detection {d_t / steps * 1e3:7.2f} ms/step, "
            f"last/first detection {d_last / max(d_first, 1e-9):.1f}, total {(m_t + d_t):.3f} s cpu")
    r = tot["AS refit only"][0] / max(tot["AS rebuild every step"][0], 1e-12)
    al_vs = sum(tot["AS rebuild every step"]) / max(sum(tot["AL bottom-up update"]), 1e-12)
    say(f"refit/rebuild cost = 1/{1 / max(r, 1e-12):.1f} (thesis 1/12); total AS-rebuild / AL = {al_vs:.2f} (thesis 2–2.5)")
    RESULTS["B5"] = {k: list(v) for k, v in tot.items()}


def b6(quick):
    say("\n== B6 static matrix: 10 variants (§7.4.3, Figs. 7.13, 7.14); cpu seconds ==")
    models = {"Tress I (0.1k x 2000)": lambda: strand_scene(100 if not quick else 20, 2000, length=0.4, seed=6),
              "Soup (1k x 100)": lambda: soup_scene(1000, 100, radius=1.2e-3),
              "Locke (250 x 98)": lambda: strand_scene(250, 98, length=0.2, curl_radius=0.004, curl_turns=4, seed=7)}
    RESULTS["B6"] = {}
    for name, make in models.items():
        f = make()
        say(f"-- {name}: {f.n_segments:,} segments")
        say(f"{'var':>4} {'build':>8} {'update':>8} {'detect':>8} {'first':>8} {'contacts':>9} {'BV tests':>11}"
            f" {'leaf BV':>10} {'prim':>9}")
        ref = None
        for v in ["AP", *VARIANTS]:
            bvh, tb = timed(FibreBVH.from_variant, f, v, k=18)
            _, tu = timed(bvh.update)
            (p, _), td = timed(bvh.self_contact_pairs)
            s = bvh.stats
            with Timer() as tf:
                for _ in range(20):
                    bvh.self_contact_pairs("first")
            ref = p if ref is None else ref
            assert np.array_equal(p, ref), v
            maint = tb.cpu if v == "AP" or VARIANTS[v][1] == "spatial" else tu.cpu
            say(f"{v:>4} {tb.cpu:8.4f} {maint:8.4f} {td.cpu:8.4f} {tf.cpu / 20:8.5f} {len(p):9d} {s.bv_tests:11d}"
                f" {s.leaf_bv_tests:10d} {s.primitive_tests:9d}")
            RESULTS["B6"].setdefault(name, {})[v] = dict(build=tb.cpu, maintenance=maint, detect=td.cpu,
                                                         first=tf.cpu / 20, bv_tests=s.bv_tests,
                                                         leaf_bv_tests=s.leaf_bv_tests, prim=s.primitive_tests)
        lv = {v: FibreBVH.from_variant(f, v).level_volumes()[:6] for v in ("SW", "SL", "OL", "AL")}
        say("   mean BV volume of levels 0..5 (m³): " + "; ".join(
            f"{v}: " + " ".join(f"{x:.1e}" for x in lv[v]) for v in lv))


def b7(quick, kmax):
    nf = 250 if quick else 2_500
    say(f"\n== B7 k-DOP sweep, DL on Locke stand-in ({nf} fibres x 98 segments) (§7.4.4, Fig. 7.15) ==")
    f = strand_scene(nf, 98, length=0.2, curl_radius=0.004, curl_turns=4, seed=7)
    ks = [k for k in (6, 8, 10, 14, 20, 26, 32, 40, 60, 100, 200) if k <= kmax]
    say(f"segments {f.n_segments:,}")
    say(f"{'k':>5} {'update ms':>10} {'detect s':>9} {'BV tests':>11} {'overlaps':>11} {'prim':>9} {'min angle':>9}")
    rows = []
    for label, bv in [("AABB", AABB())] + [(str(k), KDOP(directions=kdop_directions(k, classic=False)))
                                           for k in ks]:
        bvh = FibreBVH(f, bv, "topological")
        bvh.update()
        _, tu = timed(bvh.update)
        (p, _), td = timed(bvh.self_contact_pairs)
        s = bvh.stats
        ang = np.degrees(min_chordal_angle(bv.directions))
        say(f"{label:>5} {tu.cpu * 1e3:10.2f} {td.cpu:9.4f} {s.bv_tests:11d} {s.bv_overlaps:11d} {s.primitive_tests:9d} {ang:9.2f}")
        rows.append(dict(k=label, update=tu.cpu, detect=td.cpu, bv_tests=s.bv_tests, prim=s.primitive_tests,
                         contacts=len(p)))
    best = min(rows[1:], key=lambda r: r["detect"])
    say(f"fastest detection at k = {best['k']} (thesis: k = 20 on Locke); contacts {rows[0]['contacts']:,}")
    RESULTS["B7"] = rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="small sizes")
    ap.add_argument("--only", default="", help="comma list of sections: B1,B2,B3,soup,B4,B6,B7")
    ap.add_argument("--spheres", action="store_true", help="also run the sphere hierarchy on the head (slow)")
    ap.add_argument("--head-fibres", type=int, default=0, help="fibres of the head scene (0: 49 k, quick 4.9 k)")
    ap.add_argument("--head-al", action="store_true", help="also run AL detection on the full head (slow)")
    ap.add_argument("--kmax", type=int, default=100, help="largest k of the k-DOP sweep (≤ 200)")
    ap.add_argument("--json", default="", help="write the results here")
    a = ap.parse_args(argv)
    import numba

    say(f"headsim fibre collision benchmark; numba threads {numba.get_num_threads()}, "
        f"cpus {os.cpu_count()}, load average {os.getloadavg()[0]:.1f}")
    # compile the kernels once on a tiny scene so timings exclude JIT
    tiny = strand_scene(4, 10, length=0.01)
    for v in ["AP", *VARIANTS]:
        FibreBVH.from_variant(tiny, v, k=14).self_contact_pairs()
        FibreBVH.from_variant(tiny, v, k=14, threads=1).self_contact_pairs()
    sections = [s.strip() for s in a.only.split(",") if s.strip()] or ["B1", "B2", "B3", "soup", "B4", "B6", "B7"]
    for s in sections:
        {"B1": lambda: b1(a.quick), "B2": lambda: b2(a.quick), "B3": lambda: b3(a.quick, a.spheres, a.head_al, a.head_fibres),
         "soup": lambda: soup(a.quick), "B4": lambda: b4_b5(a.quick), "B6": lambda: b6(a.quick),
         "B7": lambda: b7(a.quick, a.kmax)}[s]()
    say(f"\nload average at the end: {os.getloadavg()[0]:.1f}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(RESULTS, fh, indent=1, default=float)


if __name__ == "__main__":
    sys.exit(main())
