"""Fibre geometry for collision detection: node chains, capsule segments, adjacency.

A bundle of fibres is one ``(N, 3)`` node array plus CSR-style ``fibre_offsets`` (fibre ``f`` owns
nodes ``fibre_offsets[f]:fibre_offsets[f+1]``), as everywhere in headsim. Segment ``j`` of a fibre is
the capsule (swept sphere) around the straight piece between two consecutive nodes
(Sobottka 2008, §7.1, §7.3.7.1: "capped cylinders"). The radius may vary along the fibre: it is given
per node or per segment; a segment between nodes of different radii uses the larger of the two, so
the capsule encloses the tapered piece (conservative for detection).

Segments are numbered globally, fibre after fibre: fibre ``f`` owns segments
``segment_offsets[f]:segment_offsets[f+1]`` with ``segment_offsets = fibre_offsets - arange(F+1)``.
Two segments are *adjacent* (their pair is never a contact, Sobottka Algorithm 3, ``adj(s)``) when
they are the same segment or consecutive segments of the same fibre.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from headsim.errors import ParameterError

__all__ = ["FibreSet", "FibreContacts", "capsule_contacts", "fibres_from_arrays", "fibres_from_rods"]


@dataclass(frozen=True, eq=False)
class FibreSet:
    """Fibres as capsule chains.

    nodes : (N, 3) float64, m — all fibre nodes, fibre after fibre.
    fibre_offsets : (F + 1,) int64 — CSR offsets into ``nodes``; every fibre has ≥ 2 nodes.
    radius : (S,) float64, m — capsule radius of every segment (S = N − F), > 0.
    """

    nodes: np.ndarray
    fibre_offsets: np.ndarray
    radius: np.ndarray

    def __post_init__(self):
        x = np.array(self.nodes, dtype=np.float64, order="C")
        off = np.array(self.fibre_offsets, dtype=np.int64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ParameterError(f"fibre nodes must be (N, 3), got {x.shape}")
        if not np.isfinite(x).all():
            raise ParameterError("fibre nodes contain NaN or inf")
        if off.ndim != 1 or off.size < 2 or off[0] != 0 or off[-1] != len(x):
            raise ParameterError(
                f"fibre_offsets must run from 0 to len(nodes) = {len(x)}, got {off[:3]}…{off[-1:]}"
            )
        if (np.diff(off) < 2).any():
            raise ParameterError("every fibre needs at least 2 nodes (one segment)")
        n_seg = len(x) - (off.size - 1)
        r = np.array(self.radius, dtype=np.float64).reshape(-1)
        if r.size == 1:
            r = np.full(n_seg, float(r[0]))
        if r.size != n_seg:
            raise ParameterError(f"radius must be a scalar or (S,) = ({n_seg},), got {r.size} values")
        if not (np.isfinite(r).all() and (r > 0).all()):
            raise ParameterError("fibre radii must be finite and > 0 (m)")
        for a in (x, off, r):
            a.flags.writeable = False
        object.__setattr__(self, "nodes", x)
        object.__setattr__(self, "fibre_offsets", off)
        object.__setattr__(self, "radius", r)

    # -- sizes ------------------------------------------------------------------------------
    @property
    def n_fibres(self) -> int:
        return self.fibre_offsets.size - 1

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_segments(self) -> int:
        return self.n_nodes - self.n_fibres

    # -- segment tables ----------------------------------------------------------------------
    @cached_property
    def segment_offsets(self) -> np.ndarray:
        """(F + 1,) int64: fibre ``f`` owns segments ``segment_offsets[f]:segment_offsets[f+1]``."""
        return self.fibre_offsets - np.arange(self.n_fibres + 1, dtype=np.int64)

    @cached_property
    def segment_fibre(self) -> np.ndarray:
        """(S,) int64: fibre id of every segment."""
        return np.repeat(np.arange(self.n_fibres, dtype=np.int64), np.diff(self.segment_offsets))

    @cached_property
    def segment_start(self) -> np.ndarray:
        """(S,) int64: node index of every segment's first endpoint (the second is +1)."""
        return np.arange(self.n_segments, dtype=np.int64) + self.segment_fibre

    @cached_property
    def segment_local(self) -> np.ndarray:
        """(S,) int64: index of every segment along its own fibre (0 at the root)."""
        return np.arange(self.n_segments, dtype=np.int64) - self.segment_offsets[self.segment_fibre]

    @cached_property
    def segment_previous(self) -> np.ndarray:
        """(S,) int64: previous segment on the same fibre, −1 at a root (``adj`` of Alg. 3)."""
        p = np.arange(self.n_segments, dtype=np.int64) - 1
        p[self.segment_offsets[:-1]] = -1
        return p

    @cached_property
    def segment_next(self) -> np.ndarray:
        """(S,) int64: next segment on the same fibre, −1 at a tip (``adj`` of Alg. 3)."""
        n = np.arange(self.n_segments, dtype=np.int64) + 1
        n[self.segment_offsets[1:] - 1] = -1
        return n

    def segment_endpoints(self, nodes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(S, 3), (S, 3) float64, m: first and second endpoint of every segment."""
        x = self.nodes if nodes is None else nodes
        i = self.segment_start
        return x[i], x[i + 1]

    def adjacent(self, seg_a: np.ndarray, seg_b: np.ndarray) -> np.ndarray:
        """(n,) bool: pairs that are the same segment or neighbours on one fibre (never contacts)."""
        a = np.asarray(seg_a, dtype=np.int64)
        b = np.asarray(seg_b, dtype=np.int64)
        same_fibre = self.segment_fibre[a] == self.segment_fibre[b]
        return same_fibre & (np.abs(a - b) <= 1)

    def total_fibre_order(self, fibre_order: np.ndarray | None = None) -> np.ndarray:
        """(S,) int64: the segments of the seed's "total fibre" (Sobottka §7.3.3, Fig. 7.4).

        The fibres are threaded into one virtual chain in ``fibre_order`` (default: as stored, which
        for generated hair is root order, so consecutive fibres are spatial neighbours), alternately
        root→tip and tip→root (boustrophedon), so that the tip of fibre i meets the tip of fibre i+1 and
        the root of i+1 meets the root of i+2. The virtual links are not adjacency.
        """
        order = np.arange(self.n_fibres) if fibre_order is None else np.asarray(fibre_order, np.int64)
        if order.shape != (self.n_fibres,) or not np.array_equal(np.sort(order), np.arange(self.n_fibres)):
            raise ParameterError("fibre_order must be a permutation of the fibre ids")
        lo = self.segment_offsets[order]
        cnt = self.segment_offsets[order + 1] - lo
        starts = np.repeat(np.cumsum(cnt) - cnt, cnt)
        within = np.arange(cnt.sum(), dtype=np.int64) - starts
        rev = np.repeat((np.arange(order.size) % 2 == 1), cnt)
        within = np.where(rev, np.repeat(cnt, cnt) - 1 - within, within)
        return np.repeat(lo, cnt) + within

    def with_nodes(self, nodes: np.ndarray) -> "FibreSet":
        """Same fibres and radii at new node positions (validated again)."""
        return replace(self, nodes=nodes)


def fibres_from_arrays(nodes, fibre_offsets, radius, *, radius_per: str = "auto") -> FibreSet:
    """Build a :class:`FibreSet` from plain arrays.

    Parameters
    ----------
    nodes : (N, 3) float, m.
    fibre_offsets : (F + 1,) int, CSR offsets into ``nodes``.
    radius : float, (N,) per node, or (S,) per segment, m. Per-node radii become per-segment radii
        ``max(r_i, r_{i+1})`` (the capsule encloses the tapered piece).
    radius_per : ``"auto"`` (decide by length; a bundle with N == S is impossible since F ≥ 1),
        ``"node"`` or ``"segment"``.
    """
    x = np.asarray(nodes, dtype=np.float64)
    off = np.asarray(fibre_offsets, dtype=np.int64)
    r = np.asarray(radius, dtype=np.float64).reshape(-1)
    n_seg = len(x) - (off.size - 1)
    per = radius_per
    if per == "auto":
        per = "node" if r.size == len(x) and r.size != 1 else "segment"
    if per == "node":
        if r.size != len(x):
            raise ParameterError(f"per-node radius needs {len(x)} values, got {r.size}")
        start = np.arange(n_seg, dtype=np.int64) + np.repeat(
            np.arange(off.size - 1, dtype=np.int64), np.diff(off) - 1
        )
        r = np.maximum(r[start], r[start + 1])
    elif per != "segment":
        raise ParameterError(f"radius_per must be 'auto', 'node' or 'segment', got {radius_per!r}")
    return FibreSet(x, off, r)


def fibres_from_rods(positions, fibre_offsets, radius) -> FibreSet:
    """Adapter for the rod solver (``headsim.solvers.rods`` / ``headsim.hair``).

    positions : (N, 3) float, m — centre-line nodes of all rods, CSR by ``fibre_offsets``.
    radius : float, (N,) per node or (S,) per segment (edge), m.

    Rod states store exactly these arrays, so this is :func:`fibres_from_arrays`; it exists so the
    rod code has one stable entry point if the conventions of either side change.
    """
    return fibres_from_arrays(positions, fibre_offsets, radius)


@dataclass(frozen=True, eq=False)
class FibreContacts:
    """Contacts of fibre segments with other segments or with obstacles (input of the response).

    All arrays have n rows (one per contact):

    body_a : (n,) int64 — fibre id of side A.
    body_b : (n,) int64 — fibre id of side B, or the obstacle id where ``obstacle`` is True.
    segment_a, segment_b : (n,) int64 — global segment ids (segment_b = −1 for obstacles);
        for fibre pairs segment_a < segment_b.
    s_a, s_b : (n,) float64 — segment parameters in [0, 1] of the closest points on the centre lines
        (point = p0 + s (p1 − p0)); s_b is NaN for obstacles.
    point_a : (n, 3) float64, m — point on A's capsule surface: axis point − r_a · normal.
    point_b : (n, 3) float64, m — point on B's surface: axis point + r_b · normal (fibre), or the
        closest point on the obstacle's contact level set (obstacle).
    normal : (n, 3) float64 — unit contact normal pointing from B to A (move A along +normal).
    depth : (n,) float64, m — penetration depth ≥ 0 (r_a + r_b − centre-line distance; obstacle:
        level + offset − φ).
    obstacle : (n,) bool — True for fibre–obstacle contacts.
    """

    body_a: np.ndarray
    body_b: np.ndarray
    segment_a: np.ndarray
    segment_b: np.ndarray
    s_a: np.ndarray
    s_b: np.ndarray
    point_a: np.ndarray
    point_b: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    obstacle: np.ndarray

    def __len__(self) -> int:
        return len(self.depth)

    @property
    def pairs(self) -> np.ndarray:
        """(n, 2) int64 segment pairs (segment_b = −1 for obstacles)."""
        return np.stack([self.segment_a, self.segment_b], axis=1)

    @classmethod
    def empty(cls) -> "FibreContacts":
        z = np.zeros(0, np.int64)
        f = np.zeros(0)
        p = np.zeros((0, 3))
        return cls(z, z, z, z, f, f, p, p, p, f, np.zeros(0, bool))

    @classmethod
    def concatenate(cls, parts) -> "FibreContacts":
        parts = list(parts)
        if not parts:
            return cls.empty()
        names = [f for f in cls.__dataclass_fields__]
        return cls(**{n: np.concatenate([getattr(p, n) for p in parts]) for n in names})


def capsule_contacts(fibres: FibreSet, pairs: np.ndarray, params: np.ndarray,
                     nodes: np.ndarray | None = None) -> FibreContacts:
    """Contact records of colliding segment pairs.

    pairs : (n, 2) int64 segment ids (a < b); params : (n, 2) float64 closest-point parameters (s, t).
    A zero centre-line distance (crossing axes) takes the normal ``d_a × d_b`` (or any
    perpendicular of d_a if parallel). Computed by a Numba kernel (``_kernels_fibre_contacts``).
    """
    from headsim.collide._kernels_fibre_contacts import contact_records

    x = fibres.nodes if nodes is None else np.ascontiguousarray(nodes, dtype=np.float64)
    pairs = np.ascontiguousarray(np.asarray(pairs, np.int64).reshape(-1, 2))
    params = np.ascontiguousarray(np.asarray(params, np.float64).reshape(-1, 2))
    n = len(pairs)
    point_a, point_b, normal = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    depth = np.empty(n)
    contact_records(x, fibres.segment_start, fibres.radius, pairs, params, point_a, point_b, normal, depth)
    a, b = pairs[:, 0], pairs[:, 1]
    return FibreContacts(
        body_a=fibres.segment_fibre[a],
        body_b=fibres.segment_fibre[b],
        segment_a=a.copy(),
        segment_b=b.copy(),
        s_a=params[:, 0].copy(),
        s_b=params[:, 1].copy(),
        point_a=point_a,
        point_b=point_b,
        normal=normal,
        depth=depth,
        obstacle=np.zeros(n, bool),
    )
