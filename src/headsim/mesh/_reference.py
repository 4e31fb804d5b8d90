"""Slow, obvious reference implementations of the vectorised mesh algorithms (tests only)."""

from __future__ import annotations

import itertools
import math

import numpy as np


def limit_slope_relaxation(h: np.ndarray, edges: np.ndarray, lengths: np.ndarray, slope: float) -> np.ndarray:
    """Bellman–Ford relaxation of h_i <= h_j + slope * l_ij over every edge until nothing changes."""
    h = np.array(h, dtype=np.float64)
    changed = True
    while changed:
        changed = False
        for (i, j), length in zip(edges.tolist(), lengths.tolist()):
            for a, b in ((i, j), (j, i)):
                if h[b] + slope * length < h[a]:
                    h[a] = h[b] + slope * length
                    changed = True
    return h


def prism_tets_loop(triangles: np.ndarray, n_vertices: int, layers: int) -> np.ndarray:
    """Prism split one prism at a time: diagonal of each quad from its smallest id, orientation by
    the sign of the determinant of an ideal straight prism (top at z = 1, bottom at z = 0)."""
    out = []
    for j in range(layers):
        for tri in np.asarray(triangles).tolist():
            p, q, r = sorted(tri)
            top = [v + j * n_vertices for v in (p, q, r)]
            bot = [v + n_vertices for v in top]
            tets = [[top[0], top[1], top[2], bot[2]], [top[0], bot[1], top[1], bot[2]],
                    [top[0], bot[0], bot[1], bot[2]]]
            # orientation: place the triangle counter-clockwise in the plane, top layer above
            pos = {tri[0]: (0.0, 0.0), tri[1]: (1.0, 0.0), tri[2]: (0.0, 1.0)}
            def coord(v):
                layer, i = divmod(v, n_vertices)
                x, y = pos[i]
                return np.array([x, y, -float(layer - j)])
            fixed = []
            for t in tets:
                a, b, c, d = (coord(v) for v in t)
                if np.dot(np.cross(b - a, c - a), d - a) < 0:
                    t = [t[1], t[0], t[2], t[3]]
                fixed.append(t)
            out.extend(fixed)
    return np.array(out, dtype=np.int64).reshape(-1, 4)


def dihedral_angles_loop(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(m, 6) interior dihedral angles, rad, by the angle between the two faces' in-plane normals
    to the shared edge, one edge at a time (order 01, 02, 03, 12, 13, 23)."""
    out = np.zeros((len(tets), 6))
    for k, t in enumerate(np.asarray(tets).tolist()):
        p = vertices[t]
        for e, (i, j) in enumerate(itertools.combinations(range(4), 2)):
            a, b = (x for x in range(4) if x not in (i, j))
            axis = (p[j] - p[i]) / np.linalg.norm(p[j] - p[i])
            u = p[a] - p[i] - np.dot(p[a] - p[i], axis) * axis
            w = p[b] - p[i] - np.dot(p[b] - p[i], axis) * axis
            c = np.dot(u, w) / (np.linalg.norm(u) * np.linalg.norm(w))
            out[k, e] = math.acos(max(-1.0, min(1.0, c)))
    return out


def radius_ratio_loop(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(m,) 3 r_in / R_circ: circumcentre by solving the 3x3 system, inradius by 3V / area."""
    out = []
    for t in np.asarray(tets).tolist():
        p = vertices[t]
        a = np.array([p[1] - p[0], p[2] - p[0], p[3] - p[0]])
        rhs = 0.5 * np.sum(a * a, axis=1)
        centre = np.linalg.solve(a, rhs)
        r_circ = np.linalg.norm(centre)
        vol = abs(np.linalg.det(a)) / 6
        area = sum(0.5 * np.linalg.norm(np.cross(p[f[1]] - p[f[0]], p[f[2]] - p[f[0]]))
                   for f in itertools.combinations(range(4), 3))
        out.append(3 * (3 * vol / area) / r_circ)
    return np.array(out)
