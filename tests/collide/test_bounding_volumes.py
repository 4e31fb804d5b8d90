"""Bounding volumes (Sobottka §7.3.7): one interface, enclosure, exact/conservative overlap tests."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from headsim.collide.bounding_volumes import (
    AABB,
    KDOP,
    OBB,
    Sphere,
    bounding_volume,
    classic_kdop_directions,
    grassmannian_directions,
    kdop_directions,
    min_chordal_angle,
)
from headsim.errors import ParameterError

TYPES = [AABB(), KDOP(14), KDOP(26), KDOP(40), OBB(), Sphere()]


def capsule_surface_points(p1, p2, r, rng, n=400):
    """Points on a capsule's surface (random points on the axis + r × random unit vectors)."""
    t = rng.uniform(size=(n, 1))
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return p1 + t * (p2 - p1) + r * u


def inside(bv_type, row, pts):
    """Point membership (n,) bool of points in one BV row, straight from the definitions."""
    if isinstance(bv_type, KDOP):
        q = pts @ bv_type.directions.T
        m = bv_type.m
        return ((q >= row[:m] - 1e-12) & (q <= row[m:] + 1e-12)).all(1)
    if isinstance(bv_type, Sphere):
        return np.linalg.norm(pts - row[:3], axis=1) <= row[3] + 1e-12
    c, ax, h = OBB.unpack(row)
    return (np.abs((pts - c[0]) @ ax[0].T) <= h[0] + 1e-12).all(1)


def test_classic_direction_sets():
    for k in (6, 14, 18, 26):
        d = classic_kdop_directions(k)
        assert d.shape == (k // 2, 3)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
        assert min_chordal_angle(d) > 0.5
    with pytest.raises(ParameterError):
        classic_kdop_directions(10)


@pytest.mark.parametrize("n_lines, best_angle_deg", [(3, 90.0), (4, 70.528779), (6, 63.434949)])
def test_grassmannian_packings_reach_the_known_optima(n_lines, best_angle_deg):
    """N = 3: orthogonal axes; N = 4: cube diagonals (arccos 1/3); N = 6: icosahedron axes (Conway et al.)."""
    d = grassmannian_directions(n_lines)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.degrees(min_chordal_angle(d)) == pytest.approx(best_angle_deg, abs=0.05)
    assert (np.abs(d) > 1e-6).all()  # no direction on a coordinate axis or plane (thesis §7.4.4)


def test_k_range_and_large_k():
    d = kdop_directions(60)
    assert d.shape == (30, 3)
    # well spread: better than a random set of 30 lines by a wide margin
    rnd = np.random.default_rng(0).normal(size=(30, 3))
    assert min_chordal_angle(d) > 3 * min_chordal_angle(rnd)
    for bad in (4, 7, 202):
        with pytest.raises(ParameterError):
            kdop_directions(bad)
    assert kdop_directions(6, classic=False).shape == (3, 3)


@pytest.mark.parametrize("bv", TYPES, ids=repr)
def test_leaf_encloses_its_capsule_and_merge_encloses_both(bv):
    rng = np.random.default_rng(1)
    p1, p2 = rng.normal(size=(2, 6, 3))
    r = rng.uniform(0.05, 0.3, 6)
    rows = bv.from_capsules(p1, p2, r)
    assert rows.shape == (6, bv.width)
    for i in range(6):
        assert inside(bv, rows[i], capsule_surface_points(p1[i], p2[i], r[i], rng)).all()
    merged = bv.merge(rows[:3], rows[3:])
    for i in range(3):
        pts = np.vstack([capsule_surface_points(p1[j], p2[j], r[j], rng) for j in (i, i + 3)])
        assert inside(bv, merged[i], pts).all()
    if not isinstance(bv, OBB):  # PCA boxes of corners need not contain child boxes exactly by the
        assert bv.contains(merged, rows[:3]).all()  # contains() test when axes differ: checked via points
    assert (bv.volume(merged) >= bv.volume(rows[:3]) * (1 - 1e-9)).all()


@pytest.mark.parametrize("bv", TYPES, ids=repr)
def test_overlap_is_conservative_for_touching_capsules(bv):
    rng = np.random.default_rng(2)
    a1, a2, b1, b2 = rng.uniform(-1, 1, size=(4, 300, 3))
    r = rng.uniform(0.05, 0.4, 300)
    from headsim.collide._reference_fibres import segment_closest_points

    _, _, d2 = segment_closest_points(a1, a2, b1, b2)
    touching = d2 < (2 * r) ** 2
    assert touching.sum() > 20
    ov = bv.overlaps(bv.from_capsules(a1, a2, r), bv.from_capsules(b1, b2, r))
    assert ov[touching].all()


def boxes_intersect_lp(b1, b2):
    """Ground truth: is there a point inside both OBBs? (linear feasibility problem)."""
    rows, rhs = [], []
    for b in (b1, b2):
        c, ax, h = OBB.unpack(b)
        for k in range(3):
            rows += [ax[0, k], -ax[0, k]]
            rhs += [h[0, k] + ax[0, k] @ c[0], h[0, k] - ax[0, k] @ c[0]]
    res = linprog(np.zeros(3), A_ub=np.array(rows), b_ub=np.array(rhs), bounds=[(None, None)] * 3)
    return res.status == 0


def test_obb_separating_axis_test_is_exact():
    rng = np.random.default_rng(3)
    bv = OBB()
    agree = 0
    for _ in range(200):
        pts_a = rng.normal(size=(5, 3)) * rng.uniform(0.1, 1, 3) + rng.uniform(-1.5, 1.5, 3)
        pts_b = rng.normal(size=(5, 3)) * rng.uniform(0.1, 1, 3) + rng.uniform(-1.5, 1.5, 3)
        a, b = bv.from_points(pts_a), bv.from_points(pts_b)
        truth = boxes_intersect_lp(a[None], b[None])
        assert bool(bv.overlaps(a, b)[0]) == truth
        agree += truth
    assert 20 < agree < 180  # both outcomes occur


def test_kdop_volume_and_points():
    cube = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    for bv in (AABB(), KDOP(14), KDOP(26)):
        assert bv.volume(bv.from_points(cube))[0] == pytest.approx(1.0)
    # a 14-DOP of a ball of radius 1 around the origin: between the ball and the cube volume
    ball = np.random.default_rng(4).normal(size=(4000, 3))
    ball /= np.linalg.norm(ball, axis=1, keepdims=True)
    v14 = KDOP(14).volume(KDOP(14).from_points(ball))[0]
    assert 4 / 3 * np.pi < v14 < 8.0
    assert Sphere().volume(Sphere().from_points(ball))[0] == pytest.approx(4 / 3 * np.pi, rel=0.05)
    assert OBB().volume(OBB().from_points(cube))[0] == pytest.approx(1.0)


def test_sphere_of_points_is_enclosing_and_nearly_minimal():
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(500, 3)) * [3, 1, 0.5]
    row = Sphere().from_points(pts)
    assert (np.linalg.norm(pts - row[:3], axis=1) <= row[3] * (1 + 1e-12)).all()
    # the minimal ball is at least half the diameter of the set
    diam = max(np.linalg.norm(pts[:, None] - pts[None], axis=2).max(), 1e-12)
    assert 0.5 * diam <= row[3] <= 0.5 * diam * 1.15


def test_factory():
    assert isinstance(bounding_volume("aabb"), AABB)
    assert bounding_volume("kdop", 18).k == 18
    with pytest.raises(ParameterError):
        bounding_volume("cylinder")
