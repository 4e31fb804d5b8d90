"""Refit after deformation gives the same answers as a fresh build (and as brute force)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from headsim.collide import TriangleBVH
from headsim.collide._reference import closest_points_bruteforce, intersect_rays_bruteforce, random_star_shape


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.01, 0.3, 2.0]))
def test_refit_after_random_deformation_equals_rebuild(seed, amplitude):
    v0, t = random_star_shape(seed, 2)
    rng = np.random.default_rng(seed)
    v1 = v0 + amplitude * rng.normal(size=v0.shape)  # large amplitudes scramble the mesh entirely
    refitted = TriangleBVH(v0, t).refit(v1)
    rebuilt = TriangleBVH(v1, t)
    p = rng.uniform(-3, 3, (150, 3))
    d = rng.normal(size=(150, 3))
    a, b = refitted.closest_points(p), rebuilt.closest_points(p)
    np.testing.assert_allclose(a.distance, b.distance, atol=1e-12)
    np.testing.assert_allclose(a.distance, closest_points_bruteforce(p, v1, t).distance, atol=1e-12)
    ra, rb = refitted.intersect_rays(p, d), rebuilt.intersect_rays(p, d)
    np.testing.assert_array_equal(ra.hit, rb.hit)
    np.testing.assert_allclose(ra.distance[ra.hit], rb.distance[rb.hit], rtol=1e-12)
    want = intersect_rays_bruteforce(p, d, v1, t)
    np.testing.assert_array_equal(ra.hit, want.hit)
    np.testing.assert_allclose(refitted.winding_number(p, beta=np.inf), rebuilt.winding_number(p, beta=np.inf),
                               atol=1e-11)
    # the far-field data are refreshed too: the fast winding numbers agree
    np.testing.assert_allclose(refitted.winding_number(p), TriangleBVH(v1, t).winding_number(p), atol=0.02)
    assert np.array_equal(refitted.vertices, v1)


def test_refit_keeps_the_input_untouched_and_copies_it():
    v0, t = random_star_shape(1, 1)
    v1 = v0 * 1.5
    keep = v1.copy()
    bvh = TriangleBVH(v0, t).refit(v1)
    v1[:] = 0.0  # the caller reuses its buffer
    np.testing.assert_array_equal(bvh.vertices, keep)
    assert not bvh.vertices.flags.writeable


def test_parallel_path_equals_the_single_thread_path():
    # >= 2048 queries run in parallel chunks, fewer on one thread: the answers must be identical
    v, t = random_star_shape(3, 2)
    rng = np.random.default_rng(4)
    p = rng.uniform(-2, 2, (3000, 3))
    d = rng.normal(size=(3000, 3))
    bvh = TriangleBVH(v, t)
    big = (bvh.closest_points(p), bvh.intersect_rays(p, d), bvh.winding_number(p))
    parts = [(bvh.closest_points(p[s]), bvh.intersect_rays(p[s], d[s]), bvh.winding_number(p[s]))
             for s in (slice(0, 1000), slice(1000, 2000), slice(2000, 3000))]
    np.testing.assert_array_equal(big[0].distance, np.concatenate([x[0].distance for x in parts]))
    np.testing.assert_array_equal(big[0].triangle, np.concatenate([x[0].triangle for x in parts]))
    np.testing.assert_array_equal(big[1].distance, np.concatenate([x[1].distance for x in parts]))
    np.testing.assert_array_equal(big[1].triangle, np.concatenate([x[1].triangle for x in parts]))
    np.testing.assert_array_equal(big[2], np.concatenate([x[2] for x in parts]))
    allh = bvh.intersect_rays_all(p, d)
    np.testing.assert_array_equal(allh.count, np.concatenate([bvh.intersect_rays_all(p[s], d[s]).count for s in
                                                             (slice(0, 1000), slice(1000, 2000), slice(2000, 3000))]))
