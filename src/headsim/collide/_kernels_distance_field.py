"""Numba kernels for grid distance fields: trilinear interpolation, narrow-band node marking.

Grid: node (i, j, k) sits at ``origin + spacing · (i, j, k)``; ``values`` (nx, ny, nz) float64, m.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always")
def trilinear_at(values, origin, spacing, x, y, z, outside):
    """Trilinear interpolation of the 8 cell corners (Sobottka §7.2.1) at one point (x, y, z), m;
    ``outside`` for a point off the grid. Inlined into every kernel that samples a grid field."""
    nx, ny, nz = values.shape
    fx = (x - origin[0]) / spacing
    fy = (y - origin[1]) / spacing
    fz = (z - origin[2]) / spacing
    if not (0.0 <= fx <= nx - 1 and 0.0 <= fy <= ny - 1 and 0.0 <= fz <= nz - 1):
        return outside
    i = min(int(fx), nx - 2)
    j = min(int(fy), ny - 2)
    k = min(int(fz), nz - 2)
    tx, ty, tz = fx - i, fy - j, fz - k
    c00 = values[i, j, k] * (1 - tx) + values[i + 1, j, k] * tx
    c10 = values[i, j + 1, k] * (1 - tx) + values[i + 1, j + 1, k] * tx
    c01 = values[i, j, k + 1] * (1 - tx) + values[i + 1, j, k + 1] * tx
    c11 = values[i, j + 1, k + 1] * (1 - tx) + values[i + 1, j + 1, k + 1] * tx
    c0 = c00 * (1 - ty) + c10 * ty
    c1 = c01 * (1 - ty) + c11 * ty
    return c0 * (1 - tz) + c1 * tz


@njit(cache=True, parallel=True)
def trilinear(values, origin, spacing, points, outside, out):
    """Trilinear interpolation of the 8 cell corners (Sobottka §7.2.1) at ``points`` (n, 3) into ``out`` (n,).

    Points outside the grid get ``outside``.
    """
    for p in prange(points.shape[0]):
        out[p] = trilinear_at(values, origin, spacing, points[p, 0], points[p, 1], points[p, 2], outside)


@njit(cache=True)
def mark_band(vertices, triangles, origin, spacing, band, shape, out):
    """Mark (uint8) every grid node within the integer box of each triangle dilated by ``band``.

    This is the "integer AABB scan" of the characteristics method (Sobottka §7.2.2 step 3); the exact
    distance of the marked nodes is computed afterwards.
    """
    inv = 1.0 / spacing
    for t in range(triangles.shape[0]):
        lo = np.empty(3, np.int64)
        hi = np.empty(3, np.int64)
        for c in range(3):
            a = vertices[triangles[t, 0], c]
            b = vertices[triangles[t, 1], c]
            d = vertices[triangles[t, 2], c]
            mn = min(a, min(b, d)) - band
            mx = max(a, max(b, d)) + band
            lo[c] = max(0, int(np.ceil((mn - origin[c]) * inv)))
            hi[c] = min(shape[c] - 1, int(np.floor((mx - origin[c]) * inv)))
        for i in range(lo[0], hi[0] + 1):
            for j in range(lo[1], hi[1] + 1):
                for k in range(lo[2], hi[2] + 1):
                    out[i, j, k] = 1
