"""Landmarks from geometry: anatomical sanity on all bundled faces, rigid-motion equivariance,
refusal of non-faces."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from headsim.data import population_paths
from headsim.errors import MeshError, UnitsError
from headsim.mask import LANDMARK_NAMES, find_landmarks, plane_section_points
from headsim.mesh.primitives import icosphere

FACE_NAMES = ["neutral", "identity000", "identity001"] + [p.stem.replace("face_", "") for p in population_paths()]


def test_all_fifteen_bundled_faces_are_covered():
    assert len(FACE_NAMES) == 15


@pytest.mark.parametrize("name", FACE_NAMES)
def test_landmarks_are_anatomically_sane(name, bundled_landmarks):
    lm = bundled_landmarks[name]
    up, fwd = lm.up, lm.forward
    # ordering along the up axis
    assert lm.chin @ up < lm.stomion @ up < lm.subnasale @ up < lm.nose_tip @ up < lm.nasion @ up
    # the nose tip is the most anterior of the landmarks
    others = [lm.nasion, lm.subnasale, lm.chin, lm.ala_left, lm.ala_right]
    assert all(lm.nose_tip @ fwd > p @ fwd for p in others)
    # adult sizes (Farkas 1994): al-al 25-45 mm (one bundled random identity has a 45.2 mm nose,
    # so the upper bound allows 46 mm), n-sn 40-65 mm
    assert 25e-3 <= lm.alar_width <= 46e-3
    assert 40e-3 <= lm.nose_height <= 65e-3
    # alae on either side of the midline, at nostril level (between subnasale and tip)
    assert (lm.ala_left - lm.nose_tip) @ lm.lateral > 10e-3
    assert (lm.ala_right - lm.nose_tip) @ lm.lateral < -10e-3
    for ala in (lm.ala_left, lm.ala_right):
        assert lm.subnasale @ up - 2e-3 < ala @ up < lm.nose_tip @ up


@pytest.mark.parametrize("name", FACE_NAMES)
def test_axes_match_the_ict_convention(name, bundled_landmarks):
    """Bundled faces are y up, +z out of the face: the estimates agree within 15 degrees."""
    lm = bundled_landmarks[name]
    assert lm.up @ np.array([0.0, 1.0, 0.0]) > np.cos(np.deg2rad(15))
    assert lm.forward @ np.array([0.0, 0.0, 1.0]) > np.cos(np.deg2rad(15))
    assert abs(lm.lateral @ np.array([1.0, 0.0, 0.0])) > np.cos(np.deg2rad(5))


def test_symmetric_neutral_face_gives_an_exact_midline(neutral_landmarks):
    """The ICT mean face is mirror-symmetric about x = 0."""
    lm = neutral_landmarks
    assert abs(lm.lateral[0]) == pytest.approx(1.0, abs=1e-4)
    for name in ("nose_tip", "nasion", "subnasale", "stomion", "chin"):
        assert abs(getattr(lm, name)[0]) < 1e-3
    assert lm.ala_left[0] == pytest.approx(-lm.ala_right[0], abs=1e-3)


def test_landmarks_move_with_a_rigid_motion(neutral_face, neutral_landmarks):
    rot = Rotation.from_euler("xyz", [25, -40, 70], degrees=True).as_matrix()
    shift = np.array([0.3, -1.2, 0.7])
    moved = neutral_face.with_vertices(neutral_face.vertices @ rot.T + shift)
    got = find_landmarks(moved)
    want = neutral_landmarks.transformed(rot, shift)
    for name in LANDMARK_NAMES:
        np.testing.assert_allclose(getattr(got, name), getattr(want, name), atol=1e-3, err_msg=name)
    np.testing.assert_allclose(got.up, want.up, atol=1e-3)
    np.testing.assert_allclose(got.forward, want.forward, atol=1e-3)


def test_explicit_axes_are_used(neutral_face):
    lm = find_landmarks(neutral_face, forward=[0, 0, 1], up=[0, 1, 0])
    np.testing.assert_allclose(lm.forward, [0, 0, 1])
    np.testing.assert_allclose(lm.up, [0, 1, 0])
    assert lm.chin[1] < lm.subnasale[1] < lm.nose_tip[1] < lm.nasion[1]


def test_a_sphere_is_not_a_face():
    with pytest.raises(MeshError, match="does not look like a face"):
        find_landmarks(icosphere(0.1, 3))


def test_a_half_sphere_has_no_nose():
    s = icosphere(0.1, 4)
    keep = np.flatnonzero(s.vertices[:, 2] > -0.02)
    half, _ = s.submesh(keep)
    with pytest.raises(MeshError, match="no face found"):
        find_landmarks(half)


def test_a_two_metre_face_is_refused(neutral_face):
    with pytest.raises(UnitsError, match="plausible range"):
        find_landmarks(neutral_face.scaled(10.0))


def test_section_points_lie_on_the_plane_and_the_mesh(neutral_face):
    pts = plane_section_points(neutral_face.vertices, neutral_face.triangles, np.zeros(3), np.array([1.0, 0, 0]))
    assert len(pts) > 100
    np.testing.assert_allclose(pts[:, 0], 0.0, atol=1e-12)
    # a plane missing the mesh gives nothing
    far = plane_section_points(neutral_face.vertices, neutral_face.triangles, np.array([5.0, 0, 0]),
                               np.array([1.0, 0, 0]))
    assert far.shape == (0, 3)


def test_section_segments_match_the_reference(neutral_face):
    from headsim.mask._reference import plane_section_reference
    from headsim.mask.landmarks import plane_section_segments

    point, normal = np.array([0.003, 0.01, 0.1]), np.array([0.2, 1.0, 0.1])
    got = plane_section_segments(neutral_face.vertices, neutral_face.triangles, point, normal)
    want = np.array(plane_section_reference(neutral_face.vertices, neutral_face.triangles, point, normal))
    assert got.shape == want.shape and len(got) > 50
    np.testing.assert_allclose(np.sort(got.reshape(len(got), 6), axis=0), np.sort(want.reshape(len(want), 6), axis=0),
                               atol=1e-12)


def test_whole_head_scan_with_a_given_forward_axis(neutral_landmarks):
    """The bundled whole head (face + scalp, nearly closed) is refused without axes; with
    forward given, its landmarks agree with the face-only mesh's (same skin)."""
    from headsim.data import head_path
    from headsim.mesh.io import load_surface

    head = load_surface(head_path())
    with pytest.raises(MeshError, match="whole-head"):
        find_landmarks(head)
    lm = find_landmarks(head, forward=[0, 0, 1])
    for name in LANDMARK_NAMES:
        assert np.linalg.norm(getattr(lm, name) - getattr(neutral_landmarks, name)) < 3e-3, name


def test_noise_and_refinement_barely_move_the_landmarks(neutral_face, neutral_landmarks):
    from headsim.mesh.subdivide import subdivide_loop

    rng = np.random.default_rng(0)
    noisy = neutral_face.with_vertices(neutral_face.vertices + rng.normal(0, 0.3e-3, neutral_face.vertices.shape))
    for variant in (noisy, subdivide_loop(neutral_face)):
        lm = find_landmarks(variant)
        for name in LANDMARK_NAMES:
            assert np.linalg.norm(getattr(lm, name) - getattr(neutral_landmarks, name)) < 3e-3, name
