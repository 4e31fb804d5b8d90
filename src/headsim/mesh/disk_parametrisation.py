"""Bijective parametrisation of a disk-like open surface onto the unit disk (Sobottka 2008 §5.3.2).

* :func:`mean_value_weights` — Floater's convex-combination weights (mean-value form, Floater 2003;
  every weight is positive, so with a convex boundary the map is a valid embedding, Tutte/Floater).
* :func:`disk_parametrisation` — boundary loop onto the unit circle by chord length, interior vertices
  as convex combinations of their neighbours: the sparse system W p = u (Sobottka eqs. 5.4-5.5), then
  Yoshizawa et al. (2004) stretch relaxation: w'_ij = w_ij / delta(p_j) with the per-vertex stretch
  of eq. 5.6, re-solved while the total stretch decreases.
* :func:`triangle_stretch` — Sander et al. (2001) L2 stretch delta(tau) = sqrt((Gamma^2 + gamma^2) / 2)
  of the map from the parameter plane to the surface (Gamma, gamma: singular values of its Jacobian);
  :func:`total_stretch` — the area-weighted L2 norm, normalised so that an isometry up to scale gives 1.

Positions in m; parameter coordinates are dimensionless (unit disk).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from headsim.errors import MeshError

__all__ = [
    "DiskParametrisation",
    "mean_value_weights",
    "disk_parametrisation",
    "triangle_stretch",
    "vertex_stretch",
    "total_stretch",
    "signed_areas_2d",
]


@dataclass(frozen=True, eq=False)
class DiskParametrisation:
    """uv (V, 2) positions in the unit disk; boundary (B,) vertex ids on the circle (in loop order);
    stretch_history: total L2 stretch after the Floater solve and after each accepted relaxation pass;
    relaxation_passes: accepted Yoshizawa passes."""

    uv: np.ndarray
    boundary: np.ndarray
    stretch_history: tuple[float, ...]
    relaxation_passes: int


def signed_areas_2d(uv: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(T,) signed areas of the parameter triangles (> 0: same orientation as the surface's boundary loop)."""
    a, b, c = uv[triangles[:, 0]], uv[triangles[:, 1]], uv[triangles[:, 2]]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def mean_value_weights(vertices: np.ndarray, triangles: np.ndarray) -> sp.csr_matrix:
    """Sparse (V, V) matrix of mean-value weights w_ij = (tan(alpha_ij/2) + tan(beta_ij/2)) / |v_j - v_i|,
    where alpha, beta are the angles at v_i of the two triangles sharing edge ij (Floater 2003). Not row-normalised."""
    v = np.asarray(vertices, float)
    t = np.asarray(triangles, np.int64)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, l = t[:, k], t[:, (k + 1) % 3], t[:, (k + 2) % 3]
        e1 = v[j] - v[i]
        e2 = v[l] - v[i]
        n1 = np.linalg.norm(e1, axis=1)
        n2 = np.linalg.norm(e2, axis=1)
        cosang = np.clip((e1 * e2).sum(1) / np.maximum(n1 * n2, 1e-300), -1.0, 1.0)
        half_tan = np.tan(0.5 * np.arccos(cosang))  # the angle at v_i between edges ij and il
        rows += [i, i]
        cols += [j, l]
        vals += [half_tan / np.maximum(n1, 1e-300), half_tan / np.maximum(n2, 1e-300)]
    V = len(v)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(V, V))


def _single_boundary_loop(triangles: np.ndarray, n_vertices: int) -> np.ndarray:
    import igl

    loops = igl.boundary_loop_all(np.ascontiguousarray(triangles, np.int64))
    if len(loops) != 1:
        raise MeshError(f"disk parametrisation needs a surface with exactly one boundary loop, found {len(loops)}")
    loop = np.asarray(loops[0], np.int64)
    used = np.zeros(n_vertices, bool)
    used[triangles.ravel()] = True
    if not used.all():
        raise MeshError(f"{int((~used).sum())} vertices are not used by any triangle")
    return loop


