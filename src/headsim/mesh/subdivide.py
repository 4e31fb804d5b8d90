"""1-to-4 subdivision of triangle meshes: midpoint (linear) and Loop (smooth).

Both split every triangle (a, b, c) into four by inserting one vertex per edge; vertex ids
``0..n-1`` keep their meaning (the old vertices) and the edge vertices follow, numbered in the order
of :func:`headsim.mesh.geometry.unique_edges`. Winding is preserved.

The new positions are a sparse linear map of the old ones, ``V' = S V`` with ``S`` of shape
(n + e, n) (:func:`loop_subdivision_matrix`, :func:`midpoint_subdivision_matrix`); the same map
carries any per-vertex field (thickness, labels by rounding, ...).

References
----------
C. Loop, "Smooth subdivision surfaces based on triangles", MSc thesis, Univ. of Utah, 1987
(interior weights, beta = (5/8 - (3/8 + cos(2 pi / k) / 4)^2) / k); boundary rules of
Hoppe et al., "Piecewise smooth surface reconstruction", SIGGRAPH 1994 (boundary edges are
cubic B-spline curves: new edge point (a + b) / 2, moved boundary vertex 3/4 v + 1/8 (v_prev + v_next)).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from headsim.errors import MeshError
from headsim.mesh.geometry import unique_edges
from headsim.mesh.surface import SurfaceMesh


def _topology(mesh: SurfaceMesh):
    """edges (e, 2), face count (e,), per-face edge ids (m, 3) for edges ab, bc, ca, new triangles."""
    n = mesh.n_vertices
    t = mesh.triangles
    edges, counts = unique_edges(t)
    if (counts > 2).any():
        raise MeshError(f"{mesh.name}: cannot subdivide a mesh with {int((counts > 2).sum())} non-manifold edges")
    codes = edges[:, 0] * n + edges[:, 1]
    def edge_id(a, b):
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        return np.searchsorted(codes, lo * n + hi)
    e_ab = edge_id(t[:, 0], t[:, 1])
    e_bc = edge_id(t[:, 1], t[:, 2])
    e_ca = edge_id(t[:, 2], t[:, 0])
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    mab, mbc, mca = n + e_ab, n + e_bc, n + e_ca
    new_t = np.concatenate([
        np.stack([a, mab, mca], axis=1),
        np.stack([mab, b, mbc], axis=1),
        np.stack([mca, mbc, c], axis=1),
        np.stack([mab, mbc, mca], axis=1),
    ])
    return edges, counts, np.stack([e_ab, e_bc, e_ca], axis=1), new_t


def midpoint_subdivision_matrix(mesh: SurfaceMesh) -> tuple[sp.csr_matrix, np.ndarray]:
    """(n + e, n) CSR map of linear 1-to-4 subdivision, and the new (4m, 3) triangles."""
    n = mesh.n_vertices
    edges, _, _, new_t = _topology(mesh)
    e = len(edges)
    rows = np.concatenate([np.arange(n), n + np.arange(e), n + np.arange(e)])
    cols = np.concatenate([np.arange(n), edges[:, 0], edges[:, 1]])
    data = np.concatenate([np.ones(n), np.full(2 * e, 0.5)])
    return sp.csr_matrix((data, (rows, cols)), shape=(n + e, n)), new_t


def loop_subdivision_matrix(mesh: SurfaceMesh) -> tuple[sp.csr_matrix, np.ndarray]:
    """(n + e, n) CSR map of one Loop subdivision step, and the new (4m, 3) triangles.

    Interior edge point: 3/8 (a + b) + 1/8 (c + d) (c, d opposite vertices); boundary edge point:
    (a + b) / 2. Interior vertex of valence k: (1 - k beta) v + beta sum(neighbours) (Loop 1987).
    Boundary vertex: 3/4 v + 1/8 (its two boundary neighbours); a boundary vertex with other than two
    boundary neighbours (where boundary loops touch) stays where it is.
    """
    n = mesh.n_vertices
    t = mesh.triangles
    edges, counts, tri_edges, new_t = _topology(mesh)
    e = len(edges)
    boundary_edge = counts == 1

    # odd (edge) rows: every half-edge contributes; interior edges have two half-edges
    he = tri_edges.T.ravel()                       # edge id of half-edges ab, bc, ca (3m,)
    tt = t.T                                       # rows: a, b, c
    ha = np.concatenate([t[:, 0], t[:, 1], t[:, 2]])
    hb = np.concatenate([t[:, 1], t[:, 2], t[:, 0]])
    hc = np.concatenate([t[:, 2], t[:, 0], t[:, 1]])  # opposite vertex
    del tt
    bnd = boundary_edge[he]
    w_end = np.where(bnd, 0.5, 3.0 / 16.0)
    w_opp = np.where(bnd, 0.0, 1.0 / 8.0)
    odd_rows = np.concatenate([he, he, he])
    odd_cols = np.concatenate([ha, hb, hc])
    odd_data = np.concatenate([w_end, w_end, w_opp])

    # even (vertex) rows
    adj = sp.coo_matrix((np.ones(2 * e), (np.concatenate([edges[:, 0], edges[:, 1]]),
                                          np.concatenate([edges[:, 1], edges[:, 0]]))), shape=(n, n)).tocsr()
    valence = np.asarray(adj.sum(axis=1)).ravel()
    be = edges[boundary_edge]
    bvalence = np.bincount(be.ravel(), minlength=n)
    on_boundary = bvalence > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.maximum(valence, 1)
        beta = (5.0 / 8.0 - (3.0 / 8.0 + 0.25 * np.cos(2.0 * np.pi / k)) ** 2) / k
    beta = np.where(on_boundary | (valence == 0), 0.0, beta)
    adj_coo = adj.tocoo()
    rows = [np.arange(n), adj_coo.row]
    cols = [np.arange(n), adj_coo.col]
    diag = np.where(on_boundary, np.where(bvalence == 2, 0.75, 1.0), 1.0 - valence * beta)
    data = [diag, beta[adj_coo.row]]
    regular_boundary = bvalence == 2
    bi = np.concatenate([be[:, 0], be[:, 1]])
    bj = np.concatenate([be[:, 1], be[:, 0]])
    keep = regular_boundary[bi]
    rows.append(bi[keep])
    cols.append(bj[keep])
    data.append(np.full(int(keep.sum()), 0.125))

    rows = np.concatenate(rows + [n + odd_rows])
    cols = np.concatenate(cols + [odd_cols])
    data = np.concatenate(data + [odd_data])
    s = sp.csr_matrix((data, (rows, cols)), shape=(n + e, n))
    s.sum_duplicates()
    return s, new_t


def subdivide_midpoint(mesh: SurfaceMesh, iterations: int = 1) -> SurfaceMesh:
    """Linear 1-to-4 subdivision: old vertices keep ids and positions, edge midpoints follow.

    The surface is unchanged as a point set (area and volume are preserved exactly).
    """
    for _ in range(int(iterations)):
        s, tri = midpoint_subdivision_matrix(mesh)
        mesh = SurfaceMesh(s @ mesh.vertices, tri, name=mesh.name)
    return mesh


def subdivide_loop(mesh: SurfaceMesh, iterations: int = 1) -> SurfaceMesh:
    """Loop subdivision (1-to-4, smoothing; boundaries follow cubic B-spline curves).

    Old vertices keep their ids but move; vertices ``n..n+e-1`` are the edge points.
    """
    for _ in range(int(iterations)):
        s, tri = loop_subdivision_matrix(mesh)
        mesh = SurfaceMesh(s @ mesh.vertices, tri, name=mesh.name)
    return mesh
