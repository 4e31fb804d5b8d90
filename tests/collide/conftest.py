"""Fixtures for the collide tests: the bundled face and its BVH."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.data import face_path


def _load_face():
    """The bundled neutral face (metres): via headsim.mesh.io when present, else trimesh."""
    try:
        from headsim.mesh.io import load_surface
    except ImportError:
        import trimesh

        m = trimesh.load(face_path(), process=False)
        return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)
    mesh = load_surface(face_path())
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


@pytest.fixture(scope="session")
def face():
    return _load_face()


@pytest.fixture(scope="session")
def face_bvh(face):
    from headsim.collide import TriangleBVH

    return TriangleBVH(*face)
