"""Winding number, contains and signed distance against the exact brute-force sums."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from headsim.collide import TriangleBVH
from headsim.collide._reference import (
    contains_bruteforce,
    icosphere,
    random_star_shape,
    signed_distance_bruteforce,
    winding_number_exact,
)


def _query_points(rng, v, n=200):
    lo, hi = v.min(axis=0), v.max(axis=0)
    pad = 0.3 * (hi - lo)
    return rng.uniform(lo - pad, hi + pad, size=(n, 3))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 2))
def test_contains_and_signed_distance_match_bruteforce(seed, subdivisions):
    v, t = random_star_shape(seed, subdivisions)
    rng = np.random.default_rng(seed)
    p = _query_points(rng, v)
    bvh = TriangleBVH(v, t)
    tol = 1e-10 * np.linalg.norm(v.max(axis=0) - v.min(axis=0))
    np.testing.assert_array_equal(bvh.contains(p), contains_bruteforce(p, v, t, tol))
    np.testing.assert_allclose(bvh.signed_distance(p), signed_distance_bruteforce(p, v, t, tol), atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_winding_number_exact_mode_and_fast_mode_accuracy(seed):
    v, t = random_star_shape(seed, 2)
    p = _query_points(np.random.default_rng(seed), v)
    bvh = TriangleBVH(v, t)
    exact = winding_number_exact(p, v, t)
    np.testing.assert_allclose(bvh.winding_number(p, beta=np.inf), exact, atol=1e-11)
    # far field up to the Hessian term (Barill et al. 2018) with beta = 2: ~3e-3 measured on the face
    assert np.abs(bvh.winding_number(p) - exact).max() < 0.02
    # and it tightens fast as beta grows (measured ~ beta^-4)
    assert np.abs(bvh.winding_number(p, beta=6.0) - exact).max() < 1e-3


def test_winding_number_values_inside_outside_and_orientation():
    v, t = icosphere(3)
    bvh = TriangleBVH(v, t)
    w = bvh.winding_number(np.array([[0.0, 0, 0], [0.3, -0.2, 0.1], [2.0, 0, 0], [0, 0, -5.0]]), beta=np.inf)
    np.testing.assert_allclose(w, [1, 1, 0, 0], atol=1e-12)
    flipped = TriangleBVH(v, t[:, ::-1])
    np.testing.assert_allclose(flipped.winding_number(np.zeros((1, 3)), beta=np.inf), [-1.0], atol=1e-12)


def test_points_on_the_surface_are_contained_with_zero_signed_distance():
    v, t = random_star_shape(7, 2)
    bvh = TriangleBVH(v, t)
    rng = np.random.default_rng(3)
    on_faces = np.einsum("mi,mik->mk", rng.dirichlet([1, 1, 1], size=len(t)), v[t])
    edge_mid = 0.5 * (v[t[:, 0]] + v[t[:, 1]])
    for pts in (v, on_faces, edge_mid):
        assert bvh.contains(pts).all()
        assert np.abs(bvh.signed_distance(pts)).max() < 1e-14
    # just off the surface along the outward normal: outside; inward: inside
    n = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert not bvh.contains(on_faces + 1e-6 * n).any()
    assert bvh.contains(on_faces - 1e-6 * n).all()
    sd = bvh.signed_distance(on_faces + 1e-6 * n)
    np.testing.assert_allclose(sd, 1e-6, rtol=1e-6)
