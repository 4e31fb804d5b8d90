"""Local-motion bound of the relative speeds of nearby fibre segments: the chain solver's relative candidate
band (``ChainOptions.candidate_band = "relative"``, :mod:`headsim.solvers.chains`).

The candidate band of a fibre pair must cover how far the pair can close its gap within the step. With the
segments' own speeds (|v| + h|ω|, the absolute band) it grows with the fall speed although neighbouring
fibres move together, and with their rotation although a bending strand turns its neighbours alike. This
bound measures each segment's motion against a smooth reference velocity field F instead (trilinear on a
grid of :data:`REFERENCE_CELL`, gathered from the segments' point velocities;
:mod:`headsim.solvers._kernels.chains_band`):

* e_s ≥ max over the points p of segment s of |u_s(p) − F(p)| (m/s), u_s(p) = v_s + ω_s × (p − x_s);
* L_s(ρ) ≥ the Lipschitz constant of F (1/s) in every cell within ρ of segment s.

For points p of segment a and q of segment b with |p − q| ≤ ρ_a + ρ_b, the straight path from p to q splits
into a part within ρ_a of p and a part within ρ_b of q, so

    |u_a(p) − u_b(q)| ≤ |u_a(p) − F(p)| + |F(p) − F(q)| + |F(q) − u_b(q)| ≤ A_a + A_b,
    A_s = e_s + L_s(ρ_s) ρ_s.

The solver takes ρ_s = the absolute band's reach of segment s (its radius, row band and margin plus
(|v| + h|ω| + 1.5 δ̂)Δt): a pair farther apart than ρ_a + ρ_b cannot close within the step even at the
segments' own speeds, and every nearer one closes at most at A_a + A_b. On the 355 × 100 ringlet start at
t = 6 ms (1 mm cell): e 0.007 m/s, L 28 1/s (medians) against own speeds of 0.12 m/s; 1.8 M detected pairs
instead of the absolute band's 4.3 M, ≈ 1 M of them around the ≈ 2,000 segments near the tips that move at
≈ 2 m/s against their neighbours (there the bound is no better than their own speed). The falling strand of
the derived geometry at t = 60 ms (0.6 m/s): 0.36 M reserve pairs instead of the former bound's 1.2 M.

A segment whose reach ρ exceeds a cell sees F on nodes far from any mass; where the Lipschitz path term
exceeds the spread of F's node values within its reach, the spread bounds |F(p) − F(m)| instead (both are
valid: F is a convex combination of those values).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from headsim.solvers._kernels import chains_band as KB

__all__ = ["LocalMotionBound", "REFERENCE_CELL"]

# grid cell of the reference field, m (a third of the reference scene's 3 mm segments: finer cells follow the
# strand's bending better but see more of the fibres' own scatter and cost more nodes; measured below)
REFERENCE_CELL = 1e-3
# largest grid (nodes): a strand spread wider gets a coarser cell (in steps of 1.25×). The bound's passes over
# the grid then cost more than a finer cell saves in pairs: falling strand (derived geometry, t = 60 ms, 112 ×
# 57 × 78 mm) 1 / 1.4 / 2 / 3 mm cells: detection 0.39 / 0.30 / 0.27 / 0.27 s per step for 364 / 362 / 372 / 392 k
# reserve pairs; ringlet start (52 k nodes at 1 mm) 0.7 / 1 / 1.4 / 2 / 3 mm: 0.67 / 0.56 / 0.58 / 0.72 / 0.79 s
MAX_REFERENCE_NODES = 200_000
# and at most this many nodes per segment (at least MIN_REFERENCE_NODES): a small strand spread wide got the whole
# 200 k-node grid, whose passes then cost more than its detection and solve (7 × 30 helical strand, 20 × 20 × 12
# cm: 20 ms of a 41 ms step at 200 k nodes, 3.8 ms of 24.5 ms at 21 k, with 213 candidates instead of 249 per step)
NODES_PER_SEGMENT = 100
MIN_REFERENCE_NODES = 4096
# sample spacing along a segment / cell: the gathering, and the deviation bound (whose between-sample term
# δ(|ω| + L)/2 shrinks with it)
GATHER_SPACING = 0.5
DEVIATION_SPACING = 0.125
# the spread of F's values is also computed for the segments whose path term L ρ exceeds this × (e + 1 mm/s)
OSCILLATION_CHECK = 4.0


class LocalMotionBound:
    """The reference field of one state and the per-segment bounds of the module docstring.

    x (S, 3) m centres, d3 (S, 3) unit axes, v (S, 3) m/s, w (S, 3) rad/s, half (S,) m half lengths,
    mass (S,) kg; reach: the largest ρ (m) expected (the grid is padded for it, and rebuilt wider when a
    later ρ needs more)."""

    def __init__(self, x, d3, v, w, half, mass, reach: float, cell: float = REFERENCE_CELL):
        self._args = tuple(np.ascontiguousarray(a, np.float64) for a in (x, d3, v, w, half, mass))
        self._cell0 = float(cell)
        self._build(float(reach))

    def _build(self, reach: float):
        x, d3, v, w, half, mass = self._args
        ends = np.abs(d3) * half[:, None]
        lo, hi = (x - ends).min(axis=0), (x + ends).max(axis=0)
        cell = self._cell0
        max_nodes = min(MAX_REFERENCE_NODES, max(MIN_REFERENCE_NODES, NODES_PER_SEGMENT * len(x)))
        while True:
            pad = int(np.ceil(reach / cell)) + 3
            dims = (np.floor((hi - lo) / cell).astype(np.int64) + 2 * pad + 2)
            if np.prod(dims.astype(float)) <= max_nodes:
                break
            cell *= 1.25
        self.cell = cell
        self.reach = reach
        self._lo = lo - pad * cell
        gather = max(2, int(np.ceil(2.0 * half.max() / (GATHER_SPACING * cell))) + 1)
        self._samples = max(2, int(np.ceil(2.0 * half.max() / (DEVIATION_SPACING * cell))) + 1)
        M = np.zeros(tuple(dims))
        MV = np.zeros(tuple(dims) + (3,))
        KB.gather_reference(x, d3, v, w, half, mass, cell, self._lo, gather, M, MV)
        V, filled = MV, np.empty(M.shape, np.bool_)
        KB.node_values(M, MV, V, filled)
        # empty nodes: two layers of their filled neighbours' means, which reach every node of the 3 × 3 × 3
        # cell blocks around the samples' cells (a nearest value alone steps between neighbours: 35 % more
        # reserve pairs on the falling strand); where a reach exceeds a cell, the nodes beyond take their nearest
        # filled node's value (else 0 there would bound a coherently moving fast segment by its own speed; the
        # fill took 36 ms on a 720 k-node grid of the falling strand, which does not need it).
        V2, f2 = np.empty_like(V), np.empty_like(filled)
        for _ in range(2):
            KB.dilate_values(V, filled, V2, f2)
            V, V2, filled, f2 = V2, V, f2, filled
        if reach + DEVIATION_SPACING * cell > cell and not filled.all():
            idx = ndimage.distance_transform_cdt(~filled, metric="chessboard", return_distances=False,
                                                 return_indices=True)
            V = V[idx[0], idx[1], idx[2]]
        self._L = np.empty(tuple(dims - 1))
        KB.cell_lipschitz(V, cell, self._L)
        self._Ln = np.empty_like(self._L)
        KB.neighbourhood_max(self._L, self._Ln)
        self._V = V
        self.deviation = np.empty(len(x))
        KB.segment_deviation(x, d3, v, w, half, cell, self._lo, V, self._Ln, self._samples, self.deviation)

    def lipschitz(self, reach) -> np.ndarray:
        """(S,) 1/s: L_s(ρ_s) for the reach ρ (S,) m (the grid is rebuilt wider where it must be)."""
        reach = np.ascontiguousarray(reach, np.float64)
        if float(reach.max()) > self.reach:
            self._build(1.5 * float(reach.max()))
        x, d3, _, _, half, _ = self._args
        out = np.empty(len(x))
        KB.segment_lipschitz(x, d3, half, self.cell, self._lo, self._L, self._Ln, self._samples, reach, out)
        return out

    def allowance(self, reach) -> np.ndarray:
        """(S,) m/s: A_s = e_s + min(L_s(ρ_s) ρ_s, osc_s(ρ_s)), so |u_a(p) − u_b(q)| ≤ A_a + A_b for
        |p − q| ≤ ρ_a + ρ_b (osc: the spread of F's node values within ρ_s of the segment, computed only where
        L ρ exceeds :data:`OSCILLATION_CHECK` × (e + 1 mm/s), i.e. where it may be the smaller term)."""
        reach = np.ascontiguousarray(reach, np.float64)
        change = self.lipschitz(reach) * reach
        # near a segment much faster than its surroundings F changes by its speed within a cell: the path bound
        # L ρ then exceeds the range of F's values, which bounds |F(p) − F(m)| as well
        which = np.flatnonzero(change > OSCILLATION_CHECK * (self.deviation + 1e-3))
        if len(which):
            x, d3, _, _, half, _ = self._args
            osc = np.empty(len(which))
            KB.segment_oscillation(x, d3, half, self.cell, self._lo, self._V, self._samples, reach, which, osc)
            change[which] = np.minimum(change[which], osc)
        return self.deviation + change
