"""A low-order Coulomb treecode for charges on fibres, with refit across charging steps.

Barnes & Hut (1986) in the target-group form (Barnes 1990): an octree over the charges sorted along
a Morton curve (charges on a fibre are contiguous along the fibre, so leaves are short fibre pieces),
Cartesian multipoles up to the quadrupole about each cell's centre of |q| (the seed found two
expansion terms visually sufficient, Sobottka §4.5), an opening angle ``theta`` and the exact direct
sum inside the near field. There is no distance cut-off: every pair is counted, near pairs exactly,
far pairs by the expansion (Sobottka §4.2, Darden 1993).

Accuracy is controlled by ``theta`` (smaller = more accurate) and ``order`` (0 monopole, 1 dipole,
2 quadrupole). With charges of one sign the dipole about the centre of |q| vanishes, so order 1
equals order 0 and the error of order 2 falls like theta^3. Measured errors against the direct sum:
``headsim.hair.electrostatics.validation.accuracy_table``.

Time coherence: :meth:`Treecode.refit` keeps the permutation and the cell topology and only
recomputes the moments and enclosing radii from the moved charges (the acceptance test uses the
recomputed radii, so the accuracy is kept; only the efficiency degrades for large motions, after which
:meth:`Treecode.build` starts over).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.electrostatics import _kernels_tree as _kt
from headsim.hair.electrostatics.units import K_COULOMB

__all__ = ["TreecodeOptions", "Treecode"]


@dataclass(frozen=True)
class TreecodeOptions:
    """theta: opening angle in (0, 1]; order: 0, 1 or 2; leaf_size: charges per leaf (>= 1);
    local: convert well-separated cells (r_cell + r_leaf < theta d) into a second-order local expansion
    about the target leaf's centre (cell-to-leaf, evaluated once per leaf) instead of evaluating the
    multipoles at every target."""

    theta: float = 0.5
    order: int = 2
    leaf_size: int = 32
    local: bool = True

    def __post_init__(self):
        if not (0.0 < self.theta <= 1.0):
            raise ParameterError(f"theta must lie in (0, 1], got {self.theta}")
        if self.order not in (0, 1, 2):
            raise ParameterError(f"order must be 0, 1 or 2, got {self.order}")
        if self.leaf_size < 1:
            raise ParameterError(f"leaf_size must be >= 1, got {self.leaf_size}")


def _check(points, charges):
    x = np.ascontiguousarray(np.asarray(points, dtype=np.float64))
    q = np.ascontiguousarray(np.asarray(charges, dtype=np.float64))
    if x.ndim != 2 or x.shape[1] != 3 or q.shape != (x.shape[0],) or x.shape[0] == 0:
        raise ParameterError(f"need points (n, 3) and charges (n,), n > 0; got {x.shape} and {q.shape}")
    if not (np.isfinite(x).all() and np.isfinite(q).all()):
        raise ParameterError("charge positions and charges must be finite")
    return x, q


class Treecode:
    """Octree + multipoles over n charges. ``positions`` (n, 3) m, ``charges`` (n,) C.

    Build once with :meth:`build` (or the constructor), then :meth:`refit` with moved positions and/or
    new charges; :meth:`field` gives E (n, 3) V/m at the charges (self excluded), :meth:`forces` q E
    in N, :meth:`field_at` E at other points.
    """

    def __init__(self, positions, charges, options: TreecodeOptions = TreecodeOptions()):
        self.options = options
        self.build(positions, charges)

    # -- construction ------------------------------------------------------------------------
    def build(self, positions, charges) -> None:
        x, q = _check(positions, charges)
        lower = x.min(axis=0)
        extent = float((x.max(axis=0) - lower).max())
        extent = extent * (1 + 1e-9) if extent > 0 else 1.0
        codes = np.empty(x.shape[0], np.uint64)
        _kt.morton_codes(x, lower, extent, codes)
        self.perm = np.argsort(codes, kind="stable")
        codes = codes[self.perm]
        n = x.shape[0]
        m = 2 * n + 1
        start = np.empty(m, np.int64)
        end = np.empty(m, np.int64)
        first = np.empty(m, np.int64)
        nchild = np.empty(m, np.int64)
        nn = _kt.build_octree(codes, int(self.options.leaf_size), start, end, first, nchild)
        self.start, self.end = start[:nn].copy(), end[:nn].copy()
        self.first_child, self.n_child = first[:nn].copy(), nchild[:nn].copy()
        self.leaves = np.flatnonzero(self.n_child == 0).astype(np.int64)
        self.centre = np.empty((nn, 3))
        self.radius = np.empty(nn)
        self.mono = np.empty(nn)
        self.dipole = np.empty((nn, 3))
        self.quad = np.empty((nn, 6))
        self.refit(x, q)

    def refit(self, positions=None, charges=None) -> None:
        """Keep the permutation and topology; recompute moments from new positions and/or charges."""
        if positions is not None or charges is not None:
            x, q = _check(self.positions if positions is None else positions,
                          self.charges if charges is None else charges)
            if x.shape[0] != self.perm.shape[0]:
                raise ParameterError("refit needs the same number of charges as the build")
            self.positions, self.charges = x, q
            xp = x[self.perm]
            self.xs = np.ascontiguousarray(xp[:, 0])
            self.ys = np.ascontiguousarray(xp[:, 1])
            self.zs = np.ascontiguousarray(xp[:, 2])
            self.qs = np.ascontiguousarray(q[self.perm])
        _kt.cell_moments(self.xs, self.ys, self.zs, self.qs, self.start, self.end, self.centre, self.radius,
                         self.mono, self.dipole, self.quad)

    @property
    def n_charges(self) -> int:
        return int(self.perm.shape[0])

    @property
    def n_nodes(self) -> int:
        return int(self.start.shape[0])

    # -- evaluation --------------------------------------------------------------------------
    def field(self, theta: float | None = None, order: int | None = None, return_counts: bool = False):
        """(n, 3) V/m: the field at every charge due to all others (input order)."""
        th = self.options.theta if theta is None else float(theta)
        od = self.options.order if order is None else int(order)
        TreecodeOptions(th, od, self.options.leaf_size, self.options.local)  # validate
        out = np.empty((self.n_charges, 3))
        args = (self.xs, self.ys, self.zs, self.qs, self.start, self.end, self.first_child, self.n_child,
                self.centre, self.radius, self.mono, self.dipole, self.quad, self.leaves, th, od, out)
        if self.options.local:
            counts = np.zeros((self.leaves.shape[0], 3), np.int64)
            _kt.treecode_field_groups_local(*args, counts)
        else:
            counts = np.zeros((self.leaves.shape[0], 2), np.int64)
            _kt.treecode_field_groups(*args, counts)
        E = np.empty_like(out)
        E[self.perm] = out
        E *= K_COULOMB
        if return_counts:
            c = counts.sum(axis=0)
            if self.options.local:
                return E, {"cell_to_leaf": int(c[0]), "far_evaluations": int(c[1]), "near_pairs": int(c[2])}
            return E, {"cell_to_leaf": 0, "far_evaluations": int(c[0]), "near_pairs": int(c[1])}
        return E

    def forces(self, theta: float | None = None, order: int | None = None) -> np.ndarray:
        """(n, 3) N: Coulomb force q_i E_i on every charge (Sobottka eq. 4.2 in SI)."""
        return self.charges[:, None] * self.field(theta, order)

    def field_at(self, points, theta: float | None = None, order: int | None = None) -> np.ndarray:
        """(m, 3) V/m at points (m, 3) m (charges located exactly at a point are skipped)."""
        p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if not np.isfinite(p).all():
            raise ParameterError("probe points must be finite")
        th = self.options.theta if theta is None else float(theta)
        od = self.options.order if order is None else int(order)
        out = np.empty((p.shape[0], 3))
        _kt.treecode_field_points(p, self.xs, self.ys, self.zs, self.qs, self.start, self.end, self.first_child,
                                  self.n_child, self.centre, self.radius, self.mono, self.dipole, self.quad,
                                  th, od, out)
        return out * K_COULOMB
