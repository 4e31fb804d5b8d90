"""Shared fixtures and helpers for the collide tests (small closed meshes, the bundled face)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from headsim.data import face_path


def icosphere(subdivisions: int = 1, radius: float = 1.0):
    """Closed, outward-wound icosphere: vertices (n, 3) float64, triangles (m, 3) int64."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def random_star_shape(seed: int, subdivisions: int = 1):
    """A closed, non-self-intersecting surface: an icosphere with random radii in [0.6, 1.4], rotated
    and shifted at random (star-shaped about its centre, so the winding stays outward)."""
    rng = np.random.default_rng(seed)
    v, t = icosphere(subdivisions)
    v = v * rng.uniform(0.6, 1.4, size=(len(v), 1))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return v @ q.T + rng.uniform(-1, 1, 3), t


def load_face():
    """The bundled neutral face (metres): via headsim.mesh.io when present, else trimesh."""
    try:
        from headsim.mesh.io import load_surface

        mesh = load_surface(face_path())
        return np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    except ImportError:
        m = trimesh.load(face_path(), process=False)
        return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


@pytest.fixture(scope="session")
def face():
    return load_face()


@pytest.fixture(scope="session")
def face_bvh(face):
    from headsim.collide import TriangleBVH

    return TriangleBVH(*face)
