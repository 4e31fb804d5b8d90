"""Icosphere and box: closed, valid, outward, with the right size."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.mesh.primitives import box, icosphere
from headsim.mesh.validate import check_surface


@pytest.mark.parametrize("s", [0, 1, 2, 3])
def test_icosphere(s):
    mesh = icosphere(0.05, s, center=(0.1, 0.2, 0.3))
    assert mesh.n_vertices == 10 * 4**s + 2 and mesh.n_triangles == 20 * 4**s
    assert check_surface(mesh).defects == ()
    r = np.linalg.norm(mesh.vertices - [0.1, 0.2, 0.3], axis=1)
    np.testing.assert_allclose(r, 0.05, rtol=1e-14)
    # outward: every face normal points away from the centre
    c = mesh.vertices[mesh.triangles].mean(axis=1) - [0.1, 0.2, 0.3]
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals, c) > 0)


def test_icosphere_volume_converges_at_second_order():
    exact = 4 / 3 * np.pi
    err = np.array([exact - icosphere(1.0, s).signed_volume() for s in (2, 3, 4)])
    assert np.all(err > 0)                       # inscribed polyhedron
    np.testing.assert_allclose(err[1:] / err[:-1], 0.25, atol=0.02)  # h halves -> error / 4


@pytest.mark.parametrize("divisions", [1, 3, (2, 3, 4)])
def test_box(divisions):
    size = np.array([0.1, 0.2, 0.3])
    mesh = box(size, divisions, center=(1, 2, 3))
    assert check_surface(mesh).defects == ()
    assert mesh.signed_volume() == pytest.approx(np.prod(size), rel=1e-12)
    assert mesh.area == pytest.approx(2 * (0.02 + 0.03 + 0.06), rel=1e-12)
    np.testing.assert_allclose(mesh.bounds, [[0.95, 1.9, 2.85], [1.05, 2.1, 3.15]])
    d = np.broadcast_to(divisions, (3,))
    nx, ny, nz = d
    assert mesh.n_triangles == 4 * (nx * ny + ny * nz + nx * nz)
    c = mesh.vertices[mesh.triangles].mean(axis=1) - [1, 2, 3]
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals, c) > 0)


def test_bad_parameters():
    with pytest.raises(ParameterError):
        icosphere(-1.0)
    with pytest.raises(ParameterError):
        icosphere(1.0, -1)
    with pytest.raises(ParameterError):
        box((1, 0, 1))
    with pytest.raises(ParameterError):
        box(1, 0)
