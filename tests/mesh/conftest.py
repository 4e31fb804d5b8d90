"""Shared small meshes for the mesh tests (handmade, metres)."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.mesh import SurfaceMesh


def grid_surface(nx: int = 6, ny: int = 5, spacing: float = 0.01, name: str = "grid") -> SurfaceMesh:
    """Flat open grid in the z = 0 plane, normals +z, (nx+1)(ny+1) vertices, 2 nx ny triangles."""
    x, y = np.meshgrid(np.arange(nx + 1) * spacing, np.arange(ny + 1) * spacing, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(nx + 1, ny + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return SurfaceMesh(v, tri, name=name)


@pytest.fixture(scope="session")
def make_grid():
    """The :func:`grid_surface` factory."""
    return grid_surface


@pytest.fixture(scope="session")
def bundled_face():
    from headsim.data import face_path
    from headsim.mesh.io import load_surface

    return load_surface(face_path())
