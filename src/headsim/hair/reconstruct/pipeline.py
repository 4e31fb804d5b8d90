"""The reconstruction pipeline (Sobottka 2008 §5.3): scalp + hair volume -> fibre hairstyle.

Stages (each timed): distance fields (§5.3.1) -> unit-disk parametrisation (§5.3.2) -> roots from the maps
-> pre-guides (§5.3.3 a) -> main guides, optimised one after another with the incremental density field
(§5.3.3 b, §5.3.4), each cut at its first exit and its strand interpolated at once (§5.3.5) -> clean-up of
all fibres against the head (pushed out to a clearance) and the hair volume (final cut).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from headsim.errors import ParameterError
from headsim.hair.reconstruct.density import DensityGrid, coefficient_of_variation, occupancy_counts
from headsim.hair.reconstruct.growth import (
    GuideOptions,
    cut_index,
    grow_preguides,
    optimise_guide,
    rod_stiffness,
    root_frames,
)
from headsim.hair.reconstruct.inputs import STYLES, StyleInputs, boundary_fields
from headsim.hair.reconstruct.maps import ScalpMap, TextureMap, default_maps, farthest_point_order
from headsim.hair.reconstruct.strands import cut_fibres, interpolate_strand, push_out_of_head

__all__ = ["StyleOptions", "Hairstyle", "reconstruct", "OCCUPANCY_CELL"]

OCCUPANCY_CELL = 0.005  # m, cell of the occupancy histogram (Fig. 5.6)


@dataclass(frozen=True)
class StyleOptions:
    """n_fibres (None: a Poisson process at the density map); n_guides; n_segments per fibre; density_per_cm2
    at grey 255 of the default density map; preguide_per_cm2; density_model none | binary | continuous;
    length m (default: the style's, else 0.1); maps: (density roots/m^2, azimuth rad, elevation rad, length m)
    TextureMaps replacing the defaults; tip_ratio and winding rad/m of the strands; head_clearance m;
    fibre_radius m; field spacings m; guide: the objective and cut options; seed."""

    n_fibres: int | None = 90_000
    n_guides: int = 3000
    n_segments: int = 24
    density_per_cm2: float = 250.0
    preguide_per_cm2: float = 1.0
    density_model: str = "continuous"
    length: float | None = None
    style: str | None = None
    maps: tuple[TextureMap, TextureMap, TextureMap, TextureMap] | None = None
    tip_ratio: float = 0.6
    winding: float = 0.0
    head_clearance: float = 0.0003
    fibre_radius: float = 35e-6
    head_spacing: float = 0.003
    hair_spacing: float = 0.004
    guide: GuideOptions = field(default_factory=GuideOptions)
    seed: int = 0


@dataclass(frozen=True, eq=False)
class Hairstyle:
    """nodes (n, 3) m and fibre_offsets (F+1,) int64: the fibres (CSR, root first; the guides are fibres too);
    strand (F,) guide index of each fibre; is_guide (F,) bool; guides (G, N+1, 3) uncut optimised guides and
    guide_kept (G,) their last kept node; preguides (P, N+1, 3); radius m; timings / timings_cpu: wall / CPU
    (process_time) s per stage; stats."""

    nodes: np.ndarray
    fibre_offsets: np.ndarray
    strand: np.ndarray
    is_guide: np.ndarray
    guides: np.ndarray
    guide_kept: np.ndarray
    preguides: np.ndarray
    radius: float
    timings: dict
    timings_cpu: dict
    stats: dict
    scalp_map: ScalpMap

    @property
    def n_fibres(self) -> int:
        return len(self.fibre_offsets) - 1


@contextlib.contextmanager
def _single_threaded_blas():
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl comes with scipy/scikit-learn installs
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def _weights(d: np.ndarray) -> np.ndarray:
    w = 1.0 / (d + 1e-3)
    return w / w.sum(axis=1, keepdims=True)


def reconstruct(inputs: StyleInputs, options: StyleOptions = StyleOptions(), progress=None, fields=None) -> Hairstyle:
    """Run every stage. progress(stage: str, done: int, total: int) is called along the way; fields: a
    precomputed (head, hair) field pair (else built here). Raises ParameterError for impossible settings."""
    if options.n_guides < 1 or options.n_segments < 2:
        raise ParameterError("need at least 1 guide and 2 segments per fibre")
    report = progress or (lambda stage, done, total: None)
    timings: dict[str, float] = {}
    timings_cpu: dict[str, float] = {}
    stats: dict = {}
    go = options.guide
    N = options.n_segments
    length = options.length or (STYLES[options.style]["length"] if options.style in STYLES else 0.1)
    if not 0 < length <= 1.5:
        raise ParameterError(f"hair length {length} m is implausible")

    t0, c0 = time.perf_counter(), time.process_time()
    report("distance fields", 0, 1)
    head_f, hair_f = fields if fields is not None else boundary_fields(inputs, options.head_spacing,
                                                                       options.hair_spacing)
    timings["distance fields"] = time.perf_counter() - t0
    timings_cpu["distance fields"] = time.process_time() - c0

    t0, c0 = time.perf_counter(), time.process_time()
    report("parametrisation", 0, 1)
    smap = ScalpMap(inputs.scalp)
    timings["parametrisation"] = time.perf_counter() - t0
    timings_cpu["parametrisation"] = time.process_time() - c0
    stats["stretch"] = list(smap.param.stretch_history)

    t0, c0 = time.perf_counter(), time.process_time()
    maps = options.maps or default_maps(length, options.density_per_cm2)
    roots = smap.sample_roots(*maps, n=options.n_fibres, seed=options.seed)
    F = len(roots)
    if F < options.n_guides:
        raise ParameterError(f"{F} roots cannot hold {options.n_guides} guides")
    n_pre = max(3, int(round(smap.area * 1e4 * options.preguide_per_cm2)))
    pre_ids = farthest_point_order(roots.positions, min(n_pre, F), seed=options.seed + 1)
    guide_ids = farthest_point_order(roots.positions, options.n_guides, seed=options.seed + 2)
    strand_of = cKDTree(roots.positions[guide_ids]).query(roots.positions)[1]
    strand_of[guide_ids] = np.arange(len(guide_ids))
    timings["roots"] = time.perf_counter() - t0
    timings_cpu["roots"] = time.process_time() - c0
    stats.update(scalp_area_cm2=smap.area * 1e4, fibres=F, mean_density_per_cm2=F / (smap.area * 1e4),
                 preguides=len(pre_ids), guides=len(guide_ids))

    t0, c0 = time.perf_counter(), time.process_time()
    report("pre-guides", 0, 1)
    K = rod_stiffness()
    pre = grow_preguides(roots.subset(pre_ids), hair_f, K, N, go)
    timings["pre-guides"] = time.perf_counter() - t0
    timings_cpu["pre-guides"] = time.process_time() - c0
    stats["preguides_fitted"] = float(pre.fitted.mean())

    t0, c0 = time.perf_counter(), time.process_time()
    G = len(guide_ids)
    groots = roots.subset(guide_ids)
    R0 = root_frames(groots)
    dist, near = cKDTree(pre.roots.positions).query(groots.positions, k=min(3, len(pre_ids)))
    dist, near = dist.reshape(G, -1), near.reshape(G, -1)
    w = _weights(dist)
    pre_d3 = np.ascontiguousarray(pre.frames[:, :, :, 2])
    pre_kl = np.ascontiguousarray(pre.kappa * pre.roots.lengths[:, None, None])
    members = [[] for _ in range(G)]
    for i, g in enumerate(strand_of):
        members[g].append(i)
    members = [np.asarray(m, np.int64) for m in members]
    radius_g = np.array([np.linalg.norm(roots.positions[m] - roots.positions[guide_ids[g]], axis=1).max()
                         if len(m) > 1 else 0.0 for g, m in enumerate(members)])
    r_typ = float(np.sqrt(smap.area / (np.pi * G)))
    radius_g = np.maximum(radius_g, 0.5 * r_typ)
    lo, hi = inputs.volume.bounds
    dens = DensityGrid(options.density_model, lo, hi, float(np.clip(r_typ, 0.0015, 0.004)))
    stats["kdm_mean_density"] = dens.calibrate(head_f, hair_f, float(groots.lengths.sum()))
    guides = np.empty((G, N + 1, 3))
    kept = np.empty(G, np.int64)
    fibres = np.empty((F, N + 1, 3))
    evaluations = 0
    taper = 1.0 - (1.0 - options.tip_ratio) * np.arange(N + 1) / N
    with _single_threaded_blas():  # L-BFGS-B's BLAS calls are tiny: a thread pool only costs time here
        for k in range(G):
            eta0 = None if go.start == "straight" else (w[k, :, None] * pre.eta[near[k]]).sum(0)
            eta, f, r, R, ev = optimise_guide(R0[k], groots.positions[k], K, float(groots.lengths[k]), N,
                                              np.ascontiguousarray(pre_d3[near[k]]),
                                              np.ascontiguousarray(pre_kl[near[k]]), np.ascontiguousarray(w[k]),
                                              head_f, hair_f, dens, go, eta0)
            evaluations += ev
            kk = cut_index(r, head_f, hair_f, go)
            guides[k], kept[k] = r, kk
            m = members[k]
            strand = interpolate_strand(r, R, kk, roots.positions[m], roots.lengths[m], float(groots.lengths[k]),
                                        N, options.tip_ratio, options.winding)
            fibres[m] = strand
            dens.add_strand(r[:kk + 1], radius_g[k] * taper[:kk + 1], strand)
            if k % 50 == 0 or k == G - 1:
                report("guides", k + 1, G)
    timings["guides"] = time.perf_counter() - t0
    timings_cpu["guides"] = time.process_time() - c0
    stats.update(objective_evaluations=evaluations, guides_cut=float((kept < N).mean()))

    t0, c0 = time.perf_counter(), time.process_time()
    report("strands", 0, 1)
    from headsim.collide.bvh import TriangleBVH

    fibres = push_out_of_head(fibres, head_f, options.head_clearance,
                              head_bvh=TriangleBVH(inputs.head.vertices, inputs.head.triangles))
    last = cut_fibres(fibres, head_f, hair_f, go.cut_distance, go.cut_length)
    seglen = np.linalg.norm(np.diff(fibres, axis=1), axis=2)
    cum = np.cumsum(seglen, axis=1)
    kept_len = np.where(last > 0, cum[np.arange(F), np.maximum(last - 1, 0)], 0.0)
    keep = (last >= 1) & (kept_len >= 0.001)
    counts = last[keep] + 1
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    mask = np.arange(N + 1)[None, :] <= last[keep, None]
    nodes = fibres[keep][mask]
    is_guide = np.zeros(F, bool)
    is_guide[guide_ids] = True
    timings["strands"] = time.perf_counter() - t0
    timings_cpu["strands"] = time.process_time() - c0
    stats.update(fibres_kept=int(keep.sum()), fibres_dropped=int((~keep).sum()), fibres_cut=float((last < N).mean()))
    occ = occupancy_counts(nodes, offsets, OCCUPANCY_CELL)
    stats["occupancy_cv"] = coefficient_of_variation(occ)
    timings["total"] = float(sum(timings.values()))
    timings_cpu["total"] = float(sum(timings_cpu.values()))
    if not np.isfinite(nodes).all():
        from headsim.errors import ConvergenceError

        raise ConvergenceError("the reconstruction produced non-finite fibre nodes")
    return Hairstyle(nodes, offsets, strand_of[keep], is_guide[keep], guides, kept, pre.positions,
                     options.fibre_radius, timings, timings_cpu, stats, smap)
