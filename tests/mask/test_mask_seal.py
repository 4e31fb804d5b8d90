"""Seal analysis on synthetic pressure fields on the bundled face."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from headsim.errors import ParameterError, RegionError
from headsim.mask import THERAPY_PRESSURE_PA, airway_vertices, analyse_seal, outer_boundary
from headsim.mask._reference import seal_reference


@pytest.fixture(scope="module")
def setup(neutral_face, neutral_landmarks):
    face, lm = neutral_face, neutral_landmarks
    centre = 0.5 * (lm.nose_tip + lm.subnasale)
    rel = face.vertices - centre
    x, y = rel @ lm.lateral, rel @ lm.up
    r = np.hypot(x, y / 1.3)                       # elliptical annulus around the nose
    angle = np.arctan2(y, x)
    ring = (r > 25e-3) & (r < 32e-3)
    seeds = airway_vertices(face, lm, "nasal")
    return face, lm, ring, angle, seeds, centre


def _angle_of(point, lm, centre):
    rel = point - centre
    return np.degrees(np.arctan2(rel @ lm.up, rel @ lm.lateral))


def test_closed_annulus_seals(setup):
    face, lm, ring, angle, seeds, _ = setup
    res = analyse_seal(face, np.where(ring, 5e3, 0.0), seeds)
    assert res.sealed
    assert res.leak_paths == []
    assert set(res.sealing_vertices) == set(np.flatnonzero(ring))
    assert not np.isin(res.leak_region, outer_boundary(face)).any()


def test_notch_leaks_at_the_notch_with_its_gap(setup):
    face, lm, ring, angle, seeds, centre = setup
    notch = ring & (np.abs(angle - np.deg2rad(-30)) < 0.12)
    pressure = np.where(ring & ~notch, 5e3, 0.0)
    gap = np.full(face.n_vertices, 5e-3)
    gap[ring & ~notch] = 0.0
    gap[notch] = 0.4e-3
    res = analyse_seal(face, pressure, seeds, gap=gap)
    assert not res.sealed
    assert len(res.leak_paths) == 1
    lp = res.leak_paths[0]
    assert notch[lp.crossing_vertex]
    assert _angle_of(lp.crossing_point, lm, centre) == pytest.approx(-30, abs=8)
    assert lp.gap_width == pytest.approx(0.4e-3)
    # the break is about as wide as the notch: 0.24 rad at 25-32 mm (6-10 mm) plus one edge either side
    assert 5e-3 < lp.channel_width < 16e-3
    # the path runs from the airway to the outer boundary through non-sealing vertices
    assert lp.vertices[0] in set(seeds)
    assert lp.vertices[-1] in set(outer_boundary(face))
    assert not (pressure[lp.vertices] > THERAPY_PRESSURE_PA).any()
    np.testing.assert_allclose(lp.positions, face.vertices[lp.vertices])


def test_two_notches_give_two_leak_paths(setup):
    face, lm, ring, angle, seeds, centre = setup
    notches = [ring & (np.abs(angle - np.deg2rad(a)) < 0.12) for a in (-30, 120)]
    pressure = np.where(ring & ~notches[0] & ~notches[1], 5e3, 0.0)
    res = analyse_seal(face, pressure, seeds)
    assert not res.sealed
    found = sorted(_angle_of(lp.crossing_point, lm, centre) for lp in res.leak_paths)
    assert len(found) == 2
    assert found[0] == pytest.approx(-30, abs=8)
    assert found[1] == pytest.approx(120, abs=8)
    assert all(lp.gap_width is None for lp in res.leak_paths)


def test_pressure_below_therapy_leaks(setup):
    face, lm, ring, angle, seeds, _ = setup
    res = analyse_seal(face, np.where(ring, 0.9 * THERAPY_PRESSURE_PA, 0.0), seeds)
    assert not res.sealed
    assert len(res.sealing_vertices) == 0
    assert len(res.leak_paths) == 1
    assert ring[res.leak_paths[0].crossing_vertex]            # highest pressure on the path
    assert res.leak_paths[0].channel_width == np.inf
    # the same field seals when the therapy pressure is lower than the contact pressure
    assert analyse_seal(face, np.where(ring, 0.9 * THERAPY_PRESSURE_PA, 0.0), seeds,
                        therapy_pressure_pa=0.5 * THERAPY_PRESSURE_PA).sealed


def test_bad_input(setup):
    face, lm, ring, angle, seeds, _ = setup
    with pytest.raises(ParameterError):
        analyse_seal(face, np.zeros(3), seeds)
    with pytest.raises(ParameterError):
        analyse_seal(face, -np.ones(face.n_vertices), seeds)
    with pytest.raises(RegionError):
        analyse_seal(face, np.zeros(face.n_vertices), np.array([], dtype=int))
    with pytest.raises(RegionError):
        analyse_seal(face, np.zeros(face.n_vertices), np.array([face.n_vertices]))


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.02, 0.2))
def test_seal_matches_the_reference_search(neutral_face, neutral_landmarks, seed, density):
    """Random blotchy rings (hole share 2–20 %: both sealed and leaking cases): the decision equals a
    pure-Python BFS."""
    face = neutral_face
    rng = np.random.default_rng(seed)
    centre = 0.5 * (neutral_landmarks.nose_tip + neutral_landmarks.subnasale)
    r = np.linalg.norm(face.vertices - centre, axis=1)
    ring = (r > 22e-3) & (r < 30e-3)
    pressure = np.where(ring & (rng.random(face.n_vertices) > density), 2e3, 0.0)
    seeds = airway_vertices(face, neutral_landmarks)
    got = analyse_seal(face, pressure, seeds, max_paths=1).sealed
    want = seal_reference(face.triangles, face.n_vertices, pressure, seeds, outer_boundary(face), THERAPY_PRESSURE_PA)
    assert got == want
