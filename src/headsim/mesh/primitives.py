"""Closed primitive surfaces with outward normals: icosphere and box (metres)."""

from __future__ import annotations

import numpy as np

from headsim.errors import ParameterError
from headsim.mesh.subdivide import subdivide_midpoint
from headsim.mesh.surface import SurfaceMesh


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    p = (1.0 + 5.0**0.5) / 2.0
    v = np.array([
        [-1, p, 0], [1, p, 0], [-1, -p, 0], [1, -p, 0],
        [0, -1, p], [0, 1, p], [0, -1, -p], [0, 1, -p],
        [p, 0, -1], [p, 0, 1], [-p, 0, -1], [-p, 0, 1],
    ], dtype=np.float64)
    f = np.array([
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ], dtype=np.int64)
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


def icosphere(radius: float = 1.0, subdivisions: int = 2, center=(0.0, 0.0, 0.0)) -> SurfaceMesh:
    """Sphere of ``radius`` (m) from an icosahedron split ``subdivisions`` times (1-to-4 midpoint,
    projected onto the sphere): 10 * 4^s + 2 vertices, 20 * 4^s triangles, outward normals.
    """
    if not radius > 0 or not np.isfinite(radius):
        raise ParameterError(f"icosphere radius must be positive, got {radius}")
    if int(subdivisions) < 0:
        raise ParameterError(f"subdivisions must be >= 0, got {subdivisions}")
    v, f = _icosahedron()
    mesh = SurfaceMesh(v, f, name="icosphere")
    for _ in range(int(subdivisions)):
        mesh = subdivide_midpoint(mesh)
        u = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
        mesh = mesh.with_vertices(u)
    return SurfaceMesh(mesh.vertices * radius + np.asarray(center, dtype=np.float64), mesh.triangles,
                       name=f"icosphere(r={radius:g}, s={int(subdivisions)})")


def box(size=(1.0, 1.0, 1.0), divisions=1, center=(0.0, 0.0, 0.0)) -> SurfaceMesh:
    """Closed axis-aligned box surface, sides ``size`` (m), each side split into a grid of
    ``divisions`` (int, or (nx, ny, nz)) squares per axis, two triangles per square, outward normals.
    """
    size = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
    div = np.broadcast_to(np.asarray(divisions, dtype=np.int64), (3,))
    if not (size > 0).all() or not np.isfinite(size).all():
        raise ParameterError(f"box size must be positive, got {size.tolist()}")
    if not (div >= 1).all():
        raise ParameterError(f"box divisions must be >= 1, got {div.tolist()}")
    nx, ny, nz = (int(d) for d in div)
    # lattice points on the surface get ids
    idx = -np.ones((nx + 1, ny + 1, nz + 1), dtype=np.int64)
    grid = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij"), axis=-1)
    on = ((grid == 0) | (grid == div)).any(axis=-1)
    idx[on] = np.arange(int(on.sum()))
    pts = grid[on] / div * size - size / 2 + np.asarray(center, dtype=np.float64)

    tris = []
    for axis in range(3):
        u_ax, v_ax = [a for a in range(3) if a != axis]
        nu, nv = div[u_ax], div[v_ax]
        iu, iv = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        iu, iv = iu.ravel(), iv.ravel()
        for side, sign in ((0, -1.0), (div[axis], 1.0)):
            def vid(du, dv):
                ijk = [None, None, None]
                ijk[axis] = np.full(iu.shape, side)
                ijk[u_ax] = iu + du
                ijk[v_ax] = iv + dv
                return idx[ijk[0], ijk[1], ijk[2]]
            a, b, c, d = vid(0, 0), vid(1, 0), vid(1, 1), vid(0, 1)
            # (u, v, axis) is right-handed when (u_ax, v_ax, axis) is a cyclic permutation of (0, 1, 2)
            right_handed = (u_ax, v_ax, axis) in ((0, 1, 2), (1, 2, 0), (2, 0, 1))
            ccw = right_handed == (sign > 0)
            if ccw:
                tris.append(np.stack([a, b, c], axis=1))
                tris.append(np.stack([a, c, d], axis=1))
            else:
                tris.append(np.stack([a, c, b], axis=1))
                tris.append(np.stack([a, d, c], axis=1))
    return SurfaceMesh(pts, np.concatenate(tris), name=f"box({size[0]:g}x{size[1]:g}x{size[2]:g})")
