"""Ray–capsule BVH over the segments of a fibre assembly (for the hair renderer).

Fibres are one (N, 3) node array plus ``fibre_offsets`` (F+1,) int64 (CSR, root first); every segment
becomes a capsule of the fibre radius. The tree is a Morton-ordered LBVH built in Numba.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.render import _kernels_bvh as _k

__all__ = ["FibreAssembly", "CapsuleBVH"]


@dataclass(frozen=True, eq=False)
class FibreAssembly:
    """Polyline fibres for rendering.

    nodes : (N, 3) float64, m, root → tip within each fibre
    fibre_offsets : (F+1,) int64, CSR offsets into ``nodes`` (every fibre ≥ 2 nodes)
    radius : (N,) float64 per-node radius, m (a scalar is broadcast); default 40 µm
    """

    nodes: np.ndarray
    fibre_offsets: np.ndarray
    radius: np.ndarray | float = 40e-6

    def __post_init__(self):
        x = np.array(self.nodes, dtype=np.float64, order="C")
        off = np.array(self.fibre_offsets, dtype=np.int64).reshape(-1)
        if x.ndim != 2 or x.shape[1] != 3 or len(x) < 2 or not np.isfinite(x).all():
            raise ParameterError(f"nodes must be finite (N ≥ 2, 3), got {x.shape}")
        if len(off) < 2 or off[0] != 0 or off[-1] != len(x) or np.any(np.diff(off) < 2):
            raise ParameterError("fibre_offsets must start at 0, end at len(nodes) and give every fibre ≥ 2 nodes")
        r = np.broadcast_to(np.asarray(self.radius, dtype=np.float64), (len(x),)).copy()
        if not np.isfinite(r).all() or np.any(r <= 0):
            raise ParameterError("fibre radius must be finite and > 0 (m)")
        if r.max() > 0.01:
            raise ParameterError(f"fibre radius {r.max()} m is implausible for hair (expected ~1e-5 … 1e-4 m)")
        for arr in (x, off, r):
            arr.flags.writeable = False
        object.__setattr__(self, "nodes", x)
        object.__setattr__(self, "fibre_offsets", off)
        object.__setattr__(self, "radius", r)

    @property
    def n_fibres(self) -> int:
        return len(self.fibre_offsets) - 1

    def segments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a (S,3), b (S,3), radius (S,)) of all segments, root-to-tip oriented."""
        n = len(self.nodes)
        is_last = np.zeros(n, dtype=bool)
        is_last[self.fibre_offsets[1:] - 1] = True
        i = np.flatnonzero(~is_last)
        return self.nodes[i], self.nodes[i + 1], 0.5 * (self.radius[i] + self.radius[i + 1])

    @classmethod
    def load_npz(cls, path) -> "FibreAssembly":
        """NPZ with ``nodes`` (N,3) m, ``fibre_offsets`` (F+1,) int64 and optional ``radius``."""
        with np.load(path) as z:
            if "nodes" not in z or "fibre_offsets" not in z:
                raise ParameterError(f"{path}: needs arrays 'nodes' and 'fibre_offsets'")
            kw = {"radius": z["radius"]} if "radius" in z else {}
            return cls(z["nodes"], z["fibre_offsets"], **kw)


