"""Cushion contouring (headsim.mask.contour): the edge follows the reference face up to the smoothing."""

import numpy as np
import pytest

from headsim.errors import ParameterError
from headsim.mask import make_mask
from headsim.mask.contour import _fourier_fit, bundled_contours, contour_correction
from headsim.mask.masks import _stored_contours, design_of, edge_correction_at


def _fourier_residual(phi, values, harmonics):
    a, b = _fourier_fit(phi, values, harmonics)
    from dataclasses import replace

    fitted = edge_correction_at(replace(design_of("nasal", contour=False), edge_correction=(a, b)), phi)
    return values - fitted


@pytest.mark.parametrize("kind", ["nasal", "oronasal"])
def test_contour_leaves_exactly_the_smoothing_residual(kind, neutral_face, neutral_landmarks):
    """Gaps are measured along the approach axis, the mask's z axis, so moving each section by the
    smoothed correction must leave, section by section, exactly what the Fourier fit did not capture
    (the rays, the skin hits and the placement's lateral position do not change)."""
    harmonics = 12
    c = contour_correction(kind, neutral_face, neutral_landmarks, harmonics=harmonics)
    expected = _fourier_residual(c.phi, c.gap_before, harmonics)
    expected -= expected.min()
    np.testing.assert_allclose(c.residual, expected, atol=1e-6)
    assert c.spread_after < c.spread_before


def test_more_harmonics_follow_the_face_closer(neutral_face, neutral_landmarks):
    spreads = [contour_correction("nasal", neutral_face, neutral_landmarks, harmonics=k).spread_after
               for k in (4, 8, 16)]
    assert spreads[0] > spreads[1] > spreads[2]


def test_stored_contours_are_reproduced():
    """The coefficients shipped with the package are what `python -m headsim.mask.contour --write`
    computes from the bundled mean face."""
    stored = _stored_contours()
    fresh = bundled_contours(harmonics=stored["nasal"]["harmonics"])
    for kind in ("nasal", "oronasal"):
        np.testing.assert_allclose(stored[kind]["a"], fresh[kind]["a"], atol=1e-9)
        np.testing.assert_allclose(stored[kind]["b"], fresh[kind]["b"], atol=1e-9)


def test_symmetric_face_gives_a_symmetric_edge():
    """The mean face is left-right symmetric, so the correction is even in x (x -> -x is
    phi -> pi - phi): the terms that change sign under it, cos k phi for odd k and sin k phi for even
    k, vanish next to the others."""
    for kind in ("nasal", "oronasal"):
        d = _stored_contours()[kind]
        a, b = np.asarray(d["a"]), np.asarray(d["b"])
        phi = np.linspace(-np.pi, np.pi, 361)
        corr = edge_correction_at(design_of(kind), phi)
        mirrored = edge_correction_at(design_of(kind), np.pi - phi)
        assert np.abs(corr - mirrored).max() < 0.02 * np.abs(corr).max()
        assert np.abs(a[1::2]).max() < 0.02 * np.abs(a).max()
        assert np.abs(b[2::2]).max() < 0.02 * np.abs(b[1::2]).max()


def test_make_mask_contour_switch():
    contoured, analytic = make_mask("nasal-M"), make_mask("nasal-M", contour=False)
    assert contoured.tetmesh.n_vertices == analytic.tetmesh.n_vertices
    dz = contoured.tetmesh.vertices[:, 2] - analytic.tetmesh.vertices[:, 2]
    assert np.abs(dz).max() > 1e-3                     # the edge moved by millimetres
    np.testing.assert_allclose(contoured.tetmesh.vertices[:, :2], analytic.tetmesh.vertices[:, :2])


def test_bad_arguments(neutral_face):
    with pytest.raises(ParameterError):
        contour_correction("nasal", neutral_face, harmonics=0)
    with pytest.raises(ParameterError):
        design_of("full-face")
