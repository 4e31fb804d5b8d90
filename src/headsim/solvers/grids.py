"""Structured tetrahedral grids (uniform or graded) for validation problems and tests.

Each hexahedral cell is split into 6 positively oriented tets around its main diagonal (Kuhn /
Freudenthal subdivision), so neighbouring cells share faces conformingly.
"""

from __future__ import annotations

import numpy as np

from headsim.errors import ParameterError
from headsim.mesh.tet import TetMesh

# Kuhn subdivision of the unit cube: vertex (i, j, k) bits -> index i + 2 j + 4 k
_KUHN = np.array([[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]])


def graded_coordinates(length: float, first: float, ratio: float, start: float = 0.0) -> np.ndarray:
    """Node coordinates from ``start`` to ``start + length`` with cells growing geometrically.

    first : size of the first cell, m; ratio : growth factor >= 1 (1 = uniform). The last cell is
    stretched or shrunk so the coordinates end exactly at ``start + length``.
    """
    if length <= 0 or first <= 0 or ratio < 1:
        raise ParameterError("need length > 0, first > 0 and ratio >= 1")
    sizes = []
    total = 0.0
    h = first
    while total + h < length * (1 - 1e-9):
        sizes.append(h)
        total += h
        h *= ratio
    if not sizes:
        return np.array([start, start + length])
    if length - total < 0.5 * sizes[-1]:
        sizes[-1] += length - total
    else:
        sizes.append(length - total)
    return start + np.concatenate([[0.0], np.cumsum(sizes)])


def structured_tet_grid(xs: np.ndarray, ys: np.ndarray, zs: np.ndarray, name: str = "grid") -> TetMesh:
    """Tet mesh of the tensor grid xs x ys x zs (node coordinates, m, increasing), 6 tets per cell."""
    xs, ys, zs = (np.asarray(a, dtype=np.float64) for a in (xs, ys, zs))
    for a in (xs, ys, zs):
        if a.ndim != 1 or len(a) < 2 or np.any(np.diff(a) <= 0):
            raise ParameterError("grid coordinates must be increasing with at least 2 nodes per axis")
    nx, ny, nz = len(xs), len(ys), len(zs)
    gx, gy, gz = np.meshgrid(xs, ys, zs, indexing="ij")
    verts = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    ids = np.arange(nx * ny * nz).reshape(nx, ny, nz)
    corners = np.stack([ids[i:nx - 1 + i, j:ny - 1 + j, k:nz - 1 + k].ravel()
                        for k in (0, 1) for j in (0, 1) for i in (0, 1)], axis=1)  # bit order i + 2j + 4k
    tets = corners[:, _KUHN].reshape(-1, 4)
    a = verts[tets[:, 0]]
    vol = np.einsum("ij,ij->i", np.cross(verts[tets[:, 1]] - a, verts[tets[:, 2]] - a), verts[tets[:, 3]] - a)
    flip = vol < 0
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return TetMesh(verts, tets, name=name)


def block_tetmesh(size=(1.0, 1.0, 1.0), divisions=(4, 4, 4), origin=(0.0, 0.0, 0.0), name: str = "block") -> TetMesh:
    """Uniform structured tet block [origin, origin + size], m."""
    axes = [np.linspace(o, o + s, d + 1) for o, s, d in zip(origin, size, divisions)]
    return structured_tet_grid(*axes, name=name)


def ball_tetmesh(radius: float = 1.0, divisions: int = 4, center=(0.0, 0.0, 0.0), name: str = "ball") -> TetMesh:
    """Tet mesh of a ball: a structured cube grid [-1, 1]^3 mapped radially onto the ball.

    A grid point p goes to R p |p|_inf / |p|_2 (concentric cubes become concentric spheres), so the
    mesh is symmetric, has 6 (2 divisions)^3 tets and needs no external mesher. ``divisions`` is the
    number of cells from the centre to the surface (>= 1).
    """
    if divisions < 1 or radius <= 0:
        raise ParameterError("need divisions >= 1 and radius > 0")
    ax = np.linspace(-1.0, 1.0, 2 * divisions + 1)
    cube = structured_tet_grid(ax, ax, ax)
    p = cube.vertices
    n2 = np.linalg.norm(p, axis=1)
    ninf = np.abs(p).max(axis=1)
    scale = np.where(n2 > 0, ninf / np.where(n2 > 0, n2, 1.0), 0.0)
    v = radius * p * scale[:, None] + np.asarray(center, dtype=np.float64)
    return TetMesh(v, cube.tets, name=name)
