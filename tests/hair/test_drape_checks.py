"""The ribbon measures (headsim.hair.drape_checks) on recordings whose answers are known by construction:
fibres laid on a sphere of the scene, moved by hand."""

from types import SimpleNamespace

import numpy as np
import pytest

from headsim.hair.drape import build_drape_scene
from headsim.hair.drape_checks import ribbon_measures

R = 0.06
r = 35e-6


def _scene(n_fibres=4):
    return build_drape_scene("sphere-horizontal", "iso", n_fibres=n_fibres, segments=4, sphere_radius=R)


def _on_sphere(z):
    """(5, 3) nodes of a fibre along x over the top of the scene's sphere (centre (0, −R, 0)) at lateral position z:
    every node at distance R + r from the centre (touching), 0.01 rad apart about it, so the chords between them
    sag into the sphere by (R + r)(1 − cos 0.005) < 0.8 µm."""
    s = z / (R + r)
    phi = np.linspace(-0.02, 0.02, 5)
    d = np.stack([np.sqrt(1 - s**2) * np.sin(phi), np.sqrt(1 - s**2) * np.cos(phi), np.full(5, s)], axis=1)
    return np.array([0.0, -R, 0.0]) + (R + r) * d


def _recording(frames, dt=0.02):
    poly = np.asarray(frames, float)  # (K, F, 5, 3)
    return SimpleNamespace(polylines=poly, times=np.arange(len(poly)) * dt)


def test_measures_of_a_hand_made_recording():
    sc = _scene()
    z0 = np.array([-3e-3, -1e-3, 1e-3, 3e-3])
    # frame k: fibre f at z0 · (1 + k) (moving outward on its side), last frame 1 mm lower than the others
    frames = [[_on_sphere(z * (1 + k)) for z in z0] for k in range(4)]
    frames.append([_on_sphere(z * 4) - [0.0, 1e-3, 0.0] for z in z0])
    m = ribbon_measures(sc, _recording(frames))
    assert m.sides_kept()
    np.testing.assert_allclose(m.excursion(), 3 * np.abs(z0))
    np.testing.assert_allclose(m.outermost_distance(), 3e-3 * np.array([1, 2, 3, 4, 4]))
    np.testing.assert_allclose(m.spread(), (6e-3, 24e-3))
    np.testing.assert_allclose(m.sideways(0.04), np.abs(z0))  # frames 2 → 4: 3 z0 → 4 z0
    np.testing.assert_allclose(m.sideways(0.05), 2 * np.abs(z0))  # frames 1 → 4 (the latest 0.05 s before)
    np.testing.assert_allclose(m.sideways(0.02), 0.0, atol=1e-15)  # frames 3 → 4: z unchanged
    assert not m.slid_off().any()
    # the last frame h = 1 mm lower: the middle node, at direction d from the centre, is then
    # √((R + r)² − 2 (R + r) h d_y + h²) − R − r from touching (the chords' sag adds < 0.8 µm)
    h, a = 1e-3, R + r
    dy = np.sqrt(1 - (4 * z0 / a) ** 2)
    np.testing.assert_allclose(m.contact_gap, np.sqrt(a**2 - 2 * a * h * dy + h**2) - a, atol=0.8e-6)
    frames[-1] = [_on_sphere(z * 4) for z in z0]
    gap = ribbon_measures(sc, _recording(frames)).contact_gap  # touching: the chords' sag only
    assert (gap <= 1e-12).all() and (gap > -0.8e-6).all()


def test_crossing_the_midline_and_sliding_below_the_equator_are_seen():
    sc = _scene(2)
    frames = [[_on_sphere(-1e-3), _on_sphere(1e-3)], [_on_sphere(-1e-3), _on_sphere(-0.5e-3)]]
    assert not ribbon_measures(sc, _recording(frames)).sides_kept()
    low = _on_sphere(2e-3) - [0.0, 0.07, 0.0]  # middle node 1 cm below the sphere's centre
    frames = [[_on_sphere(-1e-3), _on_sphere(1e-3)], [_on_sphere(-1e-3), low]]
    assert ribbon_measures(sc, _recording(frames)).slid_off().tolist() == [False, True]
    # below the sphere's centre, or in the air above it, a fibre may swing across the midline: the split is judged
    # on the upper half of the sphere, within the start's distance of its surface
    frames.append([_on_sphere(-1e-3), low * [1, 1, -1]])
    m = ribbon_measures(sc, _recording(frames))
    assert m.sides_kept() and m.middle[-1, 1, 2] < 0
    air = _on_sphere(-0.5e-3) + [0.0, 0.01, 0.0]  # 1 cm above the sphere's top, across the midline
    frames.append([_on_sphere(-1e-3), air])
    assert ribbon_measures(sc, _recording(frames)).sides_kept()
    frames.append([_on_sphere(-1e-3), _on_sphere(-0.5e-3)])  # back on the sphere, on the wrong side
    assert not ribbon_measures(sc, _recording(frames)).sides_kept()
    np.testing.assert_allclose(ribbon_measures(sc, _recording(frames)).surface_gap()[0], 0.0, atol=1e-15)


def test_bad_input_is_refused():
    sc = _scene(2)
    one = _recording([[_on_sphere(-1e-3), _on_sphere(1e-3)]])
    with pytest.raises(ValueError, match="two recorded frames"):
        ribbon_measures(sc, one)
    two = _recording([[_on_sphere(-1e-3), _on_sphere(1e-3)]] * 2)
    with pytest.raises(ValueError, match="less than the window"):
        ribbon_measures(sc, two).sideways(0.05)
    plane = build_drape_scene("plane", "iso", n_fibres=1, segments=30)
    with pytest.raises(ValueError, match="sphere-horizontal"):
        ribbon_measures(plane, two)