def _morton(p: np.ndarray) -> np.ndarray:
    lo, hi = p.min(axis=0), p.max(axis=0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-300) * 2097151).astype(np.uint64)
    code = np.zeros(len(p), dtype=np.uint64)
    for bit in range(21):
        for k in range(3):
            code |= ((q[:, k] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + (2 - k))
    return code


class CapsuleBVH:
    """LBVH over capsules. Arrays (sorted primitive order): ``a``, ``b`` (S, 3) m, ``radius`` (S,) m,
    ``segment`` (S,) original segment id; nodes: ``left``, ``right``, ``start``, ``count``, ``bmin``, ``bmax``."""

    def __init__(self, a: np.ndarray, b: np.ndarray, radius: np.ndarray, leaf_size: int = 4):
        a = np.ascontiguousarray(a, dtype=np.float64)
        b = np.ascontiguousarray(b, dtype=np.float64)
        radius = np.ascontiguousarray(radius, dtype=np.float64)
        if len(a) == 0:
            raise ParameterError("CapsuleBVH needs at least one segment")
        codes = _morton(0.5 * (a + b))
        order = np.argsort(codes, kind="stable")
        self.segment = order
        self.a, self.b, self.radius = a[order], b[order], radius[order]
        codes = codes[order]
        m = 2 * len(a)
        self.left = np.empty(m, np.int64)
        self.right = np.empty(m, np.int64)
        self.start = np.empty(m, np.int64)
        self.count = np.empty(m, np.int64)
        n_nodes = _k.build_lbvh(codes, leaf_size, self.left, self.right, self.start, self.count)
        for name in ("left", "right", "start", "count"):
            setattr(self, name, getattr(self, name)[:n_nodes].copy())
        self.bmin = np.empty((n_nodes, 3))
        self.bmax = np.empty((n_nodes, 3))
        _k.fit_bounds(self.a, self.b, self.radius, self.left, self.right, self.start, self.count, n_nodes,
                      self.bmin, self.bmax)

    @classmethod
    def from_fibres(cls, fibres: FibreAssembly, leaf_size: int = 4, max_aspect: float = 0.0) -> "CapsuleBVH":
        """BVH over the fibre segments; segments longer than ``max_aspect`` radii are cut into equal
        sub-capsules (their union is the original capsule, so hits of rays starting outside the fibres are
        unchanged) to tighten the boxes; 0 (default) keeps whole segments — measured no faster on hair."""
        a, b, r = fibres.segments()
        if max_aspect > 0:
            length = np.linalg.norm(b - a, axis=1)
            k = np.clip(np.ceil(length / (max_aspect * r)), 1, 64).astype(np.int64)
            if k.max() > 1:
                seg = np.repeat(np.arange(len(a)), k)
                first = np.repeat(np.cumsum(k) - k, k)
                j = np.arange(len(seg)) - first
                kk = k[seg].astype(np.float64)
                t0 = (j / kk)[:, None]
                t1 = ((j + 1) / kk)[:, None]
                d = b[seg] - a[seg]
                a, b, r = a[seg] + t0 * d, a[seg] + t1 * d, r[seg]
        return cls(a, b, r, leaf_size=leaf_size)

    @property
    def arrays(self) -> tuple:
        return (self.a, self.b, self.radius, self.left, self.right, self.bmin, self.bmax, self.start, self.count)

    def intersect_rays(self, origins, directions, max_distance=np.inf) -> tuple[np.ndarray, np.ndarray]:
        """First hits: (distance (n,) m or inf, sorted-primitive index (n,) or −1). Directions are normalised."""
        o = np.ascontiguousarray(np.atleast_2d(origins), dtype=np.float64)
        d = np.atleast_2d(np.asarray(directions, dtype=np.float64))
        d = np.ascontiguousarray(d / np.linalg.norm(d, axis=1, keepdims=True))
        t = np.empty(len(o))
        idx = np.empty(len(o), np.int64)
        _intersect_batch(o, d, float(max_distance), *self.arrays, t, idx)
        return t, idx


from numba import njit, prange  # noqa: E402


@njit(cache=True, parallel=True)
def _intersect_batch(o, d, tmax, a, b, radius, left, right, bmin, bmax, start, count, t_out, i_out):
    for k in prange(o.shape[0]):
        stack = np.empty(_k._STACK, np.int64)
        t, i = _k.intersect(o[k, 0], o[k, 1], o[k, 2], d[k, 0], d[k, 1], d[k, 2], 0.0, tmax, -1, False,
                            a, b, radius, left, right, bmin, bmax, start, count, stack)
        t_out[k] = t
        i_out[k] = i
