"""Bounding-volume hierarchies over fibre segments and their self-collision query.

Implements Sobottka 2008, Ch. 7 §7.3 (digest ``hair_ch7_collision_detection.md``):

* **Hierarchies.** ``"spatial"`` = H_R, top-down split at the mid-plane of the longest axis /
  thickest slab (§7.3.3, §7.3.7.2.2) with the thesis' fallbacks plus an index split; ``"topological"``
  = a balanced tree along the seed's *total fibre* (all fibres threaded boustrophedon into one chain,
  §7.3.3, Fig. 7.4). Topological BVs are *layered* (H_TI: merge of the two children, built bottom-up)
  or *wrapped* (H_TD: MEV of all leaf capsules below the node). For AABB / k-DOP both are the same
  (Lemma 7.3.1), which the tests check node by node.
* **The ten variants** of Table 7.1: AS, AL, DS, DL, OS, OW, OL, SS, SW, SL (:data:`VARIANTS`).
* **Maintenance** (Alg. 5): :meth:`FibreBVH.update` refits leaves and merges bottom-up (H_TI, and the
  lazy refit of H_R); wrapped trees recompute every node's MEV over its leaf range (what the cascade
  verification of Alg. 4 maintains, computed directly in O(S log S) without the basis bookkeeping;
  sphere MEVs are near-minimal enclosing balls, not Gärtner's exact ones); :meth:`FibreBVH.rebuild`
  re-partitions H_R; :class:`RebuildPolicy` chooses between them per step.
* **Query** (Alg. 3): simultaneous depth-first descent from (root, root) with self-pair handling
  (each unordered pair once), adjacency exclusion (same or neighbouring segment of one fibre; the
  virtual links of the total fibre are tested), exact capsule–capsule leaf test returning closest
  points, normal and depth; "all" or "first" contact; counters and timings. The top pairs are
  expanded breadth-first into independent tasks that run on several threads (Numba ``nogil``).

* **The fast default, variant AP** (:class:`PackedFibreBVH`, not in Table 7.1): the AS tree (H_R,
  AABB) stopped at 8 segments per leaf, split by a binned surface-area heuristic (or the AS mid-plane
  rule), float32 boxes rounded outwards in 32-byte records (a sibling pair per cache line), segment
  records in leaf order, a segment-box prefilter and a line-distance reject before the exact float64
  capsule test, and an O(n + S) sort of the output. Same contact set as every Table 7.1 variant and
  brute force (tested); :func:`fibre_self_contacts` and ``headsim hair collide`` use it by default.

Memory is linear in the number of segments: 2S − 1 nodes with 4 int64 and one BV row each (AP:
≈ S/3 nodes of 32 bytes + 3 int64, and 32 + 64 + 16 bytes per segment).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np

from headsim._selection import index_selection
from headsim.collide import _kernels_fibre as K
from headsim.collide import _kernels_fibre_packed as P
from headsim.collide import _kernels_fibre_traverse as T
from headsim.collide.bounding_volumes import (
    AABB,
    BV_SLAB,
    KDOP,
    OBB,
    BoundingVolume,
    Sphere,
)
from headsim.collide.fibres import FibreContacts, FibreSet, capsule_contacts
from headsim.errors import ParameterError

__all__ = ["VARIANTS", "FAST_VARIANTS", "DEFAULT_VARIANT", "FibreBVH", "PackedFibreBVH", "QueryStats",
           "RebuildPolicy", "fibre_self_contacts"]

#: Table 7.1: name → (bounding volume, hierarchy, wrapped?)
VARIANTS: dict[str, tuple[str, str, bool]] = {
    "AS": ("aabb", "spatial", False),
    "AL": ("aabb", "topological", False),
    "DS": ("kdop", "spatial", False),
    "DL": ("kdop", "topological", False),
    "OS": ("obb", "spatial", True),
    "OW": ("obb", "topological", True),
    "OL": ("obb", "topological", False),
    "SS": ("sphere", "spatial", True),
    "SW": ("sphere", "topological", True),
    "SL": ("sphere", "topological", False),
}

#: Variants beyond Table 7.1 (same contact set, built for speed): name → description.
#: ``"AP"``: AABB H_R with up to 8 segments per leaf, float32 boxes, segment-box prefilter
#: (:class:`PackedFibreBVH`).
FAST_VARIANTS: dict[str, str] = {"AP": "AABB, spatial, packed leaves (8 segments), float32 boxes"}

#: The variant used when none is named (:func:`fibre_self_contacts`, ``headsim hair collide``).
DEFAULT_VARIANT = "AP"


@dataclass
class QueryStats:
    """Counters and timings of the last query / maintenance (Sobottka §7.4 instrumentation).

    bv_tests: BV overlap tests; bv_overlaps: overlapping BV pairs; leaf_bv_tests: BV tests between two
    leaves (lowest level); primitive_tests: capsule–capsule tests; contacts: contacts found;
    seconds: wall-clock time of the query, s.
    """

    bv_tests: int = 0
    bv_overlaps: int = 0
    leaf_bv_tests: int = 0
    primitive_tests: int = 0
    contacts: int = 0
    seconds: float = 0.0

    @classmethod
    def from_counters(cls, c, seconds):
        return cls(int(c[0]), int(c[1]), int(c[2]), int(c[3]), int(c[4]), seconds)


@dataclass(frozen=True)
class RebuildPolicy:
    """When :meth:`FibreBVH.maintain` re-partitions a spatial tree instead of refitting it.

    mode: ``"refit"`` (never rebuild), ``"rebuild"`` (every step), ``"every"`` (every ``every`` steps),
    ``"quality"`` (when the summed inner BV size grew by more than ``quality_factor`` since the last
    rebuild). Topological trees are always updated bottom-up (their structure never changes).
    """

    mode: str = "refit"
    every: int = 10
    quality_factor: float = 1.5

    def __post_init__(self):
        if self.mode not in ("refit", "rebuild", "every", "quality"):
            raise ParameterError(f"rebuild policy mode must be refit/rebuild/every/quality, got {self.mode!r}")
        if self.every < 1 or not self.quality_factor > 1.0:
            raise ParameterError("rebuild policy needs every ≥ 1 and quality_factor > 1")


def _make_bv(bv: str | BoundingVolume, k: int | None) -> BoundingVolume:
    if isinstance(bv, BoundingVolume):
        return bv
    key = bv.lower()
    if key == "aabb":
        return AABB()
    if key in ("kdop", "dop"):
        return KDOP(26 if k is None else k)
    if key == "obb":
        return OBB()
    if key == "sphere":
        return Sphere()
    raise ParameterError(f"unknown bounding volume {bv!r}; choose aabb, kdop, obb or sphere")


class FibreBVH:
    """A bounding-volume hierarchy over all segments of a :class:`FibreSet`.

    Parameters
    ----------
    fibres : FibreSet
    bv : ``"aabb"``, ``"kdop"``, ``"obb"``, ``"sphere"`` or a :class:`BoundingVolume` instance.
    hierarchy : ``"spatial"`` (H_R) or ``"topological"`` (total fibre, H_TI / H_TD).
    wrapped : topological trees: wrapped (H_TD) instead of layered (H_TI) BVs; spatial trees with
        spheres/OBBs: node BV = MEV of its capsules (the thesis' H_R) rather than the merge of the
        children. AABB / k-DOP BVs are the same either way (Lemma 7.3.1).
    k : k of the k-DOP (classic set for 6/14/18/26, else Grassmannian directions).
    fibre_order : order of the fibres along the total fibre (default: as stored).
    split_rule : descent rule of Alg. 3: ``"leaves"`` (node with more leaves, ties by size) or
        ``"volume"`` (larger BV).
    threads : worker threads of the query (default: Numba's thread count).

    Attributes
    ----------
    left, right, lo, hi : (2S − 1,) int64 tree arrays (children; leaf-slot range of every node).
    perm : (S,) int64 global segment id of every leaf slot.
    bvs : (2S − 1, width) float64 BV rows (m).
    timings : dict of the last build / update / rebuild / query times, s.
    stats : :class:`QueryStats` of the last query.
    """

    def __init__(self, fibres: FibreSet, bv="aabb", hierarchy: str = "spatial", *, wrapped: bool = False,
                 k: int | None = None, fibre_order=None, split_rule: str = "leaves",
                 threads: int | None = None):
        if not isinstance(fibres, FibreSet):
            raise ParameterError("FibreBVH needs a FibreSet (see headsim.collide.fibres_from_arrays)")
        if hierarchy not in ("spatial", "topological"):
            raise ParameterError(f"hierarchy must be 'spatial' or 'topological', got {hierarchy!r}")
        if split_rule not in ("leaves", "volume"):
            raise ParameterError(f"split_rule must be 'leaves' or 'volume', got {split_rule!r}")
        self.fibres = fibres
        self.bv = _make_bv(bv, k)
        self.hierarchy = hierarchy
        self.wrapped = bool(wrapped)
        self.fibre_order = fibre_order
        self.split_rule = split_rule
        self.threads = int(threads) if threads else numba.get_num_threads()
        self.nodes = fibres.nodes
        self.timings: dict[str, float] = {}
        self.stats = QueryStats()
        self._steps_since_rebuild = 0
        self._quality_ref = None
        t0 = time.perf_counter()
        self._build()
        self.timings["build"] = time.perf_counter() - t0

    @classmethod
    def from_variant(cls, fibres: FibreSet, variant: str, *, k: int | None = None, **kw) -> "FibreBVH":
        """Build one of the ten variants of Table 7.1 (AS, AL, DS, DL, OS, OW, OL, SS, SW, SL) or
        ``"AP"`` (:class:`PackedFibreBVH`, the fast default; ``k`` is ignored there)."""
        key = variant.upper()
        if key == "AP":
            kw.pop("split_rule", None)
            return PackedFibreBVH(fibres, **kw)
        if key not in VARIANTS:
            raise ParameterError(
                f"unknown variant {variant!r}; choose one of {', '.join([*VARIANTS, *FAST_VARIANTS])}")
        bv, hierarchy, wrapped = VARIANTS[key]
        return cls(fibres, bv, hierarchy, wrapped=wrapped, k=k, **kw)

    # -- properties -----------------------------------------------------------------------------
    @property
    def kind(self) -> int:
        return self.bv.kind

    @property
    def n_nodes(self) -> int:
        return len(self.left)

    @property
    def _dirs(self) -> np.ndarray:
        if not hasattr(self, "_dirs_cache"):
            d = self.bv.directions
            self._dirs_cache = np.ascontiguousarray(d if len(d) else np.eye(3))
        return self._dirs_cache

    @property
    def _m(self) -> int:
        return len(self.bv.directions) if self.kind == BV_SLAB else 0

    def __repr__(self) -> str:
        return (f"FibreBVH({self.bv!r}, {self.hierarchy}{', wrapped' if self.wrapped else ''}, "
                f"{self.fibres.n_segments} segments)")

    # -- build and maintenance --------------------------------------------------------------------
    def _alloc(self):
        s = self.fibres.n_segments
        n = 2 * s - 1
        self.left = np.empty(n, np.int64)
        self.right = np.empty(n, np.int64)
        self.lo = np.empty(n, np.int64)
        self.hi = np.empty(n, np.int64)
        self.bvs = np.empty((n, self.bv.width), np.float64)

    def _build(self):
        f = self.fibres
        self._alloc()
        if self.hierarchy == "topological":
            self.perm = np.ascontiguousarray(f.total_fibre_order(self.fibre_order))
            K.build_topological(f.n_segments, self.left, self.right, self.lo, self.hi)
            self._index_leaves()
            self._fit_all()
        else:
            self._build_spatial()
        self._quality_ref = self._quality()

    def _build_spatial(self):
        f = self.fibres
        split_dirs = self._dirs  # slab types: own directions; sphere / OBB: the coordinate axes
        leaf = np.empty((f.n_segments, 2 * len(split_dirs)))
        K.segment_slabs(self.nodes, f.segment_start, f.radius, split_dirs, leaf)
        self.perm = np.arange(f.n_segments, dtype=np.int64)
        if self.kind == BV_SLAB:
            K.build_spatial(leaf, self.perm, self.left, self.right, self.lo, self.hi, self.bvs)
            self._index_leaves()
        else:
            tmp = np.empty((len(self.left), leaf.shape[1]))
            K.build_spatial(leaf, self.perm, self.left, self.right, self.lo, self.hi, tmp)
            del tmp
            self._index_leaves()
            self._fit_all()

    def _index_leaves(self):
        leaves = np.nonzero(self.left < 0)[0]
        self.leaf_node = np.empty(self.fibres.n_segments, np.int64)
        self.leaf_node[self.lo[leaves]] = leaves
        self._roots, self._top = K.subtree_partition(self.left, self.right, self.lo, self.hi, 8 * max(1, self.threads))

    def _refit_layered(self):
        f = self.fibres
        K.refit_layered(self.kind, self._dirs, self.nodes, f.segment_start, f.radius, self.perm, self.left,
                        self.right, self.lo, self.hi, self._roots, self._top, self.bvs)

    def _fit_all(self):
        f = self.fibres
        self._refit_layered()
        if self.wrapped:
            K.refit_inner_wrapped(self.kind, self._dirs, self.nodes, f.segment_start, f.radius, self.perm,
                                  self.left, self.lo, self.hi, self.bvs)

    def _set_nodes(self, nodes):
        if nodes is None:
            return
        x = np.ascontiguousarray(nodes, dtype=np.float64)
        if x.shape != self.fibres.nodes.shape:
            raise ParameterError(f"nodes must have shape {self.fibres.nodes.shape}, got {x.shape}")
        if not np.isfinite(x).all():
            raise ParameterError("fibre nodes contain NaN or inf")
        self.nodes = x

    def update(self, nodes=None) -> float:
        """Refit to new node positions (N, 3) m without changing the tree (Alg. 5). Returns seconds.

        Layered trees and spatial trees: leaf refit + bottom-up MERGE (linear). Wrapped trees: every
        node's MEV over its leaf range (O(S log S)).
        """
        self._set_nodes(nodes)
        t0 = time.perf_counter()
        f = self.fibres
        if self.wrapped and self.hierarchy == "topological":
            K.refit_leaves(self.kind, self._dirs, self.nodes, f.segment_start, f.radius, self.perm,
                           self.leaf_node, self.bvs)
            K.refit_inner_wrapped(self.kind, self._dirs, self.nodes, f.segment_start, f.radius, self.perm,
                                  self.left, self.lo, self.hi, self.bvs)
        else:
            self._refit_layered()
        dt = time.perf_counter() - t0
        self.timings["update"] = dt
        self._steps_since_rebuild += 1
        return dt

    def rebuild(self, nodes=None) -> float:
        """Build the tree again at new node positions (H_R re-partition). Returns seconds."""
        self._set_nodes(nodes)
        t0 = time.perf_counter()
        self._build()
        dt = time.perf_counter() - t0
        self.timings["rebuild"] = dt
        self._steps_since_rebuild = 0
        return dt

    def _quality(self) -> float:
        inner = self.left >= 0
        if self.kind == BV_SLAB:
            m = self._m
            return float((self.bvs[inner, m:] - self.bvs[inner, :m]).sum())
        if self.kind == 1:
            return float(self.bvs[inner, 3].sum())
        return float(self.bvs[inner, 12:15].sum())

    def maintain(self, nodes, policy: RebuildPolicy = RebuildPolicy()) -> str:
        """Bring the tree to new node positions by refit or rebuild according to ``policy``.

        Returns ``"refit"`` or ``"rebuild"`` (what was done). Topological trees are always refit.
        """
        if self.hierarchy == "topological" or policy.mode == "refit":
            self.update(nodes)
            return "refit"
        if policy.mode == "rebuild" or (policy.mode == "every" and self._steps_since_rebuild + 1 >= policy.every):
            self.rebuild(nodes)
            return "rebuild"
        self.update(nodes)
        if policy.mode == "quality" and self._quality() > policy.quality_factor * self._quality_ref:
            self.rebuild()
            return "rebuild"
        return "refit"

    # -- queries -----------------------------------------------------------------------------------
    def _traverse(self, tasks, first_only, counters):
        f = self.fibres
        return T.traverse_pairs(tasks, self.left, self.right, self.lo, self.hi, self.perm, self.bvs, self.kind,
                                self._m, self.nodes, f.segment_start, f.radius, f.segment_fibre,
                                0 if self.split_rule == "leaves" else 1, first_only, counters)

    def self_contact_pairs(self, mode: str = "all", *, sort: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Colliding segment pairs of the self-query (Alg. 3).

        Returns pairs (n, 2) int64 with pairs[:, 0] < pairs[:, 1], sorted, and params (n, 2) float64
        (closest-point parameters s on the first, t on the second segment). ``mode="first"``
        stops at the first contact (at most one pair). ``sort=False`` returns the same pairs in the
        traversal's order (for a caller that orders them itself).
        """
        if mode not in ("all", "first"):
            raise ParameterError(f"mode must be 'all' or 'first', got {mode!r}")
        t0 = time.perf_counter()
        counters = np.zeros(T.N_COUNTERS, np.int64)
        root = np.zeros((1, 2), np.int64)
        if mode == "first" or self.threads <= 1 or self.n_nodes < 64:
            pairs, params = self._traverse(root, mode == "first", counters)
        else:
            m = self._m
            tasks = T.expand_tasks(0, 0, self.left, self.right, self.lo, self.hi, self.bvs, self.kind, m,
                                   256 * self.threads, 0 if self.split_rule == "leaves" else 1, counters)
            n_chunks = min(len(tasks), 32 * self.threads)
            chunks = [np.ascontiguousarray(tasks[i::n_chunks]) for i in range(n_chunks)]
            cs = [np.zeros(T.N_COUNTERS, np.int64) for _ in chunks]
            with ThreadPoolExecutor(max_workers=self.threads) as ex:
                results = list(ex.map(lambda ic: self._traverse(ic[1], False, cs[ic[0]]), enumerate(chunks)))
            for c in cs:
                counters += c
            pairs = np.concatenate([r[0] for r in results]) if results else np.zeros((0, 2), np.int64)
            params = np.concatenate([r[1] for r in results]) if results else np.zeros((0, 2))
        if mode == "all" and sort and len(pairs):
            order = np.lexsort((pairs[:, 1], pairs[:, 0]))
            pairs, params = pairs[order], params[order]
        dt = time.perf_counter() - t0
        self.stats = QueryStats.from_counters(counters, dt)
        self.timings["query"] = dt
        return pairs, params

    def self_contacts(self, mode: str = "all") -> FibreContacts:
        """All (or the first) fibre–fibre contacts at the current node positions, as records."""
        pairs, params = self.self_contact_pairs(mode)
        return capsule_contacts(self.fibres, pairs, params, nodes=self.nodes)

    # -- diagnostics ---------------------------------------------------------------------------------
    def depths(self) -> np.ndarray:
        """(n_nodes,) int64 depth of every node (root 0)."""
        d = np.zeros(self.n_nodes, np.int64)
        inner = np.nonzero(self.left >= 0)[0]  # parents have smaller ids than children
        for u in inner:
            d[self.left[u]] = d[u] + 1
            d[self.right[u]] = d[u] + 1
        return d

    def level_volumes(self, max_nodes_per_level: int = 2000, seed: int = 0) -> np.ndarray:
        """(levels,) average BV volume per tree level, m³ (Fig. 7.14 right); levels are subsampled."""
        d = self.depths()
        rng = np.random.default_rng(seed)
        out = []
        for lev in range(d.max() + 1):
            ids = np.nonzero(d == lev)[0]
            if len(ids) > max_nodes_per_level:
                ids = rng.choice(ids, max_nodes_per_level, replace=False)
            out.append(float(self._node_volumes(ids).mean()))
        return np.array(out)

    def _node_volumes(self, ids: np.ndarray) -> np.ndarray:
        """(len(ids),) BV volumes of the nodes ``ids``, m³."""
        return self.bv.volume(self.bvs[ids])


def fibre_self_contacts(fibres: FibreSet, variant: str = DEFAULT_VARIANT, *, k: int | None = None,
                        mode: str = "all") -> FibreContacts:
    """One-shot: build the hierarchy ``variant`` (default the fast ``"AP"``) and return all fibre–fibre
    contacts (the same set for every variant)."""
    return FibreBVH.from_variant(fibres, variant, k=k).self_contacts(mode)



def _aligned_records(n: int) -> np.ndarray:
    """(n, 8) float32 array starting on a 64-byte boundary (a record pair per cache line)."""
    buf = np.empty(8 * n + 16, np.float32)
    off = (-buf.ctypes.data % 64) // 4
    return buf[off:off + 8 * n].reshape(n, 8)


class PackedFibreBVH(FibreBVH):
    """Variant ``"AP"``: the AS hierarchy (H_R, AABB) with several segments per leaf, built for speed.

    Same split rule as AS (Sobottka §7.3.3: mid-plane of the longest axis), stopped at ``leaf_size``
    segments; nodes in sibling-pair order with float32 boxes rounded outwards, segment boxes in leaf
    order, and the simultaneous descent of Alg. 3 with a segment-box prefilter before the exact float64
    capsule test (``_kernels_fibre_packed``). Returns exactly the contact set of the Table 7.1 variants
    and brute force. Maintenance: :meth:`update` refits all boxes bottom-up (Alg. 5, linear),
    :meth:`rebuild` re-partitions; :meth:`maintain` takes the same :class:`RebuildPolicy`.

    Parameters
    ----------
    fibres : FibreSet
    leaf_size : most segments per leaf, 1…64 (default 8).
    threads : worker threads of the query (default: Numba's thread count).

    Attributes
    ----------
    child, first, count : (n_nodes,) int64 — first child (the second is child + 1; −1 at leaves) and
        the leaf-slot range ``perm[first : first + count]`` of every node.
    perm : (S,) int64 global segment id of every leaf slot.
    nbox : (n_nodes, 8) float32 node records: box ``[min x, y, z, max x, y, z]`` (m) in columns 0–5,
        int32 child/leaf and count in 6–7 (``_kernels_fibre_packed.traverse_packed``); node 1 is an
        unused slot. sbox : (S, 8) float32 segment boxes in slot order (columns 0–5), refitted first and
        copied into ``leaf_boxes``.
    seg64 : (S, 8) float64 endpoints (m) and radius of every slot's segment (exact test).
    leaf_boxes : (L, 6, W) float32 segment boxes of every leaf as W = 8·⌈leaf_size/8⌉ lanes (structure of
        arrays, empty lanes +inf/−inf), leaf_first : (L,) first slot of every leaf, sid : (S, 2) int32
        segment and fibre id per slot: the records of the vectorised leaf stage.
    """

    def __init__(self, fibres: FibreSet, leaf_size: int = 8, *, split: str = "sah", threads: int | None = None):
        if not isinstance(fibres, FibreSet):
            raise ParameterError("PackedFibreBVH needs a FibreSet (see headsim.collide.fibres_from_arrays)")
        if not 1 <= int(leaf_size) <= 64:
            raise ParameterError(f"leaf_size must be 1…64 segments, got {leaf_size}")
        if split not in ("sah", "mid"):
            raise ParameterError(f"split must be 'sah' or 'mid', got {split!r}")
        self.leaf_size = int(leaf_size)
        self.split = split
        self.fibres = fibres
        self.bv = AABB()
        self.hierarchy = "spatial"
        self.wrapped = False
        self.fibre_order = None
        self.split_rule = "leaves"
        self.threads = int(threads) if threads else numba.get_num_threads()
        self.nodes = fibres.nodes
        self.timings = {}
        self.stats = QueryStats()
        self._steps_since_rebuild = 0
        self._quality_ref = None
        t0 = time.perf_counter()
        self._build()
        self.timings["build"] = time.perf_counter() - t0

    @property
    def n_nodes(self) -> int:
        return len(self.child)

    def __repr__(self) -> str:
        return f"PackedFibreBVH(leaf_size={self.leaf_size}, {self.fibres.n_segments} segments)"

    def _build(self):
        f = self.fibres
        s = f.n_segments
        box = np.empty((s, 6))
        P.segment_boxes(self.nodes, f.segment_start, f.radius, box)
        self.perm = np.arange(s, dtype=np.int64)
        child = np.empty(2 * s, np.int64)
        first = np.empty(2 * s, np.int64)
        count = np.empty(2 * s, np.int64)
        n = P.build_packed(box, self.perm, self.leaf_size, child, first, count, 1 if self.split == "sah" else 0)
        del box
        self.child, self.first, self.count = child[:n].copy(), first[:n].copy(), count[:n].copy()
        self.nbox = _aligned_records(n)
        self.sbox = _aligned_records(s)
        self.seg64 = np.empty((s, 8))
        self._slot_node = np.ascontiguousarray(f.segment_start[self.perm])
        self._slot_radius = np.ascontiguousarray(f.radius[self.perm])
        nmeta = self.nbox.view(np.int32)
        self._leaf_node = np.flatnonzero(self.child < 0)
        leaf_of_node = np.full(n, -1, np.int64)
        leaf_of_node[self._leaf_node] = np.arange(len(self._leaf_node))
        nmeta[:, 6] = np.where(self.child >= 0, self.child, -(leaf_of_node + 1))
        nmeta[:, 7] = self.count
        self.sid = np.column_stack([self.perm, f.segment_fibre[self.perm]]).astype(np.int32)
        self.leaf_first = self.first[self._leaf_node]          # fixed by the tree: not refitted
        lanes = 8 * ((self.leaf_size + 7) // 8)
        self.leaf_boxes = np.empty((len(self._leaf_node), 6, lanes), np.float32)
        self._refit()
        self._quality_ref = self._quality()

    def _refit(self):
        P.refit_packed(self.nodes, self._slot_node, self._slot_radius, self.child, self.first, self.count,
                       self.sbox, self.nbox, self.seg64)
        P.leaf_lanes(self._leaf_node, self.first, self.count, self.sbox, self.leaf_boxes)

    def update(self, nodes=None) -> float:
        """Refit all boxes to new node positions (N, 3) m without changing the tree (Alg. 5). Returns s."""
        self._set_nodes(nodes)
        t0 = time.perf_counter()
        self._refit()
        dt = time.perf_counter() - t0
        self.timings["update"] = dt
        self._steps_since_rebuild += 1
        return dt

    def refit_fibres(self, fibres: FibreSet) -> float:
        """Refit the tree to ``fibres``: the same fibres (same offsets) at new node positions and with new capsule
        radii, without re-partitioning (Alg. 5). The query stays exact (the refitted boxes bound the new
        capsules); only its speed depends on how far the segments moved since the build. Returns seconds."""
        if not isinstance(fibres, FibreSet):
            raise ParameterError("refit_fibres needs a FibreSet (see headsim.collide.fibres_from_arrays)")
        if not np.array_equal(fibres.fibre_offsets, self.fibres.fibre_offsets):
            raise ParameterError("refit_fibres needs the fibres the tree was built for (same fibre offsets)")
        self.fibres = fibres
        self.nodes = fibres.nodes
        self._slot_radius = np.ascontiguousarray(fibres.radius[self.perm])
        return self.update()

    def _quality(self) -> float:
        inner = self.child >= 0
        b = self.nbox[inner, :6].astype(np.float64)
        return float((b[:, 3:] - b[:, :3]).sum())

    def self_contact_pairs(self, mode: str = "all", *, sort: bool = True,
                           chunk_filter=None) -> tuple[np.ndarray, np.ndarray]:
        """Colliding segment pairs (as :meth:`FibreBVH.self_contact_pairs`: sorted unless ``sort=False``, a < b;
        params s, t). ``chunk_filter``: a callable (pairs, params) → the number n of pairs to keep, which it has
        moved to the front of both arrays; applied to every worker's pairs in that worker (so it should release
        the GIL), before the chunks are joined (mode "all" only)."""
        if mode not in ("all", "first"):
            raise ParameterError(f"mode must be 'all' or 'first', got {mode!r}")
        t0 = time.perf_counter()
        f = self.fibres
        counters = np.zeros(T.N_COUNTERS, np.int64)

        def run(tasks, first_only, c):
            pairs, params = P.traverse_packed(tasks, self.nbox, self.nbox.view(np.int32), self.leaf_boxes,
                                              self.leaf_first, self.sid, self.seg64, first_only, c)
            if chunk_filter is not None and not first_only:
                n = int(chunk_filter(pairs, params))
                pairs, params = pairs[:n], params[:n]
            return pairs, params

        if mode == "first" or self.threads <= 1 or self.n_nodes < 64:
            pairs, params = run(np.zeros((1, 2), np.int64), mode == "first", counters)
        else:
            tasks = P.expand_packed(self.nbox, self.nbox.view(np.int32), 256 * self.threads, counters)
            n_chunks = min(len(tasks), 32 * self.threads)
            chunks = [np.ascontiguousarray(tasks[i::n_chunks]) for i in range(n_chunks)]
            cs = [np.zeros(T.N_COUNTERS, np.int64) for _ in chunks]
            with ThreadPoolExecutor(max_workers=self.threads) as ex:
                results = list(ex.map(lambda ic: run(ic[1], False, cs[ic[0]]), enumerate(chunks)))
            for c in cs:
                counters += c
            pairs = np.concatenate([r[0] for r in results]) if results else np.zeros((0, 2), np.int64)
            params = np.concatenate([r[1] for r in results]) if results else np.zeros((0, 2))
        if mode == "all" and sort and len(pairs):
            pairs, params = P.sort_pairs(pairs, params, f.n_segments)
        dt = time.perf_counter() - t0
        self.stats = QueryStats.from_counters(counters, dt)
        self.timings["query"] = dt
        return pairs, params

    def depths(self) -> np.ndarray:
        """(n_nodes,) int64 depth of every node (root 0)."""
        d = np.zeros(self.n_nodes, np.int64)
        for u in np.nonzero(self.child >= 0)[0]:  # parents have smaller ids than children
            d[self.child[u]] = d[self.child[u] + 1] = d[u] + 1
        d[1] = -1  # the unused slot
        return d

    def _node_volumes(self, ids: np.ndarray) -> np.ndarray:
        """(len(ids),) volumes of the packed float32 node boxes ``ids``, m³."""
        b = self.nbox[ids, :6].astype(np.float64)
        return np.prod(b[:, 3:] - b[:, :3], axis=1)


def subset_contact_pairs(fibres: FibreSet, query) -> tuple[np.ndarray, np.ndarray]:
    """The colliding segment pairs of ``fibres`` that involve at least one segment of ``query`` (indices or an
    (S,) bool mask), as :meth:`FibreBVH.self_contact_pairs` with ``sort=False`` would report them (a < b,
    params s, t ∈ [0, 1], same-fibre neighbours skipped), without a tree: the query segments' boxes binned in
    a uniform grid (cells about their mean largest side, at most ≈ 16 per query segment), and every segment's
    box looked up in the cells it overlaps. For a few query segments (a band widened for some segments only)
    this costs O(S + Q + the pairs' box tests) instead of a whole query (the former sweep along one axis
    tested every segment of a slab as wide as the largest box: 0.12 s against 0.03 s for 1,960 of the
    reference scene's 35,500 segments)."""
    from headsim.collide._kernels_fibre_subset import bin_query_boxes, compact_hits, subset_pairs

    S = fibres.n_segments
    query_idx = index_selection(query, S, "query segment")
    is_query = np.zeros(S, np.bool_)
    is_query[query_idx] = True
    if not len(query_idx):
        return np.zeros((0, 2), np.int64), np.zeros((0, 2))
    nodes, start, r = fibres.nodes, np.ascontiguousarray(fibres.segment_start), fibres.radius
    box = np.empty((S, 6))
    P.segment_boxes(nodes, start, r, box)
    qbox = box[query_idx]
    lo = qbox[:, :3].min(axis=0)
    extent = qbox[:, 3:].max(axis=0) - lo
    cell = max(float((qbox[:, 3:] - qbox[:, :3]).max(axis=1).mean()), 1e-12)
    limit = max(4096, 16 * len(query_idx))
    while True:
        dims = np.maximum(np.ceil(extent / cell), 1).astype(np.int64)
        if int(np.prod(dims)) <= limit:
            break
        cell *= 1.5
    cell_start = np.empty(int(np.prod(dims)) + 1, np.int64)
    bin_query_boxes(box, query_idx, lo, cell, dims, cell_start, np.zeros(0, np.int64))
    members = np.empty(max(int(cell_start[-1]), 1), np.int64)
    bin_query_boxes(box, query_idx, lo, cell, dims, cell_start, members)
    counts = np.zeros(S, np.int64)
    args = (nodes, start, np.ascontiguousarray(fibres.segment_fibre), r, box, lo, cell, dims,
            cell_start, members, is_query)
    # the box pairs counted, the capsule tests written behind their offsets, then the hits compacted
    subset_pairs(*args, counts, np.zeros((0, 2), np.int64), np.zeros((0, 2)), False)
    box_offsets = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    room_p, room_r = np.empty((int(counts.sum()), 2), np.int64), np.empty((int(counts.sum()), 2))
    hits = box_offsets.copy()  # in: where each segment's box pairs start; out: its hits
    subset_pairs(*args, hits, room_p, room_r, True)
    hit_offsets = np.concatenate([[0], np.cumsum(hits)[:-1]]).astype(np.int64)
    total = int(hits.sum())
    pairs, params = np.empty((total, 2), np.int64), np.empty((total, 2))
    compact_hits(box_offsets, hits, room_p, room_r, hit_offsets, pairs, params)
    return pairs, params
