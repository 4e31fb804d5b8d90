"""Local density information (Sobottka 2008 §5.3.4) and the occupancy histogram (Fig. 5.6).

:class:`DensityGrid` is built incrementally while guides are placed:

* ``"binary"`` (BBM, eq. 5.11) — voxels overlapped by a strand's generalised-cylinder segments (their OBBs,
  separating-axis test against the voxels in the segment's AABB, Gottschalk 1996) are set to 1;
* ``"continuous"`` (KDM, eq. 5.12) — each voxel gains (fibre segment length inside it) / (cell diagonal), by
  exact voxel traversal of the strand's fibres, weighted 1 / (fibres in the strand) so one strand ~ 1;
* ``"none"`` — no density term.

Voxels are centred on the grid nodes; values are read by trilinear interpolation. Lengths in m.
"""

from __future__ import annotations

import numpy as np

from headsim.errors import ParameterError
from headsim.hair.reconstruct import _kernels as _k

__all__ = ["DensityGrid", "DENSITY_MODELS", "MODE_CODES", "occupancy_counts", "coefficient_of_variation"]

DENSITY_MODELS = ("none", "binary", "continuous")
MODE_CODES = {"none": 0, "binary": 1, "continuous": 2}


class DensityGrid:
    """values (nx, ny, nz) over the box [lower, upper] with spacing h (m)."""

    def __init__(self, model: str, lower, upper, spacing: float):
        if model not in DENSITY_MODELS:
            raise ParameterError(f"density model must be one of {', '.join(DENSITY_MODELS)}, got {model!r}")
        if not spacing > 0:
            raise ParameterError("density grid spacing must be > 0 m")
        self.model = model
        self.mode = MODE_CODES[model]
        self.origin = np.asarray(lower, float)
        self.spacing = float(spacing)
        dims = np.ceil((np.asarray(upper, float) - self.origin) / spacing).astype(int) + 1
        if model == "none":
            dims = np.array([2, 2, 2])
        if np.prod(dims.astype(float)) > 6e7:
            raise ParameterError(f"density grid {dims.tolist()} is too large; increase its spacing")
        self.values = np.zeros(tuple(dims))
        self.scale = 1.0  # KDM: 1 / (mean value if all strands were spread evenly), see :meth:`calibrate`

    def calibrate(self, head_field, hair_field, total_length: float) -> float:
        """KDM: set ``scale`` = 1 / Phi_bar, Phi_bar = (total guide length / cell diagonal) / (admissible cells:
        inside S_H and outside the head, counted on every second node). Returns Phi_bar."""
        from headsim.hair.reconstruct._kernels import field_distance

        if self.mode != 2:
            return 1.0
        nx, ny, nz = self.values.shape
        g = np.stack(np.meshgrid(np.arange(0, nx, 2), np.arange(0, ny, 2), np.arange(0, nz, 2), indexing="ij"),
                     -1).reshape(-1, 3)
        p = self.origin + self.spacing * g
        ok = (field_distance(hair_field, p) < 0) & (field_distance(head_field, p) > 0)
        cells = max(1.0, 8.0 * ok.sum())
        phi_bar = total_length / (self.spacing * np.sqrt(3.0)) / cells
        self.scale = 1.0 / max(phi_bar, 1e-12)
        return float(phi_bar)

    def add_strand(self, guide: np.ndarray, radius: np.ndarray, fibres: np.ndarray) -> None:
        """Update with a placed strand: guide (n, 3) m and its per-node strand radius (n,) m (BBM), its
        fibres (M, n, 3) m (KDM)."""
        if self.mode == 1:
            _k.bbm_add_polyline(self.values, self.origin, self.spacing, np.ascontiguousarray(guide),
                                np.ascontiguousarray(radius))
        elif self.mode == 2 and len(fibres):
            _k.kdm_add_polylines(self.values, self.origin, self.spacing, np.ascontiguousarray(fibres),
                                 1.0 / len(fibres))


def occupancy_counts(nodes: np.ndarray, fibre_offsets: np.ndarray, cell: float, lower=None) -> np.ndarray:
    """Segments per occupied cell (segment midpoints binned on a grid of side ``cell`` m), as in Fig. 5.6."""
    nodes = np.asarray(nodes, float)
    last = np.zeros(len(nodes), bool)
    last[np.asarray(fibre_offsets)[1:] - 1] = True
    i = np.flatnonzero(~last)
    mid = 0.5 * (nodes[i] + nodes[i + 1])
    lo = mid.min(0) if lower is None else np.asarray(lower, float)
    ijk = np.floor((mid - lo) / cell).astype(np.int64)
    ijk -= ijk.min(axis=0)
    dims = ijk.max(axis=0) + 1
    counts = np.bincount((ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2])
    return counts[counts > 0]


def coefficient_of_variation(counts: np.ndarray) -> float:
    """std / mean of the segments per occupied cell (0 = perfectly homogeneous occupancy)."""
    c = np.asarray(counts, float)
    return float(c.std() / c.mean())
