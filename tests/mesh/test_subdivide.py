"""Midpoint and Loop 1-to-4 subdivision."""

from __future__ import annotations

import numpy as np
import pytest

from headsim.errors import MeshError
from headsim.mesh import SurfaceMesh
from headsim.mesh.primitives import box, icosphere
from headsim.mesh.subdivide import (
    loop_subdivision_matrix,
    midpoint_subdivision_matrix,
    subdivide_loop,
    subdivide_midpoint,
)


@pytest.mark.parametrize("subdivide", [subdivide_midpoint, subdivide_loop])
@pytest.mark.parametrize("mesh_name", ["sphere", "box", "grid"])
def test_counts_and_validity(subdivide, mesh_name, make_grid):
    from headsim.mesh.validate import check_surface

    mesh = {"sphere": icosphere(1.0, 1), "box": box((1, 2, 3), 2), "grid": make_grid(4, 3)}[mesh_name]
    out = subdivide(mesh)
    assert out.n_vertices == mesh.n_vertices + len(mesh.edges)
    assert out.n_triangles == 4 * mesh.n_triangles
    assert check_surface(out).ok
    assert out.is_closed == mesh.is_closed
    assert len(out.boundary_loops) == len(mesh.boundary_loops)


@pytest.mark.parametrize("matrix", [midpoint_subdivision_matrix, loop_subdivision_matrix])
def test_affine_invariance_rows_sum_to_one(matrix, make_grid):
    for mesh in (icosphere(1.0, 1), make_grid(3, 3)):
        s, _ = matrix(mesh)
        np.testing.assert_allclose(np.asarray(s.sum(axis=1)).ravel(), 1.0, atol=1e-14)


def test_midpoint_keeps_positions_area_and_volume():
    mesh = box((0.1, 0.2, 0.3), 2)
    out = subdivide_midpoint(mesh, iterations=2)
    np.testing.assert_array_equal(out.vertices[: mesh.n_vertices], mesh.vertices)
    assert out.area == pytest.approx(mesh.area, rel=1e-13)
    assert out.signed_volume() == pytest.approx(mesh.signed_volume(), rel=1e-13)
    e = mesh.edges
    np.testing.assert_allclose(out.vertices[mesh.n_vertices: mesh.n_vertices + len(e)],
                               0.5 * (mesh.vertices[e[:, 0]] + mesh.vertices[e[:, 1]]))


def _loop_limit(mesh: SurfaceMesh) -> np.ndarray:
    """Limit positions of the (interior) vertices of a closed mesh under Loop subdivision:
    (1 - k chi) v + chi sum(neighbours), chi = 1 / (3 / (8 beta) + k) (Loop 1987, §3)."""
    adj = mesh.adjacency
    k = np.asarray(adj.sum(axis=1)).ravel()
    beta = (5 / 8 - (3 / 8 + np.cos(2 * np.pi / k) / 4) ** 2) / k
    chi = 1.0 / (3.0 / (8.0 * beta) + k)
    return (1 - k * chi)[:, None] * mesh.vertices + chi[:, None] * (adj @ mesh.vertices)


def test_loop_converges_to_its_limit_surface():
    base = icosphere(1.0, 1)
    limit = _loop_limit(base)
    errors = []
    mesh = base
    for _ in range(5):
        mesh = subdivide_loop(mesh)
        errors.append(np.abs(mesh.vertices[: base.n_vertices] - limit).max())
    errors = np.array(errors)
    # the subdominant eigenvalues of the Loop stencil are <= 1/2 for valences 5 and 6 (Loop 1987)
    assert np.all(errors[1:] / errors[:-1] < 0.56)
    assert errors[-1] < 1e-3


def test_loop_on_closed_sphere_converges():
    mesh = icosphere(1.0, 1)
    volumes, spreads = [], []
    for _ in range(4):
        mesh = subdivide_loop(mesh)
        r = np.linalg.norm(mesh.vertices, axis=1)
        volumes.append(mesh.signed_volume())
        spreads.append((r.max() - r.min()) / r.mean())
    d = np.abs(np.diff(volumes))
    assert np.all(d[1:] / d[:-1] < 0.3)        # volume converges (O(h^2): ratio about 1/4)
    # the radius spread converges to that of the limit surface (not a sphere: about 1.3 % here)
    ds = np.abs(np.diff(spreads))
    assert np.all(ds[1:] / ds[:-1] < 0.5)
    assert spreads[-1] < 0.02
    assert volumes[-1] < icosphere(1.0, 1).signed_volume()  # Loop is approximating: it shrinks convex shapes


def test_loop_keeps_a_plane_flat_and_its_straight_boundary_straight(make_grid):
    g = make_grid(5, 4, spacing=0.01)
    out = subdivide_loop(g, iterations=2)
    np.testing.assert_allclose(out.vertices[:, 2], 0.0, atol=1e-15)
    lo, hi = g.bounds
    np.testing.assert_allclose(out.bounds, g.bounds, atol=1e-15)  # boundary corners stay, sides stay straight
    on_side = np.isclose(out.vertices[:, 0], lo[0]) | np.isclose(out.vertices[:, 0], hi[0]) | \
        np.isclose(out.vertices[:, 1], lo[1]) | np.isclose(out.vertices[:, 1], hi[1])
    loop = out.boundary_loops[0]
    corners = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    far = np.min(np.linalg.norm(out.vertices[loop, None, :2] - corners[None], axis=2), axis=1) > 0.011
    assert far.sum() > 20 and on_side[loop[far]].all()  # untagged corners are rounded (Hoppe 1994), sides not


def test_loop_boundary_rule_is_cubic_bspline():
    # a single triangle: every vertex and edge is on the boundary
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    out = subdivide_loop(SurfaceMesh(v, [[0, 1, 2]]))
    np.testing.assert_allclose(out.vertices[0], 0.75 * v[0] + 0.125 * (v[1] + v[2]))
    mids = out.vertices[3:]
    assert {tuple(np.round(m, 12)) for m in mids} == {(0.5, 0, 0), (0, 0.5, 0), (0.5, 0.5, 0)}


def test_non_manifold_is_refused():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1.0]])
    mesh = SurfaceMesh(v, [[0, 1, 2], [1, 0, 3], [0, 1, 4]], name="fin")
    with pytest.raises(MeshError, match="fin: cannot subdivide a mesh with 1 non-manifold edges"):
        subdivide_loop(mesh)
