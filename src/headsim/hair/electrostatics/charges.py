"""Charge particles on fibres, stored by arc length (Sobottka §4.3.1).

Every fibre carries point charges at a constant linear density rho_P (particles per m), placed at
arc lengths s_k = (k + 1/2) L / n_f, k = 0 .. n_f - 1, n_f = max(1, round(rho_P L)) (half a spacing
away from the root, which sits on the scalp, and from the tip). A particle between nodes j and j+1
at s = (j + t) ds is interpolated linearly, x = (1 - t) r_j + t r_{j+1}, so its position stays valid
when the rod deforms. The transpose of this interpolation maps particle forces to consistent nodal
loads (the same virtual work), which the rod statics takes as dead loads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.electrostatics import _kernels as _k

__all__ = ["ChargeSampling", "sample_charges"]


@dataclass(frozen=True, eq=False)
class ChargeSampling:
    """Particles of F fibres with N segments.

    offsets : (F+1,) int64, particles of fibre f are offsets[f]:offsets[f+1]
    fibre, segment : (n,) int64; t : (n,) float64 in [0, 1); arc_length : (n,) m
    unit_charge : (n,) C, the charge of each particle when the line density is 1 C/m
    n_segments : N
    """

    offsets: np.ndarray
    fibre: np.ndarray
    segment: np.ndarray
    t: np.ndarray
    arc_length: np.ndarray
    unit_charge: np.ndarray
    n_segments: int

    def __post_init__(self):
        for name in ("offsets", "fibre", "segment", "t", "arc_length", "unit_charge"):
            a = np.array(getattr(self, name), order="C")
            a.flags.writeable = False
            object.__setattr__(self, name, a)
        if (self.segment < 0).any() or (self.segment >= self.n_segments).any():
            raise ParameterError("particle segments out of range")

    @property
    def n_particles(self) -> int:
        return int(self.fibre.shape[0])

    @property
    def n_fibres(self) -> int:
        return int(self.offsets.shape[0] - 1)

    def charges(self, line_density: float) -> np.ndarray:
        """(n,) C for a line charge density (C/m), the same on every fibre."""
        if not np.isfinite(line_density):
            raise ParameterError("line charge density must be finite")
        return self.unit_charge * float(line_density)

    def positions(self, node_positions) -> np.ndarray:
        """(n, 3) m from rod node positions (F, N+1, 3) m."""
        r = np.ascontiguousarray(np.asarray(node_positions, dtype=np.float64))
        if r.shape != (self.n_fibres, self.n_segments + 1, 3):
            raise ParameterError(f"node positions must be {(self.n_fibres, self.n_segments + 1, 3)}, got {r.shape}")
        out = np.empty((self.n_particles, 3))
        _k.sample_positions(r, self.fibre, self.segment, self.t, out)
        return out

    def node_forces(self, particle_forces) -> np.ndarray:
        """(F, N+1, 3) N: consistent nodal loads from particle forces (n, 3) N (transpose map)."""
        f = np.ascontiguousarray(np.asarray(particle_forces, dtype=np.float64))
        if f.shape != (self.n_particles, 3):
            raise ParameterError(f"particle forces must be {(self.n_particles, 3)}, got {f.shape}")
        out = np.empty((self.n_fibres, self.n_segments + 1, 3))
        _k.gather_node_forces(f, self.offsets, self.segment, self.t, out)
        return out


def sample_charges(lengths, n_segments: int, density: float) -> ChargeSampling:
    """Particles at ``density`` per m (the seed: 330 /cm = 33 000 /m) on fibres of ``lengths`` (F,) m
    with ``n_segments`` equal segments each. Each particle carries unit_charge = L / n_f (C per C/m),
    so that the total charge of a fibre equals line density x length exactly."""
    L = np.atleast_1d(np.asarray(lengths, dtype=np.float64))
    N = int(n_segments)
    if L.ndim != 1 or L.size == 0 or not (np.isfinite(L).all() and (L > 0).all()):
        raise ParameterError("fibre lengths must be positive (F,) m")
    if not (np.isfinite(density) and density > 0):
        raise ParameterError(f"particle density must be positive (per m), got {density}")
    if N < 1:
        raise ParameterError("need at least one segment")
    counts = np.maximum(1, np.rint(L * density)).astype(np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    n = int(offsets[-1])
    fibre = np.repeat(np.arange(L.size, dtype=np.int64), counts)
    k = np.arange(n, dtype=np.int64) - offsets[fibre]
    s = (k + 0.5) * (L / counts)[fibre]
    u = s / (L / N)[fibre]
    seg = np.minimum(np.floor(u).astype(np.int64), N - 1)
    t = u - seg
    unit = (L / counts)[fibre]
    return ChargeSampling(offsets, fibre, seg, t, s, unit, N)
