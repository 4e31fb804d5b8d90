"""Automatic placement: centred on the airway, along the approach axis, 2 cm off the skin."""

import numpy as np
import pytest

from headsim.collide import TriangleBVH
from headsim.errors import ParameterError
from headsim.mask import airway_point, gaps_along, make_mask, place_mask


@pytest.fixture(scope="module")
def face_bvh(neutral_face):
    return TriangleBVH(neutral_face.vertices, neutral_face.triangles)


@pytest.mark.parametrize("name", ["nasal-M", "oronasal-L"])
def test_auto_placement(name, neutral_face, neutral_landmarks, face_bvh):
    lm = neutral_landmarks
    mask = make_mask(name)
    pl = place_mask(mask, neutral_face, lm, standoff=0.02, face_bvh=face_bvh)
    placed = pl.mask
    # axis along the approach (into the face), roll matches the face's up
    np.testing.assert_allclose(placed.airway_axis, -lm.forward, atol=1e-12)
    np.testing.assert_allclose(placed.up, lm.up, atol=1e-12)
    np.testing.assert_allclose(pl.rotation @ pl.rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(pl.rotation) == pytest.approx(1.0)
    # the airway centre lies on the approach line through the face's airway point, in front of it
    target = airway_point(lm, mask.kind)
    offset = placed.airway_center - target
    np.testing.assert_allclose(offset - (offset @ lm.forward) * lm.forward, 0.0, atol=1e-9)
    assert offset @ lm.forward > 0
    # the smallest gap along the approach axis is the stand-off, measured independently here
    gaps = gaps_along(placed.tetmesh.vertices[placed.contact_vertices], face_bvh, pl.approach)
    assert np.nanmin(gaps) == pytest.approx(0.02, abs=1e-9)
    assert pl.min_gap == pytest.approx(0.02, abs=1e-9)
    # rigid motion: edge lengths unchanged
    e = mask.tetmesh.edges
    d0 = np.linalg.norm(np.diff(mask.tetmesh.vertices[e], axis=1), axis=2)
    d1 = np.linalg.norm(np.diff(placed.tetmesh.vertices[e], axis=1), axis=2)
    np.testing.assert_allclose(d0, d1, atol=1e-12)


def test_nasal_mask_surrounds_the_nose(neutral_face, neutral_landmarks, face_bvh):
    lm = neutral_landmarks
    placed = place_mask(make_mask("nasal-M"), neutral_face, lm, face_bvh=face_bvh).mask
    v = placed.tetmesh.vertices
    u = (v - lm.nose_tip) @ lm.up
    x = (v - lm.nose_tip) @ lm.lateral
    assert u.max() > (lm.nasion - lm.nose_tip) @ lm.up - 25e-3      # reaches up to the bridge
    assert u.min() < (lm.subnasale - lm.nose_tip) @ lm.up            # below the nostrils
    assert u.min() > (lm.stomion - lm.nose_tip) @ lm.up              # above the mouth
    assert x.max() > (lm.ala_left - lm.nose_tip) @ lm.lateral        # beyond the alae
    assert x.min() < (lm.ala_right - lm.nose_tip) @ lm.lateral


def test_as_is_keeps_the_pose_and_allows_overlap(neutral_face, neutral_landmarks, face_bvh):
    auto = place_mask(make_mask("nasal-M"), neutral_face, neutral_landmarks, standoff=0.0, face_bvh=face_bvh)
    pushed = auto.mask.transformed(np.eye(3), -5e-3 * neutral_landmarks.forward)   # 5 mm into the face
    kept = place_mask(pushed, neutral_face, placement="as-is", face_bvh=face_bvh)
    np.testing.assert_array_equal(kept.mask.tetmesh.vertices, pushed.tetmesh.vertices)
    assert kept.min_gap == pytest.approx(-5e-3, abs=1e-9)


def test_a_mask_far_away_cannot_be_kept_as_is(neutral_face, face_bvh):
    with pytest.raises(ParameterError, match="not in front of"):
        place_mask(make_mask("nasal-M").transformed(np.eye(3), [1.0, 0, 0]), neutral_face,
                   placement="as-is", face_bvh=face_bvh)


def test_a_mask_larger_than_the_face_cannot_be_placed(neutral_face, neutral_landmarks, face_bvh):
    from headsim.mask import build_parametric_mask
    from headsim.mask.masks import _DESIGNS

    huge = build_parametric_mask(_DESIGNS["oronasal"], scale=2.0, edge_length=5e-3)
    with pytest.raises(ParameterError, match="too large for this face"):
        place_mask(huge, neutral_face, neutral_landmarks, face_bvh=face_bvh)


def test_bad_options(neutral_face, neutral_landmarks, face_bvh):
    m = make_mask("nasal-S")
    with pytest.raises(ParameterError):
        place_mask(m, neutral_face, neutral_landmarks, placement="magic", face_bvh=face_bvh)
    with pytest.raises(ParameterError):
        place_mask(m, neutral_face, neutral_landmarks, standoff=-0.01, face_bvh=face_bvh)


def test_skin_cushion_gap(neutral_face, neutral_landmarks, face_bvh):
    from headsim.mask import skin_cushion_gap

    lm = neutral_landmarks
    pl = place_mask(make_mask("nasal-M"), neutral_face, lm, standoff=0.02, face_bvh=face_bvh)
    gap = skin_cushion_gap(neutral_face, pl.mask)
    under = np.isfinite(gap)
    assert 100 < under.sum() < neutral_face.n_vertices / 4          # only skin under the cushion
    # sampled at face vertices instead of mask vertices: within a millimetre of the stand-off
    assert 0.019 < gap[under].min() < 0.021
    # moving the mask 5 mm towards the face shortens every gap by exactly 5 mm
    closer = pl.mask.transformed(np.eye(3), -5e-3 * lm.forward)
    gap2 = skin_cushion_gap(neutral_face, closer)
    np.testing.assert_allclose(gap2[under], gap[under] - 5e-3, atol=1e-9)
