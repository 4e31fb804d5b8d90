"""Slow, obviously-correct references for tests only."""

from __future__ import annotations

from collections import deque

import numpy as np


def seal_reference(triangles: np.ndarray, n_vertices: int, pressure: np.ndarray, seeds: np.ndarray,
                   escape: np.ndarray, therapy_pressure: float) -> bool:
    """True when no escape vertex is reachable from a non-sealing seed through non-sealing vertices
    (pure-Python breadth-first search over the triangle edges)."""
    neighbours: list[set[int]] = [set() for _ in range(n_vertices)]
    for a, b, c in np.asarray(triangles).tolist():
        neighbours[a] |= {b, c}
        neighbours[b] |= {a, c}
        neighbours[c] |= {a, b}
    sealing = [float(x) > therapy_pressure for x in pressure]
    escape_set = set(int(e) for e in escape)
    seen = set()
    queue = deque(int(s) for s in seeds if not sealing[int(s)])
    seen.update(queue)
    while queue:
        i = queue.popleft()
        if i in escape_set:
            return False
        for j in neighbours[i]:
            if j not in seen and not sealing[j]:
                seen.add(j)
                queue.append(j)
    return True


def plane_section_reference(vertices: np.ndarray, triangles: np.ndarray, point: np.ndarray,
                            normal: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Section segments of a mesh by a plane, one triangle at a time (a vertex on the plane counts
    as positive)."""
    out = []
    d = (np.asarray(vertices) - point) @ normal
    for tri in np.asarray(triangles).tolist():
        ends = []
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            if (d[a] >= 0) != (d[b] >= 0):
                w = d[a] / (d[a] - d[b])
                ends.append(vertices[a] + w * (vertices[b] - vertices[a]))
        if len(ends) == 2:
            out.append((ends[0], ends[1]))
    return out