def triangle_stretch(vertices: np.ndarray, triangles: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(T,) L2 stretch delta = sqrt((Gamma^2 + gamma^2) / 2) of each triangle's affine map uv -> 3-D
    (Sander et al. 2001; Sobottka's delta(tau')). Parameter triangles must have non-zero area."""
    q1, q2, q3 = vertices[triangles[:, 0]], vertices[triangles[:, 1]], vertices[triangles[:, 2]]
    s1, s2, s3 = (uv[triangles[:, k], 0] for k in range(3))
    t1, t2, t3 = (uv[triangles[:, k], 1] for k in range(3))
    A = signed_areas_2d(uv, triangles)
    if np.any(np.abs(A) < 1e-300):
        raise MeshError("degenerate parameter triangle")
    Ss = (q1 * (t2 - t3)[:, None] + q2 * (t3 - t1)[:, None] + q3 * (t1 - t2)[:, None]) / (2 * A)[:, None]
    St = (q1 * (s3 - s2)[:, None] + q2 * (s1 - s3)[:, None] + q3 * (s2 - s1)[:, None]) / (2 * A)[:, None]
    return np.sqrt(0.5 * ((Ss * Ss).sum(1) + (St * St).sum(1)))


def vertex_stretch(vertices, triangles, uv) -> np.ndarray:
    """(V,) per-vertex stretch, eq. 5.6: sqrt(sum A(tau) delta(tau)^2 / sum A(tau)) over incident triangles,
    A the surface areas."""
    d = triangle_stretch(vertices, triangles, uv)
    area = 0.5 * np.linalg.norm(np.cross(vertices[triangles[:, 1]] - vertices[triangles[:, 0]],
                                         vertices[triangles[:, 2]] - vertices[triangles[:, 0]]), axis=1)
    num = np.zeros(len(vertices))
    den = np.zeros(len(vertices))
    for k in range(3):
        np.add.at(num, triangles[:, k], area * d**2)
        np.add.at(den, triangles[:, k], area)
    return np.sqrt(num / np.maximum(den, 1e-300))


def total_stretch(vertices, triangles, uv) -> float:
    """Area-weighted L2 stretch of the whole map, scaled by sqrt(A_2D / A_3D) so that 1 is the optimum
    (a map that preserves lengths up to one global scale)."""
    d = triangle_stretch(vertices, triangles, uv)
    a3 = 0.5 * np.linalg.norm(np.cross(vertices[triangles[:, 1]] - vertices[triangles[:, 0]],
                                       vertices[triangles[:, 2]] - vertices[triangles[:, 0]]), axis=1)
    a2 = np.abs(signed_areas_2d(uv, triangles))
    return float(np.sqrt((a3 * d**2).sum() / a3.sum()) * np.sqrt(a2.sum() / a3.sum()))


def _solve(W: sp.csr_matrix, boundary: np.ndarray, boundary_uv: np.ndarray) -> np.ndarray:
    V = W.shape[0]
    interior = np.setdiff1d(np.arange(V), boundary)
    L = sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W  # rows: sum_j w_ij (p_i - p_j) = 0
    L = L.tocsr()
    A = L[interior][:, interior].tocsc()
    b = -L[interior][:, boundary] @ boundary_uv
    uv = np.empty((V, 2))
    uv[boundary] = boundary_uv
    uv[interior] = splu(A).solve(np.ascontiguousarray(b))
    return uv


def disk_parametrisation(vertices, triangles, *, max_relaxation: int = 20, tolerance: float = 1e-4) -> DiskParametrisation:
    """Floater convex-combination map of an open, disk-like triangle mesh onto the unit disk, then
    Yoshizawa stretch relaxation (stops when the total stretch changes by less than ``tolerance``
    relative, or rises: the best map is kept). Raises MeshError for non-disk topology.

    The boundary loop is oriented so that the parameter triangles have positive area.
    """
    v = np.asarray(vertices, float)
    t = np.asarray(triangles, np.int64)
    loop = _single_boundary_loop(t, len(v))
    seg = np.linalg.norm(v[np.roll(loop, -1)] - v[loop], axis=1)
    ang = 2 * np.pi * np.concatenate([[0.0], np.cumsum(seg)[:-1]]) / seg.sum()
    circle = np.column_stack([np.cos(ang), np.sin(ang)])
    W0 = mean_value_weights(v, t)
    uv = _solve(W0, loop, circle)
    if signed_areas_2d(uv, t).sum() < 0:  # loop ran clockwise: mirror
        circle[:, 1] *= -1
        uv[:, 1] *= -1
    history = [total_stretch(v, t, uv)]
    W = W0
    passes = 0
    for _ in range(max_relaxation):
        sig = vertex_stretch(v, t, uv)
        W_new = (W @ sp.diags(1.0 / np.maximum(sig, 1e-300))).tocsr()  # w'_ij = w_ij / delta(p_j)
        uv_new = _solve(W_new, loop, circle)
        s = total_stretch(v, t, uv_new)
        if not s < history[-1]:
            break
        converged = history[-1] - s < tolerance * history[-1]
        W, uv = W_new, uv_new
        history.append(s)
        passes += 1
        if converged:
            break
    return DiskParametrisation(uv, loop, tuple(history), passes)
