"""The vectorised kernels agree with the slow references in headsim.mesh._reference."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from headsim.mesh import _reference as ref
from headsim.mesh.quality import tet_dihedral_angles, tet_radius_ratio
from headsim.mesh.tissue import limit_slope, prism_tets


@settings(max_examples=30, deadline=None)
@given(h=arrays(np.float64, 30, elements=st.floats(0.001, 0.02)), slope=st.floats(0.05, 2.0))
def test_limit_slope_matches_relaxation(make_grid, h, slope):
    g = make_grid(5, 4, spacing=0.003)
    e = g.edges
    lengths = np.linalg.norm(g.vertices[e[:, 1]] - g.vertices[e[:, 0]], axis=1)
    got = limit_slope(h, e, lengths, slope)
    np.testing.assert_allclose(got, ref.limit_slope_relaxation(h, e, lengths, slope), rtol=1e-12, atol=1e-15)
    assert np.all(got <= h)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), layers=st.integers(1, 3))
def test_prism_split_matches_loop_for_any_numbering(make_grid, seed, layers):
    g = make_grid(3, 3)
    perm = np.random.default_rng(seed).permutation(g.n_vertices)  # random global numbering
    tri = perm[g.triangles]
    got = prism_tets(tri, g.n_vertices, layers)
    want = ref.prism_tets_loop(tri, g.n_vertices, layers)
    np.testing.assert_array_equal(np.sort(got, axis=1), np.sort(want, axis=1))
    # same orientation: equal as even permutations of each other
    for a, b in zip(got, want):
        p = [list(b).index(x) for x in a]
        inversions = sum(p[i] > p[j] for i in range(4) for j in range(i + 1, 4))
        assert inversions % 2 == 0


@settings(max_examples=20, deadline=None)
@given(pts=arrays(np.float64, (4, 3), elements=st.floats(-1, 1)))
def test_quality_matches_loop(pts):
    t = np.array([[0, 1, 2, 3]])
    vol = np.linalg.det(np.array([pts[1] - pts[0], pts[2] - pts[0], pts[3] - pts[0]])) / 6
    if abs(vol) < 1e-3:
        return
    if vol < 0:
        t = t[:, [1, 0, 2, 3]]
    np.testing.assert_allclose(tet_dihedral_angles(pts, t), ref.dihedral_angles_loop(pts, t), atol=1e-9)
    np.testing.assert_allclose(tet_radius_ratio(pts, t), ref.radius_ratio_loop(pts, t), rtol=1e-9)
