"""Structured tetrahedral sweeps: a triangulated cross-section swept along a closed curve.

A mask cushion is a ring: a 2-D cross-section (radial offset ``r`` × height ``h``) swept along a
closed outline. Sweeping the cross-section's triangles between consecutive outline samples gives
triangular prisms; every prism is split into three tetrahedra by the rule of Dompierre et al.
(1999): each quadrilateral face is cut along the diagonal through its vertex of smallest global
index, so neighbouring prisms always agree on their shared faces (the mesh is conforming for any
numbering). Everything is deterministic and vectorised.

References
----------
Dompierre, J., Labbé, P., Vallet, M.-G., Camarero, R. (1999). How to subdivide pyramids, prisms and
hexahedra into tetrahedra. 8th International Meshing Roundtable, 195–204.
"""

from __future__ import annotations

import numpy as np

from headsim.errors import MeshError
from headsim.mesh.geometry import tet_signed_volumes

#: vertex permutations of a prism (bottom a0 a1 a2, top b0 b1 b2 = 3 4 5) that keep it a prism,
#: indexed by the local vertex that becomes vertex 0 (Dompierre et al. 1999, table 2)
_PRISM_ROTATIONS = np.array([
    [0, 1, 2, 3, 4, 5],
    [1, 2, 0, 4, 5, 3],
    [2, 0, 1, 5, 3, 4],
    [3, 5, 4, 0, 2, 1],
    [4, 3, 5, 1, 0, 2],
    [5, 4, 3, 2, 1, 0],
], dtype=np.int64)


def split_prisms(prisms: np.ndarray, vertices: np.ndarray, orient: bool = True) -> np.ndarray:
    """Split triangular prisms into three tetrahedra each, conformingly and positively oriented.

    Parameters
    ----------
    prisms : (p, 6) int64 global vertex ids: bottom triangle (0, 1, 2), top (3, 4, 5) with vertex
        ``k + 3`` above vertex ``k``.
    vertices : (n, 3) float64, m (only used to orient each tet positively)
    orient : swap two vertices of every negatively oriented tet (False: keep the split's own
        vertex order, whose orientation follows the prism's, to detect folded prisms)

    Returns
    -------
    (3 p, 4) int64 tets. Each quadrilateral face is split along the diagonal through its vertex
    of smallest global id (Dompierre et al. 1999), so shared faces match.
    """
    p = np.asarray(prisms, dtype=np.int64)
    if p.ndim != 2 or p.shape[1] != 6:
        raise MeshError(f"prisms must have shape (p, 6), got {p.shape}")
    # rotate every prism so that its smallest vertex id is local vertex 0
    rot = _PRISM_ROTATIONS[np.argmin(p, axis=1)]
    q = np.take_along_axis(p, rot, axis=1)
    # the quad (1, 2, 5, 4) opposite vertex 0: diagonal 1-5 if min(v1, v5) < min(v2, v4), else 2-4
    diag15 = np.minimum(q[:, 1], q[:, 5]) < np.minimum(q[:, 2], q[:, 4])
    t_a = np.where(diag15[:, None], q[:, [0, 1, 2, 5]], q[:, [0, 1, 2, 4]])
    t_b = np.where(diag15[:, None], q[:, [0, 1, 5, 4]], q[:, [0, 4, 2, 5]])
    t_c = q[:, [0, 4, 5, 3]]
    tets = np.stack([t_a, t_b, t_c], axis=1).reshape(-1, 4)
    if not orient:
        return tets
    vol = tet_signed_volumes(vertices, tets)
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return tets


def resample_closed_curve(points: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points evenly spaced by arc length along a closed polyline, and their unit tangents.

    Parameters
    ----------
    points : (k, 2) or (k, 3) float64 polyline (the closing segment is implied), k ≥ 3
    n : number of output points, ≥ 3

    Returns
    -------
    points (n, d), tangents (n, d) (central differences of the resampled curve)
    """
    pts = np.asarray(points, dtype=np.float64)
    closed = np.vstack([pts, pts[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    target = np.arange(n) * (s[-1] / n)
    out = np.column_stack([np.interp(target, s, closed[:, k]) for k in range(pts.shape[1])])
    tangent = np.roll(out, -1, axis=0) - np.roll(out, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    return out, tangent


def grid_triangles(n_rows: int, n_cols: int) -> np.ndarray:
    """(2 (n_rows-1)(n_cols-1), 3) int64 triangles of a structured node grid (row-major ids).

    Node ``(j, i)`` has id ``j * n_cols + i``. Every quad is split along the same diagonal; the
    triangles are counter-clockwise in (column, row) coordinates.
    """
    j, i = np.meshgrid(np.arange(n_rows - 1), np.arange(n_cols - 1), indexing="ij")
    a = (j * n_cols + i).ravel()
    b, c, d = a + 1, a + n_cols + 1, a + n_cols
    return np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)]).astype(np.int64)


def sweep_ring(section_triangles: np.ndarray, n_section_nodes: int, n_samples: int) -> np.ndarray:
    """(n_samples * m, 6) prisms of a cross-section swept around a closed ring.

    Node ``k`` of the cross-section at sample ``i`` has global id ``i * n_section_nodes + k``; the
    last sample connects back to the first.
    """
    tri = np.asarray(section_triangles, dtype=np.int64)
    i = np.arange(n_samples)[:, None, None]
    bottom = i * n_section_nodes + tri[None]
    top = ((i + 1) % n_samples) * n_section_nodes + tri[None]
    return np.concatenate([bottom, top], axis=2).reshape(-1, 6)
