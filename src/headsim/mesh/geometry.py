"""Array geometry of triangle and tetrahedron meshes (vectorised NumPy, SI units).

Every function takes plain arrays: ``vertices`` (n, 3) float64 in metres, ``triangles`` (m, 3) or
``tets`` (m, 4) integer indices. Nothing here validates; :class:`headsim.mesh.SurfaceMesh` and
:class:`headsim.mesh.TetMesh` validate once when built.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def triangle_cross(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m, 3) float64, m^2: (b - a) x (c - a) per triangle (twice the area, along the normal)."""
    a = vertices[triangles[:, 0]]
    return np.cross(vertices[triangles[:, 1]] - a, vertices[triangles[:, 2]] - a)


def triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m,) float64, m^2."""
    return 0.5 * np.linalg.norm(triangle_cross(vertices, triangles), axis=1)


def face_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m, 3) float64 unit normals by the right-hand rule; zero rows for degenerate triangles."""
    c = triangle_cross(vertices, triangles)
    norm = np.linalg.norm(c, axis=1, keepdims=True)
    return np.divide(c, norm, out=np.zeros_like(c), where=norm > 0)


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n, 3) float64 unit vertex normals, area weighted (sum of unnormalised face normals)."""
    c = triangle_cross(vertices, triangles)
    acc = np.zeros((len(vertices), 3))
    for k in range(3):
        np.add.at(acc, triangles[:, k], c)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.divide(acc, norm, out=np.zeros_like(acc), where=norm > 0)


def vertex_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n,) float64, m^2: one third of the area of every triangle at the vertex (barycentric lumping)."""
    area3 = triangle_areas(vertices, triangles) / 3.0
    out = np.zeros(len(vertices))
    for k in range(3):
        np.add.at(out, triangles[:, k], area3)
    return out


def signed_volume(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Signed enclosed volume, m^3, by the divergence theorem: sum a . (b x c) / 6.

    Positive for a closed surface whose normals point outwards. For an open surface the value
    depends on the origin.
    """
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def unique_edges(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected edges of a triangle mesh.

    Returns
    -------
    edges : (e, 2) int64, sorted pairs (i < j), lexicographically ordered
    face_count : (e,) int64, number of triangles using each edge (1 boundary, 2 manifold interior)
    """
    tri = np.asarray(triangles, dtype=np.int64)
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    e.sort(axis=1)
    base = int(tri.max()) + 1 if tri.size else 1
    codes, counts = np.unique(e[:, 0] * base + e[:, 1], return_counts=True)  # 1-D keys: much faster
    edges = np.stack([codes // base, codes % base], axis=1)
    return edges, counts


def boundary_edges_directed(triangles: np.ndarray) -> np.ndarray:
    """(b, 2) int64 directed boundary half-edges (as they run in their one triangle)."""
    tri = np.asarray(triangles, dtype=np.int64)
    half = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = np.sort(half, axis=1)
    base = int(tri.max()) + 1 if tri.size else 1
    _, inverse, counts = np.unique(key[:, 0] * base + key[:, 1], return_inverse=True, return_counts=True)
    return half[counts[inverse.ravel()] == 1]


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """Closed boundary loops, each an (k,) int64 array of vertex ids in half-edge order.

    Longest loop first. A vertex where two loops touch (a non-manifold boundary vertex) is followed
    along the first unused outgoing half-edge.
    """
    half = boundary_edges_directed(triangles)
    if len(half) == 0:
        return []
    outgoing: dict[int, list[int]] = {}
    for a, b in half.tolist():
        outgoing.setdefault(a, []).append(b)
    loops = []
    while outgoing:
        start = next(iter(outgoing))
        loop = [start]
        cur = start
        while True:
            nxt_list = outgoing.get(cur)
            if not nxt_list:
                break
            nxt = nxt_list.pop()
            if not nxt_list:
                del outgoing[cur]
            if nxt == start:
                break
            loop.append(nxt)
            cur = nxt
        loops.append(np.asarray(loop, dtype=np.int64))
    loops.sort(key=len, reverse=True)
    return loops


def vertex_adjacency(n_vertices: int, edges: np.ndarray) -> sp.csr_matrix:
    """(n, n) symmetric CSR adjacency (1 where an edge joins two vertices)."""
    e = np.asarray(edges, dtype=np.int64)
    data = np.ones(2 * len(e))
    rows = np.concatenate([e[:, 0], e[:, 1]])
    cols = np.concatenate([e[:, 1], e[:, 0]])
    adj = sp.csr_matrix((data, (rows, cols)), shape=(n_vertices, n_vertices))
    adj.data[:] = 1.0
    return adj


def vertex_components(n_vertices: int, triangles: np.ndarray) -> np.ndarray:
    """(n,) int64 label of the connected component (through the triangles' edges) of every vertex;
    a vertex without a triangle is a component of its own. Labels are numbered in order of their
    lowest vertex."""
    from scipy.sparse.csgraph import connected_components

    edges = unique_edges(triangles)[0] if len(triangles) else np.zeros((0, 2), np.int64)
    return connected_components(vertex_adjacency(n_vertices, edges), directed=False)[1].astype(np.int64)


def tet_signed_volumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(m,) float64, m^3: det[b-a, c-a, d-a] / 6 (positive for positively oriented tets)."""
    a = vertices[tets[:, 0]]
    return np.einsum(
        "ij,ij->i", np.cross(vertices[tets[:, 1]] - a, vertices[tets[:, 2]] - a), vertices[tets[:, 3]] - a
    ) / 6.0


def edge_pseudo_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m, 3, 3) float64 unit pseudo-normals of every triangle's edges (edge k joins corners k and k + 1):
    the sum of the unit normals of the triangles sharing the edge (Bærentzen & Aanæs 2005); a boundary
    edge of an open mesh gets its one triangle's normal."""
    fn = face_normals(vertices, triangles)
    a = triangles
    b = np.roll(triangles, -1, axis=1)
    key = np.sort(np.stack([a, b], -1).reshape(-1, 2), axis=1)  # (3m, 2): edge k of triangle i at 3i + k
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    acc = np.zeros((inv.max() + 1, 3))
    np.add.at(acc, inv, np.repeat(fn, 3, axis=0))
    out = acc[inv]
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0).reshape(-1, 3, 3)
